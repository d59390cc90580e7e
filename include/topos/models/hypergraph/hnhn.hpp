// topos/models/hypergraph/hnhn.hpp
// HNHN (Dong, Sawin & Bengio, "HNHN: hypergraph networks with hyperedge neurons", 2020; TopoModelX
// HNHN): per layer x_1 = B̃ᵀ x_0 W_0 + b_0 (nodes -> hyperedges), x_0 = relu(B̃ x_1 W_1 + b_1)
// (hyperedges -> nodes), returning relu(x_1) beside it, with HNHN's normalised incidences
// B̃[v, e] = |e|^α / Σ_{e'∋v} |e'|^α and B̃ᵀ[e, v] = d_v^β / Σ_{u∈e} d_u^β (as TopoModelX: x_1
// reaches the nodes before its relu). Parameters layers.<i>.conv_{0_to_1,1_to_0}.weight and
// layers.<i>.bias_{0_to_1,1_to_0} (1 × hidden). Written as an operator schedule (hnhn_schedule).
#pragma once

#include "topos/nn/operator_schedule.hpp"

namespace topos::models {

struct HNHNOptions {
  HNHNOptions(std::int64_t in, std::int64_t hidden) : in_channels_(in), hidden_channels_(hidden) {}
  TORCH_ARG(std::int64_t, in_channels);
  TORCH_ARG(std::int64_t, hidden_channels);
  TORCH_ARG(int, n_layers) = 2;
  TORCH_ARG(double, layer_drop) = 0.2;
  TORCH_ARG(bool, use_bias) = true;
  TORCH_ARG(bool, use_normalized_incidence) = true;
  TORCH_ARG(double, alpha) = -1.5;
  TORCH_ARG(double, beta) = -0.5;
  TORCH_ARG(double, bias_gain) = 1.414;
};

/// HNHN's normalised incidences (node × hyperedge, hyperedge × node) from B's values.
inline std::pair<nn::SparseOperator, nn::SparseOperator> hnhn_normalized_incidences(
    const nn::SparseOperator& B, double alpha, double beta) {
  const auto edge_card = B.col_sums().pow(alpha), node_card = B.row_sums().pow(beta);
  const auto P = B.pattern();
  const auto left0 =
      nn::spmm(P, edge_card.unsqueeze(1)).squeeze(1).reciprocal();  // 1 / Σ_{e∋v} |e|^α
  const auto left1 =
      nn::spmm(P.t(), node_card.unsqueeze(1)).squeeze(1).reciprocal();  // 1 / Σ_{u∈e} d_u^β
  return {B.scaled(left0, edge_card), B.t().scaled(left1, node_card)};
}

/// The schedule: per layer nodes → hyperedges and hyperedges → nodes through the (normalised)
/// incidences, each a Conv weight and a bias; x_1's relu is a parallel step beside x_0's update.
inline nn::OperatorSchedule hnhn_schedule(const HNHNOptions& o) {
  using namespace nn::ops;
  using nn::Activation;
  if (o.n_layers() < 1) throw std::invalid_argument("HNHN: n_layers must be >= 1");
  const auto h = o.hidden_channels();
  nn::OperatorSchedule s;
  s.input("x_0", 0, o.in_channels())
      .operator_input("incidence_1", 1, 0)     // B̃: nodes × hyperedges
      .operator_input("incidence_1_t", 0, 1);  // B̃ᵀ: hyperedges × nodes (its own normalisation)
  for (int l = 0; l < o.n_layers(); ++l) {
    const auto p = "layers." + std::to_string(l) + ".";
    auto edges = into(1).sum(from(0).conv(p + "conv_0_to_1", h).via("incidence_1_t"));
    auto nodes = into(0).sum(from(1).conv(p + "conv_1_to_0", h).via("incidence_1"));
    if (o.use_bias()) {
      edges.bias(p + "bias_0_to_1", {1, h}, o.bias_gain());
      nodes.bias(p + "bias_1_to_0", {1, h}, o.bias_gain());
    }
    s.step(std::move(edges));
    // The nodes hear x_1 before its relu.
    s.parallel({std::move(nodes.act(Activation::relu).dropout(o.layer_drop())),
                into(1).sum(from(1)).act(Activation::relu)});
  }
  s.output("x_0", 0).output("x_1", 1);
  return s;
}

class HNHNImpl : public nn::Cloneable<HNHNImpl, nn::OperatorNetworkImpl> {
 public:
  explicit HNHNImpl(const HNHNOptions& o) : Cloneable(hnhn_schedule(o)), options(o) {}
  /// x_0 (nodes) and the node × hyperedge incidence; returns (x_0, x_1) of the last layer.
  std::vector<torch::Tensor> forward(const torch::Tensor& x0,
                                     const nn::SparseOperator& incidence_1) {
    nn::check_node_features("HNHN", x0, incidence_1);
    nn::SparseOperator B = incidence_1, Bt = incidence_1.t();
    if (options.use_normalized_incidence())
      std::tie(B, Bt) = hnhn_normalized_incidences(incidence_1, options.alpha(), options.beta());
    return run({{"x_0", x0}}, {{"incidence_1", B}, {"incidence_1_t", Bt}}, {"x_0", "x_1"});
  }
  HNHNOptions options;
};
TORCH_MODULE(HNHN);

}  // namespace topos::models
