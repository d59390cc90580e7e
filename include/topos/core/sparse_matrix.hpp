// topos/core/sparse_matrix.hpp
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
#include <memory>
#include <numeric>
#include <stdexcept>
#include <string>
#include <type_traits>
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

/// TopoNetX's `signed` argument of the oriented operators (incidence_matrix(rank, Signed::no)):
/// a type of its own, so that no call can mean a rank where a sign was meant, or the reverse
/// (inclusion_matrix(r, s) with two ranks is the n_r × n_s inclusion).
enum class Signed : bool { no = false, yes = true };

namespace detail {
/// A call that must not compile picks a template returning Unavailable whose static_assert on
/// never<...> (false, but only once instantiated) says what to write instead; tests see the
/// return type.
template <class...>
inline constexpr bool never = false;
struct Unavailable {};

/// The oriented complexes' (SimplicialComplex, CellComplex) TopoNetX operators take a rank and a
/// Signed; these catch an int or a bool there (TopoNetX's incidence_matrix(1, 0) is |B_1|, while
/// two ints were once the inclusion between two ranks). A complex brings them in with `using`.
struct SignArgument {
  template <class T, class = std::enable_if_t<std::is_arithmetic_v<T>>>
  Unavailable incidence_matrix(int, T) const {
    static_assert(never<T>,
                  "incidence_matrix(rank, sign): write the sign as Signed::yes or Signed::no (not "
                  "an int or a bool); write inclusion_matrix(rank, to_rank) for the unsigned "
                  "inclusion between two ranks");
    return {};
  }
  template <class T, class = std::enable_if_t<std::is_arithmetic_v<T>>>
  Unavailable adjacency_matrix(int, T) const {
    static_assert(never<T>,
                  "adjacency_matrix(rank, sign): write the sign as Signed::yes or Signed::no (not "
                  "an int or a bool); write adjacency_matrix_via(rank, via_rank) for the cells "
                  "sharing a cell of rank via_rank");
    return {};
  }
  template <class T, class = std::enable_if_t<std::is_arithmetic_v<T>>>
  Unavailable coadjacency_matrix(int, T) const {
    static_assert(never<T>,
                  "coadjacency_matrix(rank, sign): write the sign as Signed::yes or Signed::no "
                  "(not an int or a bool); write coadjacency_matrix_via(rank, via_rank) for the "
                  "cells sharing a cell of rank via_rank");
    return {};
  }
};
}  // namespace detail

