// topos/nn/complex_batch-inl.hpp
// ComplexBatch's collate and to (complex_batch.hpp): compiled once in src/nn.cpp, or inlined
// with TOPOS_HEADER_ONLY (topos/config.hpp).
#pragma once

#include "topos/nn/complex_batch.hpp"

#include <stdexcept>
#include <string>

namespace topos::nn {

TOPOS_INLINE ComplexBatch ComplexBatch::collate(const std::vector<ComplexView>& complexes,
                                                int max_rank, const ComplexView* layout) {
  ComplexBatch b;
  b.num_complexes_ = static_cast<std::int64_t>(complexes.size());
  b.counts_.assign(static_cast<std::size_t>(max_rank) + 1,
                   std::vector<std::int64_t>(complexes.size(), 0));
  b.ptr_.assign(static_cast<std::size_t>(max_rank) + 1,
                std::vector<std::int64_t>(complexes.size() + 1, 0));
  for (std::size_t c = 0; c < complexes.size(); ++c) {
    for (int r = 0; r <= max_rank; ++r) {
      const std::int64_t n = static_cast<std::size_t>(r) < complexes[c].sizes.size()
                                 ? complexes[c].sizes[static_cast<std::size_t>(r)]
                                 : 0;
      b.counts_[static_cast<std::size_t>(r)][c] = n;
      b.ptr_[static_cast<std::size_t>(r)][c + 1] = b.ptr_[static_cast<std::size_t>(r)][c] + n;
    }
  }
  for (int r = 0; r <= max_rank; ++r) {
    std::vector<std::int64_t> batch;
    batch.reserve(static_cast<std::size_t>(b.size(r)));
    for (std::size_t c = 0; c < complexes.size(); ++c)
      batch.insert(batch.end(), static_cast<std::size_t>(b.counts_[static_cast<std::size_t>(r)][c]),
                   static_cast<std::int64_t>(c));
    b.batch_.push_back(torch::tensor(batch, torch::kLong));
  }
  if (complexes.empty()) {
    if (layout == nullptr) return b;
    for (const auto& [name, n] : layout->neighborhoods) {
      TensorNeighborhood t;
      t.source_rank = n.source_rank;
      t.target_rank = n.target_rank;
      t.source = torch::zeros({0}, torch::kLong);
      t.target = torch::zeros({0}, torch::kLong);
      if (!n.values.empty()) t.values = torch::zeros({0}, torch::kFloat);
      if (!n.backward_values.empty()) t.backward_values = torch::zeros({0}, torch::kFloat);
      if (!n.roles.empty()) t.roles = torch::zeros({0}, torch::kChar);
      b.neighborhoods_[name] = t;
    }
    return b;
  }
  for (const auto& [name, first] : complexes[0].neighborhoods) {
    std::vector<std::int64_t> src, tgt;
    std::vector<float> vals, bvals;
    std::vector<std::int8_t> roles;
    // Values and roles come from any complex that has them: the first may have no pairs (a
    // timestep without contacts) and so no values, while later ones do.
    bool has_vals = false, has_bvals = false, has_roles = false;
    for (const auto& v : complexes) {
      const auto it = v.neighborhoods.find(name);
      if (it == v.neighborhoods.end()) continue;
      has_vals = has_vals || !it->second.values.empty();
      has_bvals = has_bvals || !it->second.backward_values.empty();
      has_roles = has_roles || !it->second.roles.empty();
    }
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
      if (n.num_source != b.counts_[static_cast<std::size_t>(n.source_rank)][c] ||
          n.num_target != b.counts_[static_cast<std::size_t>(n.target_rank)][c])
        throw std::invalid_argument("ComplexBatch: neighborhood '" + name + "' of complex " +
                                    std::to_string(c) + " does not match the cell counts");
      const std::int64_t so = b.ptr_[static_cast<std::size_t>(n.source_rank)][c],
                         to = b.ptr_[static_cast<std::size_t>(n.target_rank)][c];
      for (std::size_t k = 0; k < n.source.size(); ++k) {
        src.push_back(n.source[k] + so);
        tgt.push_back(n.target[k] + to);
        if (has_vals) vals.push_back(static_cast<float>(n.values.empty() ? 1.0 : n.values[k]));
        if (has_bvals)
          bvals.push_back(static_cast<float>(n.backward_values.empty()
                                                 ? (n.values.empty() ? 1.0 : n.values[k])
                                                 : n.backward_values[k]));
        if (has_roles) roles.push_back(n.roles.empty() ? 0 : n.roles[k]);
      }
    }
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
    t.num_source = b.size(first.source_rank);
    t.num_target = b.size(first.target_rank);
    t.one_per_target = static_cast<std::int64_t>(tgt.size()) == t.num_target;
    for (std::size_t k = 0; t.one_per_target && k < tgt.size(); ++k)
      t.one_per_target = tgt[k] == static_cast<std::int64_t>(k);
    b.neighborhoods_[name] = t;
  }
  return b;
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
