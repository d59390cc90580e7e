// topos/models/hypergraph/hnhn.hpp
// HNHN (Dong, Sawin & Bengio, "HNHN: hypergraph networks with hyperedge neurons", 2020; TopoModelX
// HNHN): per layer x_1 = B̃ᵀ x_0 W_0 + b_0 (nodes -> hyperedges), x_0 = relu(B̃ x_1 W_1 + b_1)
// (hyperedges -> nodes), returning relu(x_1) beside it, with HNHN's normalised incidences
// B̃[v, e] = |e|^α / Σ_{e'∋v} |e'|^α and B̃ᵀ[e, v] = d_v^β / Σ_{u∈e} d_u^β (as TopoModelX: x_1
// reaches the nodes before its relu). Parameters layers.<i>.conv_{0_to_1,1_to_0}.weight and
// layers.<i>.bias_{0_to_1,1_to_0} (1 × hidden).
#pragma once

#include "topos/nn/conv.hpp"

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

class HNHNImpl : public torch::nn::Module {
 public:
  explicit HNHNImpl(const HNHNOptions& o) : options(o) {
    auto list = register_module("layers", torch::nn::ModuleList());
    for (int l = 0; l < o.n_layers(); ++l) {
      auto layer = std::make_shared<torch::nn::Module>();
      Layer L;
      if (o.use_bias()) {
        L.bias_1_to_0 =
            layer->register_parameter("bias_1_to_0", torch::empty({1, o.hidden_channels()}));
        L.bias_0_to_1 =
            layer->register_parameter("bias_0_to_1", torch::empty({1, o.hidden_channels()}));
        nn::xavier_uniform(L.bias_0_to_1, o.bias_gain());
        nn::xavier_uniform(L.bias_1_to_0, o.bias_gain());
      }
      L.conv_0_to_1 = layer->register_module(
          "conv_0_to_1", nn::Conv(nn::ConvOptions(l == 0 ? o.in_channels() : o.hidden_channels(),
                                                  o.hidden_channels())));
      L.conv_1_to_0 = layer->register_module(
          "conv_1_to_0", nn::Conv(nn::ConvOptions(o.hidden_channels(), o.hidden_channels())));
      list->push_back(layer);
      layers_.push_back(L);
    }
  }
  /// x_0 (nodes) and the node × hyperedge incidence; returns (x_0, x_1) of the last layer.
  std::vector<torch::Tensor> forward(torch::Tensor x0, const nn::SparseOperator& incidence_1) {
    nn::check_node_features("HNHN", x0, incidence_1);
    nn::SparseOperator B = incidence_1, Bt = incidence_1.t();
    if (options.use_normalized_incidence())
      std::tie(B, Bt) = hnhn_normalized_incidences(incidence_1, options.alpha(), options.beta());
    torch::Tensor x1;
    for (auto& L : layers_) {
      x1 = L.conv_0_to_1->forward(x0, Bt);
      if (L.bias_0_to_1.defined()) x1 = x1 + L.bias_0_to_1;
      x0 = L.conv_1_to_0->forward(x1, B);
      if (L.bias_1_to_0.defined()) x0 = x0 + L.bias_1_to_0;
      x0 = torch::dropout(torch::relu(x0), options.layer_drop(), is_training());
      x1 = torch::relu(x1);
    }
    return {x0, x1};
  }
  HNHNOptions options;

 private:
  struct Layer {
    nn::Conv conv_0_to_1{nullptr}, conv_1_to_0{nullptr};
    torch::Tensor bias_0_to_1, bias_1_to_0;
  };
  std::vector<Layer> layers_;
};
TORCH_MODULE(HNHN);

}  // namespace topos::models