namespace sparse {

// Eigen 3.4's SparseMatrix has no move constructor: passing or returning one by value through
// std::move or ?: copies it. These helpers take const& and return a named local (NRVO).

/// The same matrix without stored zeros.
inline SparseMatrix pruned(const SparseMatrix& m) {
  SparseMatrix r = m;
  r.prune(0.0, 0.0);
  return r;
}

namespace detail {
// Uninitialised scratch arrays (std::vector would zero them first).
template <class T>
std::unique_ptr<T[]> scratch(std::int64_t n) {
  return std::unique_ptr<T[]>(new T[static_cast<std::size_t>(std::max<std::int64_t>(n, 1))]);
}

// Transpose of a compressed matrix. One return statement: GCC 12 gives up NRVO when a function
// also returns another object, and Eigen 3.4's SparseMatrix has no move constructor, so a
// second return path would copy every result.
inline SparseMatrix transpose_compressed(const SparseMatrix& c) {
  const std::int64_t rows = c.rows(), cols = c.cols(), nnz = c.nonZeros();
  SparseMatrix t(cols, rows);
  std::int64_t* to = t.outerIndexPtr();
  const std::int64_t* co = c.outerIndexPtr();
  const std::int64_t* ci = c.innerIndexPtr();
  const double* cv = c.valuePtr();
  for (std::int64_t k = 0; k < nnz; ++k) ++to[ci[k] + 1];
  for (std::int64_t j = 0; j < cols; ++j) to[j + 1] += to[j];
  t.data().resize(static_cast<Eigen::Index>(nnz));
  std::int64_t* ti = t.innerIndexPtr();
  double* tv = t.valuePtr();
  const auto fill = scratch<std::int64_t>(cols);
  std::copy(to, to + cols, fill.get());
  for (std::int64_t i = 0; i < rows; ++i)
    for (std::int64_t k = co[i]; k < co[i + 1]; ++k) {
      const std::int64_t p = fill[static_cast<std::size_t>(ci[k])]++;
      ti[p] = i;
      tv[p] = cv[k];
    }
  return t;
}
}  // namespace detail

/// Row-major transpose by a counting sort over the columns (Eigen's generic transposed
/// assignment between two row-major matrices is an order of magnitude slower).
inline SparseMatrix transpose(const SparseMatrix& m) {
  if (m.isCompressed()) return detail::transpose_compressed(m);
  SparseMatrix c = m;
  c.makeCompressed();
  return detail::transpose_compressed(c);
}

using ProductTerms = std::vector<std::pair<const SparseMatrix*, const SparseMatrix*>>;

namespace detail {
// Shapes of a sum of products; false when some factor is not compressed.
inline bool check_product_terms(const ProductTerms& terms) {
  if (terms.empty()) throw ComplexError("sparse product: no terms");
  const std::int64_t n = terms[0].first->rows(), m = terms[0].second->cols();
  bool compressed = true;
  for (const auto& [a, b] : terms) {
    if (a->cols() != b->rows() || a->rows() != n || b->cols() != m) {
      throw ComplexError("sparse product: shapes (" + std::to_string(a->rows()) + "x" +
                         std::to_string(a->cols()) + ") and (" + std::to_string(b->rows()) + "x" +
                         std::to_string(b->cols()) + ") do not match");
    }
    compressed = compressed && a->isCompressed() && b->isCompressed();
  }
  return compressed;
}

// Calls f(terms') with every factor compressed (copies only when needed).
template <class F>
auto with_compressed_terms(const ProductTerms& terms, F&& f) {
  std::vector<SparseMatrix> copies;
  copies.reserve(2 * terms.size());
  ProductTerms t;
  for (const auto& [x, y] : terms) {
    copies.push_back(*x), copies.back().makeCompressed();
    copies.push_back(*y), copies.back().makeCompressed();
    t.push_back({&copies[copies.size() - 2], &copies.back()});
  }
  return f(t);
}

// The number of scalar products of a sum of products: a bound on its nonzeros.
inline std::int64_t product_flops(const ProductTerms& terms) {
  std::int64_t flops = 0;
  for (const auto& [a, b] : terms) {
    const std::int64_t* bo = b->outerIndexPtr();
    const std::int64_t* ai = a->innerIndexPtr();
    for (std::int64_t p = 0; p < a->nonZeros(); ++p) flops += bo[ai[p] + 1] - bo[ai[p]];
  }
  return flops;
}

// Gustavson's row-by-row accumulation (dense accumulator, column marks), rows left unsorted:
// row i's columns are cols[ptr[i] .. ptr[i+1]) with values vals[..], exact zeros dropped.
struct UnsortedRows {
  std::unique_ptr<std::int64_t[]> ptr, cols;
  std::unique_ptr<double[]> vals;
};
inline UnsortedRows accumulate_rows(const ProductTerms& terms) {
  const std::int64_t n = terms[0].first->rows(), m = terms[0].second->cols();
  const std::int64_t bound = std::min<std::int64_t>(product_flops(terms), n * m);
  // + 1: the branch-free loop below also stores a column it does not keep, one slot past the
  // last entry when a dense final row is full.
  UnsortedRows r{scratch<std::int64_t>(n + 1), scratch<std::int64_t>(bound + 1),
                 scratch<double>(bound + 1)};
  std::int64_t* ptr = r.ptr.get();
  std::int64_t* cols = r.cols.get();
  double* vals = r.vals.get();
  const auto acc = scratch<double>(m);
  std::fill(acc.get(), acc.get() + m, 0.0);
  const auto mark = scratch<std::int64_t>(m);
  std::fill(mark.get(), mark.get() + m, std::int64_t(-1));
  std::int64_t w = 0;
  ptr[0] = 0;
  for (std::int64_t i = 0; i < n; ++i) {
    const std::int64_t start = w;
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
        // Branch-free: whether column j is new to this row is a coin flip for the predictor.
        // acc is all zeros between rows (0.0 + y equals y but for the sign of a zero, and
        // zeros are dropped below).
        for (std::int64_t q = bo[k]; q < bo[k + 1]; ++q) {
          const std::int64_t j = bi[q];
          acc[j] += x * bv[q];
          cols[w] = j;
          w += mark[j] != i;
          mark[j] = i;
        }
      }
    }
    std::int64_t kept = start;
    for (std::int64_t e = start; e < w;
         ++e) {  // drop cancellations (frequent in a Hodge Laplacian), branch-free
      const std::int64_t j = cols[e];
      const double v = acc[j];
      acc[j] = 0.0;
      cols[kept] = j;
      vals[kept] = v;
      kept += v != 0.0;
    }
    w = kept;
    ptr[i + 1] = w;
  }
  return r;
}

