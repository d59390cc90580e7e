// topos/models/simplicial/sccnn_custom.hpp
// TopoBench's SCCNNCustom (simplicial convolutions of order 1 with the neighbouring ranks,
// after Yang & Isufi's SCCNN): a Linear per rank, then per layer, from the previous layer's
// cochains,
//   x_0 <- σ(Σ_k T0_k Θ0[:, :, k]),  T0 = [x_0, L_0 x_0, B_1 x_1, L_0 B_1 x_1]
//   x_1 <- σ(Σ_k T1_k Θ1[:, :, k]),  T1 = [B_1ᵀx_0, L↓B_1ᵀx_0, L↑B_1ᵀx_0, x_1, L↓x_1, L↑x_1,
//                                         B_2 x_2, L↓B_2 x_2, L↑B_2 x_2]     (L↓, L↑ of rank 1)
//   x_2 <- σ(Σ_k T2_k Θ2[:, :, k]),  T2 = [B_2ᵀx_1, L↓B_2ᵀx_1, L↑B_2ᵀx_1, x_2, L↓x_2, L↑x_2]
// with σ the sigmoid. TopoBench's code takes L↓x_1 twice in T1 (for L↑x_1) and L↑B_2ᵀx_1 twice
// in T2 (for L↓B_2ᵀx_1); `topobench_compatible` reproduces that, the default follows the
// formula. Operators incidence_1, incidence_2, hodge_laplacian_0, down_/up_laplacian_1 and _2.
// Parameters in_linear_<r>, layers.<i>.weight_<r> (channels × channels × taps).
// Written as an operator schedule (sccnn_custom_schedule).
#pragma once

#include "topos/nn/operator_schedule.hpp"

namespace topos::models {

struct SCCNNCustomOptions {
  explicit SCCNNCustomOptions(std::int64_t channels) : channels_(channels) {}
  TORCH_ARG(std::int64_t, channels);
  TORCH_ARG(int, n_layers) = 2;
  TORCH_ARG(nn::Activation, update_func) = nn::Activation::sigmoid;
  TORCH_ARG(bool, topobench_compatible) = false;
};

inline nn::OperatorSchedule sccnn_custom_schedule(const SCCNNCustomOptions& o) {
  using namespace nn::ops;
  const auto c = o.channels();
  const bool compat = o.topobench_compatible();
  nn::OperatorSchedule s;
  for (int r = 0; r < 3; ++r)
    s.input("x_" + std::to_string(r), r, c).output("x_" + std::to_string(r), r);
  s.operator_input("incidence_1", 1, 0)
      .operator_input("incidence_2", 2, 1)
      .operator_input("hodge_laplacian_0", 0, 0)
      .operator_input("down_laplacian_1", 1, 1)
      .operator_input("up_laplacian_1", 1, 1)
      .operator_input("down_laplacian_2", 2, 2)
      .operator_input("up_laplacian_2", 2, 2);
  for (int r = 0; r < 3; ++r)
    s.step(into(r).sum(from(r).linear("in_linear_" + std::to_string(r), c)));
  for (int l = 0; l < o.n_layers(); ++l) {
    const std::string p = "layers." + std::to_string(l) + ".weight_";
    const auto u = o.update_func();
    s.parallel(
        {into(0)
             .filter(p + "0", c, from(0), from(0).via("hodge_laplacian_0"),
                     from(1).via("incidence_1"),
                     from(1).via("incidence_1").via("hodge_laplacian_0"))
             .act(u),
         into(1)
             .filter(p + "1", c, from(0).via_t("incidence_1"),
                     from(0).via_t("incidence_1").via("down_laplacian_1"),
                     from(0).via_t("incidence_1").via("up_laplacian_1"), from(1),
                     from(1).via("down_laplacian_1"),
                     from(1).via(compat ? "down_laplacian_1" : "up_laplacian_1"),
                     from(2).via("incidence_2"), from(2).via("incidence_2").via("down_laplacian_1"),
                     from(2).via("incidence_2").via("up_laplacian_1"))
             .act(u),
         into(2)
             .filter(
                 p + "2", c, from(1).via_t("incidence_2"),
                 from(1).via_t("incidence_2").via(compat ? "up_laplacian_2" : "down_laplacian_2"),
                 from(1).via_t("incidence_2").via("up_laplacian_2"), from(2),
                 from(2).via("down_laplacian_2"), from(2).via("up_laplacian_2"))
             .act(u)});
  }
  return s;
}

}  // namespace topos::models
