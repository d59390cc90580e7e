// topos/models/simplicial/scn2.hpp
// SCN2 (Wu et al., "Simplicial complex neural networks", 2023; TopoModelX SCN2): on every
// rank r, x_r <- relu(L̃_r · x_r W_r) with the normalised Laplacian L̃_r; the ranks do not mix.
// Written as an operator schedule (scn2_schedule).
// Parameters layers.<i>.conv_<r>_to_<r>.weight, as in TopoModelX.
#pragma once

#include "topos/nn/operator_schedule.hpp"

namespace topos::models {

struct SCN2Options {
  SCN2Options(std::int64_t c0, std::int64_t c1, std::int64_t c2)
      : in_channels_0_(c0), in_channels_1_(c1), in_channels_2_(c2) {}
  TORCH_ARG(std::int64_t, in_channels_0);
  TORCH_ARG(std::int64_t, in_channels_1);
  TORCH_ARG(std::int64_t, in_channels_2);
  TORCH_ARG(int, n_layers) = 2;
};

/// The schedule: per layer and rank, x_r <- relu(laplacian_r · (x_r W)).
inline nn::OperatorSchedule scn2_schedule(const SCN2Options& o) {
  using namespace nn::ops;
  const std::array<std::int64_t, 3> c{o.in_channels_0(), o.in_channels_1(), o.in_channels_2()};
  nn::OperatorSchedule s;
  for (int r = 0; r < 3; ++r)
    s.input("x_" + std::to_string(r), r, c[r])
        .operator_input("laplacian_" + std::to_string(r), r, r)
        .output("x_" + std::to_string(r), r);
  for (int l = 0; l < o.n_layers(); ++l)
    for (int r = 0; r < 3; ++r) {
      const auto R = std::to_string(r);
      s.step(into(r)
                 .sum(from(r)
                          .conv("layers." + std::to_string(l) + ".conv_" + R + "_to_" + R, c[r])
                          .via("laplacian_" + R))
                 .act(nn::Activation::relu));
    }
  return s;
}

class SCN2Impl : public nn::Cloneable<SCN2Impl, nn::OperatorNetworkImpl> {
 public:
  explicit SCN2Impl(const SCN2Options& o) : Cloneable(scn2_schedule(o)), options(o) {}
  /// (x_0, x_1, x_2) and the normalised Laplacians of ranks 0, 1, 2.
  std::vector<torch::Tensor> forward(const std::vector<torch::Tensor>& x,
                                     const std::array<nn::SparseOperator, 3>& laplacian) {
    if (x.size() != 3) throw std::invalid_argument("SCN2: expected features of ranks 0, 1, 2");
    return run({{"x_0", x[0]}, {"x_1", x[1]}, {"x_2", x[2]}},
               {{"laplacian_0", laplacian[0]},
                {"laplacian_1", laplacian[1]},
                {"laplacian_2", laplacian[2]}},
               {"x_0", "x_1", "x_2"});
  }
  SCN2Options options;
};
TORCH_MODULE(SCN2);

}  // namespace topos::models
