// topos/nn/operator_schedule/build-inl.hpp
// OperatorNetwork's construction: each step's terms followed operation by operation to infer
// ranks and widths, the checks that name the step, and liveness (which steps an output needs).
// The parameters the operations ask for are made in parameters-inl.hpp.
// Compiled into topos::nn, or inline with TOPOS_HEADER_ONLY (topos/config.hpp).
#pragma once

#include "topos/nn/operator_schedule/network.hpp"
#include "topos/nn/operator_schedule/parameters-inl.hpp"

#include <algorithm>
#include <map>
#include <optional>
#include <set>
#include <string>
#include <vector>

namespace topos::nn {

namespace detail {

/// The build context of one step: operations read the widths of the cochains before the step
/// (recorded: the network keeps the steps that produce them) and create parameters through it.
class NetworkBuildContext final : public BuildContext {
 public:
  NetworkBuildContext(OperatorNetworkImpl& net, const OperatorStep& step,
                      const std::map<CochainKey, std::int64_t>& width, std::set<CochainKey>& reads,
                      const std::set<CochainKey>& step_outputs, std::set<std::string>& applied)
      : net_(net),
        step_(step),
        where_(step.name + " (into " + step.target.str() + ")"),
        width_(width),
        reads_(reads),
        step_outputs_(step_outputs),
        applied_(applied) {}
  const std::string& where() const override { return where_; }
  const CochainKey& target() const override { return step_.target; }
  std::pair<int, int> operator_ranks(const std::string& name) const override {
    auto it = net_.schedule_.operators().find(name);
    if (it == net_.schedule_.operators().end()) fail("unknown operator '" + name + "'");
    applied_.insert(name);
    return it->second;
  }
  std::int64_t cochain_width(const CochainKey& key) override {
    if (auto w = find_width(key)) return *w;
    fail("cochain " + key.str() + " is read, but no input or earlier step produces it");
  }
  /// The width of `key` before the step, if a cochain is there (and then it counts as read).
  std::optional<std::int64_t> find_width(const CochainKey& key) override {
    auto it = width_.find(key);
    if (it == width_.end()) return std::nullopt;
    reads_.insert(key);
    return it->second;
  }
  /// Does one of the step's terms start at `key`?
  bool step_reads(const CochainKey& key) const override {
    return std::any_of(step_.terms.begin(), step_.terms.end(),
                       [&](const ops::Term& t) { return t.source == key; });
  }
  /// Was `key` written by an earlier step (rather than given as an input)?
  bool written_by_a_step(const CochainKey& key) const override {
    return step_outputs_.count(key) > 0;
  }
  void parameter(const std::string& path, const std::vector<std::int64_t>& shape,
                 ParameterInit init) override {
    net_.make_parameter(where_, path, shape, init, true);
  }
  void buffer(const std::string& path, const std::vector<std::int64_t>& shape,
              double value) override {
    net_.make_parameter(where_, path, shape, ParameterInit::constant(value), false);
  }
  std::shared_ptr<torch::nn::Module> module(const std::string& path,
                                            std::shared_ptr<torch::nn::Module> m) override {
    return net_.make_module(where_, path, std::move(m));
  }
  std::shared_ptr<torch::nn::Module> find_module(const std::string& path) const override {
    auto it = net_.modules_.find(path);
    return it == net_.modules_.end() ? nullptr : it->second;
  }

