// topos/models/simplicial/scnn.hpp
// SCNN (Yang, Isufi & Leus, "Simplicial convolutional neural networks", 2022; TopoModelX SCNN):
// on one rank, y = Σ_k (L_down^k x) W_k + Σ_k (L_up^k x) W'_k + x W_0, a polynomial filter of the
// lower and upper Laplacians, one weight tensor per layer ("layers.<i>.weight", in × out ×
// (1 + conv_order_down + conv_order_up)). aggr_norm divides the powers k ≥ 2 by the Laplacian's
// row sums (TopoModelX skips the first power). TopoModelX gives the first layer neither aggr_norm
// nor update_func (the compatible mode does the same; the default gives them to every layer).
#pragma once

#include "topos/nn/conv.hpp"

namespace topos::models {

struct SCNNOptions {
  SCNNOptions(std::int64_t in, std::int64_t hidden, int conv_order_down, int conv_order_up)
      : in_channels_(in),
        hidden_channels_(hidden),
        conv_order_down_(conv_order_down),
        conv_order_up_(conv_order_up) {}
  TORCH_ARG(std::int64_t, in_channels);
  TORCH_ARG(std::int64_t, hidden_channels);
  TORCH_ARG(int, conv_order_down);
  TORCH_ARG(int, conv_order_up);
  TORCH_ARG(bool, aggr_norm) = false;
  TORCH_ARG(nn::Update, update_func) = nn::Update::none;  ///< relu, sigmoid or none
  TORCH_ARG(int, n_layers) = 2;
  TORCH_ARG(bool,
            topomodelx_compatible) = false;  ///< first layer without aggr_norm and update_func
};

class SCNNImpl : public torch::nn::Module {
 public:
  explicit SCNNImpl(const SCNNOptions& o) : options(o) {
    if (o.conv_order_down() < 0 || o.conv_order_up() < 0 ||
        o.conv_order_down() + o.conv_order_up() == 0)
      throw std::invalid_argument(
          "SCNN: conv_order_down and conv_order_up must be >= 0, not both 0");
    if (o.update_func() != nn::Update::none && o.update_func() != nn::Update::relu &&
        o.update_func() != nn::Update::sigmoid)
      throw std::invalid_argument("SCNN: update_func must be relu, sigmoid or none");
    if (o.n_layers() < 1) throw std::invalid_argument("SCNN: n_layers must be >= 1");
    auto list = register_module("layers", torch::nn::ModuleList());
    const std::int64_t terms = 1 + o.conv_order_down() + o.conv_order_up();
    for (int l = 0; l < o.n_layers(); ++l) {
      auto layer = std::make_shared<torch::nn::Module>();
      weights_.push_back(layer->register_parameter(
          "weight", torch::empty({l == 0 ? o.in_channels() : o.hidden_channels(),
                                  o.hidden_channels(), terms})));
      nn::xavier_uniform(weights_.back());
      list->push_back(layer);
    }
  }
  /// Features of one rank, its lower and upper Laplacians.
  torch::Tensor forward(torch::Tensor x, const nn::SparseOperator& laplacian_down,
                        const nn::SparseOperator& laplacian_up) {
    for (std::size_t l = 0; l < weights_.size(); ++l) {
      const bool plain = l == 0 && options.topomodelx_compatible();
      const bool norm = options.aggr_norm() && !plain;
      std::vector<torch::Tensor> t{x};
      for (auto& p : nn::powers(laplacian_down, x, options.conv_order_down(), norm, 2))
        t.push_back(p);
      for (auto& p : nn::powers(laplacian_up, x, options.conv_order_up(), norm, 2)) t.push_back(p);
      x = nn::combine_terms(t, weights_[l]);
      if (!plain) x = nn::apply_update(x, options.update_func());
    }
    return x;
  }
  SCNNOptions options;

 private:
  std::vector<torch::Tensor> weights_;
};
TORCH_MODULE(SCNN);

}  // namespace topos::models
