// topos/nn/operator_schedule/filter-inl.hpp
// A filter step's taps (StepRoute::filter): taps that are chains of sparse products run as such,
// each source's taps weighted first where that costs less, and the other taps the general way.
// Part of the interpreter (interpreter-inl.hpp); compiled into topos::nn, or inline with
// TOPOS_HEADER_ONLY (topos/config.hpp).
#pragma once

#include "topos/nn/operator_schedule/checks-inl.hpp"
#include "topos/nn/operator_schedule/plan-inl.hpp"  // and term-inl.hpp: prefix_key

#include <algorithm>
#include <map>
#include <string>
#include <vector>

namespace topos::nn {

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
  return combine_terms(terms,
                       terms.size() == f.chains.size() ? W : detail::selected_weight(W, 2, slices),
                       act, base);
}

}  // namespace topos::nn
