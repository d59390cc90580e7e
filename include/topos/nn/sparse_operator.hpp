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
//
// The definitions: sparse_operator-inl.hpp (building, transposing, the operator algebra) and
// spmm-inl.hpp (spmm and the row softmax with their autograd nodes), included below.
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
  void require_entries(const std::string& who) const;

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
                                      torch::Dtype dtype = torch::kFloat);

  /// From an Eigen sparse matrix (core's operators), its values rounded to `dtype` and entries
  /// that are zero there dropped, as from_triplets.
  /// A template so this header needs no Eigen include.
  template <class EigenSparse>
  static SparseOperator from_eigen(const EigenSparse& m, torch::Dtype dtype = torch::kFloat);

  /// The nonzero entries of a dense 2-d tensor.
  static SparseOperator from_dense(const torch::Tensor& dense);

  /// Entries already in row-major order without duplicates (checked: std::invalid_argument).
  static SparseOperator from_sorted(std::int64_t rows, std::int64_t cols,
                                    const std::vector<std::int64_t>& r,
                                    const std::vector<std::int64_t>& c, torch::Tensor values);

  /// Aᵀ; its values are a differentiable gather of A's.
  SparseOperator t() const;
  /// The same pattern with other values (one per entry, row-major order), e.g. attention.
  SparseOperator with_values(torch::Tensor v) const;
  SparseOperator to(torch::Dtype dtype) const;
  /// |A|, or every stored entry set to one (the pattern).
  SparseOperator abs() const { return with_values(values.abs()); }
  SparseOperator pattern() const { return with_values(torch::ones_like(values)); }
  /// For entry k, the entry at the mirrored place of its row (a row's i-th entry <-> its
  /// (n-1-i)-th): the pairing of code that matches values listed in ascending column order with
  /// the indices of a product listed in descending order (TopoModelX's HBS attention).
  torch::Tensor row_mirror() const;
  torch::Tensor row_sums() const;
  torch::Tensor col_sums() const;
  torch::Tensor to_dense() const;
  /// diag(left) · A · diag(right) (either may be undefined): a differentiable rescale.
  SparseOperator scaled(const torch::Tensor& left, const torch::Tensor& right = {}) const;
  /// The n × n identity.
  static SparseOperator identity(std::int64_t n, torch::Dtype dtype = torch::kFloat);
  /// The rows × cols operator whose row k picks cell index[k] (value one): S · x = x[index], a
  /// gather written as an operator (index: int64, one entry per row).
  static SparseOperator selection(const torch::Tensor& index, std::int64_t cols,
                                  torch::Dtype dtype = torch::kFloat);
  /// A square operator's pattern with every diagonal entry added (values one): GAT's self loops.
  SparseOperator pattern_with_self_loops() const;
  /// A ⊙ B (same shape), entry by entry: the entries where both patterns meet (products that
  /// are zero dropped). Operator algebra, not differentiable.
  static SparseOperator hadamard(const SparseOperator& a, const SparseOperator& b);
  /// The rows and columns `keep` of a square operator (each index at most once), renumbered in
  /// the order given: entry (i, j) is A[keep[i], keep[j]] (index_select on both dimensions, as
  /// CAN's pooling restricts its Laplacians to the cells it keeps). Not differentiable.
  SparseOperator principal_submatrix(const torch::Tensor& keep) const;
  /// A + B (same shape): the union of both patterns (entries that sum to zero dropped), by a
  /// merge of the sorted rows, O(nnz). Operator algebra, not differentiable.
  static SparseOperator sum(const SparseOperator& a, const SparseOperator& b);

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

/// act(A · X) for X of A.cols rows (any number of channels); differentiable in X and in A's
/// values. CPU tensors use the CSR kernel, with the activation applied in its row loop; other
/// devices fall back to torch's sparse product.
inline torch::Tensor spmm(const SparseOperator& A, const torch::Tensor& X,
                          Epilogue act = Epilogue::none);

/// act(A (x W)) (`weight_first`) or act((A x) W), W in × out, as one autograd node on the CPU
/// (differentiable in x and W; A's values taken as constants): the weight's product, the sparse
/// product and the activation in one node. A factored operator, values that require a gradient,
/// another device or dtype: spmm and linear_act one after the other.
inline torch::Tensor sparse_linear_act(const SparseOperator& A, const torch::Tensor& x,
                                       const torch::Tensor& W, bool weight_first,
                                       Epilogue act = Epilogue::none);

/// Softmax of per-entry scores within each row of A's pattern (a target's incoming messages),
/// as torch.sparse.softmax(·, dim=1): every row's entries sum to one, empty rows stay empty.
inline torch::Tensor row_softmax(const SparseOperator& A, const torch::Tensor& scores);

/// Per-row normalisation of per-entry scores (x / row sum), TopoModelX's non-softmax attention.
inline torch::Tensor row_normalize(const SparseOperator& A, const torch::Tensor& scores);

}  // namespace topos::nn

#include "topos/nn/sparse_operator-inl.hpp"
#include "topos/nn/spmm-inl.hpp"
