// topos/models/simplicial/hsn.hpp
// HSN (Hajij et al., "High skip networks: a higher order generalization of skip connections",
// 2022; TopoModelX HSN): node features reach the nodes by two two-step routes, node → node →
// node over the adjacency and node → edge → node over the incidence, summed, then sigmoid:
// x_0 <- σ(A σ(A x_0 W_1) W_3 + B_1 σ(B_1ᵀ x_0 W_2) W_4). Parameters
// layers.<i>.conv_level1_0_to_0 / conv_level1_0_to_1 / conv_level2_0_to_0 / conv_level2_1_to_0.
#pragma once

#include "topos/nn/conv.hpp"

namespace topos::models {

struct HSNOptions {
  explicit HSNOptions(std::int64_t channels) : channels_(channels) {}
  TORCH_ARG(std::int64_t, channels);
  TORCH_ARG(int, n_layers) = 2;
};

class HSNImpl : public torch::nn::Module {
 public:
  explicit HSNImpl(const HSNOptions& o) : options(o) {
    if (o.n_layers() < 1) throw std::invalid_argument("HSN: n_layers must be >= 1");
    const auto c = o.channels();
    auto list = register_module("layers", torch::nn::ModuleList());
    for (int l = 0; l < o.n_layers(); ++l) {
      auto m = std::make_shared<torch::nn::Module>();
      const auto sig = nn::ConvOptions(c, c).update_func(nn::Update::sigmoid);
      layers_.push_back(
          {m->register_module("conv_level1_0_to_0", nn::Conv(sig)),
           m->register_module("conv_level1_0_to_1", nn::Conv(sig)),
           m->register_module("conv_level2_0_to_0", nn::Conv(nn::ConvOptions(c, c))),
           m->register_module("conv_level2_1_to_0", nn::Conv(nn::ConvOptions(c, c)))});
      list->push_back(m);
    }
  }
  /// Node features, the node × edge incidence B_1 and the node adjacency.
  torch::Tensor forward(torch::Tensor x_0, const nn::SparseOperator& incidence_1,
                        const nn::SparseOperator& adjacency_0) {
    const auto incidence_1_t = incidence_1.t();
    for (auto& l : layers_) {
      const auto x_0_level1 = l.c00_1->forward(x_0, adjacency_0);
      const auto x_1_level1 = l.c01_1->forward(x_0, incidence_1_t);
      x_0 = nn::aggregate_messages(
          {l.c00_2->forward(x_0_level1, adjacency_0), l.c10_2->forward(x_1_level1, incidence_1)},
          nn::Aggr::sum, nn::Update::sigmoid);
    }
    return x_0;
  }
  HSNOptions options;

 private:
  struct Layer {
    nn::Conv c00_1, c01_1, c00_2, c10_2;
  };
  std::vector<Layer> layers_;
};
TORCH_MODULE(HSN);

}  // namespace topos::models
