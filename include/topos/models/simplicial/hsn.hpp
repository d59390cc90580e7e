// topos/models/simplicial/hsn.hpp
// HSN (Hajij et al., "High skip networks: a higher order generalization of skip connections",
// 2022; TopoModelX HSN): node features reach the nodes by two two-step routes, node → node →
// node over the adjacency and node → edge → node over the incidence, summed, then sigmoid:
// x_0 <- σ(A σ(A x_0 W_1) W_3 + B_1 σ(B_1ᵀ x_0 W_2) W_4). Parameters
// layers.<i>.conv_level1_0_to_0 / conv_level1_0_to_1 / conv_level2_0_to_0 / conv_level2_1_to_0.
// Written as an operator schedule (hsn_schedule).
#pragma once

#include "topos/nn/operator_schedule.hpp"

namespace topos::models {

struct HSNOptions {
  explicit HSNOptions(std::int64_t channels) : channels_(channels) {}
  TORCH_ARG(std::int64_t, channels);
  TORCH_ARG(int, n_layers) = 2;
};

/// The schedule: per layer the two first-level convolutions read one snapshot, then the node step.
inline nn::OperatorSchedule hsn_schedule(const HSNOptions& o) {
  using namespace nn::ops;
  using nn::Activation;
  if (o.n_layers() < 1) throw std::invalid_argument("HSN: n_layers must be >= 1");
  const auto c = o.channels();
  nn::OperatorSchedule s;
  s.input("x_0", 0, c)
      .operator_input("incidence_1", 1, 0)
      .operator_input("adjacency_0", 0, 0)
      .output("x_0", 0);
  for (int l = 0; l < o.n_layers(); ++l) {
    const auto p = "layers." + std::to_string(l) + ".";
    s.parallel({into(0, "level1")
                    .sum(from(0).conv(p + "conv_level1_0_to_0", c).via("adjacency_0"))
                    .act(Activation::sigmoid),
                into(1, "level1")
                    .sum(from(0).conv(p + "conv_level1_0_to_1", c).via_t("incidence_1"))
                    .act(Activation::sigmoid)});
    s.step(into(0)
               .sum(from(0, "level1").conv(p + "conv_level2_0_to_0", c).via("adjacency_0"),
                    from(1, "level1").conv(p + "conv_level2_1_to_0", c).via("incidence_1"))
               .act(Activation::sigmoid));
  }
  return s;
}

class HSNImpl : public nn::Cloneable<HSNImpl, nn::OperatorNetworkImpl> {
 public:
  explicit HSNImpl(const HSNOptions& o) : Cloneable(hsn_schedule(o)), options(o) {}
  /// Node features, the node × edge incidence B_1 and the node adjacency.
  torch::Tensor forward(const torch::Tensor& x_0, const nn::SparseOperator& incidence_1,
                        const nn::SparseOperator& adjacency_0) {
    return run({{"x_0", x_0}}, {{"incidence_1", incidence_1}, {"adjacency_0", adjacency_0}},
               {"x_0"})[0];
  }
  HSNOptions options;
};
TORCH_MODULE(HSN);

}  // namespace topos::models
