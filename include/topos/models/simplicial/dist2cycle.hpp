// topos/models/simplicial/dist2cycle.hpp
// Dist2Cycle (Keros, Nanda & Subr, "Dist2Cycle: a simplicial neural network for homology
// localization", 2022; TopoModelX Dist2Cycle): on the edges, with M = A_1 ⊙ (L_1↓ + I)⁺ (the
// edge adjacency masking the pseudo-inverse of the shifted lower Laplacian, both passed in),
// each layer is x <- fc(relu(M x)), fc a linear map with bias ("layers.<i>.fc_neigh").
// TopoModelX's layers ignore their input and return fc(relu(M)) (M's rows as features, so
// `channels` must equal the number of edges; only the last layer counts): the compatible mode.
// The default applies M to the features, which gives the same numbers for x = I.
#pragma once

#include "topos/nn/conv.hpp"

namespace topos::models {

struct Dist2CycleOptions {
  explicit Dist2CycleOptions(std::int64_t channels) : channels_(channels) {}
  TORCH_ARG(std::int64_t, channels);
  TORCH_ARG(int, n_layers) = 2;
  TORCH_ARG(bool, topomodelx_compatible) =
      false;  ///< every layer returns fc(relu(M)), ignoring its input
};

class Dist2CycleImpl : public torch::nn::Module {
 public:
  explicit Dist2CycleImpl(const Dist2CycleOptions& o) : options(o) {
    if (o.n_layers() < 1) throw std::invalid_argument("Dist2Cycle: n_layers must be >= 1");
    auto list = register_module("layers", torch::nn::ModuleList());
    for (int l = 0; l < o.n_layers(); ++l) {
      auto m = std::make_shared<torch::nn::Module>();
      fc_.push_back(m->register_module("fc_neigh", torch::nn::Linear(o.channels(), o.channels())));
      list->push_back(m);
    }
  }
  /// Edge features, the pseudo-inverse L⁺ and the edge adjacency (any two operators multiplied
  /// entrywise).
  torch::Tensor forward(torch::Tensor x, const nn::SparseOperator& linv,
                        const nn::SparseOperator& adjacency) {
    const auto M = nn::SparseOperator::hadamard(adjacency, linv);
    if (options.topomodelx_compatible()) {
      if (M.cols != options.channels())
        throw std::invalid_argument("Dist2Cycle: TopoModelX-compatible mode needs channels (" +
                                    std::to_string(options.channels()) + ") = number of edges (" +
                                    std::to_string(M.cols) + ")");
      const auto R = M.with_values(torch::relu(M.values));  // relu(M), still sparse
      for (auto& fc : fc_) x = nn::spmm(R, fc->weight.t().contiguous()) + fc->bias;
      return x;
    }
    for (auto& fc : fc_) x = fc->forward(torch::relu(nn::spmm(M, x)));
    return x;
  }
  Dist2CycleOptions options;

 private:
  std::vector<torch::nn::Linear> fc_;
};
TORCH_MODULE(Dist2Cycle);

}  // namespace topos::models
