// topos/nn/complex_batch-inl.hpp
// ComplexBatch's collate and to (complex_batch.hpp): compiled once in src/nn.cpp, or inlined
// with TOPOS_HEADER_ONLY (topos/config.hpp).
#pragma once

#include "topos/nn/complex_batch.hpp"

#include <stdexcept>
#include <string>

namespace topos::nn {

namespace detail {

/// One neighbourhood's pairs concatenated over a batch's complexes (ComplexBatch::collate), each
/// complex's cells offset by those of the complexes before it. Values and roles come from any
/// complex that has them: the first may have no pairs (a timestep without contacts) and so no
/// values, while later ones do; a complex without them gets 1 (values) and 0 (roles).
struct CollatedPairs {
  std::vector<std::int64_t> src, tgt;
  std::vector<float> vals, bvals;
  std::vector<std::int8_t> roles;
  bool has_vals = false, has_bvals = false, has_roles = false;

  void append(const Neighborhood& n, std::int64_t source_offset, std::int64_t target_offset) {
    for (std::size_t k = 0; k < n.source.size(); ++k) {
      src.push_back(n.source[k] + source_offset);
      tgt.push_back(n.target[k] + target_offset);
      const double value = n.values.empty() ? 1.0 : n.values[k];
      if (has_vals) vals.push_back(static_cast<float>(value));
      if (has_bvals)
        bvals.push_back(
            static_cast<float>(n.backward_values.empty() ? value : n.backward_values[k]));
      if (has_roles) roles.push_back(n.roles.empty() ? 0 : n.roles[k]);
    }
  }

