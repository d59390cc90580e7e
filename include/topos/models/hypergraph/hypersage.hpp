// topos/models/hypergraph/hypersage.hpp
// HyperSAGE (Arya et al., "HyperSAGE: generalizing inductive representation learning on
// hypergraphs", 2020; TopoModelX HyperSAGE): per layer, intra-edge generalised means
// m_e = (mean_{u∈e} x_u^p)^(1/p) (p = 2), inter-edge generalised means over a node's hyperedges
// weighted by their sizes, m_v = (mean_{e∋v} (|e| / Σ_{e'∋v} |e'| · m_e)^p)^(1/p), then
// σ(normalise(x + m) W). `alpha` > 0 samples at most alpha nodes per hyperedge (at random, on
// every call, as TopoModelX). TopoModelX normalises by the norm of the whole matrix; the
// default here is the paper's per-node normalisation (topomodelx_compatible for TopoModelX's).
// Parameters layers.<i>.weight (in × out). Written as an operator schedule (hypersage_schedule);
// the forward computes the sampled incidences and the inter-edge weights as its operators (the
// mean over a node's hyperedges folded into the weights).
#pragma once

#include "topos/nn/operator_schedule.hpp"

#include <cmath>

namespace topos::models {

struct HyperSAGEOptions {
  HyperSAGEOptions(std::int64_t in, std::int64_t hidden)
      : in_channels_(in), hidden_channels_(hidden) {}
  TORCH_ARG(std::int64_t, in_channels);
  TORCH_ARG(std::int64_t, hidden_channels);
  TORCH_ARG(int, n_layers) = 2;
  TORCH_ARG(int, alpha) = -1;    ///< nodes sampled per hyperedge; -1: all
  TORCH_ARG(double, power) = 2;  ///< of the generalised means
  TORCH_ARG(nn::Activation, update_func) = nn::Activation::relu;
  TORCH_ARG(bool, uniform_initialization) =
      true;  ///< TopoModelX's "uniform"; false: xavier_uniform (gain 1.414)
  TORCH_ARG(bool, topomodelx_compatible) = false;
};

/// The schedule: per layer the intra-edge means into the hyperedges, then the nodes from their
/// own features plus the inter-edge means, normalised, a weight and the update. Layer l reads the
/// operators sampled_t_<l> (the sampled incidence's transpose: hyperedges × nodes, its pattern
/// averaged) and inter_<l> (node × hyperedge: (|e| / Σ_{e'∋v} |e'|)^p / d_v).
inline nn::OperatorSchedule hypersage_schedule(const HyperSAGEOptions& o) {
  using namespace nn::ops;
  if (o.alpha() == 0 || o.alpha() < -1)
    throw std::invalid_argument(
        "HyperSAGE: alpha must be -1 (every node of a hyperedge) or positive, got " +
        std::to_string(o.alpha()));
  if (o.update_func() != nn::Activation::relu && o.update_func() != nn::Activation::sigmoid)
    throw std::invalid_argument("HyperSAGE: update_func must be relu or sigmoid");
  const double p = o.power();
  nn::OperatorSchedule s;
  s.input("x_0", 0, o.in_channels());
  for (int l = 0; l < o.n_layers(); ++l) {
    const auto L = std::to_string(l);
    s.operator_input("sampled_t_" + L, 0, 1).operator_input("inter_" + L, 1, 0);
    s.step(into(1).sum(from(0).pow(p).pattern("sampled_t_" + L, nn::Aggr::mean).pow(1 / p)));
    s.step(into(0)
               .sum(from(0), from(1).pow(p).via("inter_" + L).pow(1 / p))
               .normalize(/*per_row=*/!o.topomodelx_compatible())
               .weight("layers." + L + ".weight", o.hidden_channels())
               .act(o.update_func()));
  }
  s.output("x_0", 0);
  return s;
}

class HyperSAGEImpl : public nn::Cloneable<HyperSAGEImpl, nn::OperatorNetworkImpl> {
 public:
  explicit HyperSAGEImpl(const HyperSAGEOptions& o) : Cloneable(hypersage_schedule(o)), options(o) {
    if (!o.uniform_initialization()) return;  // the schedule's xavier_uniform (gain 1.414)
    torch::NoGradGuard g;
    for (int l = 0; l < o.n_layers(); ++l) {
      const auto& w = parameter("layers." + std::to_string(l) + ".weight");
      w.uniform_(-1 / std::sqrt(double(w.size(1))), 1 / std::sqrt(double(w.size(1))));
    }
  }
  /// x_0 (nodes) and the node × hyperedge incidence (its pattern); returns {x_0}.
  std::vector<torch::Tensor> forward(const torch::Tensor& x,
                                     const nn::SparseOperator& incidence_1) {
    nn::check_node_features("HyperSAGE", x, incidence_1);
    const auto P = incidence_1.pattern().to(x.scalar_type());
    const auto degree = P.row_sums();
    std::map<std::string, nn::SparseOperator> ops;
    for (int l = 0; l < options.n_layers(); ++l) {
      const auto L = std::to_string(l);
      if (l > 0 && options.alpha() < 0) {  // nothing sampled: every layer's operators are equal
        ops["sampled_t_" + L] = ops.at("sampled_t_0");
        ops["inter_" + L] = ops.at("inter_0");
        continue;
      }
      const auto S = sampled(P);       // the nodes each hyperedge hears
      const auto size = S.col_sums();  // |e| as sampled
      const auto share = nn::spmm(P, size.unsqueeze(1)).squeeze(1);  // Σ_{e∋v} |e|
      const auto w = P.scaled(share.reciprocal(), size);             // |e| / Σ_{e'∋v} |e'|
      ops["sampled_t_" + L] = S.t();
      ops["inter_" + L] =
          w.with_values(w.values.pow(options.power()) / degree.index_select(0, w.row));
    }
    return run({{"x_0", x}}, ops, {"x_0"});
  }
  HyperSAGEOptions options;

 private:
  // At most alpha nodes per hyperedge, drawn at random; the whole pattern when alpha is -1.
  nn::SparseOperator sampled(const nn::SparseOperator& P) const {
    if (options.alpha() < 0) return P;
    const auto Pt = P.t();
    const auto crow = Pt.crow.accessor<std::int64_t, 1>();
    const auto col = Pt.col.accessor<std::int64_t, 1>();
    std::vector<std::int64_t> r, c;
    std::vector<double> v;
    for (std::int64_t e = 0; e < Pt.rows; ++e) {
      const auto n = crow[e + 1] - crow[e];
      const auto pick = n <= options.alpha() ? torch::arange(n)
                                             : torch::randperm(n).narrow(0, 0, options.alpha());
      for (std::int64_t i = 0; i < pick.size(0); ++i)
        r.push_back(col[crow[e] + pick[i].item<std::int64_t>()]), c.push_back(e), v.push_back(1.0);
    }
    return nn::SparseOperator::from_triplets(P.rows, P.cols, r, c, v, P.values.scalar_type());
  }
};
TORCH_MODULE(HyperSAGE);

}  // namespace topos::models
