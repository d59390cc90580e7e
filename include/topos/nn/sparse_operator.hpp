// topos/nn/sparse_operator.hpp
// Weighted sparse operators for message passing: SparseOperator holds a matrix (an incidence,
// a normalised Laplacian, an attention pattern) in row-major CSR together with its transpose,
// and spmm(A, X, act) is act(A·X) with its own backward (dX = Aᵀ·dZ, d values[k] = <dZ[row k],
// X[col k]>, dZ = dY ⊙ act'(Y)) so attention weights that require grad use the same kernel. The
// kernel (kernels.hpp) walks each target row once with the channel loop in vector registers,
// several times faster on one core than torch 1.13's COO kernel. Row-wise softmax over the
// pattern (attention) and row sums complete the set.
//
// An operator too large to form can be kept as its factors (SparseOperator::product_sum):
// diag(l) · Σ_k F_k1 F_k2 ⋯ · diag(r), which spmm applies factor by factor. REDDIT-BINARY's rank-1
// down Laplacian B_1ᵀB_1 has Σ_v deg(v)² = 372 million entries; its factors have four per edge.
// Such an operator has no explicit entries: what needs them (attention, with_values, the
// operator algebra) says so; materialize() forms it.
#pragma once

#include "topos/nn/kernels.hpp"

#include <ATen/Parallel.h>
#include <torch/torch.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <cstdint>
#include <limits>
#include <memory>
#include <numeric>
#include <stdexcept>
#include <string>
#include <type_traits>
#include <vector>

namespace topos::nn {

/// A 1-d tensor's entries as a vector on the CPU: int64 indices, or values as double (detached).
inline std::vector<std::int64_t> index_vector(const torch::Tensor& t) {
  const auto c = t.to(torch::kCPU, torch::kLong).contiguous();
  return std::vector<std::int64_t>(c.data_ptr<std::int64_t>(),
                                   c.data_ptr<std::int64_t>() + c.numel());
}
inline std::vector<double> value_vector(const torch::Tensor& t) {
  const auto c = t.detach().to(torch::kCPU, torch::kDouble).contiguous();
  return std::vector<double>(c.data_ptr<double>(), c.data_ptr<double>() + c.numel());
}

/// A rows × cols sparse matrix: CSR (crow, col) with `row` (the row of every entry) and values
/// in row-major order (rows, then columns ascending: the order of a coalesced COO tensor);
/// `t_crow`, `t_col` the CSR of the transpose and `t_perm[k]` the entry of A that is the k-th
/// entry of Aᵀ. Index tensors are int64 and shared between copies.
struct SparseOperator {
  std::int64_t rows = 0, cols = 0;
  torch::Tensor crow, col, row, values;
  torch::Tensor t_crow, t_col, t_row, t_perm;
  /// Set for a factored operator (product_sum), whose CSR fields are then undefined.
  struct Factors;
  std::shared_ptr<const Factors> factors;

  /// Stored entries; for a factored operator, its factors' entries (the work of one product).
  std::int64_t nnz() const;
  bool defined() const { return crow.defined() || factors; }
  bool factored() const { return static_cast<bool>(factors); }
  /// Throws, naming `who`, when the operator is factored (it has no entries to read).
  void require_entries(const std::string& who) const {
    if (factors)
      throw std::invalid_argument(who + ": the operator (" + std::to_string(rows) + " x " +
                                  std::to_string(cols) +
                                  ") is kept as a product of sparse factors and has no explicit "
                                  "entries; materialize() it first");
  }

  /// diag(left) · Σ_k (products[k][0] · products[k][1] ⋯) · diag(right), kept as its factors and
  /// applied factor by factor (left, right: one value per row / column, or undefined). Every
  /// product must chain and have the same shape. Differentiable in x, not in the factors.
  static SparseOperator product_sum(std::vector<std::vector<SparseOperator>> products,
                                    torch::Tensor left = {}, torch::Tensor right = {});
  /// The explicit operator (a factored one multiplied out, entries that are zero dropped); an
  /// explicit one as is. Not differentiable.
  SparseOperator materialize() const;
  /// A · B for explicit operators, by rows (Gustavson), zeros dropped. Not differentiable.
  static SparseOperator product(const SparseOperator& a, const SparseOperator& b);

