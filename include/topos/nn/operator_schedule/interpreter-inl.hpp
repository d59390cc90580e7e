// topos/nn/operator_schedule/interpreter-inl.hpp
// OperatorNetwork's forward: the plan's steps (plan-inl.hpp) run in order, a parallel group on one
// snapshot (on helper threads too: step_threads), each by its route: each term evaluated
// (term-inl.hpp; a filter's taps, filter-inl.hpp) and the terms combined into the step's target.
// Compiled into topos::nn, or inline with TOPOS_HEADER_ONLY (topos/config.hpp).
#pragma once

#include "topos/nn/operator_schedule/checks-inl.hpp"
#include "topos/nn/operator_schedule/parallel-inl.hpp"
#include "topos/nn/operator_schedule/plan-inl.hpp"

#include <algorithm>
#include <atomic>
#include <exception>
#include <functional>
#include <mutex>

namespace topos::nn {

TOPOS_INLINE std::map<std::string, torch::Tensor> OperatorNetworkImpl::forward(
    const std::map<std::string, torch::Tensor>& inputs,
    const std::map<std::string, SparseOperator>& operators) {
  if (const auto lead = detail::leading_dims(schedule_.inputs(), inputs); !lead.empty())
    return detail::over_leading(schedule_.inputs(), inputs, lead,
                                [&](const auto& in) { return forward(in, operators); });
  check_arguments(inputs, operators, nullptr);
  auto h = input_cochains(inputs);
  run_range(h, operators, nullptr, 0, schedule_.groups().size(), /*live_only=*/true);
  return output_cochains(h);
}

TOPOS_INLINE std::map<std::string, torch::Tensor> OperatorNetworkImpl::forward_batch(
    const std::map<std::string, torch::Tensor>& inputs, const ComplexBatch& batch,
    const std::map<std::string, SparseOperator>& operators) {
  if (const auto lead = detail::leading_dims(schedule_.inputs(), inputs); !lead.empty())
    return detail::over_leading(schedule_.inputs(), inputs, lead, [&](const auto& in) {
      return forward_batch(in, batch, operators);
    });
  check_arguments(inputs, operators, &batch);
  auto h = input_cochains(inputs);
  run_range(h, operators, &batch, 0, schedule_.groups().size(), /*live_only=*/true);
  return output_cochains(h);
}

TOPOS_INLINE Mlp OperatorNetworkImpl::mlp(const std::string& path) const {
  auto it = modules_.find(path);
  auto m = it == modules_.end() ? nullptr : std::dynamic_pointer_cast<MlpImpl>(it->second);
  if (!m) throw ScheduleError("no mlp '" + path + "' in the schedule");
  return Mlp(m);
}

TOPOS_INLINE void OperatorNetworkImpl::run_layer(
    Cochains& h, const std::map<std::string, SparseOperator>& operators, const std::string& name,
    const ComplexBatch* batch) {
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
  run_range(h, operators, batch, it->second,
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

struct OperatorNetworkImpl::Written {
  CochainKey key;
  torch::Tensor value, rows;  // rows: defined for a compact cochain
};

TOPOS_INLINE void OperatorNetworkImpl::run_range(
    Cochains& h, const std::map<std::string, SparseOperator>& operators, const ComplexBatch* batch,
    std::size_t begin, std::size_t end, bool live_only) {
  Operators ops{&operators, batch, {}, absent_operators(operators, batch), {}, false, {},
                0,          false, {}};
  const auto& plan = plan_for(ops);
  for (std::size_t g = begin; g < end && g < plan.groups.size(); ++g) {
    const Cochains snapshot = h;
    for (auto& u : run_group(plan.groups[g], snapshot, ops, live_only)) {
      if (u.rows.defined())
        h.set_compact(u.key.rank, u.key.state, std::move(u.value), std::move(u.rows));
      else
        h.set(u.key.rank, u.key.state, std::move(u.value));
    }
  }
}

TOPOS_INLINE void OperatorNetworkImpl::step_threads(int n) {
  if (n < 1)
    throw std::invalid_argument("OperatorNetwork::step_threads: " + std::to_string(n) +
                                " threads; give 1 (the calling thread alone) or more");
  step_threads_ = n;
  helpers_.resize(static_cast<std::size_t>(n - 1));  // made when a forward first needs them
}

TOPOS_INLINE std::vector<OperatorNetworkImpl::Written> OperatorNetworkImpl::run_group(
    const std::vector<PlannedStep>& steps, const Cochains& snapshot, Operators& ops,
    bool live_only) {
  std::vector<Written> updates;
  const auto run_one = [&](const PlannedStep& p, PrefixCache& cache) {
    Written u{p.step->target, {}, {}};
    detail::naming(p.where, detail::StepReads{*p.step, snapshot}, [&] {
      if (!p.compact_readers.empty())
        std::tie(u.value, u.rows) = run_compact(p, snapshot, ops, cache);
      if (!u.value.defined()) u.value = run_step(p, snapshot, ops, cache);
    });
    return u;
  };
  // Helpers on the CPU only (a CUDA stream is the calling thread's), outside training.
  const bool on_cpu = params_.empty() || params_.begin()->second.device().is_cpu();
  auto units = step_threads_ > 1 && !is_training() && on_cpu
                   ? detail::step_units(steps, live_only)
                   : std::vector<std::vector<std::size_t>>{};
  // This network's helpers, unless another forward of it holds them now.
  struct Claim {
    const void* net = nullptr;
    Operators& ops;
    ~Claim() {
      ops.term_helpers = 0, ops.split_terms = false, ops.ahead.clear();
      if (!net) return;
      std::lock_guard<std::mutex> lock(detail::busy_networks_mutex());
      detail::busy_networks().erase(net);
    }
  } claim{nullptr, ops};
  // (Claimed for one unit only where a step may split its terms.)
  if (units.size() >= 2 || (units.size() == 1 && detail::may_split_terms(steps, live_only))) {
    std::lock_guard<std::mutex> lock(detail::busy_networks_mutex());
    if (detail::busy_networks().insert(this).second)
      claim.net = this;
    else
      units.clear();
  }
  if (units.size() < 2) {
    // One unit: its steps may still hand their terms to the helpers (run_step).
    ops.term_helpers = claim.net ? helpers_.size() : 0;
    PrefixCache cache;  // a term prefix shared by several steps of the group is computed once
    for (const auto& p : steps)
      if (!live_only || p.live) updates.push_back(run_one(p, cache));
    return updates;
  }
  // Each thread takes the next unit until none is left; the values go where the one-thread
  // order puts them, and the error of the first failing step in that order is the one thrown.
  std::vector<Written> by_step(steps.size());
  std::vector<std::exception_ptr> errors(steps.size());
  std::atomic<std::size_t> next{0};
  ++split_groups_;
  detail::run_with_helpers(helpers_, std::min(helpers_.size(), units.size() - 1), ops.shared, [&] {
    for (std::size_t u; (u = next.fetch_add(1)) < units.size();) {
      PrefixCache cache;
      for (auto i : units[u]) {
        try {
          by_step[i] = run_one(steps[i], cache);
        } catch (...) {
          errors[i] = std::current_exception();
          break;  // the unit's later steps may read its cache: left undone
        }
      }
    }
  });
  for (const auto& e : errors)
    if (e) std::rethrow_exception(e);
  for (std::size_t i = 0; i < steps.size(); ++i)
    if (!live_only || steps[i].live) updates.push_back(std::move(by_step[i]));
  return updates;
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

/// The values a step mixes, each with the term it comes from (a polynomial filter's several);
/// for a concatenation into an operation with a leading Linear layer over a batch (`first`: an
/// mlp; split_first_layer), the terms already multiplied by their block of that layer's weight W,
/// summed, and the columns of W of the values left.
struct OperatorNetworkImpl::StepTerms {
  std::vector<torch::Tensor> values;
  std::vector<const ops::Term*> from;
  const Operation* first = nullptr;
  std::shared_ptr<torch::nn::LinearImpl> linear;
  torch::Tensor W, early;
  std::vector<std::int64_t> cols;
  std::int64_t col = 0;  // the next term's first column of W
  void add(torch::Tensor t, const ops::Term* term) {
    if (W.defined())
      for (std::int64_t c = 0; c < t.size(1); ++c) cols.push_back(col + c);
    col += t.dim() == 2 ? t.size(1) : 0;
    values.push_back(std::move(t));
    from.push_back(term);
  }
};

TOPOS_INLINE torch::Tensor OperatorNetworkImpl::run_step(const PlannedStep& p, const Cochains& h,
                                                         Operators& ops, PrefixCache& cache) {
  const auto& s = *p.step;
  const auto& where = p.where;
  if (p.route == StepRoute::keep) {
    if (!h.has(s.target.rank, s.target.state))
      throw ScheduleError(where + ": every term applies an optional operator left out, and " +
                          s.target.str() + " has no value to keep");
    return h.at(s.target.rank, s.target.state);
  }
  if (p.route == StepRoute::chain) return guard(where, s, run_chain(p, h, ops), h, ops);
  const auto& tail = s.operations();
  torch::Tensor y;
  std::size_t first = 0;  // the first of the step's operations left to apply
  if (p.route == StepRoute::filter) {
    // The activation after the filter is applied as its product is stored.
    const auto* act = fusable_activation_at(detail::OperationSeq(tail), 0);
    const auto e = act ? epilogue_of(*act->traits.activation) : Epilogue::none;
    y = detail::naming(where, "the filter", [&] { return run_filter(where, s, h, ops, cache, e); });
    if (y.defined() && act) first = 1;
  }
  if (!y.defined()) {
    // A concatenation into an mlp over a batch: a term summed from fewer rows than the target
    // has is multiplied by its block of the mlp's first weight before the sum (W Σ x = Σ W x):
    // HOPNet's object-to-node message then costs a product over the objects, not the nodes.
    StepTerms values;
    if (p.route == StepRoute::split_first_layer) {
      detail::NetworkRunContext ctx(*this, where, s.target, ops, h);
      values.first = tail.front().operation.get();
      values.linear = values.first->first_linear(ctx);
      values.W = values.linear->weight;
      first = 1;  // mix applies the operation
    }
    // With helpers free (step_threads), terms with row-wise prefixes evaluated at once first.
    const auto jobs =
        ops.term_helpers > 0 ? detail::term_jobs(p, h) : std::vector<std::vector<std::size_t>>{};
    if (!jobs.empty()) {
      if (!ops.split_terms) ++split_groups_;  // the group's first step to split
      ops.split_terms = true, ++split_steps_;
      const bool may_defer = values.W.defined();
      detail::evaluate_at_once(helpers_, ops.term_helpers, ops.shared, jobs, p.terms, cache,
                               ops.ahead, [&](const PlannedTerm& t, PrefixCache& c) {
                                 return evaluate_term(where, s.target, t, h, ops, c, may_defer);
                               });
    }
    for (const auto& term : p.terms)
      detail::naming(where, term.term,
                     [&] { evaluate_into(where, s.target, term, h, ops, cache, values); });
    ops.ahead.clear();
    // Two terms summed into an operation that forms the sum in its kernel (a residual
    // connection into a layer norm), with its activation.
    const auto& v = values.values;
    if (fast_.fuse_residuals() && first == 0 && s.mix == OperatorStep::Mix::sum && v.size() == 2 &&
        !tail.empty() && tail.front().traits.fuses_residual && v[0].dim() == 2 &&
        v[0].sizes() == v[1].sizes()) {
      check_terms(where, values);
      const auto* act = fusable_activation_at(detail::OperationSeq(tail), 1);
      y = detail::naming(where, "the step's operations", [&] {
        return run_operation(where, s.target, tail.front(), v[0], ops, h, act, v[1]);
      });
      first = act ? 2 : 1;
    } else {
      y = mix(where, s, values, h, ops);
    }
  }
  y = detail::naming(where, "the step's operations", [&] {
    for (std::size_t i = first; i < tail.size(); ++i)
      i = apply_fused(where, s.target, tail, i, y, ops, h);
    return y;
  });
  return guard(where, s, std::move(y), h, ops);
}

// One term: its operations and the step's as one list, so that a product ending the term fuses
// with the step's activation.
TOPOS_INLINE torch::Tensor OperatorNetworkImpl::run_chain(const PlannedStep& p, const Cochains& h,
                                                          Operators& ops) {
  const auto& term = *p.terms[0].term;
  return detail::naming(p.where, &term, [&] {
    const detail::OperationSeq list(term.operations(), &p.step->operations());
    torch::Tensor x = h.at(term.source.rank, term.source.state);
    for (std::size_t i = 0; i < list.size(); ++i)
      i = apply_fused(p.where, p.step->target, list, i, x, ops, h);
    return x;
  });
}

TOPOS_INLINE void OperatorNetworkImpl::evaluate_into(const std::string& where,
                                                     const CochainKey& target,
                                                     const PlannedTerm& planned, const Cochains& h,
                                                     Operators& ops, PrefixCache& cache,
                                                     StepTerms& out) {
  const auto& term = *planned.term;
  auto v = evaluate_term(where, target, planned, h, ops, cache, out.W.defined());
  if (v.handled) {
    if (v.deferred) {
      // Not with backward values: they scale the gradient reaching the message, which must not
      // reach the weight.
      const bool scaled_backward = v.agg.weighted && v.n.backward_values.defined();
      if (v.agg.reduce != Aggr::max && v.agg.role == 0 && v.x.size(0) < v.n.num_target &&
          !scaled_backward) {
        const auto block =
            aggregate(nn::linear(v.x, out.W.narrow(1, out.col, v.x.size(1))), v.n, v.agg);
        out.early = out.early.defined() ? out.early + block : block;
        out.col += v.x.size(1);
        return;
      }
      v.value = aggregate(v.x, v.n, v.agg);
    }
    return out.add(std::move(v.value), &term);
  }
  torch::Tensor x = h.at(term.source.rank, term.source.state);
  const auto& list = term.operations();
  for (std::size_t i = 0; i < list.size(); ++i) {
    const auto& t = list[i];
    if (!t.traits.fans_out) {
      i = apply_fused(where, target, list, i, x, ops, h);
      continue;
    }
    detail::NetworkRunContext ctx(*this, where, target, ops, h);
    for (auto& value : t.operation->forward_terms(ctx, x)) {
      out.values.push_back(std::move(value));
      out.from.push_back(&term);
    }
    x = torch::Tensor();
  }
  if (x.defined()) out.add(std::move(x), &term);
}

TOPOS_INLINE void OperatorNetworkImpl::check_terms(const std::string& where,
                                                   const StepTerms& t) const {
  const auto& v = t.values;
  for (std::size_t i = 1; i < v.size(); ++i) {
    if (v[i].dim() != 2 || v[0].dim() != 2) break;
    if (v[i].size(0) != v[0].size(0))
      throw ScheduleError(where + ": " + detail::term_str(*t.from[i]) + " gives " +
                          std::to_string(v[i].size(0)) + " rows, " + detail::term_str(*t.from[0]) +
                          " gives " + std::to_string(v[0].size(0)) +
                          ": the terms of a step must give one row per cell of its target");
    if (v[i].scalar_type() != v[0].scalar_type())
      throw ScheduleError(where + ": " + detail::term_str(*t.from[i]) + " gives " +
                          c10::toString(v[i].scalar_type()) + ", " + detail::term_str(*t.from[0]) +
                          " gives " + c10::toString(v[0].scalar_type()) +
                          ": give the inputs and operators one dtype (net->to(dtype))");
  }
}

TOPOS_INLINE torch::Tensor OperatorNetworkImpl::mix(const std::string& where, const OperatorStep& s,
                                                    StepTerms& t, const Cochains& h,
                                                    Operators& ops) {
  check_terms(where, t);
  auto& v = t.values;
  return detail::naming(where, "mixing the terms", [&]() -> torch::Tensor {
    const auto cat = [&] { return v.size() == 1 ? v[0] : torch::cat(v, 1); };
    if (s.mix == OperatorStep::Mix::filter) return combine_terms(v, params_.at(s.filter_path));
    if (t.W.defined()) {
      detail::NetworkRunContext ctx(*this, where, s.target, ops, h);
      const auto& W = t.W;
      const auto Wd = static_cast<std::int64_t>(t.cols.size()) == W.size(1)
                          ? W
                          : detail::selected_weight(W, 1, t.cols);
      // On the bfloat16 kernels the terms are multiplied where they lie, with the bias, the early
      // sum and the activation after the layer in the same kernel: no concatenation, no pass
      // for the sum or the activation, and each term's gradient a tensor of its own.
      if (!v.empty() && detail::LinearBlocksFunction::alike(v, Wd) &&
          detail::LinearBlocksFunction::bf16_takes(v, Wd, get_float32_matmul_precision())) {
        const auto act = t.first->leading_activation(ctx);
        const bool fuse = act && *act != Activation::none && fusable(*act);
        const auto z = linear_blocks(v, Wd, fuse ? epilogue_of(*act) : Epilogue::none, t.early,
                                     t.linear->bias);
        return fuse ? t.first->forward_after_leading_activation(ctx, z)
                    : t.first->forward_after_first(ctx, z);
      }
      if (!t.early.defined()) return t.first->forward(ctx, cat());
      auto z = nn::linear(cat(), Wd, t.linear->bias);
      z.add_(t.early);
      return t.first->forward_after_first(ctx, z);
    }
    if (s.mix == OperatorStep::Mix::concat) return cat();
    auto y = v[0];
    for (std::size_t i = 1; i < v.size(); ++i) y = y + v[i];
    return s.mix == OperatorStep::Mix::mean ? y / static_cast<double>(v.size()) : y;
  });
}

TOPOS_INLINE torch::Tensor OperatorNetworkImpl::guard(const std::string& where,
                                                      const OperatorStep& s, torch::Tensor updated,
                                                      const Cochains& h,
                                                      const Operators& ops) const {
  if (s.guard_rank < 0) return updated;
  if (ops.batch == nullptr)
    throw ScheduleError(where + ": when_nonempty(" + std::to_string(s.guard_rank) +
                        ") needs a ComplexBatch");
  const auto& before = h.at(s.target.rank, s.target.state);
  // Per complex: does it hold a cell of the guard rank? Applied through the target's batch
  // vector.
  std::vector<std::int64_t> has;
  for (auto c : ops.batch->counts(s.guard_rank)) has.push_back(c > 0);
  const auto active = torch::tensor(has, torch::kLong)
                          .to(before.device())
                          .index_select(0, ops.batch->batch(s.target.rank).to(before.device()))
                          .to(torch::kBool)
                          .unsqueeze(1);
  return torch::where(active, updated, before);
}

TOPOS_INLINE std::pair<torch::Tensor, torch::Tensor> OperatorNetworkImpl::run_compact(
    const PlannedStep& p, const Cochains& h, Operators& ops, PrefixCache& cache) {
  const auto& src = p.step->terms[0].source;
  if (h.rows(src).defined()) return {};
  const auto& x = h.at(src.rank, src.state);
  std::vector<torch::Tensor> sources;
  for (const auto& name : p.compact_readers) {
    const auto* n = ops.neighborhood(name);
    if (n->num_source != x.size(0)) return {};  // the readers will say why
    sources.push_back(n->source);
  }
  const auto used =
      detail::used_rows(sources.size() == 1 ? sources[0] : torch::cat(sources), x.size(0));
  if (used.size(0) >= x.size(0)) return {};
  Cochains rows = h;
  rows.set(src.rank, src.state, x.index_select(0, used));
  return {run_step(p, rows, ops, cache), detail::compact_rows(used, x.size(0))};
}

}  // namespace topos::nn