  TensorNeighborhood tensors(const Neighborhood& first, std::int64_t num_source,
                             std::int64_t num_target) const {
    TensorNeighborhood t;
    t.source_rank = first.source_rank;
    t.target_rank = first.target_rank;
    t.source = torch::tensor(src, torch::kLong);
    t.target = torch::tensor(tgt, torch::kLong);
    if (has_vals) t.values = torch::tensor(vals, torch::kFloat);
    if (has_bvals) t.backward_values = torch::tensor(bvals, torch::kFloat);
    if (has_roles)
      t.roles = torch::tensor(std::vector<std::int64_t>(roles.begin(), roles.end()), torch::kLong)
                    .to(torch::kChar);
    t.num_source = num_source;
    t.num_target = num_target;
    t.one_per_target = static_cast<std::int64_t>(tgt.size()) == t.num_target;
    for (std::size_t k = 0; t.one_per_target && k < tgt.size(); ++k)
      t.one_per_target = tgt[k] == static_cast<std::int64_t>(k);
    return t;
  }
};

/// A neighbourhood of `layout` with no pairs: an empty batch's (ComplexBatch::collate).
TOPOS_INLINE TensorNeighborhood empty_neighborhood(const Neighborhood& n) {
  TensorNeighborhood t;
  t.source_rank = n.source_rank;
  t.target_rank = n.target_rank;
  t.source = torch::zeros({0}, torch::kLong);
  t.target = torch::zeros({0}, torch::kLong);
  if (!n.values.empty()) t.values = torch::zeros({0}, torch::kFloat);
  if (!n.backward_values.empty()) t.backward_values = torch::zeros({0}, torch::kFloat);
  if (!n.roles.empty()) t.roles = torch::zeros({0}, torch::kChar);
  return t;
}

}  // namespace detail

TOPOS_INLINE ComplexBatch ComplexBatch::collate(const std::vector<ComplexView>& complexes,
                                                int max_rank, const ComplexView* layout) {
  ComplexBatch b;
  b.collate_counts(complexes, max_rank);
  if (complexes.empty()) {
    if (layout != nullptr)
      for (const auto& [name, n] : layout->neighborhoods)
        b.neighborhoods_[name] = detail::empty_neighborhood(n);
    return b;
  }
  for (const auto& [name, first] : complexes[0].neighborhoods)
    b.neighborhoods_[name] = b.collate_neighborhood(complexes, name, first);
  return b;
}

// Per rank: each complex's cell count, its first cell in the batch, and each cell's complex.
TOPOS_INLINE void ComplexBatch::collate_counts(const std::vector<ComplexView>& complexes,
                                               int max_rank) {
  const auto ranks = static_cast<std::size_t>(max_rank) + 1;
  num_complexes_ = static_cast<std::int64_t>(complexes.size());
  counts_.assign(ranks, std::vector<std::int64_t>(complexes.size(), 0));
  ptr_.assign(ranks, std::vector<std::int64_t>(complexes.size() + 1, 0));
  for (std::size_t c = 0; c < complexes.size(); ++c)
    for (std::size_t r = 0; r < ranks; ++r) {
      const std::int64_t n = r < complexes[c].sizes.size() ? complexes[c].sizes[r] : 0;
      counts_[r][c] = n;
      ptr_[r][c + 1] = ptr_[r][c] + n;
    }
  for (std::size_t r = 0; r < ranks; ++r) {
    std::vector<std::int64_t> batch;
    batch.reserve(static_cast<std::size_t>(ptr_[r].back()));
    for (std::size_t c = 0; c < complexes.size(); ++c)
      batch.insert(batch.end(), static_cast<std::size_t>(counts_[r][c]),
                   static_cast<std::int64_t>(c));
    batch_.push_back(torch::tensor(batch, torch::kLong));
  }
}

// The neighbourhood `name` of every complex (as `first`, the first complex's, has its ranks),
// checked against the cell counts and concatenated.
TOPOS_INLINE TensorNeighborhood
ComplexBatch::collate_neighborhood(const std::vector<ComplexView>& complexes,
                                   const std::string& name, const Neighborhood& first) const {
  detail::CollatedPairs pairs;
  for (const auto& v : complexes) {
    const auto it = v.neighborhoods.find(name);
    if (it == v.neighborhoods.end()) continue;
    pairs.has_vals = pairs.has_vals || !it->second.values.empty();
    pairs.has_bvals = pairs.has_bvals || !it->second.backward_values.empty();
    pairs.has_roles = pairs.has_roles || !it->second.roles.empty();
  }
  const auto max_rank = this->max_rank();
  for (std::size_t c = 0; c < complexes.size(); ++c) {
    auto it = complexes[c].neighborhoods.find(name);
    if (it == complexes[c].neighborhoods.end())
      throw std::invalid_argument("ComplexBatch: complex " + std::to_string(c) +
                                  " lacks neighborhood '" + name + "'");
    const Neighborhood& n = it->second;
    if (n.source_rank != first.source_rank || n.target_rank != first.target_rank)
      throw std::invalid_argument("ComplexBatch: neighborhood '" + name +
                                  "' has different ranks in complex " + std::to_string(c));
    if (n.source_rank > max_rank || n.target_rank > max_rank)
      throw std::invalid_argument("ComplexBatch: neighborhood '" + name + "' uses a rank above " +
                                  std::to_string(max_rank));
    const auto s = static_cast<std::size_t>(n.source_rank),
               t = static_cast<std::size_t>(n.target_rank);
    if (n.num_source != counts_[s][c] || n.num_target != counts_[t][c])
      throw std::invalid_argument("ComplexBatch: neighborhood '" + name + "' of complex " +
                                  std::to_string(c) + " does not match the cell counts");
    pairs.append(n, ptr_[s][c], ptr_[t][c]);
  }
  return pairs.tensors(first, size(first.source_rank), size(first.target_rank));
}

TOPOS_INLINE ComplexBatch ComplexBatch::to(const torch::Device& device) const {
  ComplexBatch b = *this;
  for (auto& t : b.batch_) t = t.to(device);
  for (auto& [n, t] : b.neighborhoods_) {
    t.source = t.source.to(device);
    t.target = t.target.to(device);
    if (t.values.defined()) t.values = t.values.to(device);
    if (t.backward_values.defined()) t.backward_values = t.backward_values.to(device);
    if (t.roles.defined()) t.roles = t.roles.to(device);
  }
  return b;
}

}  // namespace topos::nn
