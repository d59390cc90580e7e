// topos/nn/operator_schedule/interpreter-inl.hpp
// OperatorNetwork's forward: the steps an output needs (build-inl.hpp's liveness) run in order, a
// parallel group on one snapshot, each term evaluated (term-inl.hpp) and the terms combined into
// the step's target. Compiled into topos::nn, or inline with TOPOS_HEADER_ONLY (topos/config.hpp).
#pragma once

#include "topos/nn/operator_schedule/checks-inl.hpp"
#include "topos/nn/operator_schedule/term-inl.hpp"

#include <algorithm>
#include <functional>
#include <set>

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
  auto it = mlps_.find(path);
  if (it == mlps_.end()) throw ScheduleError("no mlp '" + path + "' in the schedule");
  return it->second;
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

TOPOS_INLINE void OperatorNetworkImpl::run_range(
    Cochains& h, const std::map<std::string, SparseOperator>& operators, const ComplexBatch* batch,
    std::size_t begin, std::size_t end, bool live_only) {
  Operators ops{&operators, batch, {}, {}, {}};
  for (const auto& name : schedule_.optional_operators())
    if (!operators.count(name) && !(batch && batch->has_neighborhood(name)))
      ops.absent.insert(name);
  const auto& groups = schedule_.groups();
  for (std::size_t g = begin; g < end && g < groups.size(); ++g) {
    const Cochains snapshot = h;
    PrefixCache cache;  // a term prefix shared by several steps of the group is computed once
    struct Update {
      CochainKey key;
      torch::Tensor value, rows;  // rows: defined for a compact cochain
    };
    std::vector<Update> updates;
    for (std::size_t i = 0; i < groups[g].size(); ++i) {
      if (live_only && !live_[g][i]) continue;
      const auto& s = groups[g][i];
      Update u{s.target, {}, {}};
      try {
        if (auto c = compact_steps_.find({g, i}); c != compact_steps_.end())
          std::tie(u.value, u.rows) = run_compact(s, c->second, snapshot, ops, cache);
        if (!u.value.defined()) u.value = run_step(s, snapshot, ops, cache);
      } catch (const c10::Error& e) {  // LibTorch's message, without its stack, and the step
        detail::rethrow_in_step(s, snapshot, e);
      }
      updates.push_back(std::move(u));
    }
    for (auto& u : updates) {
      if (u.rows.defined())
        h.set_compact(u.key.rank, u.key.state, std::move(u.value), std::move(u.rows));
      else
        h.set(u.key.rank, u.key.state, std::move(u.value));
    }
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

TOPOS_INLINE torch::Tensor OperatorNetworkImpl::run_step(const OperatorStep& s, const Cochains& h,
                                                         Operators& ops, PrefixCache& cache) {
  const std::string where = s.name + " (into " + s.target.str() + ")";
  if (!ops.absent.empty()) {  // terms that apply an optional operator left out are skipped
    const auto uses_absent = [&](const ops::Term& term) {
      for (const auto& t : term.operations())
        for (const auto& name : detail::operators_of(t))
          if (ops.absent.count(name)) return true;
      return false;
    };
    if (std::any_of(s.terms.begin(), s.terms.end(), uses_absent)) {
      OperatorStep kept = s;
      kept.terms.clear();
      for (const auto& term : s.terms)
        if (!uses_absent(term)) kept.terms.push_back(term);
      if (kept.terms.empty()) {
        if (!h.has(s.target.rank, s.target.state))
          throw ScheduleError(where + ": every term applies an optional operator left out, and " +
                              s.target.str() + " has no value to keep");
        return h.at(s.target.rank, s.target.state);
      }
      return run_step(kept, h, ops, cache);  // the kept terms apply none of them
    }
  }
  const auto& tail = s.operations();
  const auto no_powers = [](const ops::Term& t) {
    return std::none_of(t.operations().begin(), t.operations().end(),
                        [](const TermOp& o) { return o.kind == TermOp::Kind::powers; });
  };
  const auto over_batch = [&](const ops::Term& t) {
    for (const auto& o : t.operations())
      if ((o.kind == TermOp::Kind::via || o.kind == TermOp::Kind::pattern) &&
          ops.neighborhood(o.name))
        return true;
    return false;
  };
  const bool single =
      s.terms.size() == 1 && (s.mix == OperatorStep::Mix::sum || s.mix == OperatorStep::Mix::mean);
  if (single && no_powers(s.terms[0]) && !over_batch(s.terms[0])) {
    // One term: its operations and the step's as one list, so that a product ending the term
    // fuses with the step's activation.
    auto list = s.terms[0].operations();
    list.insert(list.end(), tail.begin(), tail.end());
    torch::Tensor x = h.at(s.terms[0].source.rank, s.terms[0].source.state);
    for (std::size_t i = 0; i < list.size(); ++i)
      i = apply_fused(where, s.target, list, i, x, ops, h);
    return guard(where, s, std::move(x), h, ops);
  }
  if (fast_ && s.mix == OperatorStep::Mix::filter)
    if (auto y = run_filter(where, s, h, ops, cache); y.defined()) {
      for (std::size_t i = 0; i < tail.size(); ++i)
        i = apply_fused(where, s.target, tail, i, y, ops, h);
      return guard(where, s, std::move(y), h, ops);
    }
  // A concatenation into an mlp over a batch: a term summed from fewer rows than the target has
  // is multiplied by its block of the mlp's first weight before the sum (W Σ x = Σ W x):
  // HOPNet's object-to-node message then costs a product over the objects, not the nodes.
  const bool split = fast_ && ops.batch != nullptr && s.mix == OperatorStep::Mix::concat &&
                     !tail.empty() && tail.front().kind == TermOp::Kind::mlp;
  const torch::Tensor W =
      split ? mlps_.at(tail.front().name)->first_linear()->weight : torch::Tensor();
  torch::Tensor early;                  // Σ of the terms already multiplied by their block
  std::vector<std::int64_t> part_cols;  // the columns of W of the terms left
  std::int64_t col = 0;
  std::vector<torch::Tensor> terms;
  const auto add_term = [&](torch::Tensor t) {
    if (split)
      for (std::int64_t c = 0; c < t.size(1); ++c) part_cols.push_back(col + c);
    col += t.dim() == 2 ? t.size(1) : 0;
    terms.push_back(std::move(t));
  };
  for (const auto& term : s.terms) {
    auto v = evaluate_term(where, s.target, term, h, ops, cache, split);
    if (v.handled) {
      if (v.deferred) {
        // Not with backward values: they scale the gradient reaching the message, which must
        // not reach the weight.
        const bool scaled_backward = v.agg.weighted && v.n.backward_values.defined();
        if (v.agg.reduce != Aggr::max && v.agg.role == 0 && v.x.size(0) < v.n.num_target &&
            !scaled_backward) {
          const auto block = aggregate(nn::linear(v.x, W.narrow(1, col, v.x.size(1))), v.n, v.agg);
          early = early.defined() ? early + block : block;
          col += v.x.size(1);
          continue;
        }
        v.value = aggregate(v.x, v.n, v.agg);
      }
      add_term(std::move(v.value));
      continue;
    }
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
    if (x.defined()) add_term(std::move(x));
  }
  torch::Tensor y;
  std::size_t first_tail = 0;
  if (s.mix == OperatorStep::Mix::filter) {
    y = combine_terms(terms, params_.at(s.filter_path));
  } else if (split) {
    auto update = mlps_.at(tail.front().name);
    if (!early.defined()) {
      y = update->forward(terms.size() == 1 ? terms[0] : torch::cat(terms, 1));
    } else {
      const auto first = update->first_linear();
      const auto Wd =
          static_cast<std::int64_t>(part_cols.size()) == W.size(1)
              ? W
              : W.index_select(1, torch::tensor(part_cols, torch::kLong).to(W.device()));
      const auto dense = terms.size() == 1 ? terms[0] : torch::cat(terms, 1);
      auto z = nn::linear(dense, Wd, first->bias);
      z.add_(early);
      y = update->forward_after_first(z);
    }
    first_tail = 1;
  } else if (s.mix == OperatorStep::Mix::concat) {
    y = terms.size() == 1 ? terms[0] : torch::cat(terms, 1);
  } else {
    y = terms[0];
    for (std::size_t i = 1; i < terms.size(); ++i) y = y + terms[i];
    if (s.mix == OperatorStep::Mix::mean) y = y / static_cast<double>(terms.size());
  }
  for (std::size_t i = first_tail; i < tail.size(); ++i)
    i = apply_fused(where, s.target, tail, i, y, ops, h);
  return guard(where, s, std::move(y), h, ops);
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
                                                           Operators& ops, PrefixCache& cache) {
  const auto& W = params_.at(s.filter_path);  // in × out × taps
  const auto K = s.terms.size();
  if (W.dim() != 3 || W.size(2) != static_cast<std::int64_t>(K)) return {};  // powers fan out
  struct Link {
    const SparseOperator* A;
    const TermOp* op;
  };
  std::vector<std::vector<Link>> chains(K);
  std::vector<bool> products(K, true);
  std::int64_t target_rows = -1;
  for (std::size_t k = 0; k < K; ++k) {
    const auto& term = s.terms[k];
    if (h.rows(term.source).defined()) return {};  // a compact cochain: the general path
    auto rows = h.at(term.source.rank, term.source.state).size(0);
    for (const auto& o : term.operations()) {
      if (o.kind == TermOp::Kind::powers) return {};
      const bool product =
          (o.kind == TermOp::Kind::via || o.kind == TermOp::Kind::via_transposed) && o.role == 0 &&
          !ops.neighborhood(o.name);
      const SparseOperator* A = nullptr;
      if (product)
        A = o.kind == TermOp::Kind::via_transposed ? &ops.t(where, o.name) : &ops.at(where, o.name);
      if (A == nullptr || A->cols != rows) {  // the general path applies it, or names the misfit
        products[k] = false;
        break;
      }
      chains[k].push_back({A, &o});
      rows = A->rows;
    }
    if (!products[k]) continue;
    if (target_rows >= 0 && rows != target_rows) return {};  // combine_terms says why
    target_rows = rows;
  }
  const auto prefix = [&](std::size_t k, std::size_t j) {
    const auto& src = s.terms[k].source;
    return "filter|" + std::to_string(h.at(src.rank, src.state).size(0)) + "|" +
           detail::prefix_key(src, s.terms[k].operations(), j);
  };
  const auto name_of = [](const TermOp& o) {
    return operator_label(o.name, o.kind == TermOp::Kind::via_transposed);
  };
  // Each source's product taps: weighted first when that costs less.
  const double c_in = static_cast<double>(W.size(0)), c_out = static_cast<double>(W.size(1));
  std::map<std::string, std::vector<std::size_t>> by_source;
  for (std::size_t k = 0; k < K; ++k)
    if (products[k] && !chains[k].empty()) by_source[s.terms[k].source.str()].push_back(k);
  std::vector<std::vector<std::size_t>> weighted_first;
  std::vector<bool> first(K, false);
  for (const auto& [key, taps] : by_source) {
    const auto& src = s.terms[taps[0]].source;
    const double n_s = static_cast<double>(h.at(src.rank, src.state).size(0)),
                 n_t = static_cast<double>(target_rows), m = static_cast<double>(taps.size());
    double last = m * n_t * c_in * c_out, early = m * n_s * c_in * c_out;
    std::set<std::string> seen;
    for (auto k : taps)
      for (std::size_t j = 0; j < chains[k].size(); ++j) {
        const double nnz = 4.0 * static_cast<double>(chains[k][j].A->nnz());
        early += nnz * c_out;
        if (seen.insert(prefix(k, j + 1)).second) last += nnz * c_in;
      }
    if (early < 0.8 * last) {
      weighted_first.push_back(taps);
      for (auto k : taps) first[k] = true;
    }
  }
  // The other taps, each distinct prefix once.
  std::vector<torch::Tensor> terms;
  std::vector<std::int64_t> slices;
  for (std::size_t k = 0; k < K; ++k) {
    if (first[k]) continue;
    const auto& term = s.terms[k];
    torch::Tensor x = h.at(term.source.rank, term.source.state);
    if (products[k]) {
      std::size_t j = chains[k].size();
      for (; j > 0; --j)
        if (auto it = cache.find(prefix(k, j)); it != cache.end()) {
          x = it->second;
          break;
        }
      for (; j < chains[k].size(); ++j) {
        const auto& link = chains[k][j];
        x = detail::multiply(where, name_of(*link.op), *link.A, x, link.op->row_norm);
        cache.emplace(prefix(k, j + 1), x);
      }
    } else {
      const auto& list = term.operations();
      for (std::size_t i = 0; i < list.size(); ++i)
        i = apply_fused(where, s.target, list, i, x, ops, h);
    }
    terms.push_back(std::move(x));
    slices.push_back(static_cast<std::int64_t>(k));
  }
  torch::Tensor y;
  if (!terms.empty())
    y = combine_terms(
        terms, terms.size() == K ? W : W.index_select(2, torch::tensor(slices).to(W.device())));
  // The weighted-first taps: x_s [Θ_a | Θ_b | ...] in one product (taps with the same chain
  // summed into one block), then each chain's products on its columns, a shared prefix on the
  // columns of every tap below it.
  const auto cols = W.size(1);
  std::function<torch::Tensor(const torch::Tensor&, const std::vector<std::size_t>&, std::size_t)>
      push = [&](const torch::Tensor& z, const std::vector<std::size_t>& at, std::size_t depth) {
        torch::Tensor out;
        const auto add = [&](const torch::Tensor& t) { out = out.defined() ? out + t : t; };
        // Each tap's columns, taken apart once (one autograd node) when some go their own way.
        std::vector<torch::Tensor> pieces;
        const auto piece = [&](std::size_t p) -> const torch::Tensor& {
          if (pieces.empty())
            pieces = at.size() == 1 ? std::vector<torch::Tensor>{z} : z.split(cols, 1);
          return pieces[p];
        };
        std::vector<std::pair<std::string, std::vector<std::size_t>>> next;  // by next product
        for (std::size_t p = 0; p < at.size(); ++p) {
          const auto& chain = chains[at[p]];
          if (chain.size() == depth) {
            add(piece(p));
            continue;
          }
          const auto& o = *chain[depth].op;
          const auto key = name_of(o) + (o.row_norm ? "~" : "");
          auto it =
              std::find_if(next.begin(), next.end(), [&](const auto& n) { return n.first == key; });
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
          const auto& link = chains[below[0]][depth];
          add(push(detail::multiply(where, name_of(*link.op), *link.A, zp, link.op->row_norm),
                   below, depth + 1));
        }
        return out;
      };
  for (const auto& taps : weighted_first) {
    std::vector<std::size_t> items;  // one tap per distinct chain
    std::vector<torch::Tensor> blocks;
    for (auto k : taps) {
      const auto key = prefix(k, chains[k].size());
      std::size_t i = 0;
      while (i < items.size() && prefix(items[i], chains[items[i]].size()) != key) ++i;
      const auto w = W.select(2, static_cast<std::int64_t>(k));
      if (i == items.size()) {
        items.push_back(k);
        blocks.push_back(w);
      } else {
        blocks[i] = blocks[i] + w;
      }
    }
    const auto& src = s.terms[taps[0]].source;
    const auto part =
        push(linear_act(h.at(src.rank, src.state), torch::cat(blocks, 1).t(), {}), items, 0);
    y = y.defined() ? y + part : part;
  }
  return y;
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
    const OperatorStep& s, const std::vector<std::string>& readers, const Cochains& h,
    Operators& ops, PrefixCache& cache) {
  const auto& src = s.terms[0].source;
  if (!fast_ || ops.batch == nullptr || h.rows(src).defined()) return {};
  const auto& x = h.at(src.rank, src.state);
  std::vector<torch::Tensor> sources;
  for (const auto& name : readers) {
    const auto* n = ops.neighborhood(name);
    if (n == nullptr || n->num_source != x.size(0)) return {};  // the readers will say why
    sources.push_back(n->source);
  }
  const auto used = std::get<0>(torch::_unique(torch::cat(sources), /*sorted=*/true));
  if (used.size(0) >= x.size(0)) return {};
  Cochains rows = h;
  rows.set(src.rank, src.state, x.index_select(0, used));
  return {run_step(s, rows, ops, cache), detail::compact_rows(used, x.size(0))};
}

}  // namespace topos::nn
