// topos/models/hypergraph/hmpnn.hpp
// HMPNN (Heydari & Livi, "Message passing neural networks for hypergraphs", 2022; TopoModelX
// HMPNN): linear maps of node and hyperedge features, then per layer node messages
// m_v = σ(Linear(x_v)), their sum (or mean) per hyperedge M_e, hyperedge messages
// m_e = σ(Linear([x_e || M_e])), their sum (or mean) per node M_v, and the updates
// x_v = σ(BN(x_v) + M_v), x_e = σ(BN(x_e) + M_e), with dropout of the incidence's entries and of
// the features in training. TopoModelX aggregates over the incidence's indices, so its adjacency
// dropout has no effect, and its feature dropout keeps an entry with probability p and rescales
// rows by (2n - kept in the row) / n; topomodelx_compatible reproduces both, the default drops
// incidence entries (one draw per layer, shared by both directions) and uses standard dropout.
// BatchNorm in eval mode uses the loaded running statistics. Parameters as TopoModelX's
// (linear_node, linear_edge, layers.<i>.*). Written as an operator schedule (hmpnn_schedule),
// with HMPNN's own operations DroppedPattern and RescaledDropout.
#pragma once

#include "topos/nn/operator_schedule.hpp"

#include <sstream>
#include <string>
#include <utility>

namespace topos::models {

/// Messages over an operator's sparsity pattern (or its transpose's), summed or averaged as
/// nn::pattern_aggregate, with each entry of the operator kept with probability 1 - rate in
/// training (all of them in evaluation, or with rate 0). The entries kept are drawn once per run
/// of the schedule and shared, through RunContext::scratch under `key`, by every operation naming
/// the key: both directions of HMPNN's incidence in a layer (B's entries for nodes to hyperedges
/// over Bᵀ and back over B). HMPNN's own operation, through the extension point.
struct DroppedPattern : nn::Operation {
  DroppedPattern(std::string op, std::string key, double rate, bool transposed = false,
                 nn::Aggr aggr = nn::Aggr::sum)
      : op(std::move(op)), key(std::move(key)), rate(rate), transposed(transposed), aggr(aggr) {}
  std::string op, key;
  double rate;
  bool transposed;
  nn::Aggr aggr;

  std::string name() const { return nn::operator_label(op, transposed); }
  std::string str(const std::string& x) const override {
    std::ostringstream o;
    o << nn::aggr_name(aggr) << "|" << name();
    if (rate > 0) o << " dropped " << rate << " [" << key << "]";
    o << "|·" << x;
    return o.str();
  }
  nn::TermShape infer(nn::BuildContext& ctx, nn::TermShape x) const override {
    const auto dst = ctx.operator_from(op, x.rank, transposed).second;
    if (!(rate >= 0 && rate <= 1))
      ctx.fail("the rate of dropped entries of '" + op + "' must be in [0, 1], got " +
               std::to_string(rate));
    if (rate > 0 && key.empty())
      ctx.fail("entries of '" + op + "' dropped need a key (the draw shared by the steps)");
    return {dst, x.channels};
  }
  torch::Tensor forward(nn::RunContext& ctx, const torch::Tensor& x) const override {
    if (!ctx.is_training() || rate == 0) {
      const auto& A = transposed ? ctx.op_transposed(op) : ctx.op(op);
      check(ctx, A, x);
      return nn::pattern_aggregate(A, x, aggr);
    }
    const auto& B = ctx.op(op);
    auto& mask = ctx.scratch(key);  // which of B's entries this run keeps
    if (!mask.defined()) mask = torch::rand({B.nnz()}) >= rate;
    if (mask.dim() != 1 || mask.size(0) != B.nnz())
      ctx.fail("the entries kept under '" + key + "' are " + std::to_string(mask.numel()) +
               ", operator '" + op + "' has " + std::to_string(B.nnz()));
    const auto keep = mask.nonzero().squeeze(1).to(B.row.device());
    const auto kept = nn::SparseOperator::from_sorted(
        B.rows, B.cols, nn::index_vector(B.row.index_select(0, keep)),
        nn::index_vector(B.col.index_select(0, keep)), B.values.index_select(0, keep));
    const auto A = transposed ? kept.t() : kept;
    check(ctx, A, x);
    return nn::pattern_aggregate(A, x, aggr);
  }

