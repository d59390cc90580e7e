// topos/core/combinatorial_complex-inl.hpp
// The definitions of CombinatorialComplex's members (combinatorial_complex.hpp) that build and
// query it: adding nodes and cells (with the rank condition checked), rolling back, reading cells,
// and the set -> cell look-up table and node -> cells index behind them. Its operators are in
// combinatorial_complex_operators-inl.hpp.
#pragma once

#include "topos/core/combinatorial_complex.hpp"

#include <algorithm>
#include <cstdint>
#include <optional>
#include <sstream>
#include <string>
#include <unordered_map>
#include <utility>
#include <vector>

namespace topos {

// ----- building ---------------------------------------------------------------------------

template <class Options>
inline auto CombinatorialComplex<Options>::add_nodes(Index n) -> Index {
  if (n < 0) throw ComplexError("add_nodes: negative count " + std::to_string(n));
  ensure_rank(0);
  const Index first = num_nodes();
  Rank& r0 = ranks_[0];
  r0.nodes.resize(static_cast<std::size_t>(first + n));
  r0.oriented_nodes.resize(r0.nodes.size());
  r0.offsets.resize(r0.nodes.size() + 1);
  r0.declared_offsets.resize(r0.nodes.size() + 1, 0);
  for (Index v = first; v < first + n; ++v) {
    r0.nodes[static_cast<std::size_t>(v)] = r0.oriented_nodes[static_cast<std::size_t>(v)] = v;
    r0.offsets[static_cast<std::size_t>(v) + 1] = v + 1;
  }
  // Many nodes at once: the set -> cell table is rebuilt when next needed instead.
  if (n > 64) lookup_dirty_ = true;
  for (Index v = first; v < first + n && !lookup_dirty_; ++v)
    lookup_.insert(hash_nodes(&v, 1), {0, v});
  index_dirty_ = true;
  min_index_.clear();  // sized by the node count
  return first;
}

template <class Options>
inline auto CombinatorialComplex<Options>::add_cell(const std::vector<Index>& nodes, int rank,
                                                    const std::vector<Declared>& declared)
    -> std::pair<Index, bool> {
  if (rank < 1) {
    throw ComplexError("add_cell: rank " + std::to_string(rank) +
                       " is not allowed (nodes are rank 0 and come from add_nodes)");
  }
  if (nodes.empty()) throw ComplexError("add_cell: empty cell at rank " + std::to_string(rank));
  std::vector<Index> sorted(nodes);
  std::sort(sorted.begin(), sorted.end());
  for (Index v : sorted) {
    if (v < 0 || v >= num_nodes()) {
      throw ComplexError("add_cell: node " + std::to_string(v) + " of cell " + describe(nodes) +
                         " at rank " + std::to_string(rank) + " is out of range [0, " +
                         std::to_string(num_nodes()) + ")");
    }
  }
  if (std::adjacent_find(sorted.begin(), sorted.end()) != sorted.end()) {
    throw ComplexError("add_cell: cell " + describe(nodes) + " at rank " + std::to_string(rank) +
                       " repeats a node");
  }
  const std::uint64_t h = hash_nodes(sorted.data(), sorted.size());
  if (auto found = find_sorted(sorted, h)) {
    if (found->rank == rank) return {found->id, false};
    throw ComplexError("add_cell: cell " + describe(nodes) + " already exists at rank " +
                       std::to_string(found->rank) + ", cannot add it at rank " +
                       std::to_string(rank));
  }
  if constexpr (Options::check_rank_condition) check_rank_condition(sorted, rank, nodes);
  ensure_rank(rank);
  for (const Declared& d : declared) {
    if (d.rank < 0 || d.rank >= rank || d.id < 0 || d.id >= size(d.rank)) {
      throw ComplexError("add_cell: cell " + describe(nodes) + " at rank " + std::to_string(rank) +
                         " declares an incidence with cell " + std::to_string(d.id) + " of rank " +
                         std::to_string(d.rank) + ", which does not exist below it");
    }
    if (!is_subset(cell_nodes(d.rank, d.id), sorted)) {
      throw ComplexError("add_cell: cell " + describe(nodes) + " at rank " + std::to_string(rank) +
                         " declares an incidence with cell " + std::to_string(d.id) + " of rank " +
                         std::to_string(d.rank) + ", which is not a subset of it");
    }
  }
  Rank& R = ranks_[static_cast<std::size_t>(rank)];
  const Index id = static_cast<Index>(R.offsets.size()) - 1;
  R.nodes.insert(R.nodes.end(), sorted.begin(), sorted.end());
  R.offsets.push_back(static_cast<Index>(R.nodes.size()));
  R.oriented_nodes.insert(R.oriented_nodes.end(), nodes.begin(), nodes.end());
  R.declared.insert(R.declared.end(), declared.begin(), declared.end());
  R.declared_offsets.push_back(static_cast<Index>(R.declared.size()));
  for (Index v : sorted) tail_index_[v].push_back({rank, id});
  ++tail_entries_;
  lookup_.insert(h, {rank, id});  // find_sorted above made the table current
  invalidate_min_index(rank);
  return {id, true};
}

template <class Options>
inline auto CombinatorialComplex<Options>::add_cell_trusted(const Index* oriented, std::size_t n,
                                                            int rank) -> Index {
  ensure_rank(rank);
  Rank& R = ranks_[static_cast<std::size_t>(rank)];
  const Index id = static_cast<Index>(R.offsets.size()) - 1;
  const std::size_t begin = R.nodes.size();
  R.nodes.insert(R.nodes.end(), oriented, oriented + n);
  std::sort(R.nodes.begin() + static_cast<std::ptrdiff_t>(begin), R.nodes.end());
  R.offsets.push_back(static_cast<Index>(R.nodes.size()));
  R.oriented_nodes.insert(R.oriented_nodes.end(), oriented, oriented + n);
  R.declared_offsets.push_back(static_cast<Index>(R.declared.size()));
  index_dirty_ = true;
  lookup_dirty_ = true;  // the set -> cell table is rebuilt on the next look-up
  invalidate_min_index(rank);
  return id;
}

template <class Options>
inline auto CombinatorialComplex<Options>::add_cells_trusted(const Index* oriented,
                                                             std::size_t count, std::size_t arity,
                                                             int rank) -> Index {
  ensure_rank(rank);
  Rank& R = ranks_[static_cast<std::size_t>(rank)];
  const Index first = static_cast<Index>(R.offsets.size()) - 1;
  const std::size_t begin = R.nodes.size();
  R.nodes.insert(R.nodes.end(), oriented, oriented + count * arity);
  R.oriented_nodes.insert(R.oriented_nodes.end(), oriented, oriented + count * arity);
  R.offsets.reserve(R.offsets.size() + count);
  R.declared_offsets.resize(R.declared_offsets.size() + count,
                            static_cast<Index>(R.declared.size()));
  for (std::size_t c = 0; c < count; ++c) {
    Index* b = R.nodes.data() + begin + c * arity;
    if (arity == 2) {
      if (b[1] < b[0]) std::swap(b[0], b[1]);
    } else {
      std::sort(b, b + arity);
    }
    R.offsets.push_back(static_cast<Index>(begin + (c + 1) * arity));
  }
  index_dirty_ = true;
  lookup_dirty_ = true;
  invalidate_min_index(rank);
  return first;
}

template <class Options>
inline void CombinatorialComplex<Options>::reserve(int rank, std::size_t cells, std::size_t nodes) {
  ensure_rank(rank);
  Rank& R = ranks_[static_cast<std::size_t>(rank)];
  R.nodes.reserve(nodes);
  R.oriented_nodes.reserve(nodes);
  R.offsets.reserve(cells + 1);
  R.declared_offsets.reserve(cells + 1);
}

template <class Options>
inline void CombinatorialComplex<Options>::rollback(const Mark& m) {
  if (!m.counts.empty() &&
      static_cast<std::size_t>(m.counts[0]) != static_cast<std::size_t>(num_nodes())) {
    throw ComplexError("rollback: nodes were added after the mark; nodes cannot be removed");
  }
  for (std::size_t r = ranks_.size(); r-- > 1;) {
    const Index keep = r < m.counts.size() ? m.counts[r] : 0;
    Rank& R = ranks_[r];
    for (Index id = static_cast<Index>(R.offsets.size()) - 2; id >= keep; --id) {
      const Index* b = R.nodes.data() + R.offsets[static_cast<std::size_t>(id)];
      const Index* e = R.nodes.data() + R.offsets[static_cast<std::size_t>(id) + 1];
      const Cell cell{static_cast<int>(r), id};
      if (id < indexed_count(static_cast<int>(r))) {
        index_dirty_ = true;  // a CSR-indexed cell goes: rebuild the index on next use
      } else {
        for (const Index* p = b; p != e; ++p) {
          auto it = tail_index_.find(*p);
          if (it == tail_index_.end()) continue;
          auto& list = it->second;
          list.erase(std::remove(list.begin(), list.end(), cell), list.end());
          if (list.empty()) tail_index_.erase(it);
        }
        --tail_entries_;
      }
      if (!lookup_dirty_) lookup_.erase(hash_nodes(b, static_cast<std::size_t>(e - b)), cell);
    }
    if (keep + 1 < static_cast<Index>(R.offsets.size())) {
      invalidate_min_index(static_cast<int>(r));
      R.nodes.resize(static_cast<std::size_t>(R.offsets[static_cast<std::size_t>(keep)]));
      R.oriented_nodes.resize(R.nodes.size());
      R.offsets.resize(static_cast<std::size_t>(keep) + 1);
      R.declared.resize(
          static_cast<std::size_t>(R.declared_offsets[static_cast<std::size_t>(keep)]));
      R.declared_offsets.resize(static_cast<std::size_t>(keep) + 1);
    }
  }
}

// ----- queries ----------------------------------------------------------------------------

template <class Options>
inline auto CombinatorialComplex<Options>::cell_nodes(int r, Index id) const -> std::vector<Index> {
  check_cell(r, id, "cell_nodes");
  const Rank& R = ranks_[static_cast<std::size_t>(r)];
  return {R.nodes.begin() + R.offsets[static_cast<std::size_t>(id)],
          R.nodes.begin() + R.offsets[static_cast<std::size_t>(id) + 1]};
}

template <class Options>
inline auto CombinatorialComplex<Options>::oriented_nodes(int r, Index id) const
    -> std::vector<Index> {
  check_cell(r, id, "oriented_nodes");
  const Rank& R = ranks_[static_cast<std::size_t>(r)];
  return {R.oriented_nodes.begin() + R.offsets[static_cast<std::size_t>(id)],
          R.oriented_nodes.begin() + R.offsets[static_cast<std::size_t>(id) + 1]};
}

template <class Options>
inline auto CombinatorialComplex<Options>::skeleton(int r) const
    -> std::vector<std::vector<Index>> {
  require_rank(r, "skeleton");
  std::vector<std::vector<Index>> cells;
  cells.reserve(static_cast<std::size_t>(size(r)));
  for (Index i = 0; i < size(r); ++i) cells.push_back(cell_nodes(r, i));
  return cells;
}

template <class Options>
inline auto CombinatorialComplex<Options>::declared_incidences(int r, Index id) const
    -> std::vector<Declared> {
  check_cell(r, id, "declared_incidences");
  const Rank& R = ranks_[static_cast<std::size_t>(r)];
  return {R.declared.begin() + R.declared_offsets[static_cast<std::size_t>(id)],
          R.declared.begin() + R.declared_offsets[static_cast<std::size_t>(id) + 1]};
}

// ----- the look-up table, the node index and the checks ---------------------------------

template <class Options>
inline void CombinatorialComplex<Options>::ensure_lookup() const {
  if (!lookup_dirty_) return;
  lookup_ = CellTable{};
  std::size_t total = 0;
  for (const Rank& R : ranks_) total += R.offsets.size() - 1;
  lookup_.reserve(total);
  for (std::size_t r = 0; r < ranks_.size(); ++r) {
    const Rank& R = ranks_[r];
    for (std::size_t id = 0; id + 1 < R.offsets.size(); ++id) {
      const Index* b = R.nodes.data() + R.offsets[id];
      lookup_.insert(hash_nodes(b, static_cast<std::size_t>(R.offsets[id + 1] - R.offsets[id])),
                     Cell{static_cast<int>(r), static_cast<Index>(id)});
    }
  }
  lookup_dirty_ = false;
}

template <class Options>
inline auto CombinatorialComplex<Options>::min_index(int r) const -> const MinIndex& {
  if (min_index_.size() < ranks_.size()) min_index_.resize(ranks_.size());
  MinIndex& M = min_index_[static_cast<std::size_t>(r)];
  if (M.valid) return M;
  const Rank& R = ranks_[static_cast<std::size_t>(r)];
  const std::size_t n = static_cast<std::size_t>(num_nodes()), count = R.offsets.size() - 1;
  M.offsets.assign(n + 1, 0);
  for (std::size_t id = 0; id < count; ++id)
    ++M.offsets[static_cast<std::size_t>(R.nodes[static_cast<std::size_t>(R.offsets[id])]) + 1];
  for (std::size_t v = 0; v < n; ++v) M.offsets[v + 1] += M.offsets[v];
  M.ids.resize(count);
  std::vector<Index> fill(M.offsets.begin(), M.offsets.end() - 1);
  for (std::size_t id = 0; id < count; ++id)
    M.ids[static_cast<std::size_t>(
        fill[static_cast<std::size_t>(R.nodes[static_cast<std::size_t>(R.offsets[id])])]++)] =
        static_cast<Index>(id);
  M.valid = true;
  return M;
}

template <class Options>
inline void CombinatorialComplex<Options>::ensure_index() const {
  if (!index_dirty_ && 4 * tail_entries_ <= static_cast<Index>(index_cells_.size()) + 4096) return;
  auto* self = const_cast<CombinatorialComplex*>(this);
  self->tail_index_.clear();
  self->tail_entries_ = 0;
  const std::size_t n = static_cast<std::size_t>(num_nodes());
  index_offsets_.assign(n + 1, 0);
  for (const Rank& R : ranks_)
    for (Index v : R.nodes) ++index_offsets_[static_cast<std::size_t>(v) + 1];
  for (std::size_t i = 0; i < n; ++i) index_offsets_[i + 1] += index_offsets_[i];
  index_cells_.resize(static_cast<std::size_t>(index_offsets_[n]));
  std::vector<Index> fill(index_offsets_.begin(), index_offsets_.end() - 1);
  indexed_counts_.clear();
  for (std::size_t r = 0; r < ranks_.size(); ++r) {
    const Rank& R = ranks_[r];
    const Index count = static_cast<Index>(R.offsets.size()) - 1;
    for (Index id = 0; id < count; ++id)
      for (Index k = R.offsets[static_cast<std::size_t>(id)];
           k < R.offsets[static_cast<std::size_t>(id) + 1]; ++k)
        index_cells_[static_cast<std::size_t>(
            fill[static_cast<std::size_t>(R.nodes[static_cast<std::size_t>(k)])]++)] =
            Cell{static_cast<int>(r), id};
    indexed_counts_.push_back(count);
  }
  index_dirty_ = false;
}

template <class Options>
template <class F>
inline void CombinatorialComplex<Options>::for_each_cell_of_node(Index v, F&& f) const {
  for (Index k = index_offsets_[static_cast<std::size_t>(v)];
       k < index_offsets_[static_cast<std::size_t>(v) + 1]; ++k)
    f(index_cells_[static_cast<std::size_t>(k)]);
  if (tail_entries_ == 0) return;
  auto it = tail_index_.find(v);
  if (it != tail_index_.end())
    for (const Cell& c : it->second) f(c);
}

template <class Options>
inline std::uint64_t CombinatorialComplex<Options>::hash_nodes(const Index* p, std::size_t n) {
  std::uint64_t h = 1469598103934665603ULL ^ n;
  for (std::size_t i = 0; i < n; ++i) {
    std::uint64_t x = static_cast<std::uint64_t>(p[i]) + 0x9e3779b97f4a7c15ULL;
    x = (x ^ (x >> 30)) * 0xbf58476d1ce4e5b9ULL;
    x = (x ^ (x >> 27)) * 0x94d049bb133111ebULL;
    h = (h ^ (x ^ (x >> 31))) * 1099511628211ULL;
  }
  return h;
}

template <class Options>
inline auto CombinatorialComplex<Options>::find_sorted(const std::vector<Index>& sorted,
                                                       std::uint64_t h) const
    -> std::optional<Cell> {
  ensure_lookup();
  return lookup_.find(h, [&](const Cell& c) {
    const Rank& R = ranks_[static_cast<std::size_t>(c.rank)];
    const auto b = R.offsets[static_cast<std::size_t>(c.id)],
               e = R.offsets[static_cast<std::size_t>(c.id) + 1];
    return static_cast<std::size_t>(e - b) == sorted.size() &&
           std::equal(sorted.begin(), sorted.end(), R.nodes.begin() + b);
  });
}

template <class Options>
inline bool CombinatorialComplex<Options>::includes(const Index* b, const Index* e, const Index* lb,
                                                    const Index* le) {
  const auto n = e - b, k = le - lb;
  if (k > n) return false;
  if (n > 16 * k) {
    for (const Index* p = lb; p != le; ++p)
      if (!std::binary_search(b, e, *p)) return false;
    return true;
  }
  return std::includes(b, e, lb, le);
}

template <class Options>
inline void CombinatorialComplex<Options>::check_rank_condition(
    const std::vector<Index>& sorted, int rank, const std::vector<Index>& given) const {
  const Index* b = sorted.data();
  const Index* e = b + sorted.size();
  // Supersets contain sorted[0]; subsets have their smallest node in the cell.
  ensure_index();
  for_each_cell_of_node(sorted.front(), [&](const Cell& c) {
    const Rank& R = ranks_[static_cast<std::size_t>(c.rank)];
    const Index* cb = R.nodes.data() + R.offsets[static_cast<std::size_t>(c.id)];
    const Index* ce = R.nodes.data() + R.offsets[static_cast<std::size_t>(c.id) + 1];
    if ((c.rank < rank) && (ce - cb) > (e - b) && includes(cb, ce, b, e)) {
      throw ComplexError("add_cell: cell " + describe(given) + " at rank " + std::to_string(rank) +
                         " is a subset of cell " + std::to_string(c.id) + " of lower rank " +
                         std::to_string(c.rank) + " (rank condition)");
    }
  });
  for (const Index* p = b; p != e; ++p) {
    for_each_cell_of_node(*p, [&](const Cell& c) {
      if (c.rank <= rank) return;
      const Rank& R = ranks_[static_cast<std::size_t>(c.rank)];
      const Index* cb = R.nodes.data() + R.offsets[static_cast<std::size_t>(c.id)];
      const Index* ce = R.nodes.data() + R.offsets[static_cast<std::size_t>(c.id) + 1];
      if (*cb != *p || (ce - cb) >= (e - b)) return;
      if (includes(b, e, cb, ce)) {
        throw ComplexError("add_cell: cell " + describe(given) + " at rank " +
                           std::to_string(rank) + " contains cell " + std::to_string(c.id) +
                           " of higher rank " + std::to_string(c.rank) + " (rank condition)");
      }
    });
  }
}

template <class Options>
inline void CombinatorialComplex<Options>::require_rank(int r, const char* what) const {
  if (r < 0 || r > max_rank()) {
    throw ComplexError(std::string(what) + ": rank " + std::to_string(r) +
                       " holds no cells (the complex has ranks 0.." + std::to_string(max_rank()) +
                       ")");
  }
}

template <class Options>
inline void CombinatorialComplex<Options>::check_cell(int r, Index id, const char* what) const {
  require_rank(r, what);
  if (id < 0 || id >= size(r)) {
    throw ComplexError(std::string(what) + ": cell " + std::to_string(id) + " of rank " +
                       std::to_string(r) + " does not exist (rank has " + std::to_string(size(r)) +
                       " cells)");
  }
}

template <class Options>
inline std::string CombinatorialComplex<Options>::describe(const std::vector<Index>& nodes) {
  std::ostringstream s;
  s << '{';
  for (std::size_t i = 0; i < nodes.size() && i < 8; ++i) s << (i ? "," : "") << nodes[i];
  if (nodes.size() > 8) s << ",…(" << nodes.size() << " nodes)";
  s << '}';
  return s.str();
}

}  // namespace topos
