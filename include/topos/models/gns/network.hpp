// topos/models/gns/network.hpp
// Encode-process-decode graph networks (Battaglia et al. 2018; MeshGraphNet, FIGNet) written as
// operator schedules. A GraphNetworkSpec names typed node sets and edge sets; the schedule
// encodes each set's raw features with an MLP, runs `steps` Graph-Network blocks with unshared
// weights, and decodes the node sets that have a decoder. One block reads one snapshot:
//   edge sets:  m_e = φ_e([e, x_sender, x_receiver])      (a hyperedge with k slots: the
//               interleaved [e_0, s_0, r_0, e_1, s_1, r_1, ...] and k messages of width L)
//   node sets:  u_v = φ_v([x_v, Σ_{e→v} m_e per incoming edge set, in the spec's edge order])
//   then        e ← e + m_e,  x_v ← x_v + u_v             (the messages aggregated pre-residual)
// Sender and receiver gathers and the receivers' sums are sparse operators ("<edges>.senders",
// "<edges>.receivers", suffixed with the slot when there are several). Parameter names follow
// the FIGNet reimplementation's modules (encoder.mlp.0.NN-i, its LayerNorm encoder.mlp.1,
// <processor>.<k>.<fn>.0.NN-i and .1, decoder.node_fn.NN-i), so its state dict maps one to one.
#pragma once

#include "topos/models/namespace_aliases.hpp"
#include "topos/nn/operator_schedule.hpp"
#include "topos/sim/graph_frame.hpp"

#include <set>

namespace topos::models::gns {

// The timestep the networks read is the simulation layer's (topos/sim/graph_frame.hpp).
using sim::EdgeSetData;
using sim::GraphFrame;
using sim::IndexMatrix;
using sim::NodeSetData;
using sim::RowMatrix;

struct NodeSetSpec {
  std::string name;           ///< the input and output name, and the GraphFrame node set
  std::int64_t features = 0;  ///< raw feature columns
  std::string encoder;        ///< module path of the encoder MLP
  std::string update;         ///< name of the per-block node MLP
  std::string decoder;        ///< module path of the decoder MLP; empty: not decoded
  std::int64_t outputs = 0;   ///< decoder width
  std::string statistics;     ///< normalisation key of the raw features (sets may share one)
};

struct EdgeSetSpec {
  std::string name, sender, receiver;  ///< the edge set and its node sets
  std::int64_t features = 0;
  int slots = 1;  ///< a hyperedge's sender/receiver pairs (FIGNet's face-face edges: 3)
  std::string encoder, update, statistics;
};

struct GraphNetworkSpec {
  std::vector<NodeSetSpec> nodes;
  std::vector<EdgeSetSpec> edges;
  std::int64_t latent = 128;  ///< latent width, also the MLPs' hidden width
  int steps = 10;             ///< message-passing blocks, weights unshared
  int hidden_layers = 2;      ///< hidden layers per MLP (3 Linear layers for 2)
  std::string processor = "_processor.gnn_stacks";  ///< block k's MLPs at <processor>.<k>.<fn>

