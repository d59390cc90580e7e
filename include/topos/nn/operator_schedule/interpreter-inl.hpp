// topos/nn/operator_schedule/interpreter-inl.hpp
// OperatorNetwork's forward: the plan's steps (plan-inl.hpp) run in order, a parallel group on one
// snapshot, each by its route: each term evaluated (term-inl.hpp) and the terms combined into
// the step's target. Compiled into topos::nn, or inline with TOPOS_HEADER_ONLY (topos/config.hpp).
#pragma once

#include "topos/nn/operator_schedule/checks-inl.hpp"
#include "topos/nn/operator_schedule/plan-inl.hpp"

#include <ATen/Parallel.h>
#include <ATen/ThreadLocalState.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <exception>
#include <functional>
#include <mutex>
#include <numeric>
#include <set>

#if defined(__x86_64__) || defined(__i386__)
#include <xmmintrin.h>  // _mm_getcsr: a helper flushes denormals as its caller does
#endif

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
  Operators ops{&operators, batch, {}, absent_operators(operators, batch), {}, false, {}};
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

namespace detail {
/// A group's live steps in units, each run on one thread: steps that may share a cached term
/// prefix (the same prefix key, or filter taps over the same source cochain) stay in one unit,
/// transitively. Units in the order of their first step, steps in order within a unit.
inline std::vector<std::vector<std::size_t>> step_units(const std::vector<PlannedStep>& steps,
                                                        bool live_only) {
  std::vector<std::size_t> parent(steps.size());  // union-find over the steps
  std::iota(parent.begin(), parent.end(), std::size_t{0});
  const auto root = [&](std::size_t i) {
    while (parent[i] != i) i = parent[i] = parent[parent[i]];
    return i;
  };
  std::map<std::string, std::size_t> first_with;  // a sharing key's first step
  for (std::size_t i = 0; i < steps.size(); ++i) {
    const auto& p = steps[i];
    if (live_only && !p.live) continue;
    for (const auto& t : p.terms) {
      std::vector<std::string> keys;
      if (!t.prefix_key.empty()) keys.push_back("prefix " + t.prefix_key);
      if (p.route == StepRoute::filter || !p.compact_readers.empty())
        keys.push_back("source " + t.term->source.str());
      for (const auto& k : keys) {
        const auto [it, fresh] = first_with.emplace(k, i);
        if (!fresh) {
          const auto a = root(it->second), b = root(i);
          parent[std::max(a, b)] = std::min(a, b);
        }
      }
    }
  }
  std::vector<std::vector<std::size_t>> units;
  std::map<std::size_t, std::size_t> unit_of_root;
  for (std::size_t i = 0; i < steps.size(); ++i) {
    if (live_only && !steps[i].live) continue;
    const auto [it, fresh] = unit_of_root.emplace(root(i), units.size());
    if (fresh) units.emplace_back();
    units[it->second].push_back(i);
  }
  return units;
}

/// The networks whose helper threads are in use: a second forward of one of them at the same
/// time (another thread's, or an operation's inside a step) runs its groups on one thread.
inline std::mutex& busy_networks_mutex() {
  static std::mutex m;
  return m;
}
inline std::set<const void*>& busy_networks() {
  static std::set<const void*> s;
  return s;
}
}  // namespace detail