  /// From (row, col, value) triplets in any order; duplicates are summed and entries that are
  /// exactly zero in `dtype` dropped, so the pattern is the nonzero entries (what a dense
  /// matrix's to_sparse() keeps, which attention over the pattern depends on).
  static SparseOperator from_triplets(std::int64_t rows, std::int64_t cols,
                                      const std::vector<std::int64_t>& r,
                                      const std::vector<std::int64_t>& c,
                                      const std::vector<double>& v,
                                      torch::Dtype dtype = torch::kFloat) {
    if (r.size() != c.size() || r.size() != v.size())
      throw std::invalid_argument("SparseOperator: triplet arrays differ in length");
    std::vector<std::size_t> order(r.size());
    std::iota(order.begin(), order.end(), std::size_t{0});
    for (std::size_t k = 0; k < r.size(); ++k)
      if (r[k] < 0 || r[k] >= rows || c[k] < 0 || c[k] >= cols)
        throw std::invalid_argument("SparseOperator: entry (" + std::to_string(r[k]) + ", " +
                                    std::to_string(c[k]) + ") outside " + std::to_string(rows) +
                                    " x " + std::to_string(cols));
    std::sort(order.begin(), order.end(), [&](std::size_t a, std::size_t b) {
      return r[a] != r[b] ? r[a] < r[b] : c[a] < c[b];
    });
    std::vector<std::int64_t> rr, cc;
    std::vector<double> vv;
    for (std::size_t i = 0; i < order.size();) {
      std::size_t j = i;
      double s = 0;
      for (; j < order.size() && r[order[j]] == r[order[i]] && c[order[j]] == c[order[i]]; ++j)
        s += v[order[j]];
      const bool zero = dtype == torch::kFloat ? static_cast<float>(s) == 0.0f : s == 0.0;
      if (!zero) rr.push_back(r[order[i]]), cc.push_back(c[order[i]]), vv.push_back(s);
      i = j;
    }
    return from_sorted(rows, cols, rr, cc, torch::tensor(vv, torch::kDouble).to(dtype));
  }

  /// From an Eigen sparse matrix (core's operators), its values rounded to `dtype` and entries
  /// that are zero there dropped, as from_triplets.
  /// A template so this header needs no Eigen include.
  template <class EigenSparse>
  static SparseOperator from_eigen(const EigenSparse& m, torch::Dtype dtype = torch::kFloat) {
    std::vector<std::int64_t> r, c;
    std::vector<double> v;
    r.reserve(static_cast<std::size_t>(m.nonZeros())), c.reserve(r.capacity()),
        v.reserve(r.capacity());
    for (std::int64_t o = 0; o < static_cast<std::int64_t>(m.outerSize()); ++o)
      for (typename EigenSparse::InnerIterator it(m, o); it; ++it)
        r.push_back(static_cast<std::int64_t>(it.row())),
            c.push_back(static_cast<std::int64_t>(it.col())),
            v.push_back(static_cast<double>(it.value()));
    return from_triplets(static_cast<std::int64_t>(m.rows()), static_cast<std::int64_t>(m.cols()),
                         r, c, v, dtype);
  }

  /// The nonzero entries of a dense 2-d tensor.
  static SparseOperator from_dense(const torch::Tensor& dense) {
    if (dense.dim() != 2)
      throw std::invalid_argument("SparseOperator: a dense operator must be 2-d");
    const auto d = dense.detach().to(torch::kCPU).contiguous();
    const auto nz = d.nonzero();
    const auto r = nz.select(1, 0), c = nz.select(1, 1);
    return from_sorted(d.size(0), d.size(1), index_vector(r), index_vector(c), d.index({r, c}));
  }

