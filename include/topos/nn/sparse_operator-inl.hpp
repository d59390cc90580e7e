// topos/nn/sparse_operator-inl.hpp
// The definitions of SparseOperator's members (sparse_operator.hpp): building one (from
// triplets, an Eigen matrix, a dense tensor, sorted entries), its transpose and rescales, the
// operator algebra (sum, product, Hadamard product, principal submatrix) and factored operators.
#pragma once

#include "topos/nn/sparse_operator.hpp"

#include <torch/torch.h>

#include <algorithm>
#include <cstdint>
#include <memory>
#include <numeric>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

namespace topos::nn {

inline void SparseOperator::require_entries(const std::string& who) const {
  if (factors)
    throw std::invalid_argument(who + ": the operator (" + std::to_string(rows) + " x " +
                                std::to_string(cols) +
                                ") is kept as a product of sparse factors and has no explicit "
                                "entries; materialize() it first");
}

namespace detail {
/// The operator of entries in row-major order, in range and without repeats, as from_sorted
/// checks them and from_triplets and from_dense make them: its CSR arrays and its transpose's.
inline SparseOperator csr_from_sorted(std::int64_t rows, std::int64_t cols,
                                      const std::vector<std::int64_t>& r,
                                      const std::vector<std::int64_t>& c, torch::Tensor values) {
  const auto n = static_cast<std::int64_t>(r.size());
  SparseOperator a;
  a.rows = rows;
  a.cols = cols;
  // Written in place into the operator's tensors (no intermediate vectors to copy).
  const auto longs = [](std::int64_t size) { return torch::zeros({size}, torch::kLong); };
  a.crow = longs(rows + 1), a.t_crow = longs(cols + 1);
  a.row = longs(n), a.col = longs(n), a.t_row = longs(n), a.t_col = longs(n), a.t_perm = longs(n);
  auto* crow = a.crow.data_ptr<std::int64_t>();
  auto* tcrow = a.t_crow.data_ptr<std::int64_t>();
  std::copy(r.begin(), r.end(), a.row.data_ptr<std::int64_t>());
  std::copy(c.begin(), c.end(), a.col.data_ptr<std::int64_t>());
  for (std::int64_t k = 0; k < n; ++k)
    ++crow[r[static_cast<std::size_t>(k)] + 1], ++tcrow[c[static_cast<std::size_t>(k)] + 1];
  std::partial_sum(crow, crow + rows + 1, crow);
  std::partial_sum(tcrow, tcrow + cols + 1, tcrow);
  auto* tcol = a.t_col.data_ptr<std::int64_t>();
  auto* trow = a.t_row.data_ptr<std::int64_t>();
  auto* tperm = a.t_perm.data_ptr<std::int64_t>();
  std::vector<std::int64_t> next(tcrow, tcrow + cols);
  for (std::int64_t k = 0; k < n; ++k) {  // rows ascending, so each column of Aᵀ stays sorted
    const auto ck = c[static_cast<std::size_t>(k)];
    const auto p = next[static_cast<std::size_t>(ck)]++;
    tcol[p] = r[static_cast<std::size_t>(k)];
    trow[p] = ck;
    tperm[p] = k;
  }
  a.values = values.contiguous();
  return a;
}
}  // namespace detail

inline SparseOperator SparseOperator::from_triplets(std::int64_t rows, std::int64_t cols,
                                                    const std::vector<std::int64_t>& r,
                                                    const std::vector<std::int64_t>& c,
                                                    const std::vector<double>& v,
                                                    torch::Dtype dtype) {
  if (r.size() != c.size() || r.size() != v.size())
    throw std::invalid_argument("SparseOperator: triplet arrays differ in length");
  if (rows < 0 || cols < 0)
    throw std::invalid_argument("SparseOperator: a " + std::to_string(rows) + " x " +
                                std::to_string(cols) + " operator; rows and cols must be >= 0");
  for (std::size_t k = 0; k < r.size(); ++k)
    if (r[k] < 0 || r[k] >= rows || c[k] < 0 || c[k] >= cols)
      throw std::invalid_argument("SparseOperator: entry (" + std::to_string(r[k]) + ", " +
                                  std::to_string(c[k]) + ") outside " + std::to_string(rows) +
                                  " x " + std::to_string(cols));
  // Two stable counting sorts (by column, then by row): linear where a comparison sort was
  // n log n, and repeated entries are summed in the order they were given.
  const auto counting_sort = [](const std::vector<std::int64_t>& key, std::int64_t range,
                                const std::vector<std::size_t>& in) {
    std::vector<std::size_t> start(static_cast<std::size_t>(range) + 1, 0), out(in.size());
    for (const auto k : in) ++start[static_cast<std::size_t>(key[k]) + 1];
    std::partial_sum(start.begin(), start.end(), start.begin());
    for (const auto k : in) out[start[static_cast<std::size_t>(key[k])]++] = k;
    return out;
  };
  std::vector<std::size_t> order(r.size());
  std::iota(order.begin(), order.end(), std::size_t{0});
  order = counting_sort(r, rows, counting_sort(c, cols, order));
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
  return detail::csr_from_sorted(rows, cols, rr, cc, torch::tensor(vv, torch::kDouble).to(dtype));
}

template <class EigenSparse>
inline SparseOperator SparseOperator::from_eigen(const EigenSparse& m, torch::Dtype dtype) {
  std::vector<std::int64_t> r, c;
  std::vector<double> v;
  r.reserve(static_cast<std::size_t>(m.nonZeros())), c.reserve(r.capacity()),
      v.reserve(r.capacity());
  for (std::int64_t o = 0; o < static_cast<std::int64_t>(m.outerSize()); ++o)
    for (typename EigenSparse::InnerIterator it(m, o); it; ++it)
      r.push_back(static_cast<std::int64_t>(it.row())),
          c.push_back(static_cast<std::int64_t>(it.col())),
          v.push_back(static_cast<double>(it.value()));
  return from_triplets(static_cast<std::int64_t>(m.rows()), static_cast<std::int64_t>(m.cols()), r,
                       c, v, dtype);
}

inline SparseOperator SparseOperator::from_dense(const torch::Tensor& dense) {
  if (dense.dim() != 2) throw std::invalid_argument("SparseOperator: a dense operator must be 2-d");
  const auto d = dense.detach().to(torch::kCPU).contiguous();
  const auto nz = d.nonzero();
  const auto r = nz.select(1, 0), c = nz.select(1, 1);
  // nonzero() lists the entries in row-major order.
  return detail::csr_from_sorted(d.size(0), d.size(1), index_vector(r), index_vector(c),
                                 d.index({r, c}));
}

inline SparseOperator SparseOperator::from_sorted(std::int64_t rows, std::int64_t cols,
                                                  const std::vector<std::int64_t>& r,
                                                  const std::vector<std::int64_t>& c,
                                                  torch::Tensor values) {
  const auto n = static_cast<std::int64_t>(r.size());
  if (rows < 0 || cols < 0 || c.size() != r.size() || values.dim() != 1 || values.size(0) != n)
    throw std::invalid_argument(
        "SparseOperator::from_sorted: expected rows, cols >= 0 and as many columns and values (a "
        "1-d tensor) as rows indices; got " +
        std::to_string(rows) + " x " + std::to_string(cols) + ", " + std::to_string(r.size()) +
        " rows, " + std::to_string(c.size()) + " columns, values of shape " +
        c10::str(values.sizes()));
  for (std::size_t k = 0; k < r.size(); ++k) {
    if (r[k] < 0 || r[k] >= rows || c[k] < 0 || c[k] >= cols)
      throw std::invalid_argument("SparseOperator::from_sorted: entry (" + std::to_string(r[k]) +
                                  ", " + std::to_string(c[k]) + ") outside " +
                                  std::to_string(rows) + " x " + std::to_string(cols));
    if (k > 0 && (r[k] < r[k - 1] || (r[k] == r[k - 1] && c[k] <= c[k - 1])))
      throw std::invalid_argument(
          "SparseOperator::from_sorted: entry " + std::to_string(k) + " (" + std::to_string(r[k]) +
          ", " + std::to_string(c[k]) +
          ") is not after the one before it in row-major order, or repeats it; from_triplets "
          "sorts entries and sums repeats");
  }
  return detail::csr_from_sorted(rows, cols, r, c, std::move(values));
}

inline SparseOperator SparseOperator::t() const {
  if (factors) return transposed_factors();
  SparseOperator b;
  b.rows = cols;
  b.cols = rows;
  b.crow = t_crow, b.col = t_col, b.row = t_row, b.values = values.index_select(0, t_perm);
  b.t_crow = crow, b.t_col = col, b.t_row = row;
  b.t_perm = torch::empty_like(t_perm).index_put_({t_perm}, torch::arange(nnz(), t_perm.options()));
  return b;
}

inline SparseOperator SparseOperator::with_values(torch::Tensor v) const {
  require_entries("SparseOperator::with_values");
  if (v.dim() != 1 || v.size(0) != nnz())
    throw std::invalid_argument("SparseOperator::with_values: expected " + std::to_string(nnz()) +
                                " values");
  SparseOperator b = *this;
  b.values = std::move(v);
  return b;
}

inline torch::Tensor SparseOperator::row_mirror() const {
  require_entries("SparseOperator::row_mirror");
  const auto k = torch::arange(nnz(), row.options());
  return crow.index_select(0, row) + crow.index_select(0, row + 1) - 1 - k;
}

inline SparseOperator SparseOperator::scaled(const torch::Tensor& left,
                                             const torch::Tensor& right) const {
  if (factors) return scaled_factors(left, right);
  auto v = values;
  if (left.defined()) v = v * left.index_select(0, row);
  if (right.defined()) v = v * right.index_select(0, col);
  return with_values(v);
}

inline SparseOperator SparseOperator::identity(std::int64_t n, torch::Dtype dtype) {
  std::vector<std::int64_t> i(static_cast<std::size_t>(n));
  std::iota(i.begin(), i.end(), std::int64_t{0});
  return from_sorted(n, n, i, i, torch::ones({n}, dtype));
}

inline SparseOperator SparseOperator::selection(const torch::Tensor& index, std::int64_t cols,
                                                torch::Dtype dtype) {
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

inline SparseOperator SparseOperator::pattern_with_self_loops() const {
  if (rows != cols)
    throw std::invalid_argument(
        "SparseOperator::pattern_with_self_loops: the operator is not square");
  return sum(pattern(), identity(rows, values.scalar_type())).pattern();
}

inline SparseOperator SparseOperator::hadamard(const SparseOperator& a, const SparseOperator& b) {
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

inline SparseOperator SparseOperator::principal_submatrix(const torch::Tensor& keep) const {
  require_entries("SparseOperator::principal_submatrix");
  if (rows != cols)
    throw std::invalid_argument("SparseOperator::principal_submatrix: the operator is not square");
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

inline SparseOperator SparseOperator::sum(const SparseOperator& a, const SparseOperator& b) {
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

}  // namespace topos::nn
