// topos/models/simplicial/scn2.hpp
// SCN2 (Wu et al., "Simplicial complex neural networks", 2023; TopoModelX SCN2): on every
// rank r, x_r <- relu(L̃_r · x_r W_r) with the normalised Laplacian L̃_r; the ranks do not mix.
// Parameters layers.<i>.conv_<r>_to_<r>.weight, as in TopoModelX.
#pragma once

#include "topos/nn/conv.hpp"

namespace topos::models {

struct SCN2Options {
  SCN2Options(std::int64_t c0, std::int64_t c1, std::int64_t c2)
      : in_channels_0_(c0), in_channels_1_(c1), in_channels_2_(c2) {}
  TORCH_ARG(std::int64_t, in_channels_0);
  TORCH_ARG(std::int64_t, in_channels_1);
  TORCH_ARG(std::int64_t, in_channels_2);
  TORCH_ARG(int, n_layers) = 2;
};

class SCN2Impl : public torch::nn::Module {
 public:
  explicit SCN2Impl(const SCN2Options& o) : options(o) {
    auto list = register_module("layers", torch::nn::ModuleList());
    for (int i = 0; i < o.n_layers(); ++i) {
      auto layer = std::make_shared<torch::nn::Module>();
      std::array<nn::Conv, 3> convs{
          nn::Conv(nn::ConvOptions(o.in_channels_0(), o.in_channels_0())),
          nn::Conv(nn::ConvOptions(o.in_channels_1(), o.in_channels_1())),
          nn::Conv(nn::ConvOptions(o.in_channels_2(), o.in_channels_2()))};
      for (int r = 0; r < 3; ++r)
        layer->register_module("conv_" + std::to_string(r) + "_to_" + std::to_string(r),
                               convs[static_cast<std::size_t>(r)]);
      list->push_back(layer);
      layers_.push_back(convs);
    }
  }
  /// (x_0, x_1, x_2) and the normalised Laplacians of ranks 0, 1, 2.
  std::vector<torch::Tensor> forward(std::vector<torch::Tensor> x,
                                     const std::array<nn::SparseOperator, 3>& laplacian) {
    for (auto& convs : layers_)
      for (std::size_t r = 0; r < 3; ++r) x[r] = torch::relu(convs[r]->forward(x[r], laplacian[r]));
    return x;
  }
  SCN2Options options;

 private:
  std::vector<std::array<nn::Conv, 3>> layers_;
};
TORCH_MODULE(SCN2);

}  // namespace topos::models