// How long a helper polls for the next group before it sleeps: a rollout's forward and the work
// between two forwards (a millisecond) pass without a sleep, whose wake-up took 90 µs on average
// on a 2-vCPU VM (a group's steps take 100-250 µs there).
inline constexpr std::chrono::microseconds kHelperSpin{2000};

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
    ~Claim() {
      if (!net) return;
      std::lock_guard<std::mutex> lock(detail::busy_networks_mutex());
      detail::busy_networks().erase(net);
    }
  } claim;
  if (units.size() >= 2) {
    std::lock_guard<std::mutex> lock(detail::busy_networks_mutex());
    if (detail::busy_networks().insert(this).second)
      claim.net = this;
    else
      units.clear();
  }
  if (units.size() < 2) {
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
  const auto take_units = [&] {
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
  };
  // What a helper thread does not inherit: LibTorch's thread-local state (grad mode and the
  // like), the OpenMP team size (oneDNN's products read it), denormal flushing (MXCSR).
  const at::ThreadLocalState state;
#if defined(__x86_64__) || defined(__i386__)
  const unsigned csr = _mm_getcsr();
#endif
  const auto helpers = std::min(helpers_.size(), units.size() - 1);
  for (std::size_t k = 0; k < helpers; ++k)  // all made before any job refers to this frame
    if (!helpers_[k]) helpers_[k] = std::make_unique<detail::HelperThread>(kHelperSpin);
  // Every job posted is waited for, whatever throws, before this frame goes.
  struct Join {
    std::vector<std::unique_ptr<detail::HelperThread>>& helpers;
    Operators& ops;
    std::size_t posted = 0;
    ~Join() {
      for (std::size_t k = 0; k < posted; ++k) try {
          helpers[k]->wait();
        } catch (...) {  // take_units keeps its errors: nothing to lose here
        }
      ops.shared = false;
    }
  } join{helpers_, ops};
  ops.shared = true;
  const int intra_op = at::get_num_threads();
  for (std::size_t k = 0; k < helpers; ++k, ++join.posted) {
    helpers_[k]->post([&] {
      at::ThreadLocalStateGuard guard(state);
      at::set_num_threads(intra_op);
#if defined(__x86_64__) || defined(__i386__)
      const unsigned own = _mm_getcsr();
      _mm_setcsr(csr);
#endif
      take_units();
#if defined(__x86_64__) || defined(__i386__)
      _mm_setcsr(own);
#endif
    });
  }
  take_units();
  for (; join.posted > 0; --join.posted) helpers_[join.posted - 1]->wait();
  ops.shared = false;
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
    for (const auto& term : p.terms)
      detail::naming(where, term.term,
                     [&] { evaluate_into(where, s.target, term, h, ops, cache, values); });
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
      if (!t.early.defined()) return t.first->forward(ctx, cat());
      const auto& W = t.W;
      const auto Wd = static_cast<std::int64_t>(t.cols.size()) == W.size(1)
                          ? W
                          : W.index_select(1, torch::tensor(t.cols, torch::kLong).to(W.device()));
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

namespace detail {

/// A filter step's taps as chains of sparse products (run_filter): per tap its links, whether it
/// is such a chain (else the general path evaluates it), and the rows they all reach.
struct FilterTaps {
  struct Link {
    const SparseOperator* A;
    const OperatorProduct* op;
  };
  const OperatorStep& s;
  const Cochains& h;
  std::vector<std::vector<Link>> chains;
  std::vector<bool> products;
  std::int64_t target_rows = -1;

  std::int64_t source_rows(std::size_t k) const {
    const auto& src = s.terms[k].source;
    return h.at(src.rank, src.state).size(0);
  }
  /// The cache key of tap k's first j products (its source's rows tell batches apart).
  std::string prefix(std::size_t k, std::size_t j) const {
    return "filter|" + std::to_string(source_rows(k)) + "|" +
           prefix_key(s.terms[k].source, s.terms[k].operations(), j);
  }
  /// Link j of tap k applied to x.
  torch::Tensor multiply(const std::string& where, std::size_t k, std::size_t j,
                         const torch::Tensor& x) const {
    const auto& link = chains[k][j];
    return detail::multiply(where, label(*link.op), *link.A, x, link.op->row_norm);
  }
  static std::string label(const OperatorProduct& o) { return operator_label(o.op, o.transposed); }
};

/// The sources whose product taps cost less weighted first (x_s Θ_k on the source's rows, then
/// the chains on the weighted columns) than as written: their taps, by source.
TOPOS_INLINE std::vector<std::vector<std::size_t>> weighted_first(const FilterTaps& f,
                                                                  const torch::Tensor& W) {
  const double c_in = static_cast<double>(W.size(0)), c_out = static_cast<double>(W.size(1));
  std::map<std::string, std::vector<std::size_t>> by_source;
  for (std::size_t k = 0; k < f.chains.size(); ++k)
    if (f.products[k] && !f.chains[k].empty()) by_source[f.s.terms[k].source.str()].push_back(k);
  std::vector<std::vector<std::size_t>> first;
  for (const auto& [key, taps] : by_source) {
    const double n_s = static_cast<double>(f.source_rows(taps[0])),
                 n_t = static_cast<double>(f.target_rows), m = static_cast<double>(taps.size());
    double last = m * n_t * c_in * c_out, early = m * n_s * c_in * c_out;
    std::set<std::string> seen;
    for (auto k : taps)
      for (std::size_t j = 0; j < f.chains[k].size(); ++j) {
        const double nnz = 4.0 * static_cast<double>(f.chains[k][j].A->nnz());
        early += nnz * c_out;
        if (seen.insert(f.prefix(k, j + 1)).second) last += nnz * c_in;
      }
    if (early < 0.8 * last) first.push_back(taps);
  }
  return first;
}

/// The weighted columns z of the taps `at` (side by side, `cols` each) pushed through their
/// chains from link `depth` on, a link that several share applied once to all their columns.
TOPOS_INLINE torch::Tensor push_columns(const std::string& where, const FilterTaps& f,
                                        const torch::Tensor& z, const std::vector<std::size_t>& at,
                                        std::size_t depth, std::int64_t cols) {
  torch::Tensor out;
  const auto add = [&](const torch::Tensor& t) { out = out.defined() ? out + t : t; };
  // Each tap's columns, taken apart once (one autograd node) when some go their own way.
  std::vector<torch::Tensor> pieces;
  const auto piece = [&](std::size_t p) -> const torch::Tensor& {
    if (pieces.empty()) pieces = at.size() == 1 ? std::vector<torch::Tensor>{z} : z.split(cols, 1);
    return pieces[p];
  };
  std::vector<std::pair<std::string, std::vector<std::size_t>>> next;  // by next product
  for (std::size_t p = 0; p < at.size(); ++p) {
    const auto& chain = f.chains[at[p]];
    if (chain.size() == depth) {
      add(piece(p));
      continue;
    }
    const auto& o = *chain[depth].op;
    const auto key = FilterTaps::label(o) + (o.row_norm ? "~" : "");
    auto it = std::find_if(next.begin(), next.end(), [&](const auto& n) { return n.first == key; });
    if (it == next.end()) it = next.insert(next.end(), {key, {}});
    it->second.push_back(p);
  }
  for (const auto& [key, ps] : next) {
    std::vector<torch::Tensor> parts;
    std::vector<std::size_t> below;
    for (auto p : ps) below.push_back(at[p]);
    torch::Tensor zp = z;  // every tap takes this product: all the columns
    if (ps.size() < at.size()) {
      for (auto p : ps) parts.push_back(piece(p));
      zp = parts.size() == 1 ? parts[0].contiguous() : torch::cat(parts, 1);
    }
    add(push_columns(where, f, f.multiply(where, below[0], depth, zp), below, depth + 1, cols));
  }
  return out;
}

/// One source's weighted-first taps: x_s [Θ_a | Θ_b | ...] in one product (taps with the same
/// chain summed into one block), then pushed through their chains.
TOPOS_INLINE torch::Tensor weighted_taps(const std::string& where, const FilterTaps& f,
                                         const std::vector<std::size_t>& taps,
                                         const torch::Tensor& W) {
  std::vector<std::size_t> items;  // one tap per distinct chain
  std::vector<torch::Tensor> blocks;
  for (auto k : taps) {
    const auto key = f.prefix(k, f.chains[k].size());
    std::size_t i = 0;
    while (i < items.size() && f.prefix(items[i], f.chains[items[i]].size()) != key) ++i;
    const auto w = W.select(2, static_cast<std::int64_t>(k));
    if (i == items.size()) {
      items.push_back(k);
      blocks.push_back(w);
    } else {
      blocks[i] = blocks[i] + w;
    }
  }
  const auto& src = f.s.terms[taps[0]].source;
  return push_columns(where, f,
                      linear_act(f.h.at(src.rank, src.state), torch::cat(blocks, 1).t(), {}), items,
                      0, W.size(1));
}

}  // namespace detail

// The taps' chains; false where the step is not such a filter (powers, a compact cochain, taps
// reaching different rows: the general path runs it, or says why).
TOPOS_INLINE bool OperatorNetworkImpl::filter_chains(const std::string& where,
                                                     detail::FilterTaps& f, Operators& ops) {
  const auto K = f.s.terms.size();
  f.chains.assign(K, {});
  f.products.assign(K, true);
  for (std::size_t k = 0; k < K; ++k) {
    const auto& term = f.s.terms[k];
    if (f.h.rows(term.source).defined()) return false;
    auto rows = f.source_rows(k);
    for (const auto& o : term.operations()) {
      if (o.traits.fans_out) return false;
      const auto* p = detail::product_of(o);
      const bool product = p != nullptr && p->weighted && p->role == 0 && !ops.neighborhood(p->op);
      const SparseOperator* A = nullptr;
      if (product) A = p->transposed ? &ops.t(where, p->op) : &ops.at(where, p->op);
      if (A == nullptr || A->cols != rows) {  // the general path applies it, or names the misfit
        f.products[k] = false;
        break;
      }
      f.chains[k].push_back({A, p});
      rows = A->rows;
    }
    if (!f.products[k]) continue;
    if (f.target_rows >= 0 && rows != f.target_rows) return false;
    f.target_rows = rows;
  }
  return true;
}

// A filter Σ_k T_k Θ_k whose taps are chains of sparse products, T_k = P_k x_s, is linear in
// x_s: Σ_k P_k (x_s Θ_k) is the same sum with the dense products on x_s's rows. A source's taps
// go that way when it costs less (SCCNN's triangles into edges on REDDIT-BINARY, its edges into
// triangles on IMDB), their products applied to the weighted columns side by side where chains
// share a prefix. The other taps are evaluated once per distinct prefix in the group and stacked
// into one product (combine_terms). Costs as in apply_fused: a sparse entry weighs 4 dense
// multiply-adds.
TOPOS_INLINE torch::Tensor OperatorNetworkImpl::run_filter(const std::string& where,
                                                           const OperatorStep& s, const Cochains& h,
                                                           Operators& ops, PrefixCache& cache,
                                                           Epilogue act) {
  const auto& W = params_.at(s.filter_path);  // in × out × taps
  const auto K = s.terms.size();
  if (W.dim() != 3 || W.size(2) != static_cast<std::int64_t>(K)) return {};  // powers fan out
  detail::FilterTaps f{s, h, {}, {}, -1};
  if (!filter_chains(where, f, ops)) return {};
  const auto first = detail::weighted_first(f, W);
  std::vector<bool> is_first(K, false);
  for (const auto& taps : first)
    for (auto k : taps) is_first[k] = true;
  // The weighted-first parts, summed, are the base the other taps' product starts from.
  torch::Tensor base;
  for (const auto& taps : first) {
    const auto part = detail::weighted_taps(where, f, taps, W);
    base = base.defined() ? base + part : part;
  }
  auto y = other_taps(where, f, is_first, W, ops, cache, act, base);
  return y.defined() ? y : detail::activate(base, act);
}

// The taps not weighted first, each distinct prefix of products once (in the group's cache),
// stacked into one product with their slices of W.
TOPOS_INLINE torch::Tensor OperatorNetworkImpl::other_taps(const std::string& where,
                                                           const detail::FilterTaps& f,
                                                           const std::vector<bool>& skip,
                                                           const torch::Tensor& W, Operators& ops,
                                                           PrefixCache& cache, Epilogue act,
                                                           const torch::Tensor& base) {
  std::vector<torch::Tensor> terms;
  std::vector<std::int64_t> slices;
  for (std::size_t k = 0; k < f.chains.size(); ++k) {
    if (skip[k]) continue;
    const auto& term = f.s.terms[k];
    torch::Tensor x = f.h.at(term.source.rank, term.source.state);
    if (f.products[k]) {
      std::size_t j = f.chains[k].size();
      for (; j > 0; --j)
        if (auto it = cache.find(f.prefix(k, j)); it != cache.end()) {
          x = it->second;
          break;
        }
      for (; j < f.chains[k].size(); ++j) {
        x = f.multiply(where, k, j, x);
        cache.emplace(f.prefix(k, j + 1), x);
      }
    } else {
      const auto& list = term.operations();
      for (std::size_t i = 0; i < list.size(); ++i)
        i = apply_fused(where, f.s.target, list, i, x, ops, f.h);
    }
    terms.push_back(std::move(x));
    slices.push_back(static_cast<std::int64_t>(k));
  }
  if (terms.empty()) return {};
  return combine_terms(
      terms,
      terms.size() == f.chains.size() ? W : W.index_select(2, torch::tensor(slices).to(W.device())),
      act, base);
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
