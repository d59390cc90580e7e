// topos/models/simplicial/dist2cycle.hpp
// Dist2Cycle (Keros, Nanda & Subr, "Dist2Cycle: a simplicial neural network for homology
// localization", 2022; TopoModelX Dist2Cycle): on the edges, with M = A_1 ⊙ (L_1↓ + I)⁺ (the
// edge adjacency masking the pseudo-inverse of the shifted lower Laplacian, both passed in),
// each layer is x <- fc(relu(M x)), fc a linear map with bias ("layers.<i>.fc_neigh").
// TopoModelX's layers ignore their input and return fc(relu(M)) (M's rows as features, so
// `channels` must equal the number of edges; only the last layer counts): the compatible mode.
// The default applies M to the features, which gives the same numbers for x = I; it is an
// operator schedule (dist2cycle_schedule) over the operator "neighborhood" = M.
#pragma once

#include "topos/nn/operator_schedule.hpp"

namespace topos::models {

struct Dist2CycleOptions {
  explicit Dist2CycleOptions(std::int64_t channels) : channels_(channels) {}
  TORCH_ARG(std::int64_t, channels);
  TORCH_ARG(int, n_layers) = 2;
  TORCH_ARG(bool, topomodelx_compatible) =
      false;  ///< every layer returns fc(relu(M)), ignoring its input
};

/// The schedule: per layer x_1 <- fc(relu(M x_1)).
inline nn::OperatorSchedule dist2cycle_schedule(const Dist2CycleOptions& o) {
  using namespace nn::ops;
  if (o.n_layers() < 1) throw std::invalid_argument("Dist2Cycle: n_layers must be >= 1");
  nn::OperatorSchedule s;
  s.input("x_1", 1, o.channels()).operator_input("neighborhood", 1, 1).output("x_1", 1);
  for (int l = 0; l < o.n_layers(); ++l)
    s.step(into(1).sum(from(1)
                           .via("neighborhood")
                           .act(nn::Activation::relu)
                           .linear("layers." + std::to_string(l) + ".fc_neigh", o.channels())));
  return s;
}

class Dist2CycleImpl : public nn::Cloneable<Dist2CycleImpl, nn::OperatorNetworkImpl> {
 public:
  explicit Dist2CycleImpl(const Dist2CycleOptions& o)
      : Cloneable(dist2cycle_schedule(o)), options(o) {}
  /// Edge features, the pseudo-inverse L⁺ and the edge adjacency (any two operators multiplied
  /// entrywise).
  torch::Tensor forward(const torch::Tensor& x, const nn::SparseOperator& linv,
                        const nn::SparseOperator& adjacency) {
    const auto M = nn::SparseOperator::hadamard(adjacency, linv);
    if (!options.topomodelx_compatible())
      return run({{"x_1", x}}, {{"neighborhood", M}}, {"x_1"})[0];
    if (M.cols != options.channels())
      throw std::invalid_argument("Dist2Cycle: TopoModelX-compatible mode needs channels (" +
                                  std::to_string(options.channels()) + ") = number of edges (" +
                                  std::to_string(M.cols) + ")");
    // Only the last layer counts: fc(relu(M)) = relu(M) Wᵀ + b, relu(M) still sparse.
    const auto fc = "layers." + std::to_string(options.n_layers() - 1) + ".fc_neigh.";
    const auto params = named_parameters();
    const auto R = M.with_values(torch::relu(M.values));
    return nn::spmm(R, params[fc + "weight"].t().contiguous()) + params[fc + "bias"];
  }
  Dist2CycleOptions options;
};
TORCH_MODULE(Dist2Cycle);

}  // namespace topos::models
