// topos/models/hypergraph/hypergat.hpp
// HyperGAT (Ding et al., "Be more with less: hypergraph attention networks for inductive text
// classification", EMNLP 2020; TopoModelX HyperGAT): per layer, node-level attention gathers each
// hyperedge's nodes, x_1 = σ(Σ_{v∈e} α_ev x_v W_1) with α_e· = softmax over e's nodes of
// a_1·lrelu(x_v W_1); edge-level attention gathers each node's hyperedges, x_0 = σ(Σ_{e∋v} β_ve
// x_e W_2) with β_v· = softmax over v's hyperedges of a_2·lrelu([x_e W_2 || x_v W_1]).
// TopoModelX's softmax runs over a dimension of size 1, so every weight is 1 and the attention
// vectors get zero gradients (it also indexes hyperedge rows with node indices): with
// topomodelx_compatible the weights are 1, x_1 = σ(Bᵀ x_0 W_1), x_0 = σ(B x_1 W_2).
// Parameters layers.<i>.{weight1, weight2, att_weight1 (hidden × 1), att_weight2 (2·hidden × 1)}.
// Written as an operator schedule (hypergat_schedule).
#pragma once

#include "topos/nn/operator_schedule.hpp"

namespace topos::models {

struct HyperGATOptions {
  HyperGATOptions(std::int64_t in, std::int64_t hidden)
      : in_channels_(in), hidden_channels_(hidden) {}
  TORCH_ARG(std::int64_t, in_channels);
  TORCH_ARG(std::int64_t, hidden_channels);
  TORCH_ARG(int, n_layers) = 2;
  TORCH_ARG(double, layer_drop) = 0.2;
  TORCH_ARG(nn::Activation, update_func) = nn::Activation::relu;
  TORCH_ARG(double, initialization_gain) = 1.414;
  TORCH_ARG(bool, topomodelx_compatible) = false;
};

/// The schedule: per layer m_0 = x_0 W_1 (the state "m"), the node-level step into the
/// hyperedges (source-only scores over Bᵀ), the edge-level step into the nodes (scored against
/// m_0), then dropout. The compatible mode's unit weights are plain products with B; its attention
/// vectors are declared parameters that no step uses.
inline nn::OperatorSchedule hypergat_schedule(const HyperGATOptions& o) {
  using namespace nn::ops;
  using nn::Activation;
  using nn::AttentionNorm;
  const auto h = o.hidden_channels();
  const auto g = o.initialization_gain();
  const auto u = o.update_func();
  nn::OperatorSchedule s;
  s.input("x_0", 0, o.in_channels()).operator_input("incidence_1", 1, 0);  // nodes × hyperedges
  // a·lrelu(features) per entry, softmax per target: HyperGAT's scores, the activated features
  // as the keys (and queries) of the attention, the messages the features themselves.
  auto scores = [&](const std::string& path, std::int64_t entries) {
    return nn::AttendOptions(path)
        .shape({entries, 1})
        .gain(g)
        .activation(Activation::none)
        .norm(AttentionNorm::softmax);
  };
  for (int l = 0; l < o.n_layers(); ++l) {
    const auto p = "layers." + std::to_string(l) + ".";
    if (o.topomodelx_compatible()) {
      s.step(into(1).sum(from(0).weight(p + "weight1", h, g).via_t("incidence_1")).act(u));
      s.step(into(0)
                 .sum(from(1).weight(p + "weight2", h, g).via("incidence_1"))
                 .act(u)
                 .dropout(o.layer_drop()));
      s.parameter(p + "att_weight1", {h, 1}, g).parameter(p + "att_weight2", {2 * h, 1}, g);
      continue;
    }
    s.step(into(0, "m").sum(from(0).weight(p + "weight1", h, g)));
    s.step(into(0, "m_act").sum(from(0, "m").act(Activation::leaky_relu)));
    s.step(into(1)
               .sum(from(0, "m").attend("incidence_1", scores(p + "att_weight1", h)
                                                           .transposed(true)
                                                           .source_only(true)
                                                           .keys(nn::CochainKey{0, "m_act"})))
               .act(u));
    s.step(into(1, "m").sum(from(1).weight(p + "weight2", h, g)));
    s.step(into(1, "m_act").sum(from(1, "m").act(Activation::leaky_relu)));
    s.step(into(0)
               .sum(from(1, "m").attend("incidence_1", scores(p + "att_weight2", 2 * h)
                                                           .keys(nn::CochainKey{1, "m_act"})
                                                           .queries(nn::CochainKey{0, "m_act"})))
               .act(u)
               .dropout(o.layer_drop()));
  }
  s.output("x_0", 0).output("x_1", 1);
  return s;
}

class HyperGATImpl : public nn::Cloneable<HyperGATImpl, nn::OperatorNetworkImpl> {
 public:
  explicit HyperGATImpl(const HyperGATOptions& o) : Cloneable(hypergat_schedule(o)), options(o) {}
  /// x_0 (nodes) and the node × hyperedge incidence; returns (x_0, x_1) of the last layer.
  std::vector<torch::Tensor> forward(const torch::Tensor& x0,
                                     const nn::SparseOperator& incidence_1) {
    nn::check_node_features("HyperGAT", x0, incidence_1);
    return run({{"x_0", x0}}, {{"incidence_1", incidence_1}}, {"x_0", "x_1"});
  }
  HyperGATOptions options;
};
TORCH_MODULE(HyperGAT);

}  // namespace topos::models
