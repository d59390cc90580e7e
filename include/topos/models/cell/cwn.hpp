// topos/models/cell/cwn.hpp
// CWN (Bodnar et al., "Weisfeiler and Lehman go cellular: CW networks", 2021; TopoModelX CWN):
// features projected to a common width (elu), then per layer only the edges are updated:
// x_1 <- elu(U(elu(A_1 x_1 W_11) + elu(B_2 x_2 W_21) + elu(B_1ᵀ x_0 W_01))). Written as an
// operator schedule (cwn_schedule).
#pragma once

#include "topos/nn/operator_schedule.hpp"

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

/// The schedule: the projections, then per layer one step into the edges.
inline nn::OperatorSchedule cwn_schedule(const CWNOptions& o) {
  using namespace nn::ops;
  using nn::Activation;
  const auto h = o.hid_channels();
  const std::array<std::int64_t, 3> c{o.in_channels_0(), o.in_channels_1(), o.in_channels_2()};
  nn::OperatorSchedule s;
  s.operator_input("adjacency_1", 1, 1)
      .operator_input("incidence_2", 2, 1)
      .operator_input("incidence_1_t", 0, 1);
  for (int r = 0; r < 3; ++r) {
    const auto R = std::to_string(r);
    s.input("x_" + R, r, c[r]).output("x_" + R, r);
  }
  s.parallel({into(0).sum(from(0).linear("proj_0", h)).act(Activation::elu),
              into(1).sum(from(1).linear("proj_1", h)).act(Activation::elu),
              into(2).sum(from(2).linear("proj_2", h)).act(Activation::elu)});
  for (int l = 0; l < o.n_layers(); ++l) {
    const auto p = "layers." + std::to_string(l) + ".";
    s.step(into(1)
               .sum(from(1)
                        .conv(p + "conv_1_to_1.conv_1_to_1", h)
                        .via("adjacency_1")
                        .act(Activation::elu),
                    from(2)
                        .conv(p + "conv_1_to_1.conv_2_to_1", h)
                        .via("incidence_2")
                        .act(Activation::elu),
                    from(0)
                        .conv(p + "conv_0_to_1.conv_0_to_1", h)
                        .via("incidence_1_t")
                        .act(Activation::elu))
               .linear(p + "update_fn.transform", h)
               .act(Activation::elu));
  }
  return s;
}

class CWNImpl : public nn::Cloneable<CWNImpl, nn::OperatorNetworkImpl> {
 public:
  explicit CWNImpl(const CWNOptions& o) : Cloneable(cwn_schedule(o)), options(o) {}
  /// (x_0, x_1, x_2), the edge adjacency, the incidence of 2-cells B_2 (edges × cells), B_1ᵀ.
  std::vector<torch::Tensor> forward(const std::vector<torch::Tensor>& x,
                                     const nn::SparseOperator& adjacency_1,
                                     const nn::SparseOperator& incidence_2,
                                     const nn::SparseOperator& incidence_1_t) {
    if (x.size() != 3) throw std::invalid_argument("CWN: expected features of ranks 0, 1, 2");
    return run({{"x_0", x[0]}, {"x_1", x[1]}, {"x_2", x[2]}},
               {{"adjacency_1", adjacency_1},
                {"incidence_2", incidence_2},
                {"incidence_1_t", incidence_1_t}},
               {"x_0", "x_1", "x_2"});
  }
  CWNOptions options;
};
TORCH_MODULE(CWN);

}  // namespace topos::models
