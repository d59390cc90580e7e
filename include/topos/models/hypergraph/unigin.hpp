// topos/models/hypergraph/unigin.hpp
// UniGIN (Huang & Yang, "UniGNN", IJCAI 2021; TopoModelX UniGIN): a linear map, then per layer
// x_1 = Bᵀ x_0 (sum over a hyperedge's nodes), x_0 = Linear((1 + ε) x_0 + B x_1), optionally each
// row scaled to unit norm (the norm taken as a constant), dropout, relu. ε is a parameter with
// train_eps, else a buffer. TopoModelX never applies its input dropout (topomodelx_compatible:
// neither do we; it only matters in training).
// Parameters initial_linear_layer.*, layers.<i>.eps, layers.<i>.linear.*.
#pragma once

#include "topos/nn/conv.hpp"

namespace topos::models {

struct UniGINOptions {
  UniGINOptions(std::int64_t in, std::int64_t hidden)
      : in_channels_(in), hidden_channels_(hidden) {}
  TORCH_ARG(std::int64_t, in_channels);
  TORCH_ARG(std::int64_t, hidden_channels);
  TORCH_ARG(int, n_layers) = 2;
  TORCH_ARG(double, input_drop) = 0.2;
  TORCH_ARG(double, layer_drop) = 0.2;
  TORCH_ARG(double, eps) = 0;
  TORCH_ARG(bool, train_eps) = false;
  TORCH_ARG(bool, use_norm) = false;
  TORCH_ARG(bool, topomodelx_compatible) = false;
};

class UniGINImpl : public torch::nn::Module {
 public:
  explicit UniGINImpl(const UniGINOptions& o) : options(o) {
    initial_ = register_module("initial_linear_layer",
                               torch::nn::Linear(o.in_channels(), o.hidden_channels()));
    auto list = register_module("layers", torch::nn::ModuleList());
    for (int l = 0; l < o.n_layers(); ++l) {
      auto layer = std::make_shared<torch::nn::Module>();
      const auto e = torch::full({1}, o.eps());
      eps_.push_back(o.train_eps() ? layer->register_parameter("eps", e)
                                   : layer->register_buffer("eps", e));
      linear_.push_back(layer->register_module(
          "linear", torch::nn::Linear(o.hidden_channels(), o.hidden_channels())));
      list->push_back(layer);
    }
  }
  /// x_0 (nodes) and the node × hyperedge incidence; returns (x_0, x_1) of the last layer.
  std::vector<torch::Tensor> forward(torch::Tensor x0, const nn::SparseOperator& incidence_1) {
    nn::check_node_features("UniGIN", x0, incidence_1);
    const auto Bt = incidence_1.t();
    if (!options.topomodelx_compatible())
      x0 = torch::dropout(x0, options.input_drop(), is_training());
    x0 = initial_->forward(x0);
    torch::Tensor x1;
    for (std::size_t l = 0; l < linear_.size(); ++l) {
      x1 = nn::spmm(Bt, x0);
      x0 = linear_[l]->forward((1 + eps_[l]) * x0 + nn::spmm(incidence_1, x1));
      if (options.use_norm()) x0 = nn::unit_rows(x0);
      x0 = torch::relu(torch::dropout(x0, options.layer_drop(), is_training()));
    }
    return {x0, x1};
  }
  UniGINOptions options;

 private:
  torch::nn::Linear initial_{nullptr};
  std::vector<torch::Tensor> eps_;
  std::vector<torch::nn::Linear> linear_;
};
TORCH_MODULE(UniGIN);

}  // namespace topos::models