inline SparseMatrix multiply_sum_compressed(const ProductTerms& terms) {
  const std::int64_t n = terms[0].first->rows(), m = terms[0].second->cols();
  const UnsortedRows r = accumulate_rows(terms);
  SparseMatrix c(n, m);
  c.data().resize(static_cast<Eigen::Index>(r.ptr[static_cast<std::size_t>(n)]));
  std::copy(r.ptr.get(), r.ptr.get() + n + 1, c.outerIndexPtr());
  std::int64_t* ci = c.innerIndexPtr();
  double* cv = c.valuePtr();
  std::vector<std::int64_t> order;
  for (std::int64_t i = 0; i < n; ++i) {
    const std::int64_t b = r.ptr[static_cast<std::size_t>(i)],
                       e = r.ptr[static_cast<std::size_t>(i) + 1];
    order.resize(static_cast<std::size_t>(e - b));
    std::iota(order.begin(), order.end(), b);
    std::sort(order.begin(), order.end(), [&](std::int64_t x, std::int64_t y) {
      return r.cols[static_cast<std::size_t>(x)] < r.cols[static_cast<std::size_t>(y)];
    });
    for (std::size_t t = 0; t < order.size(); ++t) {
      ci[b + static_cast<std::int64_t>(t)] = r.cols[static_cast<std::size_t>(order[t])];
      cv[b + static_cast<std::int64_t>(t)] = r.vals[static_cast<std::size_t>(order[t])];
    }
  }
  return c;
}

inline SparseMatrix multiply_sum_symmetric_compressed(const ProductTerms& terms) {
  const std::int64_t n = terms[0].first->rows();
  const UnsortedRows r = accumulate_rows(terms);
  // Column j of a symmetric matrix is its row j, so scattering row i's entries into their
  // transposed places, i ascending, fills every row in column order: no per-row sort.
  SparseMatrix c(n, n);
  c.data().resize(static_cast<Eigen::Index>(r.ptr[static_cast<std::size_t>(n)]));
  std::int64_t* outer = c.outerIndexPtr();
  std::copy(r.ptr.get(), r.ptr.get() + n + 1, outer);  // column counts = row counts
  std::int64_t* ci = c.innerIndexPtr();
  double* cv = c.valuePtr();
  const auto fill = scratch<std::int64_t>(n);
  std::copy(outer, outer + n, fill.get());
  for (std::int64_t i = 0; i < n; ++i)
    for (std::int64_t e = r.ptr[static_cast<std::size_t>(i)];
         e < r.ptr[static_cast<std::size_t>(i) + 1]; ++e) {
      const std::int64_t p = fill[static_cast<std::size_t>(r.cols[static_cast<std::size_t>(e)])]++;
      ci[p] = i;
      cv[p] = r.vals[static_cast<std::size_t>(e)];
    }
  return c;
}
}  // namespace detail

/// A1 * B1 + A2 * B2 + ... in one Gustavson pass (dense accumulator): rows sorted, exact zeros
/// (cancellations) dropped. Every product must have the same shape.
inline SparseMatrix multiply_sum(const ProductTerms& terms) {
  if (detail::check_product_terms(terms)) return detail::multiply_sum_compressed(terms);
  return detail::with_compressed_terms(
      terms, [](const ProductTerms& t) { return detail::multiply_sum_compressed(t); });
}

/// multiply_sum for terms of the form (A, A^T) exactly (B^T B, B B^T and their sums: the
/// Laplacians). Entry (i, j) and (j, i) then add the same products in the same order, so the
/// result is exactly symmetric, and its rows come out sorted by a transposing scatter instead
/// of a sort per row. The same matrix as multiply_sum (bit for bit); the caller guarantees the
/// form (a weighted B W B^T is not of it: w (a b) and (w a) b may round differently).
inline SparseMatrix multiply_sum_symmetric(const ProductTerms& terms) {
  for (const auto& [a, b] : terms)
    if (a->rows() != b->cols())
      throw ComplexError("symmetric sparse product: a term (A, B) is not square (B must be A^T)");
  if (detail::check_product_terms(terms)) return detail::multiply_sum_symmetric_compressed(terms);
  return detail::with_compressed_terms(
      terms, [](const ProductTerms& t) { return detail::multiply_sum_symmetric_compressed(t); });
}