 private:
  OperatorNetworkImpl& net_;
  const OperatorStep& step_;
  std::string where_;
  const std::map<CochainKey, std::int64_t>& width_;
  std::set<CochainKey>& reads_;
  const std::set<CochainKey>& step_outputs_;
  std::set<std::string>& applied_;  // the operators some operation applies or asks about
};

}  // namespace detail

TOPOS_INLINE OperatorNetworkImpl::OperatorNetworkImpl(OperatorSchedule schedule)
    : schedule_(std::move(schedule)) {
  validate_and_create();
  dtype_reference_ = first_submodule_parameter();
}

TOPOS_INLINE OperatorNetworkImpl::~OperatorNetworkImpl() = default;
TOPOS_INLINE TermShape OperatorNetworkImpl::infer(detail::NetworkBuildContext& ctx, const TermOp& t,
                                                  TermShape x) {
  const std::string& where = ctx.where();
  if (!t.operation) throw ScheduleError(where + ": a custom operation is null");
  const auto y = t.operation->infer(ctx, x);
  if (y.channels <= 0)
    throw ScheduleError(where + ": operation " + t.operation->str("x") + " gives " +
                        std::to_string(y.channels) + " channels");
  // Forward's result is checked against it; a product's rows are its operator's, which the
  // step's mix checks against its other terms, naming both.
  if (!t.traits.product) inferred_[&t] = {x.rank, y};
  return y;
}

// The schedule checked step by step (each error names the step), its parameters created, and
// which steps run on compact rows (find_compact_steps) and which forward() runs at all
// (find_live_steps).
TOPOS_INLINE void OperatorNetworkImpl::validate_and_create() {
  auto width = declared_widths();
  // What each step reads (its terms' sources, and what its operations read through the build
  // context) and writes, for the liveness.
  std::vector<std::vector<std::set<CochainKey>>> reads;
  std::set<CochainKey> step_outputs;  // cochains some earlier step wrote
  std::set<std::string> applied;      // operators that some operation applies
  for (const auto& group : schedule_.groups()) {
    auto next = width;
    std::set<CochainKey> written;
    reads.emplace_back();
    for (const auto& s : group) {
      auto& read = reads.back().emplace_back();
      detail::NetworkBuildContext ctx(*this, s, width, read, step_outputs, applied);
      for (const auto& t : s.operations())
        for (const auto& name : detail::operators_of(t)) applied.insert(name);
      for (const auto& term : s.terms)
        for (const auto& t : term.operations())
          for (const auto& name : detail::operators_of(t)) applied.insert(name);
      if (!written.insert(s.target).second)
        throw ScheduleError(ctx.where() + ": another step of the same parallel group writes " +
                            s.target.str());
      next[s.target] = infer_step(ctx, s);
    }
    width = std::move(next);
    for (const auto& s : group) step_outputs.insert(s.target);
  }
  check_outputs(width, applied);
  for (const auto& p : schedule_.parameters())
    make_parameter("parameter '" + p.path + "'", p.path, p.shape, ParameterInit::glorot(p.gain));
  find_compact_steps(reads);
  find_live_steps(reads);
}

// The inputs' widths; an input or a layer declared twice is an error.
TOPOS_INLINE std::map<CochainKey, std::int64_t> OperatorNetworkImpl::declared_widths() const {
  std::map<CochainKey, std::int64_t> width;
  std::set<std::string> names;
  for (const auto& in : schedule_.inputs()) {
    if (!names.insert(in.name).second)
      throw ScheduleError("input '" + in.name + "' is declared twice");
    if (in.channels <= 0)
      throw ScheduleError("input '" + in.name + "' needs a positive number of channels");
    width[in.key] = in.channels;
  }
  std::set<std::string> layer_names;
  for (const auto& layer : schedule_.layers())
    if (!layer_names.insert(layer.first).second)
      throw ScheduleError("layer '" + layer.first + "' is declared twice");
  return width;
}

// An optional operator is skipped by dropping the terms that apply it: only a step that sums or
// averages its terms can drop one, and never its own operations.
TOPOS_INLINE void OperatorNetworkImpl::check_optional_uses(const std::string& where,
                                                           const OperatorStep& s) const {
  const auto& optional = schedule_.optional_operators();
  for (const auto& term : s.terms)
    for (const auto& t : term.operations())
      for (const auto& name : detail::operators_of(t))
        if (optional.count(name) && s.mix != OperatorStep::Mix::sum &&
            s.mix != OperatorStep::Mix::mean)
          throw ScheduleError(where + ": the term from " + term.source.str() +
                              " applies the optional operator '" + name +
                              "', which only a step that sums or averages its terms can skip");
  for (const auto& t : s.operations())
    for (const auto& name : detail::operators_of(t))
      if (optional.count(name))
        throw ScheduleError(where + ": the step's own operations apply the optional operator '" +
                            name + "', which cannot be skipped there");
}

// The width the step's terms give its mix (their sum for a concatenation), and how many values
// they give (a polynomial filter's powers fan out); each term must end on the target's rank.
TOPOS_INLINE std::pair<std::int64_t, std::int64_t> OperatorNetworkImpl::infer_terms(
    detail::NetworkBuildContext& ctx, const OperatorStep& s) {
  const std::string& where = ctx.where();
  std::int64_t channels = -1, count = 0;
  for (const auto& term : s.terms) {
    const auto w = ctx.find_width(term.source);
    if (!w)
      throw ScheduleError(where + ": source " + term.source.str() +
                          " has no cochain (no input or earlier step produces it)");
    TermShape x{term.source.rank, *w};
    term_width_[&term] = *w;
    std::int64_t fanned = 1;
    const auto& list = term.operations();
    for (std::size_t i = 0; i < list.size(); ++i) {
      if (list[i].traits.fans_out) {
        if (i + 1 != list.size())
          throw ScheduleError(where + ": " + list[i].operation->str("x") +
                              " fans out into several terms: it must be a term's last operation");
        fanned = list[i].traits.terms;
      }
      x = shapes_[&list[i]] = infer(ctx, list[i], x);
    }
    if (x.rank != s.target.rank)
      throw ScheduleError(where + ": the term from " + term.source.str() + " ends on rank " +
                          std::to_string(x.rank) + ", the target is rank " +
                          std::to_string(s.target.rank));
    if (s.mix == OperatorStep::Mix::concat) {  // widths add up
      channels = std::max<std::int64_t>(channels, 0) + x.channels;
    } else {
      if (channels >= 0 && x.channels != channels)
        throw ScheduleError(where + ": the term from " + term.source.str() + " has " +
                            std::to_string(x.channels) + " channels, the one before has " +
                            std::to_string(channels));
      channels = x.channels;
    }
    count += fanned;
  }
  return {channels, count};
}

// A step checked and its parameters created: the width it writes.
TOPOS_INLINE std::int64_t OperatorNetworkImpl::infer_step(detail::NetworkBuildContext& ctx,
                                                          const OperatorStep& s) {
  const std::string& where = ctx.where();
  if (s.terms.empty()) throw ScheduleError(where + ": a step needs at least one term");
  check_optional_uses(where, s);
  const auto [channels, count] = infer_terms(ctx, s);
  mix_width_[&s] = channels;
  TermShape y{s.target.rank, channels};
  if (s.mix == OperatorStep::Mix::filter) {
    make_parameter(where, s.filter_path, {channels, s.filter_out, count},
                   ParameterInit::glorot(1.414));
    y.channels = s.filter_out;
  } else if (count != static_cast<std::int64_t>(s.terms.size())) {
    throw ScheduleError(where + ": polynomial filter terms need a filter weight to mix them");
  }
  for (const auto& t : s.operations()) {
    if (t.traits.fans_out)
      throw ScheduleError(where + ": " + t.operation->str("x") +
                          " fans out into several terms: it applies to terms, not to a step");
    y = shapes_[&t] = infer(ctx, t, y);
  }
  if (y.rank != s.target.rank)
    throw ScheduleError(where + ": the step's operations end on rank " + std::to_string(y.rank) +
                        ", the target is rank " + std::to_string(s.target.rank));
  if (s.guard_rank >= 0) {
    const auto before = ctx.find_width(s.target);
    if (!before)
      throw ScheduleError(where + ": when_nonempty keeps the target's value elsewhere, but " +
                          s.target.str() + " has none before the step");
    if (*before != y.channels)
      throw ScheduleError(where + ": when_nonempty must keep the target's width (" +
                          std::to_string(*before) + "), the step gives " +
                          std::to_string(y.channels));
  }
  return y.channels;
}

// Every output names a cochain; every optional operator is applied by some step (else it is a
// typo: a forward without it would drop no term).
TOPOS_INLINE void OperatorNetworkImpl::check_outputs(
    const std::map<CochainKey, std::int64_t>& width, const std::set<std::string>& applied) const {
  for (const auto& o : schedule_.outputs())
    if (!width.count(o.key))
      throw ScheduleError("output '" + o.name + "': no cochain " + o.key.str());
  for (const auto& name : schedule_.optional_operators())
    if (!applied.count(name)) {
      std::string names;
      for (const auto& n : applied) names += (names.empty() ? "'" : ", '") + n + "'";
      throw ScheduleError("optional operator '" + name + "' is applied by no step (they apply " +
                          (names.empty() ? "none" : names) +
                          "): write the name a term applies, or remove the optional_operator");
    }
}

// Liveness, from the outputs back: a step is run by forward() only when a later step or an
// output reads what it writes. A group reads one snapshot, so its live steps' targets leave the
// needed set before their reads join it.
TOPOS_INLINE void OperatorNetworkImpl::find_live_steps(
    const std::vector<std::vector<std::set<CochainKey>>>& reads) {
  std::set<CochainKey> needed;
  for (const auto& o : schedule_.outputs()) needed.insert(o.key);
  const auto& groups = schedule_.groups();
  live_.assign(groups.size(), {});
  for (std::size_t g = groups.size(); g-- > 0;) {
    auto& live = live_[g];
    for (const auto& s : groups[g]) live.push_back(needed.count(s.target) > 0);
    for (std::size_t i = 0; i < groups[g].size(); ++i)
      if (live[i]) needed.erase(groups[g][i].target);
    for (std::size_t i = 0; i < groups[g].size(); ++i)
      if (live[i]) needed.insert(reads[g][i].begin(), reads[g][i].end());
  }
}

// A step whose one term maps an input row by row, and whose target nothing but aggregations (after
// row-wise operations) ever reads, can run on the rows those aggregations read (run_compact).
TOPOS_INLINE void OperatorNetworkImpl::find_compact_steps(
    const std::vector<std::vector<std::set<CochainKey>>>& reads) {
  const auto& groups = schedule_.groups();
  std::set<CochainKey> inputs, outputs;
  for (const auto& in : schedule_.inputs()) inputs.insert(in.key);
  for (const auto& out : schedule_.outputs()) outputs.insert(out.key);
  const auto all_row_wise = [](const std::vector<TermOp>& list) {
    return std::all_of(list.begin(), list.end(), detail::row_wise);
  };
  // Operations that may read a cochain other than their term's source.
  const auto reads_others = [](const std::vector<TermOp>& list) {
    return std::any_of(list.begin(), list.end(), detail::reads_cochains);
  };
  for (std::size_t g = 0; g < groups.size(); ++g)
    for (std::size_t i = 0; i < groups[g].size(); ++i) {
      const auto& s = groups[g][i];
      const auto& T = s.target;
      if (s.terms.size() != 1 || s.guard_rank >= 0 || s.mix == OperatorStep::Mix::filter ||
          s.mix == OperatorStep::Mix::concat || inputs.count(T) || outputs.count(T) ||
          !all_row_wise(s.terms[0].operations()) || !all_row_wise(s.operations()))
        continue;
      std::vector<std::string> readers;
      bool compact = true;
      for (std::size_t g2 = 0; g2 < groups.size() && compact; ++g2)
        for (std::size_t i2 = 0; i2 < groups[g2].size() && compact; ++i2) {
          const auto& r = groups[g2][i2];
          if (g2 == g && i2 == i) continue;
          if (r.target == T) compact = false;  // written again
          if (!reads[g2][i2].count(T)) continue;
          if (reads_others(r.operations())) compact = false;
          for (const auto& term : r.terms) {
            const auto& list = term.operations();
            if (reads_others(list)) compact = false;
            if (!(term.source == T)) continue;
            std::size_t k = 0;
            while (k < list.size() && detail::row_wise(list[k])) ++k;
            if (k == list.size() || !detail::aggregation(list[k]))
              compact = false;
            else
              readers.push_back(detail::product_of(list[k])->op);
          }
        }
      if (compact && !readers.empty()) compact_steps_[{g, i}] = std::move(readers);
    }
}

}  // namespace topos::nn