  /// Entries already in row-major order without duplicates.
  static SparseOperator from_sorted(std::int64_t rows, std::int64_t cols,
                                    const std::vector<std::int64_t>& r,
                                    const std::vector<std::int64_t>& c, torch::Tensor values) {
    SparseOperator a;
    a.rows = rows;
    a.cols = cols;
    const auto n = static_cast<std::int64_t>(r.size());
    std::vector<std::int64_t> crow(static_cast<std::size_t>(rows) + 1, 0),
        tcrow(static_cast<std::size_t>(cols) + 1, 0);
    for (std::int64_t k = 0; k < n; ++k)
      ++crow[static_cast<std::size_t>(r[k]) + 1], ++tcrow[static_cast<std::size_t>(c[k]) + 1];
    std::partial_sum(crow.begin(), crow.end(), crow.begin());
    std::partial_sum(tcrow.begin(), tcrow.end(), tcrow.begin());
    std::vector<std::int64_t> tcol(static_cast<std::size_t>(n)), trow(static_cast<std::size_t>(n)),
        tperm(static_cast<std::size_t>(n));
    std::vector<std::int64_t> next(tcrow.begin(), tcrow.end() - 1);
    for (std::int64_t k = 0; k < n; ++k) {  // rows ascending, so each column of Aᵀ stays sorted
      const auto p = static_cast<std::size_t>(next[static_cast<std::size_t>(c[k])]++);
      tcol[p] = r[k];
      trow[p] = c[k];
      tperm[p] = k;
    }
    a.crow = torch::tensor(crow, torch::kLong);
    a.col = torch::tensor(c, torch::kLong);
    a.row = torch::tensor(r, torch::kLong);
    a.values = values.contiguous();
    a.t_crow = torch::tensor(tcrow, torch::kLong);
    a.t_col = torch::tensor(tcol, torch::kLong);
    a.t_row = torch::tensor(trow, torch::kLong);
    a.t_perm = torch::tensor(tperm, torch::kLong);
    return a;
  }

