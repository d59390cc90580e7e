// topos/models/topobench/batch-inl.hpp
// collate's implementation (topos/models/topobench/batch.hpp declares it), compiled once into
// topos::topobench (src/topobench.cpp), or inline with TOPOS_HEADER_ONLY (topos/config.hpp).
#pragma once

#include "topos/models/topobench/batch.hpp"

#include <cstring>

namespace topos::models::topobench {

namespace detail {
/// The block-diagonal stack of part(i) over the graphs `which`, each part sorted triplets.
template <class Part>
nn::SparseOperator block_diagonal(const std::vector<std::size_t>& which, Part part) {
  std::int64_t nnz = 0;
  for (auto i : which) nnz += part(i).nnz();
  std::vector<std::int64_t> r, c;
  r.reserve(static_cast<std::size_t>(nnz)), c.reserve(static_cast<std::size_t>(nnz));
  auto values = torch::empty({nnz}, torch::kFloat);
  float* vp = values.data_ptr<float>();
  std::int64_t rows = 0, cols = 0;
  for (auto i : which) {
    const Triplets& t = part(i);
    for (std::int64_t k = 0; k < t.nnz(); ++k)
      r.push_back(t.row[static_cast<std::size_t>(k)] + rows),
          c.push_back(t.col[static_cast<std::size_t>(k)] + cols);
    if (t.nnz()) std::memcpy(vp, t.value.data(), sizeof(float) * t.value.size());
    vp += t.nnz(), rows += t.rows, cols += t.cols;
  }
  return nn::SparseOperator::from_sorted(rows, cols, r, c, values);
}
/// The concatenation of scale(i) over the graphs, `size` entries; undefined (no scale) when every
/// graph's is empty. A graph without edges has an empty scale whether the operator is scaled or
/// not, so the first graph alone cannot decide.
template <class Scale>
torch::Tensor concatenated(const std::vector<std::size_t>& which, std::int64_t size, Scale scale) {
  std::vector<float> all;
  for (auto i : which) all.insert(all.end(), scale(i).begin(), scale(i).end());
  if (all.empty()) return {};
  if (static_cast<std::int64_t>(all.size()) != size)
    throw std::invalid_argument("topobench::collate: a factored operator's scales have " +
                                std::to_string(all.size()) + " entries for " +
                                std::to_string(size) + " cells");
  return torch::tensor(all, torch::kFloat);
}
}  // namespace detail

/// The block-diagonal union of `graphs[which[i]]`. Every graph must have the same ranks, widths
/// and operator names (one lifting of one dataset).
TOPOS_INLINE Batch collate(const std::vector<LiftedGraph>& graphs,
                           const std::vector<std::size_t>& which) {
  if (which.empty()) throw std::invalid_argument("topobench::collate: an empty batch");
  const LiftedGraph& first = graphs.at(which.front());
  const std::size_t ranks = first.sizes.size();
  Batch b;
  b.num_graphs = static_cast<std::int64_t>(which.size());
  for (std::size_t r = 0; r < ranks; ++r) {
    std::int64_t rows = 0;
    for (auto i : which) rows += graphs[i].sizes.at(r);
    const std::int64_t width = first.widths[r];
    auto x = torch::empty({rows, width}, torch::kFloat);
    auto owner = torch::empty({rows}, torch::kLong);
    float* xp = x.data_ptr<float>();
    std::int64_t* op = owner.data_ptr<std::int64_t>();
    std::int64_t g = 0;
    for (auto i : which) {
      const auto& lg = graphs[i];
      if (lg.widths.size() != ranks || lg.widths[r] != width)
        throw std::invalid_argument("topobench::collate: graphs lifted with different widths");
      const auto n = lg.sizes[r];
      if (n) std::memcpy(xp, lg.x[r].data(), sizeof(float) * static_cast<std::size_t>(n * width));
      std::fill(op, op + n, g++);
      xp += n * width, op += n;
    }
    b.x.push_back(x), b.batch.push_back(owner);
  }
  for (const auto& [name, t0] : first.operators)
    b.operators.emplace(
        name, detail::block_diagonal(which, [&, n = name](std::size_t i) -> const Triplets& {
          return graphs[i].operators.at(n);
        }));
  for (const auto& [name, f0] : first.factored) {
    const auto at = [&, n = name](std::size_t i) -> const FactoredTriplets& {
      return graphs[i].factored.at(n);
    };
    std::vector<std::vector<nn::SparseOperator>> products(f0.products.size());
    for (std::size_t k = 0; k < products.size(); ++k)
      for (std::size_t j = 0; j < f0.products[k].size(); ++j)
        products[k].push_back(detail::block_diagonal(
            which, [&](std::size_t i) -> const Triplets& { return at(i).products.at(k).at(j); }));
    const auto left = detail::concatenated(
        which, products.at(0).front().rows,
        [&](std::size_t i) -> const std::vector<float>& { return at(i).left; });
    const auto right = detail::concatenated(
        which, products.at(0).back().cols,
        [&](std::size_t i) -> const std::vector<float>& { return at(i).right; });
    b.operators.emplace(name, nn::SparseOperator::product_sum(std::move(products), left, right));
  }
  std::vector<std::int64_t> labels;
  for (auto i : which) labels.push_back(graphs[i].label);
  b.labels = torch::tensor(labels, torch::kLong);
  return b;
}

}  // namespace topos::models::topobench
