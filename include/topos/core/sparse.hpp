// topos/core/sparse.hpp
// The sparse matrix type every topological operator returns (Eigen, row-major, 64-bit indices)
// and the few sparse kernels the operators need: a Gustavson product with sorted rows, explicit
// zeros dropped (so the sparsity pattern is exactly the nonzero entries, as NumPy's to_sparse
// of the dense matrix would give), entrywise abs, diagonal removal, row sums, scaling by
// diagonals. Also ComplexError, the exception of every domain. Std + Eigen only.
#pragma once

#include <Eigen/Dense>
#include <Eigen/SparseCore>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

namespace topos {

/// Thrown for every misuse of a complex: bad node ids, empty or repeated cells, rank-condition
/// violations, operators asked between ranks the complex does not have.
class ComplexError : public std::invalid_argument {
 public:
  using std::invalid_argument::invalid_argument;
};

/// The operator type of every domain: row-major, 64-bit indices, double values.
using SparseMatrix = Eigen::SparseMatrix<double, Eigen::RowMajor, std::int64_t>;

namespace sparse {

// Eigen 3.4's SparseMatrix has no move constructor: passing or returning one by value through
// std::move or ?: copies it. These helpers take const& and return a named local (NRVO).

/// The same matrix without stored zeros.
inline SparseMatrix pruned(const SparseMatrix& m) {
  SparseMatrix r = m;
  r.prune(0.0, 0.0);
  return r;
}

/// Row-major transpose by a counting sort over the columns (Eigen's generic transposed
/// assignment between two row-major matrices is an order of magnitude slower).
inline SparseMatrix transpose(const SparseMatrix& m) {
  if (!m.isCompressed()) {
    SparseMatrix c = m;
    c.makeCompressed();
    return transpose(c);
  }
  const SparseMatrix& c = m;
  const std::int64_t rows = c.rows(), cols = c.cols(), nnz = c.nonZeros();
  SparseMatrix t(cols, rows);
  if (nnz == 0) return t;
  std::int64_t* to = t.outerIndexPtr();
  const std::int64_t* co = c.outerIndexPtr();
  const std::int64_t* ci = c.innerIndexPtr();
  const double* cv = c.valuePtr();
  for (std::int64_t k = 0; k < nnz; ++k) ++to[ci[k] + 1];
  for (std::int64_t j = 0; j < cols; ++j) to[j + 1] += to[j];
  t.data().resize(static_cast<Eigen::Index>(nnz));
  std::int64_t* ti = t.innerIndexPtr();
  double* tv = t.valuePtr();
  std::vector<std::int64_t> fill(to, to + cols);
  for (std::int64_t i = 0; i < rows; ++i)
    for (std::int64_t k = co[i]; k < co[i + 1]; ++k) {
      const std::int64_t p = fill[static_cast<std::size_t>(ci[k])]++;
      ti[p] = i;
      tv[p] = cv[k];
    }
  return t;
}

/// A1 * B1 + A2 * B2 + ... in one Gustavson pass (dense accumulator): rows sorted, exact zeros
/// (cancellations) dropped. Every product must have the same shape.
inline SparseMatrix multiply_sum(const std::vector<std::pair<const SparseMatrix*, const SparseMatrix*>>& terms) {
  if (terms.empty()) throw ComplexError("sparse product: no terms");
  const std::int64_t n = terms[0].first->rows(), m = terms[0].second->cols();
  for (const auto& [a, b] : terms) {
    if (a->cols() != b->rows() || a->rows() != n || b->cols() != m) {
      throw ComplexError("sparse product: shapes (" + std::to_string(a->rows()) + "x" + std::to_string(a->cols()) + ") and (" +
                         std::to_string(b->rows()) + "x" + std::to_string(b->cols()) + ") do not match");
    }
    if (!a->isCompressed() || !b->isCompressed()) {
      std::vector<SparseMatrix> copies;
      copies.reserve(2 * terms.size());
      std::vector<std::pair<const SparseMatrix*, const SparseMatrix*>> t;
      for (const auto& [x, y] : terms) {
        copies.push_back(*x), copies.back().makeCompressed();
        copies.push_back(*y), copies.back().makeCompressed();
        t.push_back({&copies[copies.size() - 2], &copies.back()});
      }
      return multiply_sum(t);
    }
  }
  SparseMatrix c(n, m);
  auto& data = c.data();
  std::int64_t* outer = c.outerIndexPtr();
  {
    // The number of products bounds the result's size: reserve it once (no regrowth copies).
    std::int64_t flops = 0;
    for (const auto& [a, b] : terms)
      for (std::int64_t p = 0; p < a->nonZeros(); ++p) flops += b->outerIndexPtr()[a->innerIndexPtr()[p] + 1] - b->outerIndexPtr()[a->innerIndexPtr()[p]];
    data.reserve(static_cast<Eigen::Index>(std::min<std::int64_t>(flops, n * m)));
  }
  std::vector<double> acc(static_cast<std::size_t>(m), 0.0);
  std::vector<std::int64_t> mark(static_cast<std::size_t>(m), -1), cols;
  for (std::int64_t i = 0; i < n; ++i) {
    cols.clear();
    for (const auto& [a, b] : terms) {
      const std::int64_t* ao = a->outerIndexPtr();
      const std::int64_t* ai = a->innerIndexPtr();
      const double* av = a->valuePtr();
      const std::int64_t* bo = b->outerIndexPtr();
      const std::int64_t* bi = b->innerIndexPtr();
      const double* bv = b->valuePtr();
      for (std::int64_t p = ao[i]; p < ao[i + 1]; ++p) {
        const std::int64_t k = ai[p];
        const double x = av[p];
        for (std::int64_t q = bo[k]; q < bo[k + 1]; ++q) {
          const std::int64_t j = bi[q];
          if (mark[static_cast<std::size_t>(j)] != i) {
            mark[static_cast<std::size_t>(j)] = i;
            acc[static_cast<std::size_t>(j)] = x * bv[q];
            cols.push_back(j);
          } else {
            acc[static_cast<std::size_t>(j)] += x * bv[q];
          }
        }
      }
    }
    std::sort(cols.begin(), cols.end());
    for (std::int64_t j : cols) {
      const double v = acc[static_cast<std::size_t>(j)];
      if (v != 0.0) data.append(v, static_cast<Eigen::Index>(j));
    }
    outer[i + 1] = static_cast<std::int64_t>(data.size());
  }
  return c;
}

/// A * B (see multiply_sum).
inline SparseMatrix multiply(const SparseMatrix& a, const SparseMatrix& b) { return multiply_sum({{&a, &b}}); }

/// A + B (same shape), exact zeros dropped.
inline SparseMatrix add(const SparseMatrix& a, const SparseMatrix& b) {
  if (a.rows() != b.rows() || a.cols() != b.cols()) {
    throw ComplexError("sparse sum: shapes (" + std::to_string(a.rows()) + "x" + std::to_string(a.cols()) + ") and (" +
                       std::to_string(b.rows()) + "x" + std::to_string(b.cols()) + ") differ");
  }
  SparseMatrix s = a + b;
  s.prune(0.0, 0.0);
  return s;
}

/// Entrywise absolute value, in place.
inline void make_abs(SparseMatrix& m) {
  for (Eigen::Index k = 0; k < m.nonZeros(); ++k) m.valuePtr()[k] = std::abs(m.valuePtr()[k]);
}
/// Entrywise absolute value.
inline SparseMatrix abs(const SparseMatrix& m) {
  SparseMatrix r = m;
  make_abs(r);
  return r;
}

/// The matrix with its diagonal removed (scipy's setdiag(0) followed by dropping the zeros).
inline SparseMatrix without_diagonal(const SparseMatrix& m) {
  SparseMatrix out = m;
  out.prune([](const Eigen::Index& r, const Eigen::Index& c, const double& v) { return r != c && v != 0.0; });
  return out;
}

/// Sum of each row.
inline Eigen::VectorXd row_sums(const SparseMatrix& m) {
  Eigen::VectorXd s = Eigen::VectorXd::Zero(m.rows());
  for (Eigen::Index i = 0; i < m.outerSize(); ++i)
    for (SparseMatrix::InnerIterator it(m, i); it; ++it) s[i] += it.value();
  return s;
}
/// Sum of each row of |m|.
inline Eigen::VectorXd abs_row_sums(const SparseMatrix& m) {
  Eigen::VectorXd s = Eigen::VectorXd::Zero(m.rows());
  for (Eigen::Index i = 0; i < m.outerSize(); ++i)
    for (SparseMatrix::InnerIterator it(m, i); it; ++it) s[i] += std::abs(it.value());
  return s;
}

/// diag(left) * m * diag(right); an empty vector stands for the identity. Zeros dropped.
inline SparseMatrix scale(const SparseMatrix& in, const Eigen::VectorXd& left, const Eigen::VectorXd& right) {
  SparseMatrix m = in;
  if ((left.size() && left.size() != m.rows()) || (right.size() && right.size() != m.cols())) {
    throw ComplexError("sparse scale: diagonal sizes do not match the matrix");
  }
  for (Eigen::Index i = 0; i < m.outerSize(); ++i)
    for (SparseMatrix::InnerIterator it(m, i); it; ++it) {
      double v = it.value();
      if (left.size()) v *= left[it.row()];
      if (right.size()) v *= right[it.col()];
      it.valueRef() = v;
    }
  m.prune(0.0, 0.0);
  return m;
}

/// n x n identity times `value`.
inline SparseMatrix identity(std::int64_t n, double value = 1.0) {
  SparseMatrix m(n, n);
  if (value == 0.0) return m;
  auto& data = m.data();
  data.reserve(static_cast<Eigen::Index>(n));
  for (std::int64_t i = 0; i < n; ++i) {
    data.append(value, static_cast<Eigen::Index>(i));
    m.outerIndexPtr()[i + 1] = i + 1;
  }
  return m;
}

/// Sparse matrix of the nonzero entries of a dense one.
inline SparseMatrix from_dense(const Eigen::MatrixXd& d) {
  SparseMatrix m(d.rows(), d.cols());
  auto& data = m.data();
  std::int64_t* outer = m.outerIndexPtr();
  for (Eigen::Index i = 0; i < d.rows(); ++i) {
    for (Eigen::Index j = 0; j < d.cols(); ++j)
      if (d(i, j) != 0.0) data.append(d(i, j), j);
    outer[i + 1] = static_cast<std::int64_t>(data.size());
  }
  return m;
}

/// Builds a row-major matrix from (row, col, value) triplets; repeated entries are summed.
inline SparseMatrix from_triplets(std::int64_t rows, std::int64_t cols,
                                  const std::vector<Eigen::Triplet<double, std::int64_t>>& t) {
  SparseMatrix m(rows, cols);
  m.setFromTriplets(t.begin(), t.end());
  m.prune(0.0, 0.0);
  return m;
}

}  // namespace sparse
}  // namespace topos
