// examples/tdl/filters.hpp
// The operators tdl's training tasks filter with: low-pass versions of the Hodge Laplacians.
// Shared by `tdl train` (karate club) and `tdl classify` (batched point-cloud complexes).
#pragma once

#include "topos/core/operators.hpp"
#include "topos/core/sparse.hpp"

namespace tdl_cli {

/// I - D^{-1/2} L D^{-1/2} (D the row sums of |L|; spectrum in [0, 2]). Where a cell's class
/// agrees with its neighbours', filters must be low-pass: a Laplacian itself is high-pass, and
/// trained on labelled cells it pushes each unlabelled neighbour towards the other class (on
/// the karate club SCN2 and SCCNN with the normalised Laplacians reach 0.29 and 0.54 on the
/// held-out members, below chance; with these filters 0.9 and more).
inline topos::SparseMatrix low_pass_filter(const topos::SparseMatrix& laplacian) {
  const Eigen::VectorXd minus = -Eigen::VectorXd::Ones(laplacian.rows());
  return topos::sparse::add(
      topos::sparse::identity(laplacian.rows()),
      topos::sparse::scale(topos::normalized_laplacian(laplacian), minus, {}));
}

}  // namespace tdl_cli
