// topos/nn/operator_schedule/interpreter-inl.hpp
// OperatorNetwork's forward: the steps run in order (a parallel group on one snapshot), each
// term's operations applied to its cochain, products fused with the activation that follows.
// Compiled into topos::nn, or inline with TOPOS_HEADER_ONLY (topos/config.hpp).
#pragma once

#include "topos/nn/operator_schedule/parameters-inl.hpp"  // detail::shape_str
#include "topos/nn/operator_schedule/network.hpp"

#include <algorithm>

namespace topos::nn {

struct OperatorNetworkImpl::Operators {
  const std::map<std::string, SparseOperator>* given;
  std::map<std::string, SparseOperator> transposed;
  std::map<std::string, SparseOperator> derived;  // the dropped operators of this forward
  const SparseOperator& at(const std::string& where, const std::string& name) const {
    if (auto d = derived.find(name); d != derived.end()) return d->second;
    auto it = given->find(name);
    if (it == given->end()) throw ScheduleError(where + ": operator '" + name + "' was not given");
    return it->second;
  }
  const SparseOperator& t(const std::string& where, const std::string& name) {
    auto it = transposed.find(name);
    if (it == transposed.end()) it = transposed.emplace(name, at(where, name).t()).first;
    return it->second;
  }
};

namespace detail {

/// What a user operation sees of a running step (operation.hpp).
class NetworkRunContext final : public RunContext {
 public:
  NetworkRunContext(OperatorNetworkImpl& net, const std::string& where,
                    OperatorNetworkImpl::Operators& ops, const Cochains& h)
      : net_(net), where_(where), ops_(ops), h_(h) {}
  const std::string& where() const override { return where_; }
  const SparseOperator& op(const std::string& name) override { return ops_.at(where_, name); }
  const SparseOperator& op_transposed(const std::string& name) override {
    return ops_.t(where_, name);
  }
  const torch::Tensor& parameter(const std::string& path) const override {
    auto it = net_.params_.find(path);
    if (it == net_.params_.end()) fail("no parameter '" + path + "'");
    return it->second;
  }
  const torch::Tensor& cochain(const CochainKey& key) const override {
    if (!h_.has(key.rank, key.state)) fail("no cochain " + key.str() + " before the step");
    return h_.at(key.rank, key.state);
  }
  bool is_training() const override { return net_.is_training(); }

 protected:
  std::shared_ptr<torch::nn::Module> module_at(const std::string& path) const override {
    auto it = net_.modules_.find(path);
    if (it == net_.modules_.end()) fail("no module '" + path + "'");
    return it->second;
  }

 private:
  OperatorNetworkImpl& net_;
  const std::string& where_;
  OperatorNetworkImpl::Operators& ops_;
  const Cochains& h_;
};

/// A's entries, each kept with probability 1 - rate.
TOPOS_INLINE SparseOperator drop_entries(const SparseOperator& A, double rate) {
  const auto keep = (torch::rand({A.nnz()}) >= rate).nonzero().squeeze(1).to(A.row.device());
  return SparseOperator::from_sorted(A.rows, A.cols, index_vector(A.row.index_select(0, keep)),
                                     index_vector(A.col.index_select(0, keep)),
                                     A.values.index_select(0, keep));
}

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
                                    const SparseOperator& A, const torch::Tensor& x,
                                    bool row_norm) {
  detail::check_fits(where, name, A, x);
  const auto y = spmm(A, x);
  return row_norm ? divide_by_row_sums(A, y) : y;
}

}  // namespace detail

TOPOS_INLINE std::map<std::string, torch::Tensor> OperatorNetworkImpl::forward(
    const std::map<std::string, torch::Tensor>& inputs,
    const std::map<std::string, SparseOperator>& operators) {
  auto h = input_cochains(inputs);
  run_groups(h, operators, 0, schedule_.groups().size(), /*live_only=*/true);
  return output_cochains(h);
}

