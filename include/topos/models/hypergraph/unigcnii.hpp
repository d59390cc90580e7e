// topos/models/hypergraph/unigcnii.hpp
// UniGCNII (Huang & Yang, "UniGNN", 2021; TopoModelX UniGCNII): a linear map and relu, then per
// layer the two-stage message x_1 = Bᵀ x_0, x̂_0 = D_v^-1/2 B D_e^-1/2 x_1 (d_e: the mean degree
// of a hyperedge's nodes), GCNII's initial residual and identity mapping, relu. Degrees are
// vectors and the products sparse (TopoModelX uses dense diagonal matrices).
// TopoModelX ignores `beta` (β_l = log(α/(l+1) + 1)); the default here is GCNII's
// β_l = log(β/(l+1) + 1); topomodelx_compatible(true) gives TopoModelX's numbers.
#pragma once

#include "topos/nn/conv.hpp"

#include <cmath>

namespace topos::models {

struct UniGCNIIOptions {
  UniGCNIIOptions(std::int64_t in, std::int64_t hidden)
      : in_channels_(in), hidden_channels_(hidden) {}
  TORCH_ARG(std::int64_t, in_channels);
  TORCH_ARG(std::int64_t, hidden_channels);
  TORCH_ARG(int, n_layers) = 2;
  TORCH_ARG(double, alpha) = 0.5;
  TORCH_ARG(double, beta) = 0.5;
  TORCH_ARG(double, input_drop) = 0.2;
  TORCH_ARG(double, layer_drop) = 0.2;
  TORCH_ARG(bool, use_norm) = false;
  TORCH_ARG(bool, topomodelx_compatible) = false;
};

class UniGCNIIImpl : public torch::nn::Module {
 public:
  explicit UniGCNIIImpl(const UniGCNIIOptions& o) : options(o) {
    initial_ = register_module("initial_linear_layer",
                               torch::nn::Linear(o.in_channels(), o.hidden_channels()));
    auto list = register_module("layers", torch::nn::ModuleList());
    for (int l = 0; l < o.n_layers(); ++l) {
      auto layer = std::make_shared<torch::nn::Module>();
      linear_.push_back(layer->register_module(
          "linear",
          torch::nn::Linear(
              torch::nn::LinearOptions(o.hidden_channels(), o.hidden_channels()).bias(false))));
      list->push_back(layer);
      beta_.push_back(std::log((o.topomodelx_compatible() ? o.alpha() : o.beta()) / (l + 1) + 1));
    }
  }
  /// x_0 (nodes) and the node × hyperedge incidence; returns (x_0, x_1 of the last layer).
  std::vector<torch::Tensor> forward(torch::Tensor x0, const nn::SparseOperator& incidence_1) {
    const auto dv = incidence_1.row_sums();
    if ((dv <= 0).any().item<bool>())
      throw std::invalid_argument("UniGCNII: every node must be in a hyperedge (add self-loops)");
    const auto de = incidence_1.scaled(dv).col_sums() / incidence_1.col_sums();
    if (!(de > 0).all().item<bool>())
      throw std::invalid_argument("UniGCNII: every hyperedge must contain a node");
    const auto Bt = incidence_1.t();
    const auto B = incidence_1.scaled(dv.rsqrt(), de.rsqrt());  // D_v^-1/2 B D_e^-1/2
    x0 = torch::relu(initial_->forward(torch::dropout(x0, options.input_drop(), is_training())));
    const auto skip = x0;
    torch::Tensor x1;
    for (std::size_t l = 0; l < linear_.size(); ++l) {
      x1 = nn::spmm(Bt, x0);
      x0 = nn::initial_residual(nn::spmm(B, x1), skip, options.alpha(), beta_[l], linear_[l]);
      if (options.use_norm()) {
        auto scale = x0.detach().norm(2, 1, true).reciprocal();
        x0 = x0 * torch::where(torch::isinf(scale), torch::zeros_like(scale), scale);
      }
      x0 = torch::relu(torch::dropout(x0, options.layer_drop(), is_training()));
    }
    return {x0, x1};
  }
  UniGCNIIOptions options;

 private:
  torch::nn::Linear initial_{nullptr};
  std::vector<torch::nn::Linear> linear_;
  std::vector<double> beta_;
};
TORCH_MODULE(UniGCNII);

}  // namespace topos::models
