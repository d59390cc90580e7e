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
#pragma once

#include "topos/nn/conv.hpp"

namespace topos::models {

struct HyperGATOptions {
  HyperGATOptions(std::int64_t in, std::int64_t hidden)
      : in_channels_(in), hidden_channels_(hidden) {}
  TORCH_ARG(std::int64_t, in_channels);
  TORCH_ARG(std::int64_t, hidden_channels);
  TORCH_ARG(int, n_layers) = 2;
  TORCH_ARG(double, layer_drop) = 0.2;
  TORCH_ARG(nn::Update, update_func) = nn::Update::relu;
  TORCH_ARG(double, initialization_gain) = 1.414;
  TORCH_ARG(bool, topomodelx_compatible) = false;
};

class HyperGATImpl : public torch::nn::Module {
 public:
  explicit HyperGATImpl(const HyperGATOptions& o) : options(o) {
    auto list = register_module("layers", torch::nn::ModuleList());
    const auto h = o.hidden_channels();
    for (int l = 0; l < o.n_layers(); ++l) {
      auto layer = std::make_shared<torch::nn::Module>();
      Layer L;
      L.weight1 =
          layer->register_parameter("weight1", torch::empty({l == 0 ? o.in_channels() : h, h}));
      L.weight2 = layer->register_parameter("weight2", torch::empty({h, h}));
      L.att_weight1 = layer->register_parameter("att_weight1", torch::empty({h, 1}));
      L.att_weight2 = layer->register_parameter("att_weight2", torch::empty({2 * h, 1}));
      for (auto* w : {&L.weight1, &L.weight2, &L.att_weight1, &L.att_weight2})
        nn::xavier_uniform(*w, o.initialization_gain());
      list->push_back(layer);
      layers_.push_back(L);
    }
  }
  /// x_0 (nodes) and the node × hyperedge incidence; returns (x_0, x_1) of the last layer.
  std::vector<torch::Tensor> forward(torch::Tensor x0, const nn::SparseOperator& incidence_1) {
    nn::check_node_features("HyperGAT", x0, incidence_1);
    const auto& B = incidence_1;
    const auto Bt = B.t();
    const auto h = options.hidden_channels();
    torch::Tensor x1;
    for (auto& L : layers_) {
      const auto m0 = x0.matmul(L.weight1);
      if (options.topomodelx_compatible()) {
        x1 = nn::apply_update(nn::spmm(Bt, m0), options.update_func());
        x0 = nn::apply_update(nn::spmm(B, x1.matmul(L.weight2)), options.update_func());
      } else {
        // Node level: each hyperedge (row of Bᵀ) attends over its nodes.
        const auto s1 =
            torch::leaky_relu(m0).matmul(L.att_weight1).squeeze(1).index_select(0, Bt.col);
        x1 = nn::apply_update(nn::spmm(Bt.with_values(nn::row_softmax(Bt, s1) * Bt.values), m0),
                              options.update_func());
        // Edge level: each node (row of B) attends over its hyperedges.
        const auto m1 = x1.matmul(L.weight2);
        const auto a = L.att_weight2.squeeze(1);
        const auto s2 = nn::pair_scores(B, torch::leaky_relu(m1), a.narrow(0, 0, h),
                                        torch::leaky_relu(m0), a.narrow(0, h, h));
        x0 = nn::apply_update(nn::spmm(B.with_values(nn::row_softmax(B, s2) * B.values), m1),
                              options.update_func());
      }
      x0 = torch::dropout(x0, options.layer_drop(), is_training());
    }
    return {x0, x1};
  }
  HyperGATOptions options;

 private:
  struct Layer {
    torch::Tensor weight1, weight2, att_weight1, att_weight2;
  };
  std::vector<Layer> layers_;
};
TORCH_MODULE(HyperGAT);

}  // namespace topos::models