TOPOS_INLINE void OperatorNetworkImpl::run_layer(
    Cochains& h, const std::map<std::string, SparseOperator>& operators, const std::string& name) {
  const auto& layers = schedule_.layers();
  auto it =
      std::find_if(layers.begin(), layers.end(), [&](const auto& l) { return l.first == name; });
  if (it == layers.end()) {
    std::string known;
    for (const auto& l : layers) known += (known.empty() ? "" : ", ") + l.first;
    throw ScheduleError("no layer '" + name +
                        "' in the schedule (layers: " + (known.empty() ? "none" : known) + ")");
  }
  const auto next = std::next(it);
  run_groups(h, operators, it->second,
             next == layers.end() ? schedule_.groups().size() : next->second,
             /*live_only=*/false);
}

TOPOS_INLINE Cochains
OperatorNetworkImpl::input_cochains(const std::map<std::string, torch::Tensor>& inputs) const {
  Cochains h;
  for (const auto& in : schedule_.inputs()) {
    auto it = inputs.find(in.name);
    if (it == inputs.end()) throw ScheduleError("input '" + in.name + "' was not given");
    const auto& x = it->second;
    if (x.dim() != 2 || x.size(1) != in.channels)
      throw ScheduleError("input '" + in.name + "' must be (cells × " +
                          std::to_string(in.channels) + "), got " + detail::shape_str(x));
    h.set(in.key.rank, in.key.state, x);
  }
  return h;
}

TOPOS_INLINE void OperatorNetworkImpl::run_groups(
    Cochains& h, const std::map<std::string, SparseOperator>& operators, std::size_t begin,
    std::size_t end, bool live_only) {
  Operators ops{&operators, {}, {}};
  for (const auto& d : schedule_.dropped_operators()) {
    const auto& A = ops.at("dropped operator '" + d.name + "'", d.source);
    ops.derived.emplace(d.name, is_training() && d.rate > 0 ? detail::drop_entries(A, d.rate) : A);
  }
  const auto& groups = schedule_.groups();
  for (std::size_t g = begin; g < end && g < groups.size(); ++g) {
    const Cochains snapshot = h;
    std::vector<std::pair<CochainKey, torch::Tensor>> updates;
    for (std::size_t i = 0; i < groups[g].size(); ++i)
      if (!live_only || live_[g][i])
        updates.emplace_back(groups[g][i].target, run_step(groups[g][i], snapshot, ops));
    for (auto& [k, v] : updates) h.set(k.rank, k.state, std::move(v));
  }
}

TOPOS_INLINE std::map<std::string, torch::Tensor> OperatorNetworkImpl::output_cochains(
    const Cochains& h) const {
  std::map<std::string, torch::Tensor> out;
  for (const auto& o : schedule_.outputs()) out[o.name] = h.at(o.key.rank, o.key.state);
  return out;
}

TOPOS_INLINE std::vector<torch::Tensor> OperatorNetworkImpl::run(
    const std::map<std::string, torch::Tensor>& inputs,
    const std::map<std::string, SparseOperator>& operators, const std::vector<std::string>& names) {
  auto out = forward(inputs, operators);
  std::vector<torch::Tensor> v;
  for (const auto& n : names) v.push_back(out.at(n));
  return v;
}

TOPOS_INLINE std::size_t OperatorNetworkImpl::apply_fused(const std::string& where,
                                                          const CochainKey& target,
                                                          const std::vector<TermOp>& list,
                                                          std::size_t i, torch::Tensor& x,
                                                          Operators& ops, const Cochains& h) {
  const auto& t = list[i];
  const bool product =
      ((t.kind == TermOp::Kind::via || t.kind == TermOp::Kind::via_transposed) && !t.row_norm) ||
      t.kind == TermOp::Kind::linear;
  if (!product || i + 1 >= list.size() || list[i + 1].kind != TermOp::Kind::act ||
      !fusable(list[i + 1].update)) {
    x = apply(where, target, t, x, ops, h);
    return i;
  }
  const auto act = epilogue_of(list[i + 1].update);
  if (t.kind == TermOp::Kind::linear) {
    x = linear_act(x, params_.at(t.name + ".weight"),
                   t.bias ? params_.at(t.name + ".bias") : torch::Tensor(), act);
  } else {
    const bool transposed = t.kind == TermOp::Kind::via_transposed;
    const auto& A = transposed ? ops.t(where, t.name) : ops.at(where, t.name);
    detail::check_fits(where, transposed ? t.name + "ᵀ" : t.name, A, x);
    x = spmm(A, x, act);
  }
  return i + 1;
}

