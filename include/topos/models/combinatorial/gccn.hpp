// topos/models/combinatorial/gccn.hpp
// GCCN (TopoTune's generalized combinatorial complex network): per layer, one GNN per route
// (a neighbourhood of TopoTune's vocabulary, topobench/routes.hpp), each PyG's BasicGNN of
// `gnn_layers` convolutions (GCN, GIN, GraphSAGE or GAT) with BatchNorm, relu and dropout between
// them; the routes into a rank summed, then the activation: x_r <- act(Σ_{routes into r} GNN(...)).
// A rank no route reaches keeps its features.
//
// An intra-rank route (adjacency, Laplacian) runs its GNN on the graph of its operator's pattern.
// An inter-rank route (incidence) runs it on the union graph of the two ranks' cells, the target
// cells first with zero features, the source cells after them, an edge from each source cell to
// each target cell it reaches; the GNN's output on the target cells is the route's (TopoTune's
// interrank_expand and interrank_gnn_forward; its BatchNorm's statistics are those of the union's
// rows, the schedule's batch_norm over a union). The operators are the lifted graph's of the
// neighbourhoods' names (topobench/lifting.hpp), target × source. Parameters are named as the
// PyTorch model's state_dict: graph_routes.<layer>.<route>.convs.<j>.lin.weight, ... (PyG), and
// initialised as PyG initialises them (GCNConv's and GATConv's `lin` Glorot, their biases zero;
// GIN's MLP and SAGEConv's lins torch.nn.Linear's).
// Written as an operator schedule (gccn_schedule).
#pragma once

#include "topos/models/topobench/routes.hpp"
#include "topos/nn/operator_schedule.hpp"

#include <algorithm>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