 private:
  void check(nn::RunContext& ctx, const nn::SparseOperator& A, const torch::Tensor& x) const {
    if (A.cols != x.size(0))
      ctx.fail("operator '" + name() + "' has " + std::to_string(A.cols) +
               " columns but the cochain it is applied to has " + std::to_string(x.size(0)) +
               " rows");
  }
};

struct HMPNNOptions {
  HMPNNOptions(std::int64_t in, std::int64_t hidden) : in_channels_(in), hidden_channels_(hidden) {}
  TORCH_ARG(std::int64_t, in_channels);
  TORCH_ARG(std::int64_t, hidden_channels);
  TORCH_ARG(int, n_layers) = 2;
  TORCH_ARG(double, adjacency_dropout_rate) = 0.7;
  TORCH_ARG(double, regular_dropout_rate) = 0.5;
  TORCH_ARG(nn::Aggr, aggr_func) = nn::Aggr::sum;
  TORCH_ARG(bool, topomodelx_compatible) = false;
};

/// TopoModelX HMPNN's feature dropout (training only): each entry kept with probability `keep`,
/// then row i multiplied by (2n - kept_i) / n, n the number of rows. HMPNN's own operation,
/// through the operator schedule's extension point.
struct RescaledDropout : nn::Operation {
  explicit RescaledDropout(double keep) : keep(keep) {}
  double keep;
  std::string str(const std::string& x) const override { return "rescaled_dropout(" + x + ")"; }
  nn::TermShape infer(nn::BuildContext& ctx, nn::TermShape x) const override {
    if (!(keep >= 0 && keep <= 1))
      ctx.fail("a dropout rate must be in [0, 1], got " + std::to_string(keep));
    return x;
  }
  torch::Tensor forward(nn::RunContext& ctx, const torch::Tensor& x) const override {
    if (!ctx.is_training()) return x;
    const auto mask = torch::bernoulli(torch::full_like(x, keep));
    const double n = static_cast<double>(x.size(0));
    return x * mask * ((2 * n - mask.sum(1, true)) / n);
  }
};

/// The schedule: the two input maps, then per layer three steps of messages (states "message"
/// and "message_sum") and one parallel update of both ranks; without the compatible mode each
/// layer drops entries of "incidence_1" (DroppedPattern, one draw per layer under the key
/// "incidence_1.layer_<l>" for both directions).
inline nn::OperatorSchedule hmpnn_schedule(const HMPNNOptions& o) {
  using namespace nn::ops;
  using nn::Activation;
  if (o.in_channels() <= 0 || o.hidden_channels() <= 0)
    throw std::invalid_argument("HMPNN: in_channels and hidden_channels must be positive");
  if (o.n_layers() < 0) throw std::invalid_argument("HMPNN: n_layers must be >= 0");
  for (double r : {o.adjacency_dropout_rate(), o.regular_dropout_rate()})
    if (!(r >= 0 && r <= 1)) throw std::invalid_argument("HMPNN: dropout rates must be in [0, 1]");
  const auto h = o.hidden_channels();
  const bool compatible = o.topomodelx_compatible();
  const auto aggr = o.aggr_func();
  nn::OperatorSchedule s;
  s.input("x_0", 0, o.in_channels())
      .input("x_1", 1, o.in_channels())
      .operator_input("incidence_1", 1, 0)  // nodes × hyperedges
      .output("x_0", 0)
      .output("x_1", 1);
  s.parallel({into(0).sum(from(0).linear("linear_node", h)),
              into(1).sum(from(1).linear("linear_edge", h))});
  for (int l = 0; l < o.n_layers(); ++l) {
    const auto p = "layers." + std::to_string(l) + ".";
    const double dropped = compatible ? 0.0 : o.adjacency_dropout_rate();
    const auto key = "incidence_1.layer_" + std::to_string(l);
    const DroppedPattern up("incidence_1", key, dropped, /*transposed=*/true, aggr);
    const DroppedPattern down("incidence_1", key, dropped, /*transposed=*/false, aggr);
    const auto rate = o.regular_dropout_rate();
    auto normalised = [&](int r, const std::string& path) {
      auto t = from(r);
      t.batch_norm(path);
      return std::move(compatible ? t.apply(RescaledDropout(rate)) : t.dropout(rate));
    };
    s.step(into(0, "message")
               .sum(from(0).linear(p + "node_to_hyperedge_messenger.messaging_func.0", h))
               .act(Activation::sigmoid));
    s.step(into(1, "message_sum").sum(from(0, "message").apply(up)));
    s.step(into(1, "message")
               .concat(from(1), from(1, "message_sum"))
               .linear(p + "hyperedge_to_node_messenger.messaging_func.linear", h)
               .act(Activation::sigmoid));
    s.parallel({into(0)
                    .sum(normalised(0, p + "node_batchnorm"),
                         dropped > 0 ? from(1, "message").apply(down)
                                     : from(1, "message").pattern("incidence_1", aggr))
                    .act(Activation::sigmoid),
                into(1)
                    .sum(normalised(1, p + "hyperedge_batchnorm"), from(1, "message_sum"))
                    .act(Activation::sigmoid)});
  }
  return s;
}

class HMPNNImpl : public nn::Cloneable<HMPNNImpl, nn::OperatorNetworkImpl> {
 public:
  explicit HMPNNImpl(const HMPNNOptions& o) : Cloneable(hmpnn_schedule(o)), options(o) {}
  /// x_0 (nodes), x_1 (hyperedges) and the node × hyperedge incidence (its pattern); returns (x_0,
  /// x_1).
  std::vector<torch::Tensor> forward(const torch::Tensor& x0, const torch::Tensor& x1,
                                     const nn::SparseOperator& incidence_1) {
    return run({{"x_0", x0}, {"x_1", x1}}, {{"incidence_1", incidence_1}}, {"x_0", "x_1"});
  }
  HMPNNOptions options;
};
TORCH_MODULE(HMPNN);

}  // namespace topos::models