TOPOS_INLINE torch::Tensor OperatorNetworkImpl::apply(const std::string& where,
                                                      const CochainKey& target, const TermOp& t,
                                                      torch::Tensor x, Operators& ops,
                                                      const Cochains& h) {
  switch (t.kind) {
    case TermOp::Kind::via: {
      return detail::multiply(where, t.name, ops.at(where, t.name), x, t.row_norm);
    }
    case TermOp::Kind::via_transposed: {
      return detail::multiply(where, t.name + "ᵀ", ops.t(where, t.name), x, t.row_norm);
    }
    case TermOp::Kind::attend:
      return attend(where, target, t, x, ops, h);
    case TermOp::Kind::batch_norm:
      return batch_norms_.at(t.name)->forward(x);
    case TermOp::Kind::layer_norm:
      return layer_norms_.at(t.name)->forward(x);
    case TermOp::Kind::pattern: {
      const auto& A = t.transposed ? ops.t(where, t.name) : ops.at(where, t.name);
      detail::check_fits(where, t.name + (t.transposed ? "ᵀ" : ""), A, x);
      return pattern_aggregate(A, x, t.aggr);
    }
    case TermOp::Kind::weight: {
      const auto& W = params_.at(t.name);
      return x.dim() == 2 && W.dim() == 2 ? linear_act(x, W.t(), {}) : x.matmul(W);
    }
    case TermOp::Kind::linear: {
      const auto& b = t.bias ? params_.at(t.name + ".bias") : torch::Tensor();
      return torch::linear(x, params_.at(t.name + ".weight"), b);
    }
    case TermOp::Kind::act:
      return apply_update(x, t.update, t.slope);
    case TermOp::Kind::dropout: {
      if (!t.rescale_rows || !is_training()) return torch::dropout(x, t.p, is_training());
      const auto mask = torch::bernoulli(torch::full_like(x, t.p));
      const double n = static_cast<double>(x.size(0));
      return x * mask * ((2 * n - mask.sum(1, true)) / n);
    }
    case TermOp::Kind::unit_rows:
      return unit_rows(x);
    case TermOp::Kind::initial_residual: {
      const auto mixed = (1 - t.p) * x + t.p * h.at(t.skip.rank, t.skip.state);
      return (1 - t.beta) * mixed + t.beta * torch::linear(mixed, params_.at(t.name + ".weight"));
    }
    case TermOp::Kind::powers:
      break;  // handled by the caller (it fans out)
    case TermOp::Kind::scale:
      return x * t.p;
    case TermOp::Kind::head_weights: {     // x [W_1 | ... | W_H]: one product, head-major
      const auto& W = params_.at(t.name);  // heads × in × out
      return linear_act(x, W.permute({1, 0, 2}).reshape({W.size(1), -1}).t(), {});
    }
    case TermOp::Kind::bias:
      return x + params_.at(t.name).reshape({-1});
    case TermOp::Kind::learned_scale:
      return (t.offset + params_.at(t.name)) * x;
    case TermOp::Kind::pow:
      return x.pow(t.value);
    case TermOp::Kind::normalize:
      return x / (t.per_row ? x.norm(2, 1, true) : x.norm()).clamp_min(1e-12);
    case TermOp::Kind::intra_aggregate:
      return x * torch::sigmoid(x.matmul(torch::relu(x.sum(0)))).unsqueeze(1);
    case TermOp::Kind::affine_power: {
      std::vector<SparseOperator> terms;
      for (const auto& f : t.filters) {
        terms.push_back(ops.at(where, f.first));
        detail::check_fits(where, f.first, terms.back(), x);
      }
      return apply_affine_power(terms, x, t.filters[0].second, t.value, t.offset);
    }
    case TermOp::Kind::custom: {
      detail::NetworkRunContext ctx(*this, where, ops, h);
      return t.operation->forward(ctx, x);
    }
  }
  return x;
}

