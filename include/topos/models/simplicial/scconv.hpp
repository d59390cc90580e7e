// topos/models/simplicial/scconv.hpp
// SCConv (Bunch et al., "Simplicial 2-complex convolutional neural networks", 2020; TopoModelX
// SCConv): on nodes, edges and triangles of a 2-complex, every rank gathers linear messages from
// itself (a normalised adjacency; edges use the sum of the lower and upper ones) and from the
// ranks next to it (normalised incidences on the way up, plain ones on the way down), summed,
// then sigmoid. Parameters layers.<i>.conv_<s>_to_<t>.weight. The operators are passed in
// TopoModelX's order and orientation: the incidences as (co)incidences B_1ᵀ, B_2ᵀ (edges ×
// nodes, triangles × edges) and their normalised forms, which the layer transposes.
// Written as an operator schedule (scconv_schedule).
#pragma once

#include "topos/nn/operator_schedule.hpp"

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

/// The schedule: per layer one parallel group over the three ranks. TopoModelX passes the
/// incidences transposed (rank r × rank r-1), so B_r itself is via_t.
inline nn::OperatorSchedule scconv_schedule(const SCConvOptions& o) {
  using namespace nn::ops;
  using nn::Activation;
  if (o.n_layers() < 1) throw std::invalid_argument("SCConv: n_layers must be >= 1");
  const auto c0 = o.node_channels(), c1 = o.edge_channels() > 0 ? o.edge_channels() : c0,
             c2 = o.face_channels() > 0 ? o.face_channels() : c0;
  nn::OperatorSchedule s;
  s.input("x_0", 0, c0).input("x_1", 1, c1).input("x_2", 2, c2);
  s.output("x_0", 0).output("x_1", 1).output("x_2", 2);
  s.operator_input("incidence_1", 0, 1)          // B_1ᵀ: edges × nodes
      .operator_input("incidence_1_norm", 1, 0)  // nodes × edges
      .operator_input("incidence_2", 1, 2)       // B_2ᵀ: faces × edges
      .operator_input("incidence_2_norm", 2, 1)  // edges × faces
      .operator_input("adjacency_up_0_norm", 0, 0)
      .operator_input("adjacency_1_norm", 1, 1)  // down + up
      .operator_input("adjacency_down_2_norm", 2, 2);
  for (int l = 0; l < o.n_layers(); ++l) {
    const auto p = "layers." + std::to_string(l) + ".conv_";
    s.parallel({into(0)
                    .sum(from(0).conv(p + "0_to_0", c0).via("adjacency_up_0_norm"),
                         from(1).conv(p + "1_to_0", c0).via_t("incidence_1"))
                    .act(Activation::sigmoid),
                into(1)
                    .sum(from(0).conv(p + "0_to_1", c1).via_t("incidence_1_norm"),
                         from(1).conv(p + "1_to_1", c1).via("adjacency_1_norm"),
                         from(2).conv(p + "2_to_1", c1).via_t("incidence_2"))
                    .act(Activation::sigmoid),
                into(2)
                    .sum(from(1).conv(p + "1_to_2", c2).via_t("incidence_2_norm"),
                         from(2).conv(p + "2_to_2", c2).via("adjacency_down_2_norm"))
                    .act(Activation::sigmoid)});
  }
  return s;
}

class SCConvImpl : public nn::Cloneable<SCConvImpl, nn::OperatorNetworkImpl> {
 public:
  explicit SCConvImpl(const SCConvOptions& o) : Cloneable(scconv_schedule(o)), options(o) {}
  std::vector<torch::Tensor> forward(const std::vector<torch::Tensor>& x,
                                     const SCConvOperators& op) {
    if (x.size() != 3) throw std::invalid_argument("SCConv: expected features of ranks 0, 1, 2");
    return run({{"x_0", x[0]}, {"x_1", x[1]}, {"x_2", x[2]}},
               {{"incidence_1", op.incidence_1},
                {"incidence_1_norm", op.incidence_1_norm},
                {"incidence_2", op.incidence_2},
                {"incidence_2_norm", op.incidence_2_norm},
                {"adjacency_up_0_norm", op.adjacency_up_0_norm},
                {"adjacency_1_norm",
                 nn::SparseOperator::sum(op.adjacency_down_1_norm, op.adjacency_up_1_norm)},
                {"adjacency_down_2_norm", op.adjacency_down_2_norm}},
               {"x_0", "x_1", "x_2"});
  }
  SCConvOptions options;
};
TORCH_MODULE(SCConv);

}  // namespace topos::models
