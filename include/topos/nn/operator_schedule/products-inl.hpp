// topos/nn/operator_schedule/products-inl.hpp
// The built-in operations that apply operators (products.hpp): their printed forms, checks,
// parameters, forwards over sparse operators and costs. Over a batch's neighbourhoods the network
// runs a Product as an aggregation itself (term-inl.hpp). Compiled into topos::nn, or inline with
// TOPOS_HEADER_ONLY (topos/config.hpp).
#pragma once

#include "topos/nn/operator_schedule/printer-inl.hpp"  // detail::num
#include "topos/nn/operator_schedule/products.hpp"

#include <sstream>
#include <string>
#include <vector>

namespace topos::nn {

namespace detail {
/// A clear error naming the step and the operator when A cannot be applied to x.
TOPOS_INLINE void check_fits(const std::string& where, const std::string& name,
                             const SparseOperator& A, const torch::Tensor& x) {
  if (A.cols != x.size(0))
    throw ScheduleError(where + ": operator '" + name + "' has " + std::to_string(A.cols) +
                        " columns but the cochain it is applied to has " +
                        std::to_string(x.size(0)) + " rows");
}

/// A · x, divided by A's row sums with `row_norm` (0 where a row sums to 0).
TOPOS_INLINE torch::Tensor multiply(const std::string& where, const std::string& name,
                                    const SparseOperator& A, const torch::Tensor& x, bool row_norm,
                                    Epilogue act = Epilogue::none) {
  detail::check_fits(where, name, A, x);
  const auto y = spmm(A, x, act);
  return row_norm ? divide_by_row_sums(A, y) : y;
}

/// The operator a product applies, as the running step has it (its transpose made once).
TOPOS_INLINE const SparseOperator& operator_of(RunContext& ctx, const OperatorProduct& p) {
  return p.transposed ? ctx.op_transposed(p.op) : ctx.op(p.op);
}
}  // namespace detail

namespace builtin {

TOPOS_INLINE std::string Product::str(const std::string& x) const {
  const auto role = p_.role == 0 ? "" : "[role " + std::to_string(p_.role) + "]";
  if (!p_.weighted) return std::string(aggr_name(p_.reduce)) + "|" + p_.op + role + "|·" + x;
  return operator_label(p_.op, p_.transposed) + (p_.row_norm ? "~" : "") + role + "·" + x;
}
TOPOS_INLINE TermShape Product::infer(BuildContext& ctx, TermShape x) const {
  return {ctx.operator_from(p_.op, x.rank, p_.transposed).second, x.channels};
}
TOPOS_INLINE torch::Tensor Product::forward(RunContext& ctx, const torch::Tensor& x) const {
  if (p_.role != 0)
    ctx.fail("only(" + std::to_string(p_.role) + ") needs a neighbourhood with roles, and " +
             "operator '" + p_.op + "' is a sparse operator");
  const auto& A = detail::operator_of(ctx, p_);
  if (A.cols != x.size(0))  // the label is made only for the error
    detail::check_fits(ctx.where(), operator_label(p_.op, p_.transposed), A, x);
  if (!p_.weighted) return pattern_aggregate(A, x, p_.reduce);
  const auto y = spmm(A, x);
  return p_.row_norm ? divide_by_row_sums(A, y) : y;
}
TOPOS_INLINE OperationTraits Product::traits() const {
  OperationTraits t;
  t.reads_cochains = false;
  t.operators = {p_.op};
  t.product = p_;
  t.identity = "product";  // the printed form says the rest
  return t;
}
TOPOS_INLINE OperationCost Product::cost(const CostContext& c) const {
  if (!p_.weighted) return {};
  return OperationCost::sparse(c.nnz(p_.op), c.x.channels);
}

TOPOS_INLINE std::string Attend::str(const std::string& x) const {
  return "att[" + o_.param() + (o_.heads() > 1 ? " ×" + std::to_string(o_.heads()) : "") + "]" +
         operator_label(op_, o_.transposed()) + "·" + x;
}
TOPOS_INLINE TermShape Attend::infer(BuildContext& ctx, TermShape x) const {
  const auto& o = o_;
  const CochainKey& target = ctx.target();
  const auto [src, dst] = ctx.operator_from(op_, x.rank, o.transposed());
  const auto name = operator_label(op_, o.transposed());
  const auto fail = [&](const std::string& why) {
    ctx.fail("attention over '" + name + "' " + why);
  };
  std::int64_t ck = x.channels, cq = 0;
  if (o.keys()) {
    const auto w = o.keys()->rank == src ? ctx.find_width(*o.keys()) : std::nullopt;
    if (!w)
      fail("takes its keys from " + o.keys()->str() + ", which needs a cochain of rank " +
           std::to_string(src) + " before the step");
    ck = *w;
  }
  const auto H = o.heads();
  if (const auto& kw = o.key_weights()) {
    if (H < 1 || kw->channels() < 1)
      fail("needs at least one head and one channel per head of key weights '" + kw->path() +
           "' (" + std::to_string(H) + " heads, " + std::to_string(kw->channels()) + " channels)");
    ctx.parameter(kw->path(), {H, ck, kw->channels()}, ParameterInit::glorot(kw->gain()));
    ck = H * kw->channels();
  }
  if (!o.source_only()) {
    const auto key = o.queries() ? *o.queries() : target;
    const auto w = key.rank == dst ? ctx.find_width(key) : std::nullopt;
    if (!w)
      fail("scores against " + std::string(o.queries() ? "" : "the target ") + key.str() +
           ", which needs a cochain of rank " + std::to_string(dst) + " before the step");
    // The target before the step is the rank's features this step replaces (TopoModelX's
    // x_target), or an input given for it. A target in a named state that an earlier step wrote
    // and this step does not read is a scratch cochain: before the step it holds whatever an
    // earlier layer left there (a wrong model, and no error).
    if (!o.queries() && !target.state.empty() && ctx.written_by_a_step(target) &&
        !ctx.step_reads(target))
      fail("scores against the target " + target.str() +
           " as it was before the step, but no term of the step reads it: name the queries "
           "(AttendOptions::queries)");
    cq = *w;
  }
  if (H < 1 || x.channels % H || ck % H || cq % H)
    fail("with " + std::to_string(H) + " heads: the messages (" + std::to_string(x.channels) +
         "), keys (" + std::to_string(ck) + ") and queries (" + std::to_string(cq) +
         ") need channels divisible by the heads");
  if (!(o.dropout() >= 0 && o.dropout() <= 1)) fail("needs a dropout rate in [0, 1]");
  const auto n = ck + cq;  // a_s, then a_t (none with source_only)
  auto shape = o.shape().empty() ? std::vector<std::int64_t>{n} : o.shape();
  std::int64_t numel = 1;
  for (auto d : shape) numel *= d;
  if (numel != n) {
    std::ostringstream sizes;
    sizes << torch::IntArrayRef(shape);
    fail("needs " + std::to_string(n) + " entries in '" + o.param() + "', its shape " +
         sizes.str() + " has " + std::to_string(numel));
  }
  ctx.parameter(o.param(), shape, ParameterInit::glorot(o.gain()));
  return {dst, o.concat() ? x.channels : x.channels / H};
}
TOPOS_INLINE torch::Tensor Attend::forward(RunContext& ctx, const torch::Tensor& x) const {
  const auto& o = o_;
  const auto& A = o.transposed() ? ctx.op_transposed(op_) : ctx.op(op_);
  const auto name = operator_label(op_, o.transposed());
  const auto& where = ctx.where();
  detail::check_fits(where, name, A, x);
  A.require_entries(where + ": attention over operator '" + name + "'");
  auto k = x;
  if (o.keys()) {
    k = ctx.cochain(*o.keys());
    detail::check_fits(where, name, A, k);
  }
  torch::Tensor q;
  if (!o.source_only()) {
    const auto& key = o.queries() ? *o.queries() : ctx.target();
    q = ctx.cochain(key);
    if (A.rows != q.size(0))
      ctx.fail("operator '" + name + "' has " + std::to_string(A.rows) + " rows but the " +
               (o.queries() ? "query cochain " + key.str() : "target cochain") + " has " +
               std::to_string(q.size(0)));
  }
  // The parameter's parts a_s and a_t (heads-major), per cell and head <f_h, a_h>; per entry
  // a_s·k_j (+ a_t·q_i), the weights and each head's messages (functional.hpp).
  const auto H = o.heads();
  const auto a = ctx.parameter(o.param()).reshape({-1});
  torch::Tensor K;  // key weights: heads × in × channels
  if (o.key_weights()) K = ctx.parameter(o.key_weights()->path());
  const auto ck = K.defined() ? K.size(0) * K.size(2) : k.size(1);
  const auto a_s = q.defined() ? a.narrow(0, 0, ck) : a;
  // Folded keys: per head K_h a_h (in × heads), one product for every head's scores (one head's
  // a vector, as head_scores gives it), on topos's dense kernel where it takes the heads.
  auto source = K.defined()
                    ? linear_act(k, torch::einsum("hic,hc->ih", {K, a_s.reshape({H, -1})}).t(), {})
                    : head_scores(k, a_s, H);
  if (K.defined() && H == 1) source = source.reshape({-1});
  const auto target = q.defined() ? head_scores(q, a.narrow(0, ck, a.size(0) - ck), H) : q;
  return multi_head_attention_from_cells(A, source, target, x, o.concat(), o.activation(),
                                         o.negative_slope(), o.norm(), o.dropout(),
                                         ctx.is_training(), ctx.fast_paths().fuse_attention());
}
TOPOS_INLINE OperationTraits Attend::traits() const {
  OperationTraits t;  // reads its keys and queries, scores every entry: not row-wise
  t.operators = {op_};
  return t;
}
// The weighted sum over A's entries. The per-cell scores are not counted: a dot product per cell
// and head, or with key weights a product of `heads` columns (in·heads per cell).
TOPOS_INLINE OperationCost Attend::cost(const CostContext& c) const {
  return OperationCost::sparse(c.nnz(op_), c.x.channels);
}

TOPOS_INLINE std::string Powers::str(const std::string& x) const {
  std::string f;
  for (const auto& [op, k] : filters_) f += " " + op + "^1.." + std::to_string(k);
  return "powers[" + x + ";" + f + "]";
}
TOPOS_INLINE TermShape Powers::infer(BuildContext& ctx, TermShape x) const {
  for (const auto& [name, order] : filters_) {
    const auto [src, dst] = ctx.operator_ranks(name);
    if (src != x.rank || dst != x.rank)
      ctx.fail("filter operator '" + name + "' must map rank " + std::to_string(x.rank) +
               " to itself");
    if (order < 0) ctx.fail("filter order of '" + name + "' is negative");
  }
  return x;
}
TOPOS_INLINE torch::Tensor Powers::forward(RunContext& ctx, const torch::Tensor&) const {
  ctx.fail("powers fan a term out into several values: the network calls forward_terms");
}
TOPOS_INLINE std::vector<torch::Tensor> Powers::forward_terms(RunContext& ctx,
                                                              const torch::Tensor& x) const {
  std::vector<torch::Tensor> out{x};
  for (const auto& [name, order] : filters_) {
    const auto& A = ctx.op(name);
    detail::check_fits(ctx.where(), name, A, x);
    for (auto& p : powers(A, x, order, row_norm_, norm_from_)) out.push_back(std::move(p));
  }
  return out;
}
TOPOS_INLINE OperationTraits Powers::traits() const {
  OperationTraits t;
  t.reads_cochains = false;
  t.fans_out = true;
  for (const auto& [name, order] : filters_) {
    t.operators.push_back(name);
    t.terms += order;
  }
  t.identity = "powers" + std::string(row_norm_ ? "~" : "") + std::to_string(norm_from_);
  return t;
}
TOPOS_INLINE OperationCost Powers::cost(const CostContext& c) const {
  std::int64_t f = 0;
  for (const auto& [name, order] : filters_) f += 2 * order * c.nnz(name) * c.x.channels;
  return {f, "sparse"};
}

}  // namespace builtin
}  // namespace topos::nn