TOPOS_INLINE torch::Tensor OperatorNetworkImpl::attend(const std::string& where,
                                                       const CochainKey& target, const TermOp& t,
                                                       const torch::Tensor& x, Operators& ops,
                                                       const Cochains& h) {
  const auto& o = t.attention;
  const auto& A = o.transposed() ? ops.t(where, t.name) : ops.at(where, t.name);
  const auto name = t.name + (o.transposed() ? "ᵀ" : "");
  detail::check_fits(where, name, A, x);
  auto k = x;
  if (o.keys()) {
    k = h.at(o.keys()->rank, o.keys()->state);
    detail::check_fits(where, name, A, k);
  }
  torch::Tensor q;
  if (!o.source_only()) {
    const auto& key = o.queries() ? *o.queries() : target;
    q = h.at(key.rank, key.state);
    if (A.rows != q.size(0))
      throw ScheduleError(where + ": operator '" + name + "' has " + std::to_string(A.rows) +
                          " rows but the " +
                          (o.queries() ? "query cochain " + key.str() : "target cochain") +
                          " has " + std::to_string(q.size(0)));
  }
  if (o.feature_activation() != Update::none) {
    k = apply_update(k, o.feature_activation(), o.feature_slope());
    if (q.defined()) q = apply_update(q, o.feature_activation(), o.feature_slope());
  }
  const auto H = o.heads();
  // The parameter parts: a_s (and a_t) as vectors, heads-major.
  auto a = params_.at(o.param()).reshape({-1});
  torch::Tensor a_s = a, a_t;
  if (!o.target_param().empty()) {
    a_t = params_.at(o.target_param()).reshape({-1});
  } else if (q.defined() && !o.v2()) {
    // a's entries from `offset` on, wrapping around.
    const auto part = [&a](std::int64_t offset, std::int64_t n) {
      return offset == 0 ? a.narrow(0, 0, n) : a.roll({-offset}).narrow(0, 0, n);
    };
    a_s = part(o.source_offset().value_or(0), k.size(1));
    a_t = part(o.target_offset().value_or(k.size(1)), a.size(0) - k.size(1));
  }
  // Per cell and head <f_h, a_h> (one head: a matrix-vector product, as pair_scores, and
  // the scores a vector: torch's index_select on an n × 1 matrix is 2.5x slower).
  auto dots = [H](const torch::Tensor& f, const torch::Tensor& v) {
    if (H == 1) return f.mv(v);
    return (f.reshape({f.size(0), H, -1}) * v.reshape({1, H, -1})).sum(-1);
  };
  const auto col = A.col.to(x.device()), row = A.row.to(x.device());
  torch::Tensor raw;  // nnz × heads, or nnz with one head
  if (o.v2()) {
    const auto e = apply_update(k.index_select(0, col) + q.index_select(0, row), o.activation(),
                                o.negative_slope());
    raw = (e.reshape({e.size(0), H, -1}) * a_s.reshape({1, H, -1})).sum(-1);
  } else {
    raw = dots(k, a_s).index_select(0, col);
    if (q.defined()) raw = raw + dots(q, a_t).index_select(0, row);
  }
  const auto act = o.v2() ? Update::none : o.activation();
  // Head i's weights on A's entries, times A's values.
  const auto weighted = [&](std::int64_t i) {
    auto w = attention_weights(A, raw.dim() == 1 ? raw : raw.select(1, i).contiguous(), act,
                               o.negative_slope(), o.norm());
    if (o.mirrored_rows()) w = w.index_select(0, A.row_mirror());
    if (o.dropout() > 0) w = torch::dropout(w, o.dropout(), is_training());
    return A.with_values(w * A.values.to(w.scalar_type()));
  };
  // The slices by one split: its backward writes every slice's gradient into one matrix, where
  // a narrow per slice allocates a zero-filled one each.
  if (o.filters() > 1) {  // Σ_p W^(p+1) x_p = W(x_0 + W(x_1 + ... W x_(P-1))): P products
    const auto W = weighted(0);
    const auto P = o.filters();
    const auto x_p = x.split(x.size(1) / P, 1);
    auto z = x_p[static_cast<std::size_t>(P - 1)].contiguous();
    for (auto p = P - 2; p >= 0; --p) z = x_p[static_cast<std::size_t>(p)] + spmm(W, z);
    return spmm(W, z);
  }
  std::vector<torch::Tensor> heads;
  const auto x_h = H == 1 ? std::vector<torch::Tensor>{x} : x.split(x.size(1) / H, 1);
  for (std::int64_t i = 0; i < H; ++i)
    heads.push_back(spmm(weighted(i), x_h[static_cast<std::size_t>(i)].contiguous()));
  if (H == 1) return heads[0];
  return o.concat() ? torch::cat(heads, 1) : torch::stack(heads, 0).mean(0);
}