namespace topos::models {

/// The GNN each route runs: PyG's GCN (GCNConv), GIN (GINConv, ε = 0, MLP of two Linear layers
/// with the norm between them), GraphSAGE (SAGEConv, mean aggregation, root weight) or GAT
/// (GATConv: `gat_heads` heads, concatenated in the hidden convolutions of channels / heads each,
/// averaged in the last of `channels` each, as BasicGNN's GAT with out_channels; self-loops,
/// LeakyReLU 0.2, attention dropout `gnn_dropout` as BasicGNN passes its dropout).
enum class GccnGnn { gcn, gin, sage, gat };

inline GccnGnn gccn_gnn(const std::string& name) {
  if (name == "GCN") return GccnGnn::gcn;
  if (name == "GIN") return GccnGnn::gin;
  if (name == "GraphSAGE" || name == "SAGE") return GccnGnn::sage;
  if (name == "GAT") return GccnGnn::gat;
  throw std::invalid_argument("GCCN: unknown GNN '" + name + "' (known: GCN, GIN, GraphSAGE, GAT)");
}

struct GCCNOptions {
  GCCNOptions(std::int64_t channels, std::vector<std::string> neighborhoods)
      : channels_(channels), neighborhoods_(std::move(neighborhoods)) {}
  TORCH_ARG(std::int64_t, channels);  ///< every width (TopoTune: in = hidden = out)
  TORCH_ARG(std::vector<std::string>, neighborhoods);  ///< the routes, in order
  TORCH_ARG(GccnGnn, gnn) = GccnGnn::gcn;
  TORCH_ARG(int, gnn_layers) = 2;          ///< convolutions per GNN (PyG's num_layers)
  TORCH_ARG(int, n_layers) = 2;            ///< GCCN layers (TopoTune's `layers`)
  TORCH_ARG(bool, batch_norm) = true;      ///< PyG's norm="BatchNorm" (else no norm)
  TORCH_ARG(double, gnn_dropout) = 0;      ///< PyG's dropout after each inner convolution
  TORCH_ARG(std::int64_t, gat_heads) = 1;  ///< GAT's heads (PyG's `heads`)
  TORCH_ARG(nn::Activation, activation) = nn::Activation::relu;
};

/// The ranks a GCCN reads and writes: 0 .. the highest rank of its routes.
inline int gccn_max_rank(const GCCNOptions& o) {
  int top = 0;
  for (const auto& name : o.neighborhoods()) {
    const auto r = topobench::neighborhood_route(name);
    top = std::max({top, r.source_rank(), r.target_rank()});
  }
  return top;
}

namespace detail {

/// One convolution's propagation and own-row part on the cells `at`, before its norm: reads the
/// route graph's features `prev` (intra) or the union's target and source parts.
struct GccnConv {
  const GCCNOptions& o;
  std::string op, p;  // operator, parameter prefix of convolution j
  bool last;          // the GNN's last convolution (GAT: heads averaged)
  /// GCNConv's or GATConv's `lin` (Glorot, no bias) on a term: GAT's last convolution maps to
  /// heads × channels, its hidden ones to channels (heads × channels / heads).
  nn::ops::Term lin(nn::ops::Term t) const {
    const auto w = o.gnn() == GccnGnn::gat && last ? o.gat_heads() * o.channels() : o.channels();
    return std::move(t.linear(p + "lin", w, false, nn::LinearInit::glorot));
  }
  nn::ops::Term gat(nn::ops::Term t, nn::GatPart part,
                    std::optional<nn::CochainKey> targets = std::nullopt) const {
    return std::move(lin(std::move(t))
                         .gat(op, p.substr(0, p.size() - 1),
                              nn::GatOptions()
                                  .heads(o.gat_heads())
                                  .concat(!last)
                                  .dropout(o.gnn_dropout())
                                  .part(part)
                                  .targets(std::move(targets))));
  }
  /// An intra-rank convolution of `prev` over the pattern of `op`.
  nn::OperatorStep intra(const nn::CochainKey& into_key, const nn::CochainKey& prev) const {
    using namespace nn::ops;
    const auto c = o.channels();
    auto from_prev = [&] { return from(prev.rank, prev.state); };
    auto s = into(into_key.rank, into_key.state);
    switch (o.gnn()) {
      case GccnGnn::gcn:
        return s.sum(lin(from_prev()).gcn(op)).bias(p + "bias");
      case GccnGnn::gat:
        return s.sum(gat(from_prev(), nn::GatPart::graph)).bias(p + "bias");
      case GccnGnn::gin:  // GINConv's sum over the neighbours plus (1 + ε) x, ε = 0
        return s.sum(from_prev().pattern(op), from_prev());
      case GccnGnn::sage:
        return s.sum(from_prev().pattern(op, nn::Aggr::mean).linear(p + "lin_l", c),
                     from_prev().linear(p + "lin_r", c, false));
    }
    return s;
  }
  /// The union graph's target part (`first`: its features are zero, the term left out). GAT's
  /// `t` is GATConv's lin of the targets' features, which its attention reads.
  nn::OperatorStep targets(const nn::CochainKey& into_key, const nn::CochainKey& t,
                           const nn::CochainKey& src, bool first) const {
    using namespace nn::ops;
    const auto c = o.channels();
    std::vector<nn::ops::Term> terms;
    auto s = into(into_key.rank, into_key.state);
    switch (o.gnn()) {
      case GccnGnn::gcn:
        terms.push_back(lin(from(src.rank, src.state)).gcn(op, nn::GcnPart::union_sources));
        if (!first) terms.push_back(lin(from(t.rank, t.state)).gcn(op, nn::GcnPart::union_targets));
        return s.sum(std::move(terms)).bias(p + "bias");
      case GccnGnn::gat:
        return s
            .sum(gat(from(src.rank, src.state), nn::GatPart::union_targets,
                     first ? std::nullopt : std::optional<nn::CochainKey>(t)))
            .bias(p + "bias");
      case GccnGnn::gin:
        terms.push_back(from(src.rank, src.state).pattern(op));
        if (!first) terms.push_back(from(t.rank, t.state));
        return s.sum(std::move(terms));
      case GccnGnn::sage:
        terms.push_back(
            from(src.rank, src.state).pattern(op, nn::Aggr::mean).linear(p + "lin_l", c));
        if (!first) terms.push_back(from(t.rank, t.state).linear(p + "lin_r", c, false));
        return s.sum(std::move(terms));
    }
    return s;
  }
  /// The union graph's source part: a source cell's only incoming edge is its self-loop.
  nn::OperatorStep sources(const nn::CochainKey& into_key, const nn::CochainKey& src) const {
    using namespace nn::ops;
    const auto c = o.channels();
    auto s = into(into_key.rank, into_key.state);
    switch (o.gnn()) {
      case GccnGnn::gcn:
        return s.sum(lin(from(src.rank, src.state))).bias(p + "bias");
      case GccnGnn::gat:  // its self-loop alone: weight 1 (dropped out in training)
        return s.sum(gat(from(src.rank, src.state), nn::GatPart::union_sources)).bias(p + "bias");
      case GccnGnn::gin:
        return s.sum(from(src.rank, src.state));
      case GccnGnn::sage:  // lin_l of an empty mean (0): its bias
        return s.sum(from(src.rank, src.state).linear(p + "lin_r", c, false))
            .bias(p + "lin_l.bias");
    }
    return s;
  }
};

}  // namespace detail

inline nn::OperatorSchedule gccn_schedule(const GCCNOptions& o) {
  using namespace nn::ops;
  using nn::CochainKey;
  const auto c = o.channels();
  const int J = o.gnn_layers();
  if (o.neighborhoods().empty()) throw std::invalid_argument("GCCN: no neighbourhoods");
  if (c < 1 || J < 1 || o.n_layers() < 1)
    throw std::invalid_argument("GCCN: channels, gnn_layers and n_layers must be positive");
  if (o.gnn() == GccnGnn::gat && (o.gat_heads() < 1 || c % o.gat_heads()))
    throw std::invalid_argument("GCCN: GAT's " + std::to_string(o.gat_heads()) +
                                " heads must divide the " + std::to_string(c) +
                                " channels (PyG's BasicGNN GAT splits them among the heads)");
  const int top = gccn_max_rank(o);
  nn::OperatorSchedule s;
  for (int r = 0; r <= top; ++r) s.input("x_" + std::to_string(r), r, c);
  std::vector<topobench::NeighborhoodRoute> routes;
  for (const auto& name : o.neighborhoods()) {
    routes.push_back(topobench::neighborhood_route(name));
    if (!s.operators().count(name))
      s.operator_input(name, routes.back().source_rank(), routes.back().target_rank());
  }
  // After convolution j < J - 1: the norm (over `union_of` when the GNN runs on a union graph),
  // relu, dropout.
  const auto between = [&](nn::OperatorStep step, const std::string& norm,
                           const std::vector<CochainKey>& union_of, std::size_t part) {
    if (o.batch_norm()) {
      if (union_of.empty())
        step.batch_norm(norm);
      else
        step.batch_norm(norm, union_of, part);
    }
    step.act(nn::Activation::relu);
    if (o.gnn_dropout() > 0) step.dropout(o.gnn_dropout());
    return step;
  };
  // GIN's MLP after its sum: Linear, norm (over the union), relu, Linear.
  const auto gin_mlp = [&](nn::OperatorSchedule& sch, const std::string& p, const CochainKey& sum,
                           const std::vector<CochainKey>& union_of, std::size_t part,
                           const CochainKey& out) {
    auto step = into(out.rank, out.state).sum(from(sum.rank, sum.state));
    if (o.batch_norm()) {
      if (union_of.empty())
        step.batch_norm(p + "nn.norms.0.module");
      else
        step.batch_norm(p + "nn.norms.0.module", union_of, part);
    }
    sch.step(step.act(nn::Activation::relu).linear(p + "nn.lins.1", c));
  };
  for (int l = 0; l < o.n_layers(); ++l) {
    s.layer("layer_" + std::to_string(l));
    std::vector<std::vector<nn::ops::Term>> into_rank(static_cast<std::size_t>(top) + 1);
    for (std::size_t i = 0; i < routes.size(); ++i) {
      const auto& route = routes[i];
      const int src = route.source_rank(), dst = route.target_rank();
      const std::string& op = o.neighborhoods()[i];
      const std::string g = "graph_routes." + std::to_string(l) + "." + std::to_string(i) + ".";
      const std::string tag = "l" + std::to_string(l) + "_r" + std::to_string(i) + "_";
      const auto key = [&](int rank, const std::string& what, int j) {
        return CochainKey{rank, tag + what + std::to_string(j)};
      };
      CochainKey out;
      if (src == dst) {
        CochainKey prev{src, ""};
        for (int j = 0; j < J; ++j) {
          const std::string p = g + "convs." + std::to_string(j) + ".";
          const detail::GccnConv conv{o, op, p, j == J - 1};
          const bool gin = o.gnn() == GccnGnn::gin;
          CochainKey pre = key(src, "pre", j);
          s.step(conv.intra(gin ? key(src, "gin", j) : pre, prev));
          if (gin) {
            s.step(into(src, tag + "ginl" + std::to_string(j))
                       .sum(from(src, tag + "gin" + std::to_string(j)))
                       .linear(p + "nn.lins.0", c));
            gin_mlp(s, p, key(src, "ginl", j), {}, 0, pre);
          }
          if (j == J - 1) {
            out = pre;
            break;
          }
          const auto next = key(src, "h", j);
          s.step(between(into(next.rank, next.state).sum(from(pre.rank, pre.state)),
                         g + "norms." + std::to_string(j) + ".module", {}, 0));
          prev = next;
        }
      } else {
        CochainKey t{dst, ""}, sc{src, ""};  // t unused while the targets are zero (j = 0)
        for (int j = 0; j < J; ++j) {
          const std::string p = g + "convs." + std::to_string(j) + ".";
          const bool last = j == J - 1;
          const detail::GccnConv conv{o, op, p, last};
          const CochainKey pt = key(dst, "pt", j), ps = key(src, "ps", j);
          if (o.gnn() == GccnGnn::gin) {
            // Sum, then the MLP's first Linear on both parts, its norm over the union.
            const CochainKey st = key(dst, "gt", j), ss = key(src, "gs", j);
            const CochainKey lt = key(dst, "lt", j), ls = key(src, "ls", j);
            s.step(conv.targets(st, t, sc, j == 0));
            s.step(conv.sources(ss, sc));
            s.step(into(lt.rank, lt.state).sum(from(st.rank, st.state)).linear(p + "nn.lins.0", c));
            s.step(into(ls.rank, ls.state).sum(from(ss.rank, ss.state)).linear(p + "nn.lins.0", c));
            gin_mlp(s, p, lt, {lt, ls}, 0, pt);
            if (!last) gin_mlp(s, p, ls, {lt, ls}, 1, ps);
          } else if (o.gnn() == GccnGnn::gat) {
            const CochainKey lt = key(dst, "lt", j);  // lin of the targets, for their scores
            if (j > 0) s.step(into(lt.rank, lt.state).sum(conv.lin(from(t.rank, t.state))));
            s.step(conv.targets(pt, lt, sc, j == 0));
            if (!last) s.step(conv.sources(ps, sc));
          } else {
            s.step(conv.targets(pt, t, sc, j == 0));
            if (!last) s.step(conv.sources(ps, sc));
          }
          if (last) {
            out = pt;
            break;
          }
          const std::string norm = g + "norms." + std::to_string(j) + ".module";
          const auto nt = key(dst, "ht", j), ns = key(src, "hs", j);
          s.step(between(into(nt.rank, nt.state).sum(from(pt.rank, pt.state)), norm, {pt, ps}, 0));
          s.step(between(into(ns.rank, ns.state).sum(from(ps.rank, ps.state)), norm, {pt, ps}, 1));
          t = nt, sc = ns;
        }
      }
      into_rank[static_cast<std::size_t>(dst)].push_back(from(out.rank, out.state));
    }
    for (int r = 0; r <= top; ++r)
      if (!into_rank[static_cast<std::size_t>(r)].empty())
        s.step(into(r).sum(std::move(into_rank[static_cast<std::size_t>(r)])).act(o.activation()));
  }
  for (int r = 0; r <= top; ++r) s.output("x_" + std::to_string(r), r);
  return s;
}

}  // namespace topos::models
