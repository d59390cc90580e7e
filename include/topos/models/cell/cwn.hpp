// topos/models/cell/cwn.hpp
// CWN (Bodnar et al., "Weisfeiler and Lehman go cellular: CW networks", 2021; TopoModelX CWN):
// features projected to a common width (elu), then per layer only the edges are updated:
// x_1 <- elu(U(elu(A_1 x_1 W_11) + elu(B_2 x_2 W_21) + elu(B_1ᵀ x_0 W_01))).
#pragma once

#include "topos/nn/conv.hpp"

namespace topos::models {

struct CWNOptions {
  CWNOptions(std::int64_t c0, std::int64_t c1, std::int64_t c2, std::int64_t hid, int n_layers)
      : in_channels_0_(c0),
        in_channels_1_(c1),
        in_channels_2_(c2),
        hid_channels_(hid),
        n_layers_(n_layers) {}
  TORCH_ARG(std::int64_t, in_channels_0);
  TORCH_ARG(std::int64_t, in_channels_1);
  TORCH_ARG(std::int64_t, in_channels_2);
  TORCH_ARG(std::int64_t, hid_channels);
  TORCH_ARG(int, n_layers);
};

class CWNImpl : public torch::nn::Module {
 public:
  explicit CWNImpl(const CWNOptions& o) : options(o) {
    const auto h = o.hid_channels();
    proj_ = {register_module("proj_0", torch::nn::Linear(o.in_channels_0(), h)),
             register_module("proj_1", torch::nn::Linear(o.in_channels_1(), h)),
             register_module("proj_2", torch::nn::Linear(o.in_channels_2(), h))};
    auto list = register_module("layers", torch::nn::ModuleList());
    for (int l = 0; l < o.n_layers(); ++l) {
      auto layer = std::make_shared<torch::nn::Module>();
      auto first = nn::submodule_group(*layer, "conv_1_to_1");
      auto second = nn::submodule_group(*layer, "conv_0_to_1");
      auto update = nn::submodule_group(*layer, "update_fn");
      layers_.push_back({first->register_module("conv_1_to_1", nn::Conv(nn::ConvOptions(h, h))),
                         first->register_module("conv_2_to_1", nn::Conv(nn::ConvOptions(h, h))),
                         second->register_module("conv_0_to_1", nn::Conv(nn::ConvOptions(h, h))),
                         update->register_module("transform", torch::nn::Linear(h, h))});
      list->push_back(layer);
    }
  }
  /// (x_0, x_1, x_2), the edge adjacency, the incidence of 2-cells B_2 (edges × cells), B_1ᵀ.
  std::vector<torch::Tensor> forward(const std::vector<torch::Tensor>& x,
                                     const nn::SparseOperator& adjacency_1,
                                     const nn::SparseOperator& incidence_2,
                                     const nn::SparseOperator& incidence_1_t) {
    auto x0 = torch::elu(proj_[0]->forward(x[0])), x1 = torch::elu(proj_[1]->forward(x[1])),
         x2 = torch::elu(proj_[2]->forward(x[2]));
    for (auto& l : layers_) {
      const auto m = torch::elu(l.c11->forward(x1, adjacency_1)) +
                     torch::elu(l.c21->forward(x2, incidence_2)) +
                     torch::elu(l.c01->forward(x0, incidence_1_t));
      x1 = torch::elu(l.transform->forward(m));
    }
    return {x0, x1, x2};
  }
  CWNOptions options;

 private:
  struct Layer {
    nn::Conv c11, c21, c01;
    torch::nn::Linear transform;
  };
  std::array<torch::nn::Linear, 3> proj_{nullptr, nullptr, nullptr};
  std::vector<Layer> layers_;
};
TORCH_MODULE(CWN);

}  // namespace topos::models
