// topos/core/operators.hpp
// Operators built from incidence matrices, shared by every domain: up-, down- and Hodge
// Laplacians (optionally weighted), adjacency from an incidence (TopoNetX's
// incidence_to_adjacency) and the symmetric normalised Laplacian; the dense spectral ones (the
// largest eigenvalue, the pseudo-inverse, the Hodge decomposition) are in spectral.hpp, whose
// Eigen solvers cost a translation unit seconds to compile. Conventions follow
// TopoNetX: B_k is n_{k-1} x n_k, L_k = B_k^T B_k + B_{k+1} B_{k+1}^T, "unsigned" means the
// entrywise absolute value of the signed result. Std + Eigen only.
#pragma once

#include "topos/core/sparse_matrix.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <random>

namespace topos {

/// B W B^T, with W = diag(weights) (no weights: W = I). B = B_{k+1} gives the up-Laplacian of rank
/// k.
inline SparseMatrix up_laplacian(const SparseMatrix& b_next, const Eigen::VectorXd& weights = {}) {
  const SparseMatrix bt = sparse::transpose(b_next);
  if (weights.size() == 0) return sparse::multiply_sum_symmetric({{&b_next, &bt}});
  return sparse::multiply(b_next, sparse::scale(bt, weights, {}));
}

/// B^T W B, with W = diag(weights) on the rows of B (no weights: W = I). B = B_k gives the
/// down-Laplacian of rank k.
inline SparseMatrix down_laplacian(const SparseMatrix& b, const Eigen::VectorXd& weights = {}) {
  const SparseMatrix bt = sparse::transpose(b);
  if (weights.size() == 0) return sparse::multiply_sum_symmetric({{&bt, &b}});
  return sparse::multiply(bt, sparse::scale(b, weights, {}));
}

/// The off-diagonal part of |B|^T |B| (TopoNetX's incidence_to_adjacency with s = 1, unsigned):
/// entry (i, j) counts the rows of B shared by columns i and j.
inline SparseMatrix incidence_to_adjacency(const SparseMatrix& b) {
  const SparseMatrix a = sparse::abs(b), at = sparse::transpose(a);
  return sparse::without_diagonal(sparse::multiply_sum_symmetric({{&at, &a}}));
}

/// D^{-1/2} L D^{-1/2} with D = diag(row sums of |L|), zero where a row is zero (TopoNetX's
/// SimplicialComplex.normalized_laplacian_matrix applied to the signed Hodge Laplacian).
inline SparseMatrix normalized_laplacian(const SparseMatrix& l) {
  Eigen::VectorXd d = sparse::abs_row_sums(l);
  for (Eigen::Index i = 0; i < d.size(); ++i) d[i] = d[i] > 0 ? 1.0 / std::sqrt(d[i]) : 0.0;
  return sparse::scale(l, d, d);
}

}  // namespace topos
