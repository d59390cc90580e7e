// topos/core/spectral.hpp
// Dense spectral operators on a domain's matrices: the largest-magnitude eigenvalue (TopoNetX's
// normalisations), the Moore-Penrose pseudo-inverse as numpy computes it, the harmonic basis and
// projector (ker L), and the Hodge decomposition of a cochain (gradient + curl + harmonic, the
// harmonic part being the projection onto ker L). Std + Eigen only.
// Their definitions (spectral-inl.hpp) instantiate Eigen's dense eigen- and singular-value
// solvers, 17 s of compile time at -O3 for any translation unit that merely includes them: with
// topos::core_compiled (TOPOS_CORE_COMPILED) they are compiled once in src/core.cpp and this
// header only declares them; with topos::core alone they are inline here.
#pragma once

#include "topos/config.hpp"
#include "topos/core/operators.hpp"
#include "topos/core/sparse_matrix.hpp"

namespace topos {

/// The eigenvalue of largest magnitude of a symmetric matrix (scipy's eigsh(k=1, which="LM")),
/// with its sign. Dense solver up to 1500 rows, Lanczos with full reorthogonalisation above.
TOPOS_CORE_INLINE double largest_magnitude_eigenvalue(const SparseMatrix& m);

/// Moore-Penrose pseudo-inverse as numpy.linalg.pinv computes it (float64 SVD, singular values
/// below 1e-15 * the largest treated as zero). Symmetric input goes through an eigendecomposition.
TOPOS_CORE_INLINE Eigen::MatrixXd pinv(const Eigen::MatrixXd& a, double rcond = 1e-15);

/// An orthonormal basis (columns) of the kernel of a symmetric positive semi-definite matrix
/// (the harmonic space when L is a Hodge Laplacian): eigenvectors with eigenvalue below `tol`
/// times the largest. Dense; its column count is the Betti number.
TOPOS_CORE_INLINE Eigen::MatrixXd harmonic_basis(const SparseMatrix& l, double tol = 1e-9);

/// The projector onto ker L (dense n x n), as used by SAN/HSN-style harmonic filters.
TOPOS_CORE_INLINE Eigen::MatrixXd harmonic_projector(const SparseMatrix& l, double tol = 1e-9);

/// The Hodge decomposition x = B_k^T a + B_{k+1} b + h of a k-cochain x (B_k: n_{k-1} x n_k,
/// B_{k+1}: n_k x n_{k+1}; either may be empty): gradient = the projection onto im B_k^T,
/// curl = the projection onto im B_{k+1}, harmonic = the rest (in ker L_k). The three parts are
/// mutually orthogonal because B_k B_{k+1} = 0.
struct HodgeDecomposition {
  Eigen::VectorXd gradient, curl, harmonic;
};

TOPOS_CORE_INLINE HodgeDecomposition hodge_decomposition(const SparseMatrix& b_k,
                                                         const SparseMatrix& b_next,
                                                         const Eigen::VectorXd& x);

}  // namespace topos

#if !defined(TOPOS_CORE_COMPILED) || defined(TOPOS_CORE_COMPILED_SOURCE)
#include "topos/core/spectral-inl.hpp"
#endif