/// The row sums of |A1 * B1 + A2 * B2 + ...| without forming the sum: one row at a time in a
/// dense accumulator, so the memory is O(columns) however many entries the sum has (the
/// normalisation of a Hodge Laplacian applied as its factors, where entries of the two products
/// cancel and |L| is not |A1 B1| + |A2 B2|).
inline Eigen::VectorXd abs_row_sums_of_products(const ProductTerms& terms) {
  if (!detail::check_product_terms(terms))
    return detail::with_compressed_terms(
        terms, [](const ProductTerms& t) { return abs_row_sums_of_products(t); });
  const std::int64_t n = terms[0].first->rows(), m = terms[0].second->cols();
  Eigen::VectorXd sums = Eigen::VectorXd::Zero(n);
  std::vector<double> acc(static_cast<std::size_t>(m), 0.0);
  std::vector<std::int64_t> touched;
  for (std::int64_t i = 0; i < n; ++i) {
    for (const auto& [a, b] : terms) {
      const std::int64_t *ao = a->outerIndexPtr(), *ai = a->innerIndexPtr();
      const std::int64_t *bo = b->outerIndexPtr(), *bi = b->innerIndexPtr();
      const double *av = a->valuePtr(), *bv = b->valuePtr();
      for (std::int64_t p = ao[i]; p < ao[i + 1]; ++p)
        for (std::int64_t q = bo[ai[p]]; q < bo[ai[p] + 1]; ++q) {
          auto& x = acc[static_cast<std::size_t>(bi[q])];
          if (x == 0.0) touched.push_back(bi[q]);  // listed again if it cancels to 0: harmless
          x += av[p] * bv[q];
        }
    }
    double s = 0;
    for (const auto j : touched)
      s += std::abs(acc[static_cast<std::size_t>(j)]), acc[static_cast<std::size_t>(j)] = 0.0;
    sums[i] = s;
    touched.clear();
  }
  return sums;
}

/// A * B (see multiply_sum).
inline SparseMatrix multiply(const SparseMatrix& a, const SparseMatrix& b) {
  return multiply_sum({{&a, &b}});
}

/// A + B (same shape), exact zeros dropped.
inline SparseMatrix add(const SparseMatrix& a, const SparseMatrix& b) {
  if (a.rows() != b.rows() || a.cols() != b.cols()) {
    throw ComplexError("sparse sum: shapes (" + std::to_string(a.rows()) + "x" +
                       std::to_string(a.cols()) + ") and (" + std::to_string(b.rows()) + "x" +
                       std::to_string(b.cols()) + ") differ");
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

namespace detail {
// The entries of a compressed matrix off the diagonal and nonzero, |.| if asked.
inline SparseMatrix off_diagonal_compressed(const SparseMatrix& m, bool absolute) {
  SparseMatrix out(m.rows(), m.cols());
  out.data().resize(m.nonZeros());
  const std::int64_t* mo = m.outerIndexPtr();
  const std::int64_t* mi = m.innerIndexPtr();
  const double* mv = m.valuePtr();
  std::int64_t* oo = out.outerIndexPtr();
  std::int64_t* oi = out.innerIndexPtr();
  double* ov = out.valuePtr();
  std::int64_t w = 0;
  for (std::int64_t i = 0; i < m.rows(); ++i) {
    for (std::int64_t k = mo[i]; k < mo[i + 1]; ++k)
      if (mi[k] != i && mv[k] != 0.0) oi[w] = mi[k], ov[w++] = absolute ? std::abs(mv[k]) : mv[k];
    oo[i + 1] = w;
  }
  out.data().resize(w);
  return out;
}
}  // namespace detail

/// The matrix with its diagonal removed (scipy's setdiag(0) followed by dropping the zeros),
/// entrywise |.| when `absolute`.
inline SparseMatrix without_diagonal(const SparseMatrix& m, bool absolute = false) {
  if (m.isCompressed()) return detail::off_diagonal_compressed(m, absolute);
  SparseMatrix c = m;
  c.makeCompressed();
  return detail::off_diagonal_compressed(c, absolute);
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
inline SparseMatrix scale(const SparseMatrix& in, const Eigen::VectorXd& left,
                          const Eigen::VectorXd& right) {
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
