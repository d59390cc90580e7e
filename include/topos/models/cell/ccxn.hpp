// topos/models/cell/ccxn.hpp
// CCXN (Hajij, Istvan & Zamzmi, "Cell complex neural networks", 2020; TopoModelX CCXN): per
// layer x_0 <- relu(A_0 relu(x_0) W_0) and x_2 <- relu(B_2ᵀ relu(x_1) W_1), x_1 <- relu(x_1);
// optional elu attention on each neighbourhood (Conv's att). Parameters
// layers.<i>.conv_0_to_0.* (in_channels_0 × in_channels_0), layers.<i>.conv_1_to_2.*
// (in_channels_1 × in_channels_2). x_2 is recomputed from x_1 in every layer, so only the
// last layer's rank-2 output survives (as in TopoModelX).
// With attention, TopoModelX scores a 2-cell's incoming edges with the features of the edge
// whose index is the 2-cell's (x_target = None): the compatible mode. The default scores them
// with the sum of the 2-cell's boundary edges' features (|B_2|ᵀ x_1, the same width).
#pragma once

#include "topos/nn/conv.hpp"

namespace topos::models {

struct CCXNOptions {
  CCXNOptions(std::int64_t c0, std::int64_t c1, std::int64_t c2)
      : in_channels_0_(c0), in_channels_1_(c1), in_channels_2_(c2) {}
  TORCH_ARG(std::int64_t, in_channels_0);
  TORCH_ARG(std::int64_t, in_channels_1);
  TORCH_ARG(std::int64_t, in_channels_2);
  TORCH_ARG(int, n_layers) = 2;
  TORCH_ARG(bool, att) = false;
  TORCH_ARG(bool, topomodelx_compatible) =
      false;  ///< attention targets as TopoModelX indexes them (above)
};

class CCXNImpl : public torch::nn::Module {
 public:
  explicit CCXNImpl(const CCXNOptions& o) : options(o) {
    if (o.n_layers() < 1) throw std::invalid_argument("CCXN: n_layers must be >= 1");
    auto list = register_module("layers", torch::nn::ModuleList());
    for (int l = 0; l < o.n_layers(); ++l) {
      auto m = std::make_shared<torch::nn::Module>();
      layers_.push_back(
          {m->register_module(
               "conv_0_to_0",
               nn::Conv(nn::ConvOptions(o.in_channels_0(), o.in_channels_0()).att(o.att()))),
           m->register_module(
               "conv_1_to_2",
               nn::Conv(nn::ConvOptions(o.in_channels_1(), o.in_channels_2()).att(o.att())))});
      list->push_back(m);
    }
  }
  /// Node and edge features, the node adjacency and B_2ᵀ (2-cells × edges). Returns (x_0, x_1,
  /// x_2).
  std::vector<torch::Tensor> forward(torch::Tensor x_0, torch::Tensor x_1,
                                     const nn::SparseOperator& adjacency_0,
                                     const nn::SparseOperator& incidence_2_t) {
    torch::Tensor x_2;
    for (auto& l : layers_) {
      x_0 = torch::relu(l.c00->forward(torch::relu(x_0), adjacency_0));
      x_1 = torch::relu(x_1);
      torch::Tensor target;
      if (options.att()) {
        if (options.topomodelx_compatible()) {
          if (incidence_2_t.rows > x_1.size(0))
            throw std::invalid_argument(
                "CCXN: TopoModelX-compatible attention needs no more 2-cells than edges");
        } else {
          target = nn::spmm(incidence_2_t.abs(), x_1);
        }
      }
      x_2 = torch::relu(l.c12->forward(x_1, incidence_2_t, target));
    }
    return {x_0, x_1, x_2};
  }
  CCXNOptions options;

 private:
  struct Layer {
    nn::Conv c00, c12;
  };
  std::vector<Layer> layers_;
};
TORCH_MODULE(CCXN);

}  // namespace topos::models
