// topos/nn/schedule-inl.hpp
// The schedule DSL's network: validation (channel inference step by step), the encoders, the
// steps' messages, combinations and updates, and the printer. Compiled into topos::nn, or inline
// with TOPOS_HEADER_ONLY (topos/config.hpp).
#pragma once

#include "topos/nn/schedule.hpp"

#include <set>
#include <sstream>

namespace topos::nn {

TOPOS_INLINE std::string Schedule::str() const {
  std::ostringstream o;
  for (const auto& e : encoders_)
    o << "encode " << e.key.str() << " <- " << e.module << "(" << e.input << ")\n";
  for (const auto& g : groups_) {
    if (g.size() > 1) o << "parallel {\n";
    for (const auto& s : g) {
      o << (g.size() > 1 ? "  " : "") << s.name << ": into " << s.target.str();
      if (s.guard_rank >= 0) o << " when rank " << s.guard_rank << " nonempty";
      o << " = " << s.update << "(" << (s.combine == Combine::cat_self ? "cat" : "sum") << "[self";
      for (const auto& m : s.messages) {
        o << (m.accumulate ? " + " : ", ") << (m.map.empty() ? "" : m.map + "·") << m.source.str()
          << " via " << m.via;
        if (!m.by_role.empty())
          o << " by role";
        else
          o << " " << to_string(m.agg.reduce) << (m.agg.weighted ? " weighted" : "")
            << (m.agg.role ? " role " + std::to_string(m.agg.role) : "");
      }
      o << "])\n";
    }
    if (g.size() > 1) o << "}\n";
  }
  for (const auto& d : decoders_)
    o << "decode " << d.key.str() << " -> " << d.module << " -> " << d.output << "\n";
  return o.str();
}

TOPOS_INLINE ScheduleNetworkImpl::ScheduleNetworkImpl(
    Schedule schedule, const std::map<std::string, MlpOptions>& modules, ScheduleSignature sig)
    : schedule_(std::move(schedule)), sig_(std::move(sig)) {
  auto dict = register_module("modules", std::make_shared<torch::nn::Module>());
  for (const auto& [name, opt] : modules) {
    if (name.empty() || name.find('.') != std::string::npos)
      throw ScheduleError("module name '" + name + "' must be non-empty and contain no '.'");
    Mlp m(opt);
    dict->register_module(name, m);
    modules_.emplace(name, m);
  }
  validate();
  find_read_only();
}

TOPOS_INLINE std::map<std::string, torch::Tensor> ScheduleNetworkImpl::forward(
    const std::map<std::string, torch::Tensor>& inputs, const ComplexBatch& batch) {
  Cochains h = encode(inputs, &batch);
  process(h, batch);
  return decode(h);
}

TOPOS_INLINE Cochains ScheduleNetworkImpl::encode(
    const std::map<std::string, torch::Tensor>& inputs, const ComplexBatch* batch) {
  Cochains h;
  for (const auto& e : schedule_.encoders()) {
    auto it = inputs.find(e.input);
    if (it == inputs.end())
      throw ScheduleError("encode " + e.key.str() + ": input '" + e.input + "' was not given");
    torch::Tensor x = it->second;
    if (!e.negate.empty()) {
      auto sign = torch::ones({x.size(1)}, x.options());
      for (auto c : e.negate) sign[c] = -1;
      x = x * sign;
    }
    if (!e.columns.empty())
      x = x.index_select(1, torch::tensor(e.columns, torch::kLong).to(x.device()));
    auto readers = read_only_.find(e.key);
    if (fast_ && batch != nullptr && readers != read_only_.end()) {
      std::vector<torch::Tensor> sources;
      for (const auto& via : readers->second) sources.push_back(batch->neighborhood(via).source);
      const auto used = std::get<0>(torch::_unique(torch::cat(sources), /*sorted=*/true));
      if (used.size(0) < x.size(0)) {
        h.set_compact(e.key.rank, e.key.state,
                      modules_.at(e.module)->forward(x.index_select(0, used)),
                      compact_rows(used, x.size(0)));
        continue;
      }
    }
    h.set(e.key.rank, e.key.state, modules_.at(e.module)->forward(x));
  }
  return h;
}

TOPOS_INLINE void ScheduleNetworkImpl::process(Cochains& h, const ComplexBatch& batch) {
  for (const auto& group : schedule_.groups()) {
    const Cochains snapshot = h;
    MapCache cache;  // a module mapped over all rows of a source is computed once per group
    std::vector<std::pair<CochainKey, torch::Tensor>> updates;
    for (const auto& s : group) updates.emplace_back(s.target, run_step(s, snapshot, batch, cache));
    for (auto& [k, v] : updates) h.set(k.rank, k.state, v);
  }
}

TOPOS_INLINE std::map<std::string, torch::Tensor> ScheduleNetworkImpl::decode(const Cochains& h) {
  std::map<std::string, torch::Tensor> out;
  for (const auto& d : schedule_.decoders())
    out[d.output] = modules_.at(d.module)->forward(h.at(d.key.rank, d.key.state));
  return out;
}

TOPOS_INLINE Mlp ScheduleNetworkImpl::module(const std::string& name) const {
  auto it = modules_.find(name);
  if (it == modules_.end()) throw ScheduleError("no module '" + name + "'");
  return it->second;
}

TOPOS_INLINE torch::Tensor ScheduleNetworkImpl::compact_rows(const torch::Tensor& used,
                                                             std::int64_t rows) {
  auto row = torch::full({rows}, -1, used.options());
  row.index_put_({used}, torch::arange(used.size(0), used.options()));
  return row;
}

TOPOS_INLINE void ScheduleNetworkImpl::find_read_only() {
  std::set<CochainKey> written;
  for (const auto& g : schedule_.groups())
    for (const auto& s : g) written.insert(s.target);
  for (const auto& d : schedule_.decoders()) written.insert(d.key);
  for (const auto& e : schedule_.encoders()) {
    if (written.count(e.key)) continue;
    std::vector<std::string> vias;
    for (const auto& g : schedule_.groups())
      for (const auto& s : g)
        for (const auto& m : s.messages)
          if (m.source == e.key) vias.push_back(m.via);
    if (!vias.empty()) read_only_[e.key] = std::move(vias);
  }
}

TOPOS_INLINE torch::Tensor ScheduleNetworkImpl::run_step(const Step& s, const Cochains& h,
                                                         const ComplexBatch& batch,
                                                         MapCache& cache) {
  const torch::Tensor& self = h.at(s.target.rank, s.target.state);
  Mlp update = modules_.at(s.update);
  // cat_self feeds [self, m1, m2, ...] to the update's first Linear layer. A message reduced
  // linearly (sum or mean) from fewer rows than it has targets is multiplied by its block of
  // that layer's weight *before* the reduction (W·Σx = Σ W·x): HOPNet's object-to-node message
  // then costs one matmul over the objects instead of one over every node.
  const bool cat = s.combine == Combine::cat_self;
  const torch::Tensor W = cat ? update->first_linear()->weight : torch::Tensor();
  std::vector<torch::Tensor> parts;     // concatenated, then one matmul
  std::vector<std::int64_t> part_cols;  // their columns of W
  torch::Tensor early;                  // Σ of messages already multiplied by their block
  std::int64_t col = 0;
  auto add_part = [&](const torch::Tensor& t) {
    parts.push_back(t);
    for (std::int64_t c = 0; c < t.size(1); ++c) part_cols.push_back(col + c);
    col += t.size(1);
  };
  if (cat) add_part(self);
  torch::Tensor total = cat ? torch::Tensor() : self;
  for (std::size_t mi = 0; mi < s.messages.size(); ++mi) {
    const auto& m = s.messages[mi];
    torch::Tensor x = h.at(m.source.rank, m.source.state);
    TensorNeighborhood n = batch.neighborhood(m.via);
    if (const auto row = h.rows(m.source); row.defined()) {  // a compact cochain
      n.source = row.index_select(0, n.source);
      n.num_source = x.size(0);
    }
    if (!m.map.empty()) {
      auto cached = cache.find({m.source, m.map});
      if (cached != cache.end()) {
        x = cached->second;
      } else if (const auto used = fast_ ? std::get<0>(torch::_unique(n.source, /*sorted=*/true))
                                         : torch::Tensor();
                 used.defined() && used.size(0) < x.size(0)) {
        // Some source rows send nothing here: map only those that do (the module acts row by
        // row, so the messages are the same), and renumber the pairs' sources.
        x = modules_.at(m.map)->forward(x.index_select(0, used));
        n.source = compact_rows(used, n.num_source).index_select(0, n.source);
        n.num_source = used.size(0);
      } else {
        x = modules_.at(m.map)->forward(x);
        cache.emplace(std::make_pair(m.source, m.map), x);
      }
    }
    const bool next_adds = mi + 1 < s.messages.size() && s.messages[mi + 1].accumulate;
    // Not with backward values: they scale the gradient reaching the message, which must not
    // reach the update's weight.
    const bool scaled_backward = m.agg.weighted && n.backward_values.defined();
    if (fast_ && cat && !m.accumulate && !next_adds && m.by_role.empty() &&
        m.agg.reduce != Reduce::max && x.size(0) < n.num_target && !scaled_backward) {
      const auto block = aggregate(nn::linear(x, W.narrow(1, col, x.size(1))), n, m.agg);
      early = early.defined() ? early + block : block;
      col += x.size(1);
      continue;
    }
    torch::Tensor agg;
    if (m.by_role.empty()) {
      agg = aggregate(x, n, m.agg);
    } else {
      std::vector<torch::Tensor> per_role;
      for (int r : m.by_role)
        per_role.push_back(aggregate(x, n, AggregateOptions(m.agg).with_role(r)));
      agg = torch::cat(per_role, 1);
    }
    if (m.accumulate) {
      if (cat)
        parts.back() = parts.back() + agg;
      else
        total = total + agg;
    } else if (cat) {
      add_part(agg);
    } else {
      total = total + agg;
    }
  }
  torch::Tensor updated;
  if (!cat) {
    updated = update->forward(total);
  } else if (!early.defined()) {
    updated = update->forward(parts.size() == 1 ? parts[0] : torch::cat(parts, 1));
  } else {
    const auto first = update->first_linear();
    const auto Wd = static_cast<std::int64_t>(part_cols.size()) == W.size(1)
                        ? W
                        : W.index_select(1, torch::tensor(part_cols, torch::kLong).to(W.device()));
    const auto dense = parts.size() == 1 ? parts[0] : torch::cat(parts, 1);
    auto z = nn::linear(dense, Wd, first->bias);
    z.add_(early);
    updated = update->forward_after_first(z);
  }
  if (s.guard_rank >= 0) {
    // Per complex: does it hold a cell of the guard rank? Applied through the target's batch
    // vector.
    std::vector<std::int64_t> has;
    for (auto c : batch.counts(s.guard_rank)) has.push_back(c > 0);
    const auto active = torch::tensor(has, torch::kLong)
                            .to(self.device())
                            .index_select(0, batch.batch(s.target.rank))
                            .to(torch::kBool)
                            .unsqueeze(1);
    if (updated.size(1) != self.size(1)) return updated * active.to(updated.dtype());
    updated = torch::where(active, updated, self);
  }
  return updated;
}

TOPOS_INLINE void ScheduleNetworkImpl::validate() {
  std::map<CochainKey, std::int64_t> width;
  auto mod = [&](const std::string& where, const std::string& name) -> const MlpOptions& {
    auto it = modules_.find(name);
    if (it == modules_.end()) throw ScheduleError(where + ": unknown module '" + name + "'");
    return it->second->options;
  };
  for (const auto& e : schedule_.encoders()) {
    const std::string where = "encode " + e.key.str();
    auto in = sig_.inputs.find(e.input);
    if (in == sig_.inputs.end()) throw ScheduleError(where + ": unknown input '" + e.input + "'");
    for (auto c : e.columns)
      if (c < 0 || c >= in->second)
        throw ScheduleError(where + ": column " + std::to_string(c) + " out of range for input '" +
                            e.input + "' of " + std::to_string(in->second) + " columns");
    for (auto c : e.negate)
      if (c < 0 || c >= in->second)
        throw ScheduleError(where + ": negated column " + std::to_string(c) + " out of range");
    const std::int64_t cols =
        e.columns.empty() ? in->second : static_cast<std::int64_t>(e.columns.size());
    const auto& m = mod(where, e.module);
    if (m.in() != cols)
      throw ScheduleError(where + ": module '" + e.module + "' takes " + std::to_string(m.in()) +
                          " channels but gets " + std::to_string(cols));
    width[e.key] = m.out();
  }
  for (const auto& group : schedule_.groups()) {
    std::map<CochainKey, std::int64_t> next = width;
    for (const auto& s : group) {
      const std::string where = s.name + " (into " + s.target.str() + ")";
      auto self = width.find(s.target);
      if (self == width.end())
        throw ScheduleError(where + ": target " + s.target.str() +
                            " has no cochain (no encoder or earlier step produces it)");
      std::int64_t cat = s.combine == Combine::cat_self ? self->second : 0;
      std::int64_t last = 0;  // width of the previous message
      for (const auto& m : s.messages) {
        auto src = width.find(m.source);
        if (src == width.end())
          throw ScheduleError(where + ": source " + m.source.str() + " has no cochain");
        auto n = sig_.neighborhoods.find(m.via);
        if (n == sig_.neighborhoods.end())
          throw ScheduleError(where + ": unknown neighborhood '" + m.via + "'");
        if (n->second.first != m.source.rank || n->second.second != s.target.rank)
          throw ScheduleError(where + ": neighborhood '" + m.via + "' goes from rank " +
                              std::to_string(n->second.first) + " to rank " +
                              std::to_string(n->second.second) + ", not from " +
                              std::to_string(m.source.rank) + " to " +
                              std::to_string(s.target.rank));
        std::int64_t c = src->second;
        if (!m.map.empty()) {
          const auto& mm = mod(where, m.map);
          if (mm.in() != c)
            throw ScheduleError(where + ": message module '" + m.map + "' takes " +
                                std::to_string(mm.in()) + " channels but " + m.source.str() +
                                " has " + std::to_string(c));
          c = mm.out();
        }
        if (!m.by_role.empty()) c *= static_cast<std::int64_t>(m.by_role.size());
        if (m.accumulate) {
          if (&m == &s.messages.front())
            throw ScheduleError(where + ": an added message needs a message before it");
          if (c != last)
            throw ScheduleError(where + ": added message from " + m.source.str() + " has " +
                                std::to_string(c) + " channels, the message it is added to has " +
                                std::to_string(last));
          continue;
        }
        last = c;
        if (s.combine == Combine::cat_self)
          cat += c;
        else if (c != self->second)
          throw ScheduleError(where + ": summed message from " + m.source.str() + " has " +
                              std::to_string(c) + " channels, the target has " +
                              std::to_string(self->second));
      }
      if (s.combine == Combine::sum_self) cat = self->second;
      const auto& u = mod(where, s.update);
      if (u.in() != cat)
        throw ScheduleError(where + ": update module '" + s.update + "' takes " +
                            std::to_string(u.in()) + " channels but the combined input has " +
                            std::to_string(cat));
      if (s.guard_rank >= 0 && u.out() != self->second)
        throw ScheduleError(where + ": a guarded step must keep the target's width (" +
                            std::to_string(self->second) + "), its update gives " +
                            std::to_string(u.out()));
      next[s.target] = u.out();
    }
    width = std::move(next);
  }
  for (const auto& d : schedule_.decoders()) {
    const std::string where = "decode " + d.key.str();
    auto w = width.find(d.key);
    if (w == width.end()) throw ScheduleError(where + ": no cochain to decode");
    const auto& m = mod(where, d.module);
    if (m.in() != w->second)
      throw ScheduleError(where + ": module '" + d.module + "' takes " + std::to_string(m.in()) +
                          " channels but the cochain has " + std::to_string(w->second));
  }
}

}  // namespace topos::nn
