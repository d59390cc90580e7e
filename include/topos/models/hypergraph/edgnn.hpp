// topos/models/hypergraph/edgnn.hpp
// EDGNN (Wang et al., "Equivariant hypergraph diffusion neural operators", ICLR 2023;
// TopoBench's EDGNN with EquivSetConv, one-layer MLPs and sum aggregation): one convolution,
// its weights shared by every layer, applied `n_layers` times to dropout(x), each followed by
// relu; dropout once more at the end. The convolution, with x0 the network's input:
//   X_e = Σ_{v ∈ e} W_1 x_v                                 (nodes -> hyperedges)
//   X_v = Σ_{e ∋ v} W_2 [x_v ‖ X_e]                          (back, per incidence)
//   x'  = W (½ X_v + ½ x0)                                  (restart with α = ½)
// W_2 acts on a concatenation per incidence, so it splits into a node half (with W_2's bias,
// counted once per hyperedge of v: the "node_degree" diagonal) and a hyperedge half over H.
// Operators "incidence_1" (H, nodes × hyperedges) and "node_degree" (diag of H's row sums).
// reset_edgnn_parameters draws W_2's halves as the one Linear TopoBench has.
// Written as an operator schedule (edgnn_schedule).
#pragma once

#include "topos/nn/operator_schedule.hpp"

#include <cmath>

namespace topos::models {

struct EDGNNOptions {
  explicit EDGNNOptions(std::int64_t channels) : channels_(channels) {}
  TORCH_ARG(std::int64_t, channels);
  TORCH_ARG(int, n_layers) = 2;
  TORCH_ARG(double, dropout) = 0.5;
  TORCH_ARG(double, restart_alpha) = 0.5;
};

inline nn::OperatorSchedule edgnn_schedule(const EDGNNOptions& o) {
  using namespace nn::ops;
  const auto c = o.channels();
  const double a = o.restart_alpha();
  nn::OperatorSchedule s;
  s.input("x_0", 0, c, "x0")
      .operator_input("incidence_1", 1, 0)
      .operator_input("node_degree", 0, 0)
      .output("x_0", 0);
  s.step(into(0).sum(from(0, "x0")));
  for (int l = 0; l < o.n_layers(); ++l) {
    s.step(into(0, "in").sum(from(0).dropout(o.dropout())));
    s.step(into(1).sum(from(0, "in").linear("conv.W1", c).via_t("incidence_1")));
    s.step(into(0, "xv").sum(from(0, "in").linear("conv.W2_node", c).via("node_degree"),
                             from(1).linear("conv.W2_edge", c, false).via("incidence_1")));
    s.step(into(0)
               .sum(from(0, "xv").scale(1 - a), from(0, "x0").scale(a))
               .linear("conv.W", c)
               .act(nn::Activation::relu));
  }
  s.step(into(0).sum(from(0).dropout(o.dropout())));
  return s;
}

/// Draws W_2's two halves as the one Linear(2c, c) they are in TopoBench (PyTorch's default,
/// U(±1/sqrt(2c)) for weight and bias): each half alone would start √2 wider.
inline void reset_edgnn_parameters(const nn::OperatorNetworkImpl& net, std::int64_t channels) {
  torch::NoGradGuard no_grad;
  const double bound = 1.0 / std::sqrt(2.0 * static_cast<double>(channels));
  for (const char* path : {"conv.W2_node.weight", "conv.W2_node.bias", "conv.W2_edge.weight"})
    net.parameter(path).uniform_(-bound, bound);
}

}  // namespace topos::models
