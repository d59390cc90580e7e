// topos/nn/complex_batch.hpp
// ComplexBatch: the disjoint union of many complexes (all timesteps of a trajectory, or many
// scenes), a GraphsTuple for combinatorial complexes. Per rank: counts per complex, offsets
// (ptr) and a batch vector; named, directed neighbourhoods with indices shifted by the offsets
// of their source and target ranks. Every rank up to max_rank is present, possibly with zero
// rows, so "no contacts" needs no special case. Tensors can be moved to any device. collate and to
// are compiled once (complex_batch-inl.hpp, src/nn.cpp; topos/config.hpp).
#pragma once

#include "topos/config.hpp"
#include "topos/core/neighborhood.hpp"

#include <torch/torch.h>

#include <map>
#include <stdexcept>
#include <string>
#include <vector>

namespace topos::nn {

/// A Neighborhood as tensors: source/target int64 [nnz], optional float values (and the
/// backward's values, see Neighborhood::backward_values) and int8 roles.
struct TensorNeighborhood {
  int source_rank = 0, target_rank = 0;
  torch::Tensor source, target, values, backward_values, roles;
  std::int64_t num_source = 0, num_target = 0;
  bool one_per_target = false;  ///< target[k] == k for every pair: aggregation is a plain gather
  std::int64_t nnz() const { return source.defined() ? source.size(0) : 0; }
};

/// One complex as message passing sees it: cell counts per rank and named neighbourhoods.
struct ComplexView {
  std::vector<std::int64_t> sizes;  ///< cells per rank, ranks 0..max
  std::map<std::string, Neighborhood> neighborhoods;
};

class ComplexBatch {
 public:
  ComplexBatch() = default;

  /// Concatenates complexes; all must name the same neighbourhoods with the same ranks. An
  /// empty batch takes its neighbourhood names and ranks from `layout` (else it has none).
  static ComplexBatch collate(const std::vector<ComplexView>& complexes, int max_rank,
                              const ComplexView* layout = nullptr);

  std::int64_t num_complexes() const { return num_complexes_; }
  int max_rank() const { return static_cast<int>(counts_.size()) - 1; }
  std::int64_t size(int r) const { return ptr_.at(static_cast<std::size_t>(r)).back(); }
  const std::vector<std::int64_t>& counts(int r) const {
    return counts_.at(static_cast<std::size_t>(r));
  }
  const std::vector<std::int64_t>& ptr(int r) const { return ptr_.at(static_cast<std::size_t>(r)); }
  const torch::Tensor& batch(int r) const { return batch_.at(static_cast<std::size_t>(r)); }
  bool has_neighborhood(const std::string& n) const { return neighborhoods_.count(n) > 0; }
  const TensorNeighborhood& neighborhood(const std::string& n) const {
    auto it = neighborhoods_.find(n);
    if (it == neighborhoods_.end())
      throw std::out_of_range("ComplexBatch: no neighborhood '" + n + "'");
    return it->second;
  }
  const std::map<std::string, TensorNeighborhood>& neighborhoods() const { return neighborhoods_; }

  /// Copies every tensor to `device`.
  ComplexBatch to(const torch::Device& device) const;

 private:
  void collate_counts(const std::vector<ComplexView>& complexes, int max_rank);
  TensorNeighborhood collate_neighborhood(const std::vector<ComplexView>& complexes,
                                          const std::string& name, const Neighborhood& first) const;

  std::int64_t num_complexes_ = 0;
  std::vector<std::vector<std::int64_t>> counts_, ptr_;
  std::vector<torch::Tensor> batch_;
  std::map<std::string, TensorNeighborhood> neighborhoods_;
};

}  // namespace topos::nn

#ifdef TOPOS_HEADER_ONLY
#include "topos/nn/complex_batch-inl.hpp"
#endif