  int rank_of(const std::string& set) const {
    for (std::size_t i = 0; i < nodes.size(); ++i)
      if (nodes[i].name == set) return static_cast<int>(i);
    for (std::size_t i = 0; i < edges.size(); ++i)
      if (edges[i].name == set) return static_cast<int>(nodes.size() + i);
    throw std::invalid_argument("graph network: no node or edge set '" + set + "'");
  }
  /// Checks names, widths and references; throws std::invalid_argument naming the set.
  void validate() const {
    std::set<std::string> names;
    auto fresh = [&](const std::string& n, const char* what) {
      if (n.empty())
        throw std::invalid_argument(std::string("graph network: a ") + what + " set has no name");
      if (!names.insert(n).second)
        throw std::invalid_argument("graph network: set name '" + n + "' is used twice");
    };
    if (latent <= 0 || steps < 0 || hidden_layers < 0)
      throw std::invalid_argument(
          "graph network: latent must be positive, steps and "
          "hidden_layers not negative");
    if (nodes.empty()) throw std::invalid_argument("graph network: no node set");
    for (const auto& n : nodes) {
      fresh(n.name, "node");
      if (n.features <= 0 || n.encoder.empty() || n.update.empty() || n.statistics.empty())
        throw std::invalid_argument("graph network: node set '" + n.name +
                                    "' needs features, an encoder, an update and statistics");
      if (!n.decoder.empty() && n.outputs <= 0)
        throw std::invalid_argument("graph network: node set '" + n.name +
                                    "' has a decoder but no outputs");
    }
    for (const auto& e : edges) {
      fresh(e.name, "edge");
      if (e.features <= 0 || e.slots < 1 || e.encoder.empty() || e.update.empty() ||
          e.statistics.empty())
        throw std::invalid_argument("graph network: edge set '" + e.name +
                                    "' needs features, slots >= 1, an encoder, an update and "
                                    "statistics");
      for (const auto* end : {&e.sender, &e.receiver}) {
        const bool found = std::any_of(nodes.begin(), nodes.end(),
                                       [&](const NodeSetSpec& n) { return n.name == *end; });
        if (!found)
          throw std::invalid_argument("graph network: edge set '" + e.name + "' names node set '" +
                                      *end + "', which does not exist");
      }
    }
  }
};

/// The name of edge set `e`'s sender or receiver operator for `slot`.
inline std::string gather_operator(const EdgeSetSpec& e, bool sender, int slot) {
  return e.name + (sender ? ".senders" : ".receivers") + (e.slots > 1 ? std::to_string(slot) : "");
}

/// Columns [begin, begin + width) of a term: slot k of a hyperedge's latent or messages.
class Columns final : public nn::Operation {
 public:
  Columns(std::int64_t begin, std::int64_t width) : begin_(begin), width_(width) {}
  std::string str(const std::string& x) const override {
    return x + "[" + std::to_string(begin_) + ":" + std::to_string(begin_ + width_) + "]";
  }
  nn::TermShape infer(nn::BuildContext& ctx, nn::TermShape x) const override {
    if (begin_ < 0 || width_ <= 0 || begin_ + width_ > x.channels)
      ctx.fail("columns " + std::to_string(begin_) + ":" + std::to_string(begin_ + width_) +
               " of a term with " + std::to_string(x.channels) + " channels");
    return {x.rank, width_};
  }
  torch::Tensor forward(nn::RunContext&, const torch::Tensor& x) const override {
    return x.narrow(-1, begin_, width_);
  }