  /// Aᵀ; its values are a differentiable gather of A's.
  SparseOperator t() const {
    if (factors) return transposed_factors();
    SparseOperator b;
    b.rows = cols;
    b.cols = rows;
    b.crow = t_crow, b.col = t_col, b.row = t_row, b.values = values.index_select(0, t_perm);
    b.t_crow = crow, b.t_col = col, b.t_row = row;
    b.t_perm =
        torch::empty_like(t_perm).index_put_({t_perm}, torch::arange(nnz(), t_perm.options()));
    return b;
  }
  /// The same pattern with other values (one per entry, row-major order), e.g. attention.
  SparseOperator with_values(torch::Tensor v) const {
    require_entries("SparseOperator::with_values");
    if (v.dim() != 1 || v.size(0) != nnz())
      throw std::invalid_argument("SparseOperator::with_values: expected " + std::to_string(nnz()) +
                                  " values");
    SparseOperator b = *this;
    b.values = std::move(v);
    return b;
  }
  SparseOperator to(torch::Dtype dtype) const;
  /// |A|, or every stored entry set to one (the pattern).
  SparseOperator abs() const { return with_values(values.abs()); }
  SparseOperator pattern() const { return with_values(torch::ones_like(values)); }
  /// For entry k, the entry at the mirrored place of its row (a row's i-th entry <-> its
  /// (n-1-i)-th): the pairing of code that matches values listed in ascending column order with
  /// the indices of a product listed in descending order (TopoModelX's HBS attention).
  torch::Tensor row_mirror() const {
    require_entries("SparseOperator::row_mirror");
    const auto k = torch::arange(nnz(), row.options());
    return crow.index_select(0, row) + crow.index_select(0, row + 1) - 1 - k;
  }
  torch::Tensor row_sums() const;
  torch::Tensor col_sums() const;
  torch::Tensor to_dense() const;
  /// diag(left) · A · diag(right) (either may be undefined): a differentiable rescale.
  SparseOperator scaled(const torch::Tensor& left, const torch::Tensor& right = {}) const {
    if (factors) return scaled_factors(left, right);
    auto v = values;
    if (left.defined()) v = v * left.index_select(0, row);
    if (right.defined()) v = v * right.index_select(0, col);
    return with_values(v);
  }
  /// The n × n identity.
  static SparseOperator identity(std::int64_t n, torch::Dtype dtype = torch::kFloat) {
    std::vector<std::int64_t> i(static_cast<std::size_t>(n));
    std::iota(i.begin(), i.end(), std::int64_t{0});
    return from_sorted(n, n, i, i, torch::ones({n}, dtype));
  }
  /// The rows × cols operator whose row k picks cell index[k] (value one): S · x = x[index], a
  /// gather written as an operator (index: int64, one entry per row).
  static SparseOperator selection(const torch::Tensor& index, std::int64_t cols,
                                  torch::Dtype dtype = torch::kFloat) {
    const auto c = index_vector(index);
    std::vector<std::int64_t> r(c.size());
    std::iota(r.begin(), r.end(), std::int64_t{0});
    for (auto j : c)
      if (j < 0 || j >= cols)
        throw std::invalid_argument("SparseOperator::selection: index " + std::to_string(j) +
                                    " outside " + std::to_string(cols) + " cells");
    const auto n = static_cast<std::int64_t>(c.size());
    return from_sorted(n, cols, r, c, torch::ones({n}, dtype));
  }
  /// A square operator's pattern with every diagonal entry added (values one): GAT's self loops.
  SparseOperator pattern_with_self_loops() const {
    if (rows != cols)
      throw std::invalid_argument(
          "SparseOperator::pattern_with_self_loops: the operator is not square");
    return sum(pattern(), identity(rows, values.scalar_type())).pattern();
  }
  /// A ⊙ B (same shape), entry by entry: the entries where both patterns meet (products that
  /// are zero dropped). Operator algebra, not differentiable.
  static SparseOperator hadamard(const SparseOperator& a, const SparseOperator& b) {
    a.require_entries("SparseOperator::hadamard"), b.require_entries("SparseOperator::hadamard");
    if (a.rows != b.rows || a.cols != b.cols)
      throw std::invalid_argument("SparseOperator::hadamard: shapes differ");
    const auto ca = index_vector(a.crow), cola = index_vector(a.col), cb = index_vector(b.crow),
               colb = index_vector(b.col);
    const auto va = value_vector(a.values), vb = value_vector(b.values);
    std::vector<std::int64_t> r, c;
    std::vector<double> v;
    for (std::int64_t i = 0; i < a.rows; ++i) {  // both rows are sorted by column: a merge
      auto p = ca[static_cast<std::size_t>(i)], q = cb[static_cast<std::size_t>(i)];
      const auto pe = ca[static_cast<std::size_t>(i) + 1], qe = cb[static_cast<std::size_t>(i) + 1];
      while (p < pe && q < qe) {
        const auto jp = cola[static_cast<std::size_t>(p)], jq = colb[static_cast<std::size_t>(q)];
        if (jp < jq)
          ++p;
        else if (jq < jp)
          ++q;
        else
          r.push_back(i), c.push_back(jp),
              v.push_back(va[static_cast<std::size_t>(p++)] * vb[static_cast<std::size_t>(q++)]);
      }
    }
    return from_triplets(a.rows, a.cols, r, c, v, a.values.scalar_type());
  }
  /// The rows and columns `keep` of a square operator (each index at most once), renumbered in
  /// the order given: entry (i, j) is A[keep[i], keep[j]] (index_select on both dimensions, as
  /// CAN's pooling restricts its Laplacians to the cells it keeps). Not differentiable.
  SparseOperator principal_submatrix(const torch::Tensor& keep) const {
    require_entries("SparseOperator::principal_submatrix");
    if (rows != cols)
      throw std::invalid_argument(
          "SparseOperator::principal_submatrix: the operator is not square");
    const auto k = index_vector(keep);
    std::vector<std::int64_t> at(static_cast<std::size_t>(rows), -1);
    for (std::size_t i = 0; i < k.size(); ++i) {
      if (k[i] < 0 || k[i] >= rows || at[static_cast<std::size_t>(k[i])] >= 0)
        throw std::invalid_argument("SparseOperator::principal_submatrix: index " +
                                    std::to_string(k[i]) + " is outside 0.." +
                                    std::to_string(rows - 1) + " or repeated");
      at[static_cast<std::size_t>(k[i])] = static_cast<std::int64_t>(i);
    }
    const auto r = index_vector(row), c = index_vector(col);
    const auto v = value_vector(values);
    std::vector<std::int64_t> rr, cc;
    std::vector<double> vv;
    for (std::size_t e = 0; e < r.size(); ++e) {
      const auto i = at[static_cast<std::size_t>(r[e])], j = at[static_cast<std::size_t>(c[e])];
      if (i >= 0 && j >= 0) rr.push_back(i), cc.push_back(j), vv.push_back(v[e]);
    }
    const auto n = static_cast<std::int64_t>(k.size());
    return from_triplets(n, n, rr, cc, vv, values.scalar_type());
  }
  /// A + B (same shape): the union of both patterns (entries that sum to zero dropped), by a
  /// merge of the sorted rows, O(nnz). Operator algebra, not differentiable.
  static SparseOperator sum(const SparseOperator& a, const SparseOperator& b) {
    a.require_entries("SparseOperator::sum"), b.require_entries("SparseOperator::sum");
    if (a.rows != b.rows || a.cols != b.cols)
      throw std::invalid_argument("SparseOperator::sum: shapes differ");
    const auto ca = index_vector(a.crow), cola = index_vector(a.col), cb = index_vector(b.crow),
               colb = index_vector(b.col);
    const auto va = value_vector(a.values), vb = value_vector(b.values);
    const bool single = a.values.scalar_type() == torch::kFloat;
    std::vector<std::int64_t> r, c;
    std::vector<double> v;
    r.reserve(cola.size() + colb.size()), c.reserve(r.capacity()), v.reserve(r.capacity());
    auto emit = [&](std::int64_t i, std::int64_t j, double x) {
      if (single ? static_cast<float>(x) != 0.0f : x != 0.0)
        r.push_back(i), c.push_back(j), v.push_back(x);
    };
    for (std::int64_t i = 0; i < a.rows; ++i) {
      auto p = ca[static_cast<std::size_t>(i)], q = cb[static_cast<std::size_t>(i)];
      const auto pe = ca[static_cast<std::size_t>(i) + 1], qe = cb[static_cast<std::size_t>(i) + 1];
      while (p < pe || q < qe) {
        const auto jp = p < pe ? cola[static_cast<std::size_t>(p)] : a.cols;
        const auto jq = q < qe ? colb[static_cast<std::size_t>(q)] : b.cols;
        if (jp < jq)
          emit(i, jp, va[static_cast<std::size_t>(p++)]);
        else if (jq < jp)
          emit(i, jq, vb[static_cast<std::size_t>(q++)]);
        else
          emit(i, jp, va[static_cast<std::size_t>(p++)] + vb[static_cast<std::size_t>(q++)]);
      }
    }
    return from_sorted(a.rows, a.cols, r, c,
                       torch::tensor(v, torch::kDouble).to(a.values.scalar_type()));
  }

