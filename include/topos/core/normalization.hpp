// topos/core/normalization.hpp
// The normalisations TopoModelX's models are fed, as toponetx.utils.normalization computes them
// (same names, same formulas, same handling of zero rows), on sparse matrices:
//   compute_laplacian_normalized_matrix(L)          L / lambda_max(L)
//   compute_x_laplacian_normalized_matrix(L, Lx)    Lx / lambda_max(L)
//   compute_kipf_adjacency_normalized_matrix(A)     D^{-1/2} (|A| + m I)^T D^{-1/2}, D = row sums
//   compute_xu_asymmetric_normalized_matrix(B)      D^{-1} B, D = row sums of |B| (zero rows stay
//     0)
//   compute_bunch_normalized_matrices(B1, B2)       Bunch et al.'s B1N, B1TN, B2N, B2TN
// lambda_max is the eigenvalue of largest magnitude (scipy's eigsh "LM"). Std + Eigen only.
#pragma once

#include "topos/core/operators.hpp"
#include "topos/core/spectral.hpp"
#include "topos/core/sparse_matrix.hpp"

#include <array>
#include <cmath>

namespace topos {

inline SparseMatrix compute_laplacian_normalized_matrix(const SparseMatrix& l) {
  if (l.rows() != l.cols())
    throw ComplexError("compute_laplacian_normalized_matrix: the Laplacian must be square");
  return sparse::pruned(SparseMatrix(l * (1.0 / largest_magnitude_eigenvalue(l))));
}

inline SparseMatrix compute_x_laplacian_normalized_matrix(const SparseMatrix& l,
                                                          const SparseMatrix& lx) {
  if (l.rows() != l.cols())
    throw ComplexError("compute_x_laplacian_normalized_matrix: the Laplacian must be square");
  return sparse::pruned(SparseMatrix(lx * (1.0 / largest_magnitude_eigenvalue(l))));
}

inline SparseMatrix compute_kipf_adjacency_normalized_matrix(const SparseMatrix& a,
                                                             bool add_identity = false,
                                                             double identity_multiplier = 1.0) {
  if (a.rows() != a.cols())
    throw ComplexError("compute_kipf_adjacency_normalized_matrix: the adjacency must be square");
  SparseMatrix m = sparse::abs(a);
  if (add_identity) m = sparse::add(m, sparse::identity(a.rows(), identity_multiplier));
  Eigen::VectorXd d = sparse::row_sums(m);
  for (Eigen::Index i = 0; i < d.size(); ++i) {
    const double r = std::pow(d[i], -0.5);
    d[i] = std::isinf(r) ? 0.0 : r;  // NumPy: 0^-0.5 = inf -> 0 (a negative sum gives NaN, kept)
  }
  return sparse::scale(sparse::transpose(m), d, d);
}

/// `is_sparse` selects TopoNetX's sparse or dense branch; both give D^{-1} B with zero rows left
/// at zero, so the result is the same (the flag is accepted for parity of the vocabulary).
inline SparseMatrix compute_xu_asymmetric_normalized_matrix(const SparseMatrix& b,
                                                            bool is_sparse = true) {
  (void)is_sparse;
  Eigen::VectorXd d = sparse::abs_row_sums(b);
  for (Eigen::Index i = 0; i < d.size(); ++i) d[i] = d[i] != 0.0 ? 1.0 / d[i] : 0.0;
  return sparse::scale(b, d, {});
}

/// (B1N, B1TN, B2N, B2TN) of Bunch, You, Fung, Singh (TopoNetX's
/// compute_bunch_normalized_matrices):
///   D2 = diag(max(rowsum |B2|, 1)), D1 = 2 diag(rowsum(|B1| D2)), D3 = I / 3, D5 = diag(rowsum
///     |B2|),
///   B1N = D1^+ B1, B1TN = D2 B1^T D1^+, B2N = B2 D3, B2TN = B2^T D5^+   (^+: pseudo-inverse).
inline std::array<SparseMatrix, 4> compute_bunch_normalized_matrices(const SparseMatrix& b1,
                                                                     const SparseMatrix& b2) {
  if (b1.cols() != b2.rows()) {
    throw ComplexError("compute_bunch_normalized_matrices: B1 has " + std::to_string(b1.cols()) +
                       " columns but B2 has " + std::to_string(b2.rows()) + " rows");
  }
  const auto pinv_diag = [](Eigen::VectorXd d) {
    // numpy.linalg.pinv of a diagonal matrix: 1/d above 1e-15 * max |d|, else 0.
    const double cut = d.size() ? 1e-15 * d.cwiseAbs().maxCoeff() : 0.0;
    for (Eigen::Index i = 0; i < d.size(); ++i) d[i] = std::abs(d[i]) > cut ? 1.0 / d[i] : 0.0;
    return d;
  };
  Eigen::VectorXd d2 = sparse::abs_row_sums(b2).cwiseMax(1.0);
  const Eigen::VectorXd d1 = 2.0 * sparse::abs_row_sums(sparse::scale(sparse::abs(b1), {}, d2));
  const Eigen::VectorXd d1p = pinv_diag(d1);
  const Eigen::VectorXd d5p = pinv_diag(sparse::abs_row_sums(b2));
  const SparseMatrix b1t = sparse::transpose(b1), b2t = sparse::transpose(b2);
  return {sparse::scale(b1, d1p, {}), sparse::scale(b1t, d2, d1p),
          sparse::scale(b2, {}, Eigen::VectorXd::Constant(b2.cols(), 1.0 / 3.0)),
          sparse::scale(b2t, {}, d5p)};
}

}  // namespace topos