 private:
  std::int64_t begin_, width_;
};

namespace detail {
/// Linear layers at <prefix>i (i = 0..hidden), ReLU between them, none after the last.
template <class Chain>
Chain& mlp(Chain& c, const std::string& prefix, const GraphNetworkSpec& s, std::int64_t out) {
  for (int i = 0; i <= s.hidden_layers; ++i) {
    if (i > 0) c.act(nn::Activation::relu);
    c.linear(prefix + std::to_string(i), i == s.hidden_layers ? out : s.latent);
  }
  return c;
}
}  // namespace detail

/// The schedule of `spec`: inputs and outputs named by the sets, operators named by
/// gather_operator. Latent cochains are (rank of the set, ""); raw features (rank, "features").
inline nn::OperatorSchedule graph_network_schedule(const GraphNetworkSpec& spec) {
  using namespace nn::ops;
  spec.validate();
  const std::int64_t L = spec.latent;
  nn::OperatorSchedule s;
  for (const auto& n : spec.nodes) s.input(n.name, spec.rank_of(n.name), n.features, "features");
  for (const auto& e : spec.edges) {
    const int r = spec.rank_of(e.name);
    s.input(e.name, r, e.features, "features");
    for (int k = 0; k < e.slots; ++k) {
      s.operator_input(gather_operator(e, true, k), spec.rank_of(e.sender), r);
      s.operator_input(gather_operator(e, false, k), spec.rank_of(e.receiver), r);
    }
  }
  // Encoders: Linear..., then LayerNorm, in the reference's module layout.
  s.layer("encode");
  std::vector<nn::OperatorStep> encoders;
  auto encode = [&](int r, const std::string& path, std::int64_t out) {
    auto step = into(r).sum(from(r, "features"));
    detail::mlp(step, path + ".mlp.0.NN-", spec, out).layer_norm(path + ".mlp.1");
    encoders.push_back(step.named(path));
  };
  for (const auto& n : spec.nodes) encode(spec.rank_of(n.name), n.encoder, L);
  for (const auto& e : spec.edges) encode(spec.rank_of(e.name), e.encoder, e.slots * L);
  s.parallel(std::move(encoders));

  for (int k = 0; k < spec.steps; ++k) {
    s.layer("block " + std::to_string(k));
    const std::string block = spec.processor + "." + std::to_string(k) + ".";
    auto mlp_ln = [&](nn::OperatorStep& step, const std::string& fn, std::int64_t out) {
      detail::mlp(step, block + fn + ".0.NN-", spec, out).layer_norm(block + fn + ".1");
    };
    // Edge messages from the snapshot.
    std::vector<nn::OperatorStep> messages;
    for (const auto& e : spec.edges) {
      const int r = spec.rank_of(e.name), rs = spec.rank_of(e.sender),
                rr = spec.rank_of(e.receiver);
      std::vector<Term> terms;
      for (int j = 0; j < e.slots; ++j) {
        terms.push_back(e.slots > 1 ? from(r).apply(Columns(j * L, L)) : from(r));
        terms.push_back(from(rs).via(gather_operator(e, true, j)));
        terms.push_back(from(rr).via(gather_operator(e, false, j)));
      }
      auto step = into(r, "message").concat(std::move(terms));
      mlp_ln(step, e.update, e.slots * L);
      messages.push_back(step.named(block + e.update));
    }
    if (!messages.empty()) s.parallel(std::move(messages));
    // Sums at the receivers: slot j of every hyperedge to its j-th receiver.
    std::vector<nn::OperatorStep> sums;
    for (const auto& e : spec.edges) {
      if (e.slots == 1) continue;
      const int r = spec.rank_of(e.name);
      std::vector<Term> terms;
      for (int j = 0; j < e.slots; ++j)
        terms.push_back(
            from(r, "message").apply(Columns(j * L, L)).via_t(gather_operator(e, false, j)));
      auto step = into(spec.rank_of(e.receiver), e.name + " sum").sum(std::move(terms));
      sums.push_back(step.named(block + e.name + " sum"));
    }
    if (!sums.empty()) s.parallel(std::move(sums));
    // Node updates from the snapshot and the incoming messages.
    std::vector<nn::OperatorStep> updates, residuals;
    for (const auto& n : spec.nodes) {
      const int r = spec.rank_of(n.name);
      std::vector<Term> terms{from(r)};
      for (const auto& e : spec.edges) {
        if (e.receiver != n.name) continue;
        terms.push_back(
            e.slots == 1 ? from(spec.rank_of(e.name), "message").via_t(gather_operator(e, false, 0))
                         : from(r, e.name + " sum"));
      }
      auto step = into(r, "update").concat(std::move(terms));
      mlp_ln(step, n.update, L);
      updates.push_back(step.named(block + n.update));
      residuals.push_back(into(r).sum(from(r), from(r, "update")).named(block + n.name + " +"));
    }
    s.parallel(std::move(updates));
    for (const auto& e : spec.edges) {
      const int r = spec.rank_of(e.name);
      residuals.push_back(into(r).sum(from(r), from(r, "message")).named(block + e.name + " +"));
    }
    s.parallel(std::move(residuals));
  }
  // Decoders: bare MLPs.
  s.layer("decode");
  std::vector<nn::OperatorStep> decoders;
  for (const auto& n : spec.nodes) {
    if (n.decoder.empty()) continue;
    const int r = spec.rank_of(n.name);
    auto step = into(r, "decoded").sum(from(r));
    detail::mlp(step, n.decoder + ".node_fn.NN-", spec, n.outputs);
    decoders.push_back(step.named(n.decoder));
    s.output(n.name, r, "decoded");
  }
  if (!decoders.empty()) s.parallel(std::move(decoders));
  return s;
}

}  // namespace topos::models::gns
