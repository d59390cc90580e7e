// topos/nn/spmm-inl.hpp
// The definitions of spmm, row_softmax and row_normalize (sparse_operator.hpp) and the autograd
// nodes behind them: act(A·X) through the CSR kernel (kernels.hpp) with its own backward, and
// the row-wise softmax that keeps only its output, and sparse_linear_act's node (a weight, a
// sparse product and an activation as one). Also the members of SparseOperator that
// apply it (row and column sums, to_dense).
#pragma once

#include "topos/nn/kernels.hpp"
#include "topos/nn/sparse_operator.hpp"

#include <torch/torch.h>

#include <cstdint>
#include <limits>
#include <stdexcept>
#include <string>
#include <tuple>

namespace topos::nn {

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
// The backward multiplies by the operator of t_values, t_crow, t_col, t_perm: Aᵀ (t_values are
// A's values), or the transpose of another operator B of A's shape (its pattern may differ):
// dX = Bᵀ·dZ. The values' gradient is A's only where t_values are A's values.
struct SpmmFunction : public torch::autograd::Function<SpmmFunction> {
  static torch::Tensor forward(torch::autograd::AutogradContext* ctx, const torch::Tensor& values,
                               const torch::Tensor& X, const torch::Tensor& crow,
                               const torch::Tensor& col, const torch::Tensor& row,
                               const torch::Tensor& t_crow, const torch::Tensor& t_col,
                               const torch::Tensor& t_perm, const torch::Tensor& t_values,
                               std::int64_t rows, std::int64_t act) {
    const auto e = static_cast<Epilogue>(act);
    auto y = csr_apply(crow, col, values, torch::Tensor(), X, rows, e);
    // X only for the values' gradient: an aggregation over constant values keeps no features.
    ctx->save_for_backward({t_values, values.requires_grad() ? X : torch::Tensor(), col, row,
                            t_crow, t_col, t_perm, e == Epilogue::none ? torch::Tensor() : y});
    ctx->saved_data["act"] = act;
    ctx->saved_data["cols"] = X.size(0);
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
    if (ctx->needs_input_grad(1))
      dX = csr_apply(t_crow, t_col, values, t_perm, dY, ctx->saved_data["cols"].toInt());
    if (ctx->needs_input_grad(0) && X.defined()) {
      const auto x = X.contiguous();
      dvalues = torch::empty({values.size(0)}, values.options());
      AT_DISPATCH_FLOATING_TYPES(x.scalar_type(), "topos_csr_value_grad", [&] {
        csr_value_grad<scalar_t>(row.data_ptr<std::int64_t>(), col.data_ptr<std::int64_t>(),
                                 dY.data_ptr<scalar_t>(), x.data_ptr<scalar_t>(),
                                 dvalues.data_ptr<scalar_t>(), values.size(0), x.size(1));
      });
    }
    return {dvalues, dX, {}, {}, {}, {}, {}, {}, {}, {}, {}};
  }
};

// act(A (x W)) or act((A x) W) (W: in × out, as a schedule's weight) as one node keeping x or
// A x, W and the output: one context and one saved set where the weight and the product would
// each make their own, and no transposed view of W recorded.
struct SparseLinearFunction : public torch::autograd::Function<SparseLinearFunction> {
  /// The forward's values: the output, the dense product's input (x, or A x), and the library
  /// that ran the dense product.
  struct Values {
    torch::Tensor y, dense_input;
    ProductPath path = ProductPath::kernel;
  };
  static Values product(const torch::Tensor& values, const torch::Tensor& x, const torch::Tensor& W,
                        const torch::Tensor& crow, const torch::Tensor& col, std::int64_t rows,
                        bool weight_first, Epilogue e) {
    Values v;
    if (weight_first) {
      const auto [t, path] = LinearFunction::product_right(x, W, {}, Epilogue::none);
      v.y = csr_apply(crow, col, values, torch::Tensor(), t, rows, e);
      v.dense_input = x, v.path = path;
    } else {
      v.dense_input = csr_apply(crow, col, values, torch::Tensor(), x, rows);
      std::tie(v.y, v.path) = LinearFunction::product_right(v.dense_input, W, {}, e);
    }
    return v;
  }
  static torch::Tensor forward(torch::autograd::AutogradContext* ctx, const torch::Tensor& x,
                               const torch::Tensor& W, const torch::Tensor& values,
                               const torch::Tensor& crow, const torch::Tensor& col,
                               const torch::Tensor& t_crow, const torch::Tensor& t_col,
                               const torch::Tensor& t_perm, std::int64_t rows, bool weight_first,
                               std::int64_t act) {
    const auto e = static_cast<Epilogue>(act);
    auto v = product(values, x, W, crow, col, rows, weight_first, e);
    ctx->save_for_backward({v.dense_input, W, values, t_crow, t_col, t_perm,
                            e == Epilogue::none ? torch::Tensor() : v.y});
    // One entry (each costs a hash-map insertion): the activation in two bits, a flag, the path.
    ctx->saved_data["how"] = act | (weight_first ? 4 : 0) | static_cast<std::int64_t>(v.path) << 3;
    return v.y;
  }
  static torch::autograd::tensor_list backward(torch::autograd::AutogradContext* ctx,
                                               torch::autograd::tensor_list grads) {
    const auto s = ctx->get_saved_variables();
    const auto &input = s[0], &W = s[1], &values = s[2], &t_crow = s[3], &t_col = s[4],
               &t_perm = s[5], &Y = s[6];
    const auto how = ctx->saved_data["how"].toInt();
    const auto e = static_cast<Epilogue>(how & epilogue_mask);
    const auto path = static_cast<ProductPath>(how >> 3);
    const auto x_rows = t_crow.size(0) - 1;  // Aᵀ's rows
    const bool want_dx = ctx->needs_input_grad(0), want_dW = ctx->needs_input_grad(1);
    torch::Tensor dx, dW;
    if ((how & 4) != 0) {  // y = act(A t), t = x W
      const auto dY = apply_epilogue(Y, grads[0].contiguous(), e);
      const auto dt = csr_apply(t_crow, t_col, values, t_perm, dY, x_rows);
      auto g = LinearFunction::gradients(input, W.t(), {}, dt, Epilogue::none, path, want_dx,
                                         want_dW, false);
      dx = g[0], dW = g[1];
    } else {  // y = act(z W), z = A x
      auto g =
          LinearFunction::gradients(input, W.t(), Y, grads[0], e, path, want_dx, want_dW, false);
      if (want_dx) dx = csr_apply(t_crow, t_col, values, t_perm, g[0], x_rows);
      dW = g[1];
    }
    return {dx, dW.defined() ? dW.t() : dW, {}, {}, {}, {}, {}, {}, {}, {}, {}};
  }
};

}  // namespace detail

