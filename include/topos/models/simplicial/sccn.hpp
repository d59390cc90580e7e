// topos/models/simplicial/sccn.hpp
// SCCN (Yang, Sala & Bogdan, "Efficient representation learning for higher-order data with
// simplicial complexes", 2022; TopoModelX SCCN): every rank r ≤ max_rank sums linear messages
// from itself (over an adjacency), from rank r+1 (over B_{r+1}) and from rank r-1 (over
// B_rᵀ), then an update. Parameters layers.<i>.convs_same_rank.rank_<r>.weight,
// convs_high_to_low.rank_<r> (r < max_rank), convs_low_to_high.rank_<r> (r ≥ 1), all
// channels × channels. TopoModelX's layer always aggregates by a sum.
#pragma once

#include "topos/nn/conv.hpp"

namespace topos::models {

struct SCCNOptions {
  SCCNOptions(std::int64_t channels, int max_rank) : channels_(channels), max_rank_(max_rank) {}
  TORCH_ARG(std::int64_t, channels);
  TORCH_ARG(int, max_rank);
  TORCH_ARG(int, n_layers) = 2;
  TORCH_ARG(nn::Update, update_func) = nn::Update::sigmoid;  ///< relu, sigmoid, tanh or none
};

class SCCNImpl : public torch::nn::Module {
 public:
  explicit SCCNImpl(const SCCNOptions& o) : options(o) {
    if (o.max_rank() < 1) throw std::invalid_argument("SCCN: max_rank must be >= 1");
    if (o.n_layers() < 1) throw std::invalid_argument("SCCN: n_layers must be >= 1");
    const auto u = o.update_func();
    if (u != nn::Update::none && u != nn::Update::relu && u != nn::Update::sigmoid &&
        u != nn::Update::tanh)
      throw std::invalid_argument("SCCN: update_func must be relu, sigmoid, tanh or none");
    const auto c = o.channels();
    auto list = register_module("layers", torch::nn::ModuleList());
    for (int l = 0; l < o.n_layers(); ++l) {
      auto m = std::make_shared<torch::nn::Module>();
      auto same = nn::submodule_group(*m, "convs_same_rank"),
           up = nn::submodule_group(*m, "convs_low_to_high"),
           down = nn::submodule_group(*m, "convs_high_to_low");
      Layer layer;
      for (int r = 0; r <= o.max_rank(); ++r) {
        const auto key = "rank_" + std::to_string(r);
        layer.same.push_back(same->register_module(key, nn::Conv(nn::ConvOptions(c, c))));
        layer.low_to_high.push_back(
            r >= 1 ? up->register_module(key, nn::Conv(nn::ConvOptions(c, c))) : nn::Conv(nullptr));
        layer.high_to_low.push_back(
            r < o.max_rank() ? down->register_module(key, nn::Conv(nn::ConvOptions(c, c)))
                             : nn::Conv(nullptr));
      }
      layers_.push_back(std::move(layer));
      list->push_back(m);
    }
  }
  /// x[r] for r = 0..max_rank; incidences[r - 1] = B_r (rank r-1 × rank r) for r = 1..max_rank;
  /// adjacencies[r] the same-rank neighbourhood of rank r.
  std::vector<torch::Tensor> forward(std::vector<torch::Tensor> x,
                                     const std::vector<nn::SparseOperator>& incidences,
                                     const std::vector<nn::SparseOperator>& adjacencies) {
    const auto R = static_cast<std::size_t>(options.max_rank());
    if (x.size() != R + 1 || incidences.size() != R || adjacencies.size() != R + 1)
      throw std::invalid_argument("SCCN: expected features and adjacencies of ranks 0.." +
                                  std::to_string(R) + " and incidences of ranks 1.." +
                                  std::to_string(R));
    std::vector<nn::SparseOperator> transposed;
    for (const auto& b : incidences) transposed.push_back(b.t());
    for (auto& l : layers_) {
      std::vector<torch::Tensor> y(R + 1);
      for (std::size_t r = 0; r <= R; ++r) {
        std::vector<torch::Tensor> m{l.same[r]->forward(x[r], adjacencies[r])};
        if (r < R) m.push_back(l.high_to_low[r]->forward(x[r + 1], incidences[r]));
        if (r > 0) m.push_back(l.low_to_high[r]->forward(x[r - 1], transposed[r - 1]));
        y[r] = nn::aggregate_messages(m, nn::Aggr::sum, options.update_func());
      }
      x = std::move(y);
    }
    return x;
  }
  SCCNOptions options;

 private:
  struct Layer {
    std::vector<nn::Conv> same, low_to_high, high_to_low;
  };
  std::vector<Layer> layers_;
};
TORCH_MODULE(SCCN);

}  // namespace topos::models
