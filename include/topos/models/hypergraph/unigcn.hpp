// topos/models/hypergraph/unigcn.hpp
// UniGCN (Huang & Yang, "UniGNN", IJCAI 2021; TopoModelX UniGCN) as TopoModelX computes it: per
// layer x_1 = Bᵀ x_0 W_1 (optionally BatchNorm), x_0 = B x_1 W_2, both optionally averaged
// (aggr_norm: divided by the incidence's row sums); no activation. TopoModelX drops a layer's
// first linear map when in_channels == hidden_channels (topomodelx_compatible: so do we, and
// that layer has no conv_level1_0_to_1.weight); the default keeps it.
// Parameters layers.<i>.conv_level1_0_to_1.weight, layers.<i>.conv_level2_1_to_0.weight,
// layers.<i>.bn.*.
#pragma once

#include "topos/nn/conv.hpp"

namespace topos::models {

struct UniGCNOptions {
  UniGCNOptions(std::int64_t in, std::int64_t hidden)
      : in_channels_(in), hidden_channels_(hidden) {}
  TORCH_ARG(std::int64_t, in_channels);
  TORCH_ARG(std::int64_t, hidden_channels);
  TORCH_ARG(int, n_layers) = 2;
  TORCH_ARG(bool, aggr_norm) = false;
  TORCH_ARG(bool, use_bn) = false;
  TORCH_ARG(bool, topomodelx_compatible) = false;
};

class UniGCNImpl : public torch::nn::Module {
 public:
  explicit UniGCNImpl(const UniGCNOptions& o) : options(o) {
    auto list = register_module("layers", torch::nn::ModuleList());
    for (int l = 0; l < o.n_layers(); ++l) {
      const auto in = l == 0 ? o.in_channels() : o.hidden_channels(), h = o.hidden_channels();
      auto layer = std::make_shared<torch::nn::Module>();
      Layer L;
      L.level1 = layer->register_module(
          "conv_level1_0_to_1",
          nn::Conv(nn::ConvOptions(in, h)
                       .aggr_norm(o.aggr_norm())
                       .with_linear_transform(!o.topomodelx_compatible() || in != h)));
      L.level2 = layer->register_module("conv_level2_1_to_0",
                                        nn::Conv(nn::ConvOptions(h, h).aggr_norm(o.aggr_norm())));
      if (o.use_bn()) L.bn = layer->register_module("bn", torch::nn::BatchNorm1d(h));
      list->push_back(layer);
      layers_.push_back(L);
    }
  }
  /// x_0 (nodes) and the node × hyperedge incidence; returns (x_0, x_1) of the last layer.
  std::vector<torch::Tensor> forward(torch::Tensor x0, const nn::SparseOperator& incidence_1) {
    if (x0.size(0) != incidence_1.rows)
      throw std::invalid_argument("UniGCN: " + std::to_string(x0.size(0)) +
                                  " node features for an incidence of " +
                                  std::to_string(incidence_1.rows) + " nodes");
    const auto Bt = incidence_1.t();
    torch::Tensor x1;
    for (auto& L : layers_) {
      x1 = L.level1->forward(x0, Bt);
      if (!L.bn.is_empty()) x1 = L.bn->forward(x1);
      x0 = L.level2->forward(x1, incidence_1);
    }
    return {x0, x1};
  }
  UniGCNOptions options;

 private:
  struct Layer {
    nn::Conv level1{nullptr}, level2{nullptr};
    torch::nn::BatchNorm1d bn{nullptr};
  };
  std::vector<Layer> layers_;
};
TORCH_MODULE(UniGCN);

}  // namespace topos::models
