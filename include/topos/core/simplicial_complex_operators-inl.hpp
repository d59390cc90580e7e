// topos/core/simplicial_complex_operators-inl.hpp
// The definitions of SimplicialComplex's operators (simplicial_complex.hpp), TopoNetX's: the
// (co)incidence matrices from the stored face ids, the inclusion between any two ranks, the up,
// down, Hodge and weighted Hodge Laplacians, and the adjacency and coadjacency through a rank.
#pragma once

#include "topos/core/operators.hpp"
#include "topos/core/simplicial_complex.hpp"
#include "topos/core/sparse_matrix.hpp"

#include <algorithm>
#include <cstdint>
#include <string>
#include <utility>
#include <vector>

namespace topos {

inline SparseMatrix SimplicialComplex::incidence_matrix(int rank, Signed sign) const {
  const bool signed_ = sign == Signed::yes;
  require_rank(rank, "incidence_matrix");
  if (rank == 0) {
    SparseMatrix m(1, num_nodes());
    for (Index v = 0; v < num_nodes(); ++v) m.data().append(1.0, static_cast<Eigen::Index>(v));
    m.outerIndexPtr()[1] = num_nodes();
    return m;
  }
  return sparse::transpose(coboundary(rank, signed_));
}

inline SparseMatrix SimplicialComplex::inclusion_matrix(int rank, int to_rank) const {
  require_rank(rank, "inclusion_matrix");
  require_rank(to_rank, "inclusion_matrix");
  if (rank == to_rank)
    throw ComplexError("inclusion_matrix: ranks must differ (got " + std::to_string(rank) +
                       " twice)");
  const int lo = std::min(rank, to_rank), hi = std::max(rank, to_rank);
  SparseMatrix up(num_cells(hi), num_cells(lo));
  std::vector<Index> ids;
  for (Index j = 0; j < num_cells(hi); ++j) {
    ids.clear();
    for_each_subset(data(hi, j), hi + 1, lo + 1,
                    [&](const Index* f) { ids.push_back(find_sorted(lo, f)); });
    std::sort(ids.begin(), ids.end());
    for (Index i : ids) up.data().append(1.0, static_cast<Eigen::Index>(i));
    up.outerIndexPtr()[j + 1] = static_cast<std::int64_t>(up.data().size());
  }
  if (rank > to_rank) return up;
  return sparse::transpose(up);
}

inline SparseMatrix SimplicialComplex::up_laplacian_matrix(int rank, bool signed_) const {
  if (rank < 0 || rank >= dim())
    throw ComplexError("up_laplacian_matrix: rank " + std::to_string(rank) + " must be in [0, " +
                       std::to_string(dim() - 1) + "] (the complex has dimension " +
                       std::to_string(dim()) + ")");
  const SparseMatrix bt = coboundary(rank + 1, true), b = sparse::transpose(bt);
  SparseMatrix l = sparse::multiply_sum_symmetric({{&b, &bt}});
  if (!signed_) sparse::make_abs(l);
  return l;
}

inline SparseMatrix SimplicialComplex::down_laplacian_matrix(int rank, bool signed_) const {
  if (rank < 1 || rank > dim())
    throw ComplexError("down_laplacian_matrix: rank " + std::to_string(rank) + " must be in [1, " +
                       std::to_string(dim()) + "] (the complex has dimension " +
                       std::to_string(dim()) + ")");
  const SparseMatrix bt = coboundary(rank, true), b = sparse::transpose(bt);
  SparseMatrix l = sparse::multiply_sum_symmetric({{&bt, &b}});
  if (!signed_) sparse::make_abs(l);
  return l;
}

inline SparseMatrix SimplicialComplex::hodge_laplacian_matrix(int rank, bool signed_) const {
  require_rank(rank, "hodge_laplacian_matrix");
  SparseMatrix l = signed_hodge(rank);
  if (!signed_) sparse::make_abs(l);
  return l;
}

inline SparseMatrix SimplicialComplex::weighted_hodge_laplacian_matrix(
    int rank, const Eigen::VectorXd& w_below, const Eigen::VectorXd& w_above) const {
  require_rank(rank, "weighted_hodge_laplacian_matrix");
  SparseMatrix l(num_cells(rank), num_cells(rank));
  if (rank > 0)
    l = sparse::add(l, down_laplacian(incidence_matrix(rank),
                                      weights_or_empty(w_below, num_cells(rank - 1), "below")));
  if (rank < dim())
    l = sparse::add(l, up_laplacian(incidence_matrix(rank + 1),
                                    weights_or_empty(w_above, num_cells(rank + 1), "above")));
  return l;
}

inline SparseMatrix SimplicialComplex::adjacency_matrix_via(int rank, int via_rank) const {
  if (via_rank <= rank)
    throw ComplexError("adjacency_matrix_via: via rank " + std::to_string(via_rank) +
                       " must be above rank " + std::to_string(rank));
  return incidence_to_adjacency(inclusion_matrix(via_rank, rank));
}

inline SparseMatrix SimplicialComplex::coadjacency_matrix_via(int rank, int via_rank) const {
  if (via_rank >= rank)
    throw ComplexError("coadjacency_matrix_via: via rank " + std::to_string(via_rank) +
                       " must be below rank " + std::to_string(rank));
  return incidence_to_adjacency(inclusion_matrix(via_rank, rank));
}

inline Eigen::VectorXd SimplicialComplex::weights_or_empty(const Eigen::VectorXd& w, Index n,
                                                           const char* which) {
  if (w.size() != 0 && w.size() != n)
    throw ComplexError(std::string("weighted_hodge_laplacian_matrix: ") + which + " weights have " +
                       std::to_string(w.size()) + " entries, expected " + std::to_string(n));
  return w;
}

inline SparseMatrix SimplicialComplex::signed_hodge(int rank) const {
  if (rank == 0 && dim() == 0) return SparseMatrix(num_nodes(), num_nodes());
  if (rank == 0) return up_laplacian_matrix(0);
  if (rank == dim()) return down_laplacian_matrix(rank);
  const SparseMatrix bt = coboundary(rank, true), b = sparse::transpose(bt);
  const SparseMatrix ct = coboundary(rank + 1, true), c = sparse::transpose(ct);
  return sparse::multiply_sum_symmetric({{&bt, &b}, {&c, &ct}});
}

inline SparseMatrix SimplicialComplex::coboundary(int k, bool signed_) const {
  const Index n = num_cells(k);
  const std::size_t w = static_cast<std::size_t>(k) + 1;
  SparseMatrix m(n, num_cells(k - 1));
  auto& d = m.data();
  d.resize(static_cast<Eigen::Index>(n * static_cast<Index>(w)));
  std::int64_t* outer = m.outerIndexPtr();
  std::int64_t* index = m.innerIndexPtr();
  double* value = m.valuePtr();
  const Index* faces = ranks_[static_cast<std::size_t>(k)].faces.data();
  const std::int64_t total = n * static_cast<Index>(w);
  for (Index j = 0; j <= n; ++j) outer[j] = j * static_cast<Index>(w);
  // With lexicographic face ids, dropping node i gives a larger face than dropping node
  // i + 1, so the faces in descending i are already in id order: no sort.
  if (ranks_[static_cast<std::size_t>(k) - 1].order.empty()) {
    for (std::int64_t e = 0; e < total; e += static_cast<std::int64_t>(w))
      for (std::size_t i = 0; i < w; ++i) {
        index[e + static_cast<std::int64_t>(w - 1 - i)] = faces[e + static_cast<std::int64_t>(i)];
        value[e + static_cast<std::int64_t>(w - 1 - i)] = signed_ && (i % 2) ? -1.0 : 1.0;
      }
    return m;
  }
  std::pair<Index, double> row[kMaxArity];
  for (std::int64_t e = 0; e < total; e += static_cast<std::int64_t>(w)) {
    for (std::size_t i = 0; i < w; ++i)
      row[i] = {faces[e + static_cast<std::int64_t>(i)], signed_ && (i % 2) ? -1.0 : 1.0};
    std::sort(row, row + w, [](const auto& a, const auto& b) { return a.first < b.first; });
    for (std::size_t i = 0; i < w; ++i)
      index[e + static_cast<std::int64_t>(i)] = row[i].first,
                value[e + static_cast<std::int64_t>(i)] = row[i].second;
  }
  return m;
}

}  // namespace topos
