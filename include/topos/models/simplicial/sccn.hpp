// topos/models/simplicial/sccn.hpp
// SCCN (Yang, Sala & Bogdan, "Efficient representation learning for higher-order data with
// simplicial complexes", 2022; TopoModelX SCCN): every rank r ≤ max_rank sums linear messages
// from itself (over an adjacency), from rank r+1 (over B_{r+1}) and from rank r-1 (over
// B_rᵀ), then an update. Parameters layers.<i>.convs_same_rank.rank_<r>.weight,
// convs_high_to_low.rank_<r> (r < max_rank), convs_low_to_high.rank_<r> (r ≥ 1), all
// channels × channels. TopoModelX's layer always aggregates by a sum.
// Written as an operator schedule (sccn_schedule).
#pragma once

#include "topos/nn/operator_schedule.hpp"

namespace topos::models {

struct SCCNOptions {
  SCCNOptions(std::int64_t channels, int max_rank) : channels_(channels), max_rank_(max_rank) {}
  TORCH_ARG(std::int64_t, channels);
  TORCH_ARG(int, max_rank);
  TORCH_ARG(int, n_layers) = 2;
  TORCH_ARG(nn::Activation,
            update_func) = nn::Activation::sigmoid;  ///< relu, sigmoid, tanh or none
};

/// The schedule: per layer one parallel group, each rank summing its same-rank, higher-rank and
/// lower-rank convolutions.
inline nn::OperatorSchedule sccn_schedule(const SCCNOptions& o) {
  using namespace nn::ops;
  if (o.max_rank() < 1) throw std::invalid_argument("SCCN: max_rank must be >= 1");
  if (o.n_layers() < 1) throw std::invalid_argument("SCCN: n_layers must be >= 1");
  const auto u = o.update_func();
  if (u != nn::Activation::none && u != nn::Activation::relu && u != nn::Activation::sigmoid &&
      u != nn::Activation::tanh)
    throw std::invalid_argument("SCCN: update_func must be relu, sigmoid, tanh or none");
  const auto c = o.channels();
  const int R = o.max_rank();
  nn::OperatorSchedule s;
  for (int r = 0; r <= R; ++r) {
    const auto k = std::to_string(r);
    s.input("x_" + k, r, c).output("x_" + k, r).operator_input("adjacency_" + k, r, r);
    if (r >= 1) s.operator_input("incidence_" + k, r, r - 1);
  }
  for (int l = 0; l < o.n_layers(); ++l) {
    const auto p = "layers." + std::to_string(l) + ".";
    std::vector<nn::OperatorStep> ranks;
    for (int r = 0; r <= R; ++r) {
      const auto k = "rank_" + std::to_string(r);
      std::vector<Term> terms{
          from(r).conv(p + "convs_same_rank." + k, c).via("adjacency_" + std::to_string(r))};
      if (r < R)
        terms.push_back(from(r + 1)
                            .conv(p + "convs_high_to_low." + k, c)
                            .via("incidence_" + std::to_string(r + 1)));
      if (r > 0)
        terms.push_back(from(r - 1)
                            .conv(p + "convs_low_to_high." + k, c)
                            .via_t("incidence_" + std::to_string(r)));
      ranks.push_back(into(r).sum(std::move(terms)).act(u));
    }
    s.parallel(std::move(ranks));
  }
  return s;
}

class SCCNImpl : public nn::Cloneable<SCCNImpl, nn::OperatorNetworkImpl> {
 public:
  explicit SCCNImpl(const SCCNOptions& o) : Cloneable(sccn_schedule(o)), options(o) {}
  /// x[r] for r = 0..max_rank; incidences[r - 1] = B_r (rank r-1 × rank r) for r = 1..max_rank;
  /// adjacencies[r] the same-rank neighbourhood of rank r.
  std::vector<torch::Tensor> forward(const std::vector<torch::Tensor>& x,
                                     const std::vector<nn::SparseOperator>& incidences,
                                     const std::vector<nn::SparseOperator>& adjacencies) {
    const auto R = static_cast<std::size_t>(options.max_rank());
    if (x.size() != R + 1 || incidences.size() != R || adjacencies.size() != R + 1)
      throw std::invalid_argument("SCCN: expected features and adjacencies of ranks 0.." +
                                  std::to_string(R) + " and incidences of ranks 1.." +
                                  std::to_string(R));
    std::map<std::string, torch::Tensor> in;
    std::map<std::string, nn::SparseOperator> ops;
    std::vector<std::string> out;
    for (std::size_t r = 0; r <= R; ++r) {
      const auto k = std::to_string(r);
      in["x_" + k] = x[r];
      out.push_back("x_" + k);
      ops["adjacency_" + k] = adjacencies[r];
      if (r >= 1) ops["incidence_" + k] = incidences[r - 1];
    }
    return run(in, ops, out);
  }
  SCCNOptions options;
};
TORCH_MODULE(SCCN);

}  // namespace topos::models