TOPOS_INLINE torch::Tensor OperatorNetworkImpl::run_step(const OperatorStep& s, const Cochains& h,
                                                         Operators& ops) {
  const std::string where = s.name + " (into " + s.target.str() + ")";
  const bool single =
      s.terms.size() == 1 && (s.mix == OperatorStep::Mix::sum || s.mix == OperatorStep::Mix::mean);
  if (single && std::none_of(s.terms[0].operations().begin(), s.terms[0].operations().end(),
                             [](const TermOp& t) { return t.kind == TermOp::Kind::powers; })) {
    // One term: its operations and the step's as one list, so that a product ending the term
    // fuses with the step's activation.
    auto list = s.terms[0].operations();
    list.insert(list.end(), s.operations().begin(), s.operations().end());
    torch::Tensor x = h.at(s.terms[0].source.rank, s.terms[0].source.state);
    for (std::size_t i = 0; i < list.size(); ++i)
      i = apply_fused(where, s.target, list, i, x, ops, h);
    return x;
  }
  std::vector<torch::Tensor> terms;
  for (const auto& term : s.terms) {
    torch::Tensor x = h.at(term.source.rank, term.source.state);
    const auto& list = term.operations();
    for (std::size_t i = 0; i < list.size(); ++i) {
      const auto& t = list[i];
      if (t.kind != TermOp::Kind::powers) {
        i = apply_fused(where, s.target, list, i, x, ops, h);
        continue;
      }
      terms.push_back(x);
      for (const auto& [name, order] : t.filters) {
        const auto& A = ops.at(where, name);
        detail::check_fits(where, name, A, x);
        for (auto& p : powers(A, x, order, t.row_norm, t.norm_from)) terms.push_back(p);
      }
      x = torch::Tensor();
    }
    if (x.defined()) terms.push_back(x);
  }
  torch::Tensor y;
  if (s.mix == OperatorStep::Mix::filter) {
    y = combine_terms(terms, params_.at(s.filter_path));
  } else if (s.mix == OperatorStep::Mix::concat) {
    y = torch::cat(terms, 1);
  } else {
    y = terms[0];
    for (std::size_t i = 1; i < terms.size(); ++i) y = y + terms[i];
    if (s.mix == OperatorStep::Mix::mean) y = y / static_cast<double>(terms.size());
  }
  const auto& list = s.operations();
  for (std::size_t i = 0; i < list.size(); ++i)
    i = apply_fused(where, s.target, list, i, y, ops, h);
  return y;
}

}  // namespace topos::nn
