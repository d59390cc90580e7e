// topos/models/topobench/batch-inl.hpp
// collate's implementation (topos/models/topobench/batch.hpp declares it), compiled once into
// topos::topobench (src/topobench.cpp), or inline with TOPOS_HEADER_ONLY (topos/config.hpp).
#pragma once

#include "topos/models/topobench/batch.hpp"

#include <cstring>
#include <limits>
#include <numeric>

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

/// A batch's features, cell owners and labels (what collate and Collator share).
TOPOS_INLINE Batch collate_features(const std::vector<LiftedGraph>& graphs,
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
  std::vector<std::int64_t> labels;
  for (auto i : which) labels.push_back(graphs[i].label);
  b.labels = torch::tensor(labels, torch::kLong);
  return b;
}

/// The factored operators of the batch, each factor block-diagonal, the scales concatenated.
TOPOS_INLINE void collate_factored(const std::vector<LiftedGraph>& graphs,
                                   const std::vector<std::size_t>& which, Batch& b) {
  const LiftedGraph& first = graphs.at(which.front());
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
}
}  // namespace detail

/// The block-diagonal union of `graphs[which[i]]`. Every graph must have the same ranks, widths
/// and operator names (one lifting of one dataset).
TOPOS_INLINE Batch collate(const std::vector<LiftedGraph>& graphs,
                           const std::vector<std::size_t>& which) {
  Batch b = detail::collate_features(graphs, which);
  const LiftedGraph& first = graphs[which.front()];
  for (const auto& [name, t0] : first.operators)
    b.operators.emplace(
        name, detail::block_diagonal(which, [&, n = name](std::size_t i) -> const Triplets& {
          return graphs[i].operators.at(n);
        }));
  detail::collate_factored(graphs, which, b);
  return b;
}

TOPOS_INLINE Collator::Collator(const std::vector<LiftedGraph>& graphs,
                                const std::vector<std::size_t>& part)
    : graphs_(graphs), csr_(graphs.size()) {
  if (graphs.empty()) return;
  for (const auto& [name, t] : graphs.front().operators) names_.push_back(name);
  std::vector<std::size_t> all;
  if (part.empty()) {
    all.resize(graphs.size());
    std::iota(all.begin(), all.end(), std::size_t{0});
  }
  for (auto i : part.empty() ? all : part) {
    const LiftedGraph& g = graphs.at(i);
    auto& ops = csr_[i];
    ops.clear();
    for (const auto& name : names_) {
      const auto it = g.operators.find(name);
      if (it == g.operators.end())
        throw std::invalid_argument("topobench::Collator: graph " + std::to_string(i) +
                                    " has no operator '" + name + "'");
      const Triplets& t = it->second;
      if (t.nnz() > std::numeric_limits<std::int32_t>::max() ||
          std::max(t.rows, t.cols) > std::numeric_limits<std::int32_t>::max())
        throw std::invalid_argument("topobench::Collator: operator '" + name + "' of graph " +
                                    std::to_string(i) + " has over 2^31 entries or cells");
      Csr c;  // from_sorted's counting, on one graph
      c.entries = &t;
      c.crow.assign(static_cast<std::size_t>(t.rows) + 1, 0);
      c.t_crow.assign(static_cast<std::size_t>(t.cols) + 1, 0);
      for (std::int64_t k = 0; k < t.nnz(); ++k)
        ++c.crow[static_cast<std::size_t>(t.row[k]) + 1],
            ++c.t_crow[static_cast<std::size_t>(t.col[k]) + 1];
      std::partial_sum(c.crow.begin(), c.crow.end(), c.crow.begin());
      std::partial_sum(c.t_crow.begin(), c.t_crow.end(), c.t_crow.begin());
      c.t_perm.resize(static_cast<std::size_t>(t.nnz()));
      std::vector<std::int32_t> next(c.t_crow.begin(), c.t_crow.end() - 1);
      for (std::int64_t k = 0; k < t.nnz(); ++k)  // rows ascending: each column of Aᵀ sorted
        c.t_perm[static_cast<std::size_t>(next[static_cast<std::size_t>(t.col[k])]++)] =
            static_cast<std::int32_t>(k);
      ops.push_back(std::move(c));
    }
  }
}

TOPOS_INLINE Batch Collator::operator()(const std::vector<std::size_t>& which) const {
  for (auto i : which)
    if (i >= csr_.size() || csr_[i].size() != names_.size())
      throw std::invalid_argument("topobench::Collator: graph " + std::to_string(i) +
                                  " was not prepared (not in the Collator's part)");
  Batch b = detail::collate_features(graphs_, which);
  for (std::size_t o = 0; o < names_.size(); ++o) {
    std::int64_t rows = 0, cols = 0, nnz = 0;
    for (auto i : which) {
      const Triplets& t = *csr_[i][o].entries;
      rows += t.rows, cols += t.cols, nnz += t.nnz();
    }
    nn::SparseOperator a;
    a.rows = rows, a.cols = cols;
    const auto index = [](std::int64_t n) { return torch::empty({n}, torch::kLong); };
    a.crow = index(rows + 1), a.t_crow = index(cols + 1);
    a.col = index(nnz), a.row = index(nnz), a.t_col = index(nnz), a.t_row = index(nnz),
    a.t_perm = index(nnz);
    a.values = torch::empty({nnz}, torch::kFloat);
    std::int64_t *crow = a.crow.data_ptr<std::int64_t>(),
                 *t_crow = a.t_crow.data_ptr<std::int64_t>(), *col = a.col.data_ptr<std::int64_t>(),
                 *row = a.row.data_ptr<std::int64_t>(), *t_col = a.t_col.data_ptr<std::int64_t>(),
                 *t_row = a.t_row.data_ptr<std::int64_t>(),
                 *t_perm = a.t_perm.data_ptr<std::int64_t>();
    float* values = a.values.data_ptr<float>();
    crow[0] = 0, t_crow[0] = 0;
    std::int64_t R = 0, C = 0, N = 0;  // the graph's offsets in rows, columns and entries
    for (auto i : which) {
      const Csr& c = csr_[i][o];
      const Triplets& t = *c.entries;
      const std::int64_t n = t.nnz();
      for (std::int64_t r = 1; r <= t.rows; ++r)
        crow[R + r] = c.crow[static_cast<std::size_t>(r)] + N;
      for (std::int64_t j = 1; j <= t.cols; ++j)
        t_crow[C + j] = c.t_crow[static_cast<std::size_t>(j)] + N;
      for (std::int64_t k = 0; k < n; ++k) {
        const auto uk = static_cast<std::size_t>(k);
        row[N + k] = t.row[uk] + R, col[N + k] = t.col[uk] + C;
        const auto q = static_cast<std::size_t>(c.t_perm[uk]);
        t_perm[N + k] = static_cast<std::int64_t>(q) + N;
        t_col[N + k] = t.row[q] + R, t_row[N + k] = t.col[q] + C;
      }
      if (n) std::memcpy(values + N, t.value.data(), sizeof(float) * static_cast<std::size_t>(n));
      R += t.rows, C += t.cols, N += n;
    }
    b.operators.emplace(names_[o], std::move(a));
  }
  detail::collate_factored(graphs_, which, b);
  return b;
}

}  // namespace topos::models::topobench