 private:
  /// The dtype and device of the values, a factored operator's those of its first factor.
  torch::TensorOptions value_options() const;
  SparseOperator transposed_factors() const;
  SparseOperator scaled_factors(const torch::Tensor& left, const torch::Tensor& right) const;
};

/// A factored operator's parts (SparseOperator::product_sum).
struct SparseOperator::Factors {
  std::vector<std::vector<SparseOperator>> products;  ///< each applied right to left
  torch::Tensor left, right;                          ///< diagonal scales, or undefined
};

inline std::int64_t SparseOperator::nnz() const {
  if (!factors) return col.defined() ? col.size(0) : 0;
  std::int64_t n = 0;
  for (const auto& p : factors->products)
    for (const auto& f : p) n += f.nnz();
  return n;
}

inline SparseOperator SparseOperator::product_sum(std::vector<std::vector<SparseOperator>> products,
                                                  torch::Tensor left, torch::Tensor right) {
  if (products.empty() || products[0].empty())
    throw std::invalid_argument("SparseOperator::product_sum: no product");
  const auto rows = products[0].front().rows, cols = products[0].back().cols;
  for (std::size_t k = 0; k < products.size(); ++k) {
    const auto& p = products[k];
    if (p.empty()) throw std::invalid_argument("SparseOperator::product_sum: an empty product");
    for (std::size_t i = 0; i < p.size(); ++i) {
      if (!p[i].defined())
        throw std::invalid_argument("SparseOperator::product_sum: product " + std::to_string(k) +
                                    " has an undefined factor");
      if (i + 1 < p.size() && p[i].cols != p[i + 1].rows)
        throw std::invalid_argument(
            "SparseOperator::product_sum: in product " + std::to_string(k) + ", factor " +
            std::to_string(i) + " has " + std::to_string(p[i].cols) + " columns but factor " +
            std::to_string(i + 1) + " has " + std::to_string(p[i + 1].rows) + " rows");
    }
    if (p.front().rows != rows || p.back().cols != cols)
      throw std::invalid_argument("SparseOperator::product_sum: product " + std::to_string(k) +
                                  " is " + std::to_string(p.front().rows) + " x " +
                                  std::to_string(p.back().cols) + ", product 0 is " +
                                  std::to_string(rows) + " x " + std::to_string(cols));
  }
  if ((left.defined() && (left.dim() != 1 || left.size(0) != rows)) ||
      (right.defined() && (right.dim() != 1 || right.size(0) != cols)))
    throw std::invalid_argument("SparseOperator::product_sum: the diagonal scales must have " +
                                std::to_string(rows) + " and " + std::to_string(cols) + " entries");
  SparseOperator a;
  a.rows = rows, a.cols = cols;
  a.factors = std::make_shared<const Factors>(Factors{std::move(products), left, right});
  return a;
}

inline torch::TensorOptions SparseOperator::value_options() const {
  return factors ? factors->products[0][0].value_options() : values.options();
}

inline SparseOperator SparseOperator::transposed_factors() const {
  std::vector<std::vector<SparseOperator>> products;
  for (const auto& p : factors->products) {
    std::vector<SparseOperator> q;
    for (auto it = p.rbegin(); it != p.rend(); ++it) q.push_back(it->t());
    products.push_back(std::move(q));
  }
  return product_sum(std::move(products), factors->right, factors->left);
}

inline SparseOperator SparseOperator::scaled_factors(const torch::Tensor& left,
                                                     const torch::Tensor& right) const {
  const auto times = [](const torch::Tensor& a, const torch::Tensor& b) {
    return !a.defined() ? b : !b.defined() ? a : a * b;
  };
  return product_sum(factors->products, times(factors->left, left), times(factors->right, right));
}

inline SparseOperator SparseOperator::to(torch::Dtype dtype) const {
  if (!factors) return with_values(values.to(dtype));
  auto products = factors->products;
  for (auto& p : products)
    for (auto& f : p) f = f.to(dtype);
  const auto cast = [&](const torch::Tensor& d) { return d.defined() ? d.to(dtype) : d; };
  return product_sum(std::move(products), cast(factors->left), cast(factors->right));
}

inline SparseOperator SparseOperator::product(const SparseOperator& a, const SparseOperator& b) {
  a.require_entries("SparseOperator::product"), b.require_entries("SparseOperator::product");
  if (a.cols != b.rows)
    throw std::invalid_argument("SparseOperator::product: " + std::to_string(a.rows) + " x " +
                                std::to_string(a.cols) + " times " + std::to_string(b.rows) +
                                " x " + std::to_string(b.cols));
  const auto ac = index_vector(a.crow), acol = index_vector(a.col), bc = index_vector(b.crow),
             bcol = index_vector(b.col);
  const auto av = value_vector(a.values), bv = value_vector(b.values);
  std::vector<double> acc(static_cast<std::size_t>(b.cols), 0.0);
  std::vector<char> seen(static_cast<std::size_t>(b.cols), 0);
  std::vector<std::int64_t> r, c, touched;
  std::vector<double> v;
  for (std::int64_t i = 0; i < a.rows; ++i) {
    for (auto p = ac[static_cast<std::size_t>(i)]; p < ac[static_cast<std::size_t>(i) + 1]; ++p) {
      const auto k = static_cast<std::size_t>(acol[static_cast<std::size_t>(p)]);
      for (auto q = bc[k]; q < bc[k + 1]; ++q) {
        const auto j = static_cast<std::size_t>(bcol[static_cast<std::size_t>(q)]);
        if (!seen[j]) seen[j] = 1, touched.push_back(static_cast<std::int64_t>(j));
        acc[j] += av[static_cast<std::size_t>(p)] * bv[static_cast<std::size_t>(q)];
      }
    }
    std::sort(touched.begin(), touched.end());
    for (auto j : touched) {
      r.push_back(i), c.push_back(j), v.push_back(acc[static_cast<std::size_t>(j)]);
      acc[static_cast<std::size_t>(j)] = 0.0, seen[static_cast<std::size_t>(j)] = 0;
    }
    touched.clear();
  }
  return from_triplets(a.rows, b.cols, r, c, v, a.values.scalar_type());
}

inline SparseOperator SparseOperator::materialize() const {
  if (!factors) return *this;
  SparseOperator total;
  for (const auto& p : factors->products) {
    SparseOperator m = p.front().materialize();
    for (std::size_t i = 1; i < p.size(); ++i) m = product(m, p[i].materialize());
    total = total.defined() ? sum(total, m) : m;
  }
  const auto dtype = total.values.scalar_type();
  const auto cast = [&](const torch::Tensor& d) { return d.defined() ? d.detach().to(dtype) : d; };
  return total.scaled(cast(factors->left), cast(factors->right));
}

namespace detail {
inline torch::Tensor csr_apply(const torch::Tensor& crow, const torch::Tensor& col,
                               const torch::Tensor& values, const torch::Tensor& perm,
                               const torch::Tensor& X, std::int64_t rows,
                               Epilogue e = Epilogue::none) {
  const auto x = X.contiguous();
  const auto v = values.contiguous();
  auto y = torch::empty({rows, x.size(1)}, x.options());
  AT_DISPATCH_FLOATING_TYPES(x.scalar_type(), "topos_csr_mm", [&] {
    csr_mm<scalar_t>(crow.data_ptr<std::int64_t>(), col.data_ptr<std::int64_t>(),
                     v.data_ptr<scalar_t>(),
                     perm.defined() ? perm.data_ptr<std::int64_t>() : nullptr,
                     x.data_ptr<scalar_t>(), y.data_ptr<scalar_t>(), rows, x.size(1), e);
  });
  return y;
}

// act(A·X) as one node: with an activation it keeps its output, and the backward first turns dY
// into dZ = dY ⊙ act'(Y) (no exp recomputed, as torch's elu backward does from its input).
struct SpmmFunction : public torch::autograd::Function<SpmmFunction> {
  static torch::Tensor forward(torch::autograd::AutogradContext* ctx, const torch::Tensor& values,
                               const torch::Tensor& X, const torch::Tensor& crow,
                               const torch::Tensor& col, const torch::Tensor& row,
                               const torch::Tensor& t_crow, const torch::Tensor& t_col,
                               const torch::Tensor& t_perm, std::int64_t rows, std::int64_t act) {
    const auto e = static_cast<Epilogue>(act);
    auto y = csr_apply(crow, col, values, torch::Tensor(), X, rows, e);
    ctx->save_for_backward(
        {values, X, col, row, t_crow, t_col, t_perm, e == Epilogue::none ? torch::Tensor() : y});
    ctx->saved_data["act"] = act;
    return y;
  }
  static torch::autograd::tensor_list backward(torch::autograd::AutogradContext* ctx,
                                               torch::autograd::tensor_list grads) {
    const auto saved = ctx->get_saved_variables();
    const auto &values = saved[0], &X = saved[1], &col = saved[2], &row = saved[3],
               &t_crow = saved[4], &t_col = saved[5], &t_perm = saved[6], &Y = saved[7];
    const auto e = static_cast<Epilogue>(ctx->saved_data["act"].toInt());
    const auto dY = apply_epilogue(Y, grads[0].contiguous(), e);
    torch::Tensor dvalues, dX;
    if (ctx->needs_input_grad(1)) dX = csr_apply(t_crow, t_col, values, t_perm, dY, X.size(0));
    if (ctx->needs_input_grad(0)) {
      const auto x = X.contiguous();
      dvalues = torch::empty({values.size(0)}, values.options());
      AT_DISPATCH_FLOATING_TYPES(x.scalar_type(), "topos_csr_value_grad", [&] {
        csr_value_grad<scalar_t>(row.data_ptr<std::int64_t>(), col.data_ptr<std::int64_t>(),
                                 dY.data_ptr<scalar_t>(), x.data_ptr<scalar_t>(),
                                 dvalues.data_ptr<scalar_t>(), values.size(0), x.size(1));
      });
    }
    return {dvalues, dX, {}, {}, {}, {}, {}, {}, {}, {}};
  }
};

}  // namespace detail

/// act(A · X) for X of A.cols rows (any number of channels); differentiable in X and in A's
/// values. CPU tensors use the CSR kernel, with the activation applied in its row loop; other
/// devices fall back to torch's sparse product.
inline torch::Tensor spmm(const SparseOperator& A, const torch::Tensor& X,
                          Epilogue act = Epilogue::none) {
  if (X.dim() != 2 || X.size(0) != A.cols)
    throw std::invalid_argument("spmm: operator is " + std::to_string(A.rows) + " x " +
                                std::to_string(A.cols) + " but the features have " +
                                (X.dim() == 2 ? std::to_string(X.size(0)) + " rows"
                                              : std::to_string(X.dim()) + " dimensions"));
  if (A.factored()) {  // factor by factor, right to left; autograd composes the backward
    const auto& f = *A.factors;
    const auto scale = [&](const torch::Tensor& x, const torch::Tensor& d) {
      return d.defined() ? x * d.to(x.options()).unsqueeze(1) : x;
    };
    const auto x = scale(X, f.right);
    torch::Tensor y;
    for (const auto& p : f.products) {
      auto z = x;
      for (auto it = p.rbegin(); it != p.rend(); ++it) z = spmm(*it, z);
      y = y.defined() ? y + z : z;
    }
    return detail::activate(scale(y, f.left), act);
  }
  auto values = A.values.scalar_type() == X.scalar_type() ? A.values : A.values.to(X.scalar_type());
  if (!X.device().is_cpu()) {
    const auto idx = torch::stack({A.row, A.col}).to(X.device());
    const auto y = torch::sparse_coo_tensor(idx, values.to(X.device()), {A.rows, A.cols})
                       ._coalesced_(true)
                       .mm(X);
    return detail::activate(y, act);
  }
  return detail::SpmmFunction::apply(values, X, A.crow, A.col, A.row, A.t_crow, A.t_col, A.t_perm,
                                     A.rows, static_cast<std::int64_t>(act));
}

inline torch::Tensor SparseOperator::row_sums() const {
  if (factors) return spmm(*this, torch::ones({cols, 1}, value_options())).squeeze(1);
  return torch::zeros({rows}, values.options()).index_add(0, row, values);
}
inline torch::Tensor SparseOperator::col_sums() const {
  if (factors) return t().row_sums();
  return torch::zeros({cols}, values.options()).index_add(0, col, values);
}
inline torch::Tensor SparseOperator::to_dense() const {
  if (factors) return spmm(*this, torch::eye(cols, value_options()));
  return torch::zeros({rows, cols}, values.options()).index_put({row, col}, values);
}

namespace detail {
// The per-row softmax as one autograd node that keeps only its output: its backward is
// y ⊙ (dy - Σ_row y ⊙ dy). Composed of torch ops it kept the shifted scores, their exponentials
// and the row sums, four nnz-long tensors per attention (SAN on the grid: 20 MB of 230).
struct RowSoftmaxFunction : public torch::autograd::Function<RowSoftmaxFunction> {
  static torch::Tensor forward(torch::autograd::AutogradContext* ctx, const torch::Tensor& scores,
                               const torch::Tensor& row, std::int64_t rows) {
    const auto max = torch::full({rows}, -std::numeric_limits<double>::infinity(), scores.options())
                         .scatter_reduce(0, row, scores, "amax", /*include_self=*/true);
    const auto e = (scores - max.index_select(0, row)).exp();
    const auto sum = torch::zeros({rows}, scores.options()).index_add(0, row, e);
    auto y = e / sum.index_select(0, row);
    ctx->save_for_backward({y, row});
    ctx->saved_data["rows"] = rows;
    return y;
  }
  static torch::autograd::tensor_list backward(torch::autograd::AutogradContext* ctx,
                                               torch::autograd::tensor_list grads) {
    const auto saved = ctx->get_saved_variables();
    const auto &y = saved[0], &row = saved[1];
    const auto g = y * grads[0];
    const auto s =
        torch::zeros({ctx->saved_data["rows"].toInt()}, g.options()).index_add(0, row, g);
    return {g - y * s.index_select(0, row), torch::Tensor(), torch::Tensor()};
  }
};
}  // namespace detail

/// Softmax of per-entry scores within each row of A's pattern (a target's incoming messages),
/// as torch.sparse.softmax(·, dim=1): every row's entries sum to one, empty rows stay empty.
inline torch::Tensor row_softmax(const SparseOperator& A, const torch::Tensor& scores) {
  A.require_entries("row_softmax");
  if (scores.dim() != 1 || scores.size(0) != A.nnz())
    throw std::invalid_argument("row_softmax: expected one score per entry (" +
                                std::to_string(A.nnz()) + ")");
  return detail::RowSoftmaxFunction::apply(scores, A.row.to(scores.device()), A.rows);
}

/// Per-row normalisation of per-entry scores (x / row sum), TopoModelX's non-softmax attention.
inline torch::Tensor row_normalize(const SparseOperator& A, const torch::Tensor& scores) {
  A.require_entries("row_normalize");
  const auto row = A.row.to(scores.device());
  const auto sum = torch::zeros({A.rows}, scores.options()).index_add(0, row, scores);
  return scores / sum.index_select(0, row);
}

}  // namespace topos::nn