inline torch::Tensor spmm(const SparseOperator& A, const torch::Tensor& X, Epilogue act) {
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
                                     values, A.rows, static_cast<std::int64_t>(act));
}

namespace detail {
/// A·X going forward, Bᵀ·dY going back (B: the same shape, its own pattern), on the CPU; A's and
/// B's values taken as constants. What a neighbourhood with backward values aggregates by.
inline torch::Tensor spmm_backward_by(const SparseOperator& A, const torch::Tensor& X,
                                      const SparseOperator& B) {
  if (A.factored() || B.factored() || B.rows != A.rows || B.cols != A.cols || X.dim() != 2 ||
      X.size(0) != A.cols || !X.device().is_cpu())
    throw std::invalid_argument(
        "spmm_backward_by: explicit operators of one shape and CPU "
        "features of their columns' rows");
  const auto as = [&](const torch::Tensor& v) {
    return v.scalar_type() == X.scalar_type() ? v.detach() : v.detach().to(X.scalar_type());
  };
  return SpmmFunction::apply(as(A.values), X, A.crow, A.col, A.row, B.t_crow, B.t_col, B.t_perm,
                             as(B.values), A.rows, static_cast<std::int64_t>(Epilogue::none));
}
}  // namespace detail

inline torch::Tensor sparse_linear_act(const SparseOperator& A, const torch::Tensor& x,
                                       const torch::Tensor& W, bool weight_first, Epilogue act) {
  const bool fused = x.device().is_cpu() && x.dim() == 2 && W.dim() == 2 && !A.factored() &&
                     (x.scalar_type() == torch::kFloat || x.scalar_type() == torch::kDouble) &&
                     W.scalar_type() == x.scalar_type() && !A.values.requires_grad();
  if (!fused) {
    const auto y = weight_first ? spmm(A, linear_act(x, W.t(), {}), act)
                                : linear_act(spmm(A, x), W.t(), {}, act);
    return y;
  }
  if (x.size(0) != A.cols || x.size(1) != W.size(0))
    throw std::invalid_argument("sparse_linear_act: the operator is " + std::to_string(A.rows) +
                                " x " + std::to_string(A.cols) + " and the weight " +
                                std::to_string(W.size(0)) + " x " + std::to_string(W.size(1)) +
                                " but x is " + std::to_string(x.size(0)) + " x " +
                                std::to_string(x.size(1)));
  const auto values =
      A.values.scalar_type() == x.scalar_type() ? A.values : A.values.to(x.scalar_type());
  if (!torch::GradMode::is_enabled() || !(x.requires_grad() || W.requires_grad()))
    return detail::SparseLinearFunction::product(values, x, W, A.crow, A.col, A.rows, weight_first,
                                                 act)
        .y;
  return detail::SparseLinearFunction::apply(x, W, values, A.crow, A.col, A.t_crow, A.t_col,
                                             A.t_perm, A.rows, weight_first,
                                             static_cast<std::int64_t>(act));
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

inline torch::Tensor row_softmax(const SparseOperator& A, const torch::Tensor& scores) {
  A.require_entries("row_softmax");
  if (scores.dim() != 1 || scores.size(0) != A.nnz())
    throw std::invalid_argument("row_softmax: expected one score per entry (" +
                                std::to_string(A.nnz()) + ")");
  return detail::RowSoftmaxFunction::apply(scores, A.row.to(scores.device()), A.rows);
}

inline torch::Tensor row_normalize(const SparseOperator& A, const torch::Tensor& scores) {
  A.require_entries("row_normalize");
  const auto row = A.row.to(scores.device());
  const auto sum = torch::zeros({A.rows}, scores.options()).index_add(0, row, scores);
  return scores / sum.index_select(0, row);
}

}  // namespace topos::nn
