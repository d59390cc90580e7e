// topos/models/simplicial/scconv.hpp
// SCConv (Bunch et al., "Simplicial 2-complex convolutional neural networks", 2020; TopoModelX
// SCConv): on nodes, edges and triangles of a 2-complex, every rank gathers linear messages from
// itself (a normalised adjacency; edges use the sum of the lower and upper ones) and from the
// ranks next to it (normalised incidences on the way up, plain ones on the way down), summed,
// then sigmoid. Parameters layers.<i>.conv_<s>_to_<t>.weight. The operators are passed in
// TopoModelX's order and orientation: the incidences as (co)incidences B_1ᵀ, B_2ᵀ (edges ×
// nodes, triangles × edges) and their normalised forms, which the layer transposes.
#pragma once

#include "topos/nn/conv.hpp"

namespace topos::models {

struct SCConvOptions {
  explicit SCConvOptions(std::int64_t node_channels) : node_channels_(node_channels) {}
  TORCH_ARG(std::int64_t, node_channels);
  TORCH_ARG(std::int64_t, edge_channels) = 0;  ///< 0: node_channels (TopoModelX's None)
  TORCH_ARG(std::int64_t, face_channels) = 0;  ///< 0: node_channels
  TORCH_ARG(int, n_layers) = 2;
};

/// The operators of one SCConv layer, named as TopoModelX's forward arguments.
struct SCConvOperators {
  nn::SparseOperator incidence_1, incidence_1_norm, incidence_2, incidence_2_norm;
  nn::SparseOperator adjacency_up_0_norm, adjacency_up_1_norm, adjacency_down_1_norm,
      adjacency_down_2_norm;
};

class SCConvImpl : public torch::nn::Module {
 public:
  explicit SCConvImpl(const SCConvOptions& o) : options(o) {
    if (o.n_layers() < 1) throw std::invalid_argument("SCConv: n_layers must be >= 1");
    const auto c0 = o.node_channels(), c1 = o.edge_channels() > 0 ? o.edge_channels() : c0,
               c2 = o.face_channels() > 0 ? o.face_channels() : c0;
    auto list = register_module("layers", torch::nn::ModuleList());
    for (int l = 0; l < o.n_layers(); ++l) {
      auto m = std::make_shared<torch::nn::Module>();
      auto conv = [&](const char* name, std::int64_t in, std::int64_t out) {
        return m->register_module(name, nn::Conv(nn::ConvOptions(in, out)));
      };
      layers_.push_back({conv("conv_0_to_0", c0, c0), conv("conv_0_to_1", c0, c1),
                         conv("conv_1_to_1", c1, c1), conv("conv_1_to_0", c1, c0),
                         conv("conv_1_to_2", c1, c2), conv("conv_2_to_1", c2, c1),
                         conv("conv_2_to_2", c2, c2)});
      list->push_back(m);
    }
  }
  std::vector<torch::Tensor> forward(std::vector<torch::Tensor> x, const SCConvOperators& op) {
    if (x.size() != 3) throw std::invalid_argument("SCConv: expected features of ranks 0, 1, 2");
    const auto b1 = op.incidence_1.t(), b1n_t = op.incidence_1_norm.t(), b2 = op.incidence_2.t(),
               b2n_t = op.incidence_2_norm.t();
    const auto adj_1 = nn::SparseOperator::sum(op.adjacency_down_1_norm, op.adjacency_up_1_norm);
    for (auto& l : layers_) {
      auto agg = [](std::vector<torch::Tensor> m) {
        return nn::aggregate_messages(m, nn::Aggr::sum, nn::Update::sigmoid);
      };
      auto y0 = agg({l.c00->forward(x[0], op.adjacency_up_0_norm), l.c10->forward(x[1], b1)});
      auto y1 =
          agg({l.c01->forward(x[0], b1n_t), l.c11->forward(x[1], adj_1), l.c21->forward(x[2], b2)});
      auto y2 = agg({l.c12->forward(x[1], b2n_t), l.c22->forward(x[2], op.adjacency_down_2_norm)});
      x = {y0, y1, y2};
    }
    return x;
  }
  SCConvOptions options;

 private:
  struct Layer {
    nn::Conv c00, c01, c11, c10, c12, c21, c22;
  };
  std::vector<Layer> layers_;
};
TORCH_MODULE(SCConv);

}  // namespace topos::models
