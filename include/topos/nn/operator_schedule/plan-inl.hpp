// topos/nn/operator_schedule/plan-inl.hpp
// Planning a forward: the steps an output needs (build-inl.hpp's liveness), each step's route as
// the fast paths decide it from the schedule and the kinds of operators given, each term's
// row-wise prefix and cache key; kept per kind of forward (plan_for). Plan::str prints a plan.
// Compiled into topos::nn, or inline with TOPOS_HEADER_ONLY (topos/config.hpp).
#pragma once

#include "topos/nn/operator_schedule/term-inl.hpp"

#include <iomanip>
#include <iterator>
#include <sstream>

namespace topos::nn {

namespace detail {

/// FLOPs as a plan prints them: digits grouped by thousands.
TOPOS_INLINE std::string flops_str(std::int64_t v) {
  auto s = std::to_string(v);
  for (auto i = static_cast<std::int64_t>(s.size()) - 3; i > 0; i -= 3)
    s.insert(static_cast<std::size_t>(i), ",");
  return s;
}

/// Does the term apply an optional operator that this forward left out?
inline bool applies_absent(const ops::Term& term, const std::set<std::string>& absent) {
  if (absent.empty()) return false;
  for (const auto& t : term.operations())
    for (const auto& name : operators_of(t))
      if (absent.count(name)) return true;
  return false;
}

}  // namespace detail

TOPOS_INLINE std::string Plan::str() const {
  std::ostringstream o;
  o << "fast paths: " << fast_paths.str() << "\n";
  auto layer = layers.begin();
  for (std::size_t g = 0; g < groups.size(); ++g) {
    for (; layer != layers.end() && layer->second == g; ++layer)
      o << "layer " << layer->first << "\n";
    for (const auto& p : groups[g]) {
      if (!p.live) continue;
      o << "  step " << p.where.substr(0, p.where.rfind(')')) << ", group " << g
        << "): " << route_name(p.route);
      if (!p.compact_readers.empty()) {
        o << ", on the rows that ";
        for (std::size_t i = 0; i < p.compact_readers.size(); ++i)
          o << (i ? ", " : "") << p.compact_readers[i];
        o << " read";
      }
      o << "\n";
      for (const auto& l : p.lines) {
        o << std::string(static_cast<std::size_t>(4 + 2 * l.depth), ' ') << l.what;
        if (l.flops >= 0) o << "  " << detail::flops_str(l.flops) << " FLOPs";
        if (l.fused_with_next > 0)
          o << "  (one node with the next " << (l.fused_with_next == 1 ? "operation" : "two")
            << ")";
        if (l.rows >= 0) {
          o << "  -> " << l.rows << " × " << l.channels;
          if (l.terms != 1) o << ", " << l.terms << " terms";
        }
        o << "\n";
      }
    }
  }
  if (total_flops >= 0) o << "total " << detail::flops_str(total_flops) << " FLOPs\n";
  if (total_values >= 0) {
    o << "buffers " << detail::flops_str(total_values) << " values";
    if (value_bytes > 0) {
      // In the largest unit that leaves at least 1 (1024-based, as RSS is read).
      const char* unit[] = {"bytes", "KiB", "MiB", "GiB", "TiB"};
      auto v = static_cast<double>(total_values) * static_cast<double>(value_bytes);
      std::size_t u = 0;
      for (; v >= 1024 && u + 1 < std::size(unit); ++u) v /= 1024;
      o << " (" << std::fixed << std::setprecision(u ? 1 : 0) << v << " " << unit[u] << ")";
    }
    o << "\n";
  }
  return o.str();
}

TOPOS_INLINE PlannedTerm OperatorNetworkImpl::plan_term(const ops::Term& term,
                                                        const Operators& ops) const {
  PlannedTerm pt;
  pt.term = &term;
  const auto& list = term.operations();
  std::size_t k = 0;
  while (k < list.size() && detail::row_wise(list[k])) ++k;
  pt.row_wise_prefix = k;
  if (k < list.size() && detail::aggregation(list[k])) {
    const auto& name = detail::product_of(list[k])->op;
    if (ops.neighborhood(name) != nullptr) {
      pt.neighborhood = name;
      if (fast_.prefix_cache() && k > 0) pt.prefix_key = detail::prefix_key(term.source, list, k);
    }
  }
  return pt;
}

TOPOS_INLINE StepRoute OperatorNetworkImpl::route_of(const OperatorStep& s,
                                                     const std::vector<PlannedTerm>& terms,
                                                     const Operators& ops) const {
  if (terms.empty()) return StepRoute::keep;
  // A term that fans out (powers) or aggregates over a batch's neighbourhood runs the general way.
  const auto plain = [&](const ops::Term& t) {
    for (const auto& o : t.operations()) {
      const auto* p = detail::product_of(o);
      if (o.traits.fans_out || (p != nullptr && !p->transposed && ops.neighborhood(p->op)))
        return false;
    }
    return true;
  };
  const bool sums = s.mix == OperatorStep::Mix::sum || s.mix == OperatorStep::Mix::mean;
  if (terms.size() == 1 && sums && plain(*terms[0].term)) return StepRoute::chain;
  if (fast_.filter_taps() && s.mix == OperatorStep::Mix::filter) {
    const auto& W = params_.at(s.filter_path);  // in × out × taps; powers fan out into more
    if (W.dim() == 3 && W.size(2) == static_cast<std::int64_t>(s.terms.size()))
      return StepRoute::filter;
  }
  const auto& tail = s.operations();
  if (fast_.split_first_layer() && ops.batch != nullptr && s.mix == OperatorStep::Mix::concat &&
      !tail.empty() && tail.front().traits.leading_linear)
    return StepRoute::split_first_layer;
  return StepRoute::general;
}

TOPOS_INLINE std::set<std::string> OperatorNetworkImpl::absent_operators(
    const std::map<std::string, SparseOperator>& operators, const ComplexBatch* batch) const {
  std::set<std::string> absent;
  for (const auto& name : schedule_.optional_operators())
    if (!operators.count(name) && !(batch && batch->has_neighborhood(name))) absent.insert(name);
  return absent;
}

TOPOS_INLINE Plan OperatorNetworkImpl::make_plan(const Operators& ops) const {
  Plan plan;
  plan.fast_paths = fast_;
  plan.over_batch = ops.batch != nullptr;
  plan.absent = ops.absent;
  plan.layers = schedule_.layers();
  const auto& groups = schedule_.groups();
  plan.groups.resize(groups.size());
  for (std::size_t g = 0; g < groups.size(); ++g)
    for (std::size_t i = 0; i < groups[g].size(); ++i) {
      const auto& s = groups[g][i];
      PlannedStep p;
      p.group = g, p.index = i, p.step = &s, p.live = live_[g][i];
      p.where = s.name + " (into " + s.target.str() + ")";
      for (const auto& term : s.terms)
        if (!detail::applies_absent(term, ops.absent)) p.terms.push_back(plan_term(term, ops));
      p.route = route_of(s, p.terms, ops);
      // Compact only where every reader is a neighbourhood of this batch.
      if (auto c = compact_steps_.find({g, i});
          c != compact_steps_.end() && fast_.compact_cochains() && ops.batch != nullptr &&
          std::all_of(c->second.begin(), c->second.end(),
                      [&](const auto& name) { return ops.neighborhood(name) != nullptr; }))
        p.compact_readers = c->second;
      plan.groups[g].push_back(std::move(p));
    }
  return plan;
}

TOPOS_INLINE const Plan& OperatorNetworkImpl::plan_for(const Operators& ops) {
  // The key: the fast paths on, over a batch or not, and each declared operator's kind.
  std::string key;
  for (const auto& name : FastPaths::names()) key += fast_.get(name) ? '1' : '0';
  key += ops.batch != nullptr ? 'b' : '-';
  for (const auto& [name, ranks] : schedule_.operators())
    key += ops.given->count(name)   ? 'g'
           : ops.absent.count(name) ? 'a'
           : ops.neighborhood(name) ? 'n'
                                    : '?';
  const std::lock_guard<std::mutex> lock(plans_mutex_);
  auto& plan = plans_[key];
  if (!plan) plan = std::make_shared<const Plan>(make_plan(ops));
  return *plan;
}

}  // namespace topos::nn
