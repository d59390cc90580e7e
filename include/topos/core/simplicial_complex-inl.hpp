// topos/core/simplicial_complex-inl.hpp
// The definitions of SimplicialComplex's members (simplicial_complex.hpp) that build and query
// it: from simplices, a flat list, a given order or a trusted canonical form; faces, cofaces,
// star and link; and the canonical form behind them (every face staged, sorted and deduplicated
// by a counting sort on the first node, the face ids found once). Its operators are in
// simplicial_complex_operators-inl.hpp.
#pragma once

#include "topos/core/simplicial_complex.hpp"

#include <algorithm>
#include <cassert>
#include <cstdint>
#include <iterator>
#include <numeric>
#include <optional>
#include <sstream>
#include <string>
#include <utility>
#include <vector>

namespace topos {

// ----- building ---------------------------------------------------------------------------

inline SimplicialComplex SimplicialComplex::from_flat(const Index* nodes, std::size_t count,
                                                      int arity, Index num_nodes) {
  if (arity < 1)
    throw ComplexError("SimplicialComplex::from_flat: arity " + std::to_string(arity) +
                       " must be at least 1");
  SimplicialComplex sc;
  std::vector<std::vector<Index>> staged;
  Index max_node = -1;
  for (std::size_t c = 0; c < count; ++c)
    max_node = std::max(max_node, check_simplex(nodes + c * static_cast<std::size_t>(arity),
                                                static_cast<std::size_t>(arity), num_nodes));
  sc.set_nodes(num_nodes >= 0 ? num_nodes : max_node + 1);
  sc.stage_faces(nodes, count, static_cast<std::size_t>(arity), staged);
  sc.finish(staged);
  return sc;
}

inline SimplicialComplex SimplicialComplex::from_ordered(
    const std::vector<std::vector<std::vector<Index>>>& cells) {
  SimplicialComplex sc;
  if (cells.empty()) return sc;
  const Index n = static_cast<Index>(cells[0].size());
  for (Index v = 0; v < n; ++v) {
    const auto& c = cells[0][static_cast<std::size_t>(v)];
    if (c.size() != 1 || c[0] != v) {
      throw ComplexError("SimplicialComplex::from_ordered: rank-0 cell " + std::to_string(v) +
                         " must be [" + std::to_string(v) +
                         "] (nodes are listed in id order), got " + describe(c.data(), c.size()));
    }
  }
  sc.set_nodes(n);
  for (std::size_t k = 1; k < cells.size(); ++k) {
    Rank& R = sc.ranks_.emplace_back();
    R.count = static_cast<Index>(cells[k].size());
    R.nodes.reserve(cells[k].size() * (k + 1));
    for (const auto& s : cells[k]) {
      if (s.size() != k + 1) {
        throw ComplexError("SimplicialComplex::from_ordered: simplex " +
                           describe(s.data(), s.size()) + " is listed at rank " +
                           std::to_string(k) + " but has " + std::to_string(s.size()) + " nodes");
      }
      check_simplex(s.data(), s.size(), n);
      std::vector<Index> sorted(s);
      std::sort(sorted.begin(), sorted.end());
      R.nodes.insert(R.nodes.end(), sorted.begin(), sorted.end());
    }
    sc.build_lookup(static_cast<int>(k));
    // Duplicates and missing faces.
    for (Index id = 0; id < R.count; ++id) {
      const Index* s = sc.data(static_cast<int>(k), id);
      if (sc.find_sorted(static_cast<int>(k), s) != id) {
        throw ComplexError("SimplicialComplex::from_ordered: simplex " + describe(s, k + 1) +
                           " is listed twice at rank " + std::to_string(k));
      }
    }
    sc.build_faces(static_cast<int>(k));
    for (Index id = 0; id < R.count; ++id) {
      for (std::size_t i = 0; i <= k; ++i) {
        if (sc.ranks_[k].faces[static_cast<std::size_t>(id) * (k + 1) + i] >= 0) continue;
        const Index* s = sc.data(static_cast<int>(k), id);
        Index face[kMaxArity];
        std::size_t f = 0;
        for (std::size_t j = 0; j <= k; ++j)
          if (j != i) face[f++] = s[j];
        throw ComplexError("SimplicialComplex::from_ordered: face " + describe(face, k) +
                           " of simplex " + describe(s, k + 1) + " is not listed at rank " +
                           std::to_string(k - 1));
      }
    }
  }
  sc.ordered_ = true;
  return sc;
}

inline SimplicialComplex SimplicialComplex::from_canonical_trusted(
    Index num_nodes, std::vector<std::vector<Index>> flat) {
  SimplicialComplex sc(num_nodes);
  while (!flat.empty() && flat.back().empty()) flat.pop_back();
  for (std::size_t k = 1; k <= flat.size(); ++k) {
    Rank& R = sc.ranks_.emplace_back();
    R.nodes = std::move(flat[k - 1]);
    R.count = static_cast<Index>(R.nodes.size() / (k + 1));
    sc.build_lookup(static_cast<int>(k));
    assert(R.order.empty());
    sc.build_faces(static_cast<int>(k));
  }
  return sc;
}

inline void SimplicialComplex::add_simplices(const std::vector<std::vector<Index>>& simplices) {
  std::vector<std::vector<Index>> all = simplices;
  for (int k = 1; k <= dim(); ++k)
    for (Index id = 0; id < num_cells(k); ++id) all.push_back(simplex(k, id));
  const Index n = num_nodes();
  Index max_node = n - 1;
  for (const auto& s : simplices)
    max_node = std::max(max_node, check_simplex(s.data(), s.size(), -1));
  *this = SimplicialComplex();
  insert(all, max_node + 1);
}

// ----- queries ----------------------------------------------------------------------------

inline auto SimplicialComplex::skeleton(int rank) const -> std::vector<std::vector<Index>> {
  require_rank(rank, "skeleton");
  std::vector<std::vector<Index>> out;
  out.reserve(static_cast<std::size_t>(num_cells(rank)));
  for (Index i = 0; i < num_cells(rank); ++i) out.push_back(simplex(rank, i));
  return out;
}

inline auto SimplicialComplex::find(std::vector<Index> nodes) const -> std::optional<Index> {
  const int rank = static_cast<int>(nodes.size()) - 1;
  if (rank < 0 || rank > dim()) return std::nullopt;
  std::sort(nodes.begin(), nodes.end());
  const Index id = find_sorted(rank, nodes.data());
  return id >= 0 ? std::optional<Index>(id) : std::nullopt;
}

inline auto SimplicialComplex::faces(int rank, Index id, int face_rank) const
    -> std::vector<Index> {
  check_cell(rank, id, "faces");
  if (face_rank < 0 || face_rank >= rank)
    throw ComplexError("faces: face rank " + std::to_string(face_rank) + " must be in [0, " +
                       std::to_string(rank) + ")");
  std::vector<Index> out;
  for_each_subset(data(rank, id), rank + 1, face_rank + 1,
                  [&](const Index* f) { out.push_back(find_sorted(face_rank, f)); });
  std::sort(out.begin(), out.end());
  return out;
}

inline auto SimplicialComplex::cofaces(int rank, Index id, int coface_rank) const
    -> std::vector<Index> {
  check_cell(rank, id, "cofaces");
  std::vector<Index> out;
  if (coface_rank <= rank)
    throw ComplexError("cofaces: coface rank " + std::to_string(coface_rank) + " must be above " +
                       std::to_string(rank));
  if (coface_rank > dim()) return out;
  const Index* s = data(rank, id);
  for (Index j = 0; j < num_cells(coface_rank); ++j) {
    const Index* c = data(coface_rank, j);
    if (std::includes(c, c + coface_rank + 1, s, s + rank + 1)) out.push_back(j);
  }
  return out;
}

inline auto SimplicialComplex::star(int rank, Index id) const
    -> std::vector<std::pair<int, Index>> {
  std::vector<std::pair<int, Index>> out{{rank, id}};
  for (int r = rank + 1; r <= dim(); ++r)
    for (Index j : cofaces(rank, id, r)) out.push_back({r, j});
  return out;
}

inline auto SimplicialComplex::link(int rank, Index id) const
    -> std::vector<std::pair<int, Index>> {
  std::vector<std::pair<int, Index>> out;
  const Index* s = data(rank, id);
  for (auto [r, j] : star(rank, id)) {
    if (r == rank) continue;
    std::vector<Index> rest;
    const Index* c = data(r, j);
    std::set_difference(c, c + r + 1, s, s + rank + 1, std::back_inserter(rest));
    out.push_back({static_cast<int>(rest.size()) - 1,
                   find_sorted(static_cast<int>(rest.size()) - 1, rest.data())});
  }
  std::sort(out.begin(), out.end());
  out.erase(std::unique(out.begin(), out.end()), out.end());
  return out;
}

// ----- building the canonical form: checks, faces, sorting, the look-up ---------------

inline void SimplicialComplex::set_nodes(Index n) {
  if (n < 0) throw ComplexError("SimplicialComplex: negative node count " + std::to_string(n));
  ranks_.assign(1, Rank{});
  ranks_[0].count = n;
  ranks_[0].nodes.resize(static_cast<std::size_t>(n));
  std::iota(ranks_[0].nodes.begin(), ranks_[0].nodes.end(), Index(0));
  ranks_[0].first.resize(static_cast<std::size_t>(n) + 1);
  std::iota(ranks_[0].first.begin(), ranks_[0].first.end(), Index(0));
}

inline std::string SimplicialComplex::describe(const Index* p, std::size_t n) {
  std::ostringstream s;
  s << '[';
  for (std::size_t i = 0; i < n && i < 10; ++i) s << (i ? ", " : "") << p[i];
  if (n > 10) s << ", ... (" << n << " nodes)";
  s << ']';
  return s.str();
}

inline auto SimplicialComplex::check_simplex(const Index* p, std::size_t n, Index num_nodes)
    -> Index {
  if (n == 0) throw ComplexError("SimplicialComplex: empty simplex");
  if (n > kMaxArity)
    throw ComplexError("SimplicialComplex: simplex " + describe(p, n) + " has " +
                       std::to_string(n) + " nodes; at most " + std::to_string(kMaxArity) +
                       " are supported");
  Index sorted[kMaxArity];
  std::copy(p, p + n, sorted);
  std::sort(sorted, sorted + n);
  if (sorted[0] < 0)
    throw ComplexError("SimplicialComplex: simplex " + describe(p, n) + " has a negative node id");
  if (num_nodes >= 0 && sorted[n - 1] >= num_nodes)
    throw ComplexError("SimplicialComplex: simplex " + describe(p, n) + " uses node " +
                       std::to_string(sorted[n - 1]) + ", outside [0, " +
                       std::to_string(num_nodes) + ")");
  for (std::size_t i = 1; i < n; ++i)
    if (sorted[i] == sorted[i - 1])
      throw ComplexError("SimplicialComplex: simplex " + describe(p, n) + " repeats node " +
                         std::to_string(sorted[i]));
  return sorted[n - 1];
}

inline void SimplicialComplex::insert(const std::vector<std::vector<Index>>& simplices,
                                      Index num_nodes) {
  Index max_node = -1;
  for (const auto& s : simplices)
    max_node = std::max(max_node, check_simplex(s.data(), s.size(), num_nodes));
  set_nodes(num_nodes >= 0 ? num_nodes : max_node + 1);
  std::vector<std::vector<Index>> staged;
  for (const auto& s : simplices) stage_faces(s.data(), 1, s.size(), staged);
  finish(staged);
}

inline void SimplicialComplex::stage_faces(const Index* p, std::size_t count, std::size_t arity,
                                           std::vector<std::vector<Index>>& staged) {
  if (staged.size() < arity) staged.resize(arity);
  Index sorted[kMaxArity];
  for (std::size_t c = 0; c < count; ++c) {
    std::copy(p + c * arity, p + (c + 1) * arity, sorted);
    std::sort(sorted, sorted + arity);
    for (std::size_t k = 2; k <= arity; ++k) {
      auto& out = staged[k - 1];
      for_each_subset(sorted, static_cast<int>(arity), static_cast<int>(k),
                      [&](const Index* f) { out.insert(out.end(), f, f + k); });
    }
  }
}

inline void SimplicialComplex::finish(std::vector<std::vector<Index>>& staged) {
  int top = static_cast<int>(staged.size()) - 1;
  while (top >= 1 && staged[static_cast<std::size_t>(top)].empty()) --top;
  ranks_.resize(1);
  for (int k = 1; k <= top; ++k) {
    Rank& R = ranks_.emplace_back();
    R.nodes = sort_unique(staged[static_cast<std::size_t>(k)], static_cast<std::size_t>(k) + 1,
                          num_nodes());
    R.count = static_cast<Index>(R.nodes.size() / static_cast<std::size_t>(k + 1));
    build_lookup(k);
    build_faces(k);
  }
}

inline auto SimplicialComplex::sort_unique(const std::vector<Index>& flat, std::size_t w, Index n)
    -> std::vector<Index> {
  const std::size_t count = flat.size() / w;
  std::vector<Index> start(static_cast<std::size_t>(n) + 1, 0), idx(count);
  for (std::size_t c = 0; c < count; ++c) ++start[static_cast<std::size_t>(flat[c * w]) + 1];
  for (std::size_t v = 0; v < static_cast<std::size_t>(n); ++v) start[v + 1] += start[v];
  {
    std::vector<Index> fill(start.begin(), start.end() - 1);
    for (std::size_t c = 0; c < count; ++c)
      idx[static_cast<std::size_t>(fill[static_cast<std::size_t>(flat[c * w])]++)] =
          static_cast<Index>(c);
  }
  const auto less = [&](Index a, Index b) {
    const Index* x = flat.data() + static_cast<std::size_t>(a) * w;
    const Index* y = flat.data() + static_cast<std::size_t>(b) * w;
    return std::lexicographical_compare(x + 1, x + w, y + 1, y + w);
  };
  const auto equal = [&](Index a, Index b) {
    return std::equal(flat.data() + static_cast<std::size_t>(a) * w + 1,
                      flat.data() + (static_cast<std::size_t>(a) + 1) * w,
                      flat.data() + static_cast<std::size_t>(b) * w + 1);
  };
  std::vector<Index> out;
  out.reserve(flat.size());
  for (std::size_t v = 0; v < static_cast<std::size_t>(n); ++v) {
    auto b = idx.begin() + start[v], e = idx.begin() + start[v + 1];
    if (w == 2) {
      std::sort(b, e, [&](Index x, Index y) {
        return flat[static_cast<std::size_t>(x) * 2 + 1] <
               flat[static_cast<std::size_t>(y) * 2 + 1];
      });
    } else {
      std::sort(b, e, less);
    }
    for (auto it = b; it != e; ++it) {
      if (it != b && equal(*it, *(it - 1))) continue;
      out.insert(
          out.end(), flat.begin() + static_cast<std::ptrdiff_t>(static_cast<std::size_t>(*it) * w),
          flat.begin() + static_cast<std::ptrdiff_t>((static_cast<std::size_t>(*it) + 1) * w));
    }
  }
  return out;
}

inline void SimplicialComplex::build_lookup(int k) {
  Rank& R = ranks_[static_cast<std::size_t>(k)];
  const std::size_t w = static_cast<std::size_t>(k) + 1;
  R.order.clear();
  bool sorted = true;
  for (Index i = 1; i < R.count && sorted; ++i)
    sorted = !std::lexicographical_compare(R.nodes.data() + static_cast<std::size_t>(i) * w,
                                           R.nodes.data() + static_cast<std::size_t>(i + 1) * w,
                                           R.nodes.data() + static_cast<std::size_t>(i - 1) * w,
                                           R.nodes.data() + static_cast<std::size_t>(i) * w);
  if (!sorted) {
    R.order.resize(static_cast<std::size_t>(R.count));
    std::iota(R.order.begin(), R.order.end(), Index(0));
    std::stable_sort(R.order.begin(), R.order.end(), [&](Index a, Index b) {
      return std::lexicographical_compare(R.nodes.data() + static_cast<std::size_t>(a) * w,
                                          R.nodes.data() + static_cast<std::size_t>(a + 1) * w,
                                          R.nodes.data() + static_cast<std::size_t>(b) * w,
                                          R.nodes.data() + static_cast<std::size_t>(b + 1) * w);
    });
  }
  R.first.assign(static_cast<std::size_t>(num_nodes()) + 1, 0);
  for (Index i = 0; i < R.count; ++i)
    ++R.first[static_cast<std::size_t>(R.nodes[static_cast<std::size_t>(i) * w]) + 1];
  for (std::size_t v = 0; v + 1 < R.first.size(); ++v) R.first[v + 1] += R.first[v];
}

inline void SimplicialComplex::build_faces(int k) {
  Rank& R = ranks_[static_cast<std::size_t>(k)];
  const std::size_t w = static_cast<std::size_t>(k) + 1;
  R.faces.resize(static_cast<std::size_t>(R.count) * w);
  Index face[kMaxArity];
  for (Index j = 0; j < R.count; ++j) {
    const Index* s = R.nodes.data() + static_cast<std::size_t>(j) * w;
    for (std::size_t i = 0; i < w; ++i) {
      std::size_t f = 0;
      for (std::size_t q = 0; q < w; ++q)
        if (q != i) face[f++] = s[q];
      R.faces[static_cast<std::size_t>(j) * w + i] = find_sorted(k - 1, face);
    }
  }
}

inline auto SimplicialComplex::find_sorted(int k, const Index* s) const -> Index {
  if (k == 0) return s[0] >= 0 && s[0] < num_nodes() ? s[0] : -1;
  const Rank& R = ranks_[static_cast<std::size_t>(k)];
  const std::size_t w = static_cast<std::size_t>(k) + 1;
  if (s[0] < 0 || s[0] >= num_nodes()) return -1;
  Index lo = R.first[static_cast<std::size_t>(s[0])],
        hi = R.first[static_cast<std::size_t>(s[0]) + 1];
  const Index end = hi;
  const Index* nodes = R.nodes.data();
  const Index* order = R.order.empty() ? nullptr : R.order.data();
  // Hand-written comparisons: simplices are a few nodes long, and std::lexicographical_compare /
  // std::equal on them cost a memcmp call each (this search runs once per face at build time).
  const auto less_than_s = [&](const Index* c) {
    for (std::size_t q = 1; q < w; ++q)
      if (c[q] != s[q]) return c[q] < s[q];
    return false;
  };
  if (!order && hi - lo <= 16) {
    // Small bucket (the common case): count the smaller simplices, no unpredictable branch.
    Index below = 0;
    for (Index pos = lo; pos < hi; ++pos)
      below += less_than_s(nodes + static_cast<std::size_t>(pos) * w);
    lo += below;
  } else {
    while (lo < hi) {
      const Index mid = lo + (hi - lo) / 2;
      const Index* c = nodes + static_cast<std::size_t>(order ? order[mid] : mid) * w;
      if (less_than_s(c))
        lo = mid + 1;
      else
        hi = mid;
    }
  }
  if (lo < end) {
    const Index id = order ? order[lo] : lo;
    const Index* c = nodes + static_cast<std::size_t>(id) * w;
    for (std::size_t q = 0; q < w; ++q)
      if (c[q] != s[q]) return -1;
    return id;
  }
  return -1;
}

template <class F>
inline void SimplicialComplex::for_each_subset(const Index* p, int n, int k, F&& f) {
  if (k == n - 1) {  // the common case: drop one node
    Index face[kMaxArity];
    for (int i = 0; i < n; ++i) {
      int m = 0;
      for (int j = 0; j < n; ++j)
        if (j != i) face[m++] = p[j];
      f(static_cast<const Index*>(face));
    }
    return;
  }
  int pos[kMaxArity];
  Index sub[kMaxArity];
  for (int i = 0; i < k; ++i) pos[i] = i;
  while (true) {
    for (int i = 0; i < k; ++i) sub[i] = p[pos[i]];
    f(static_cast<const Index*>(sub));
    int i = k - 1;
    while (i >= 0 && pos[i] == n - k + i) --i;
    if (i < 0) return;
    ++pos[i];
    for (int j = i + 1; j < k; ++j) pos[j] = pos[j - 1] + 1;
  }
}

inline void SimplicialComplex::require_rank(int r, const char* what) const {
  if (r < 0 || r > dim())
    throw ComplexError(std::string(what) + ": rank " + std::to_string(r) + " is outside [0, " +
                       std::to_string(dim()) + "] (the complex has dimension " +
                       std::to_string(dim()) + ")");
}

inline void SimplicialComplex::check_cell(int r, Index id, const char* what) const {
  require_rank(r, what);
  if (id < 0 || id >= num_cells(r))
    throw ComplexError(std::string(what) + ": simplex " + std::to_string(id) + " of rank " +
                       std::to_string(r) + " does not exist (the rank has " +
                       std::to_string(num_cells(r)) + ")");
}

}  // namespace topos
