// topos/core/combinatorial_complex.hpp
// A rank-indexed combinatorial complex (CC): cells are sets of node ids, each with a rank, and
// the rank function is monotone under inclusion (a subset never has a higher rank). Ids are
// dense per rank in insertion order, so row i of every operator is the i-th cell of that rank.
// Operators (incidence, adjacency, coadjacency) are Eigen sparse matrices with 64-bit indices.
// Std + Eigen only.
#pragma once

#include "topos/core/sparse_matrix.hpp"

#include <Eigen/SparseCore>

#include <algorithm>
#include <cstdint>
#include <initializer_list>
#include <optional>
#include <sstream>
#include <stdexcept>
#include <string>
#include <unordered_map>
#include <utility>
#include <vector>

namespace topos {

/// Options of a CombinatorialComplex (GUDHI style): index and scalar types, and whether the
/// rank condition is checked on every insertion.
struct DefaultComplexOptions {
  using Index = std::int64_t;
  using Scalar = double;
  static constexpr bool check_rank_condition = true;
};

/// A value or a role that a higher cell declares for one of its lower cells (for example the
/// -1 / +1 sides of a HOPNet contact cell). Role 0 means "no role".
template <class Index, class Scalar>
struct DeclaredIncidence {
  int rank;      ///< rank of the lower cell
  Index id;      ///< id of the lower cell within its rank
  Scalar value;  ///< value of the incidence entry (replaces the default 1)
  int role = 0;  ///< optional role tag carried into Neighborhood::roles
};

template <class Options = DefaultComplexOptions>
class CombinatorialComplex {
 public:
  using Index = typename Options::Index;
  using Scalar = typename Options::Scalar;
  using SparseMatrix = Eigen::SparseMatrix<Scalar, Eigen::RowMajor, std::int64_t>;
  using Declared = DeclaredIncidence<Index, Scalar>;

  /// A cell handle: its rank and its dense id within that rank.
  struct Cell {
    int rank;
    Index id;
    friend bool operator==(const Cell& a, const Cell& b) {
      return a.rank == b.rank && a.id == b.id;
    }
  };

  /// Records the number of cells of each rank, so that later cells can be removed again
  /// (per-frame cells on top of a static part, without rebuilding the static part).
  struct Mark {
    std::vector<Index> counts;
  };

  CombinatorialComplex() = default;
  explicit CombinatorialComplex(Index num_nodes) { add_nodes(num_nodes); }

  // ----- building ---------------------------------------------------------------------------

  /// Adds `n` nodes (rank-0 cells {id}); returns the id of the first.
  Index add_nodes(Index n) {
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

  /// Adds a cell of rank `rank` >= 1 over `nodes`. The node order given is kept as the cell's
  /// orientation (used by signed_incidence_matrix); the set itself is what identifies the cell.
  /// Returns (id, inserted): inserting an existing set at the same rank returns its id and false.
  std::pair<Index, bool> add_cell(const std::vector<Index>& nodes, int rank,
                                  const std::vector<Declared>& declared = {}) {
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
        throw ComplexError("add_cell: cell " + describe(nodes) + " at rank " +
                           std::to_string(rank) + " declares an incidence with cell " +
                           std::to_string(d.id) + " of rank " + std::to_string(d.rank) +
                           ", which does not exist below it");
      }
      if (!is_subset(cell_nodes(d.rank, d.id), sorted)) {
        throw ComplexError("add_cell: cell " + describe(nodes) + " at rank " +
                           std::to_string(rank) + " declares an incidence with cell " +
                           std::to_string(d.id) + " of rank " + std::to_string(d.rank) +
                           ", which is not a subset of it");
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

  /// Appends a cell without any check. For bulk builders (mesh lifting) that guarantee
  /// themselves that the nodes are valid, distinct, new as a set, and respect the rank condition.
  Index add_cell_trusted(const Index* oriented, std::size_t n, int rank) {
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

  /// Appends `count` cells of `arity` nodes each (flat, oriented) without any check, as
  /// add_cell_trusted does one by one; returns the id of the first.
  Index add_cells_trusted(const Index* oriented, std::size_t count, std::size_t arity, int rank) {
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

  /// Reserves storage for `cells` cells of total `nodes` node entries at rank r.
  void reserve(int rank, std::size_t cells, std::size_t nodes) {
    ensure_rank(rank);
    Rank& R = ranks_[static_cast<std::size_t>(rank)];
    R.nodes.reserve(nodes);
    R.oriented_nodes.reserve(nodes);
    R.offsets.reserve(cells + 1);
    R.declared_offsets.reserve(cells + 1);
  }

  std::pair<Index, bool> add_cell(std::initializer_list<Index> nodes, int rank,
                                  const std::vector<Declared>& declared = {}) {
    return add_cell(std::vector<Index>(nodes), rank, declared);
  }

  /// The current cell counts, to be passed to rollback() later.
  Mark mark() const {
    Mark m;
    for (const Rank& r : ranks_) m.counts.push_back(static_cast<Index>(r.offsets.size()) - 1);
    return m;
  }

  /// Removes every cell added after `m` (cells of ranks >= 1 only; nodes cannot be removed).
  void rollback(const Mark& m) {
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

  Index num_nodes() const { return ranks_.empty() ? 0 : size(0); }
  /// Highest rank that was ever used (cells may be zero at lower ranks); -1 when empty.
  int max_rank() const { return static_cast<int>(ranks_.size()) - 1; }
  /// Number of cells of rank r (0 for ranks above max_rank()).
  Index size(int r) const {
    if (r < 0 || r > max_rank()) return 0;
    return static_cast<Index>(ranks_[static_cast<std::size_t>(r)].offsets.size()) - 1;
  }
  /// Number of cells of rank r (the domain concept's name for size()).
  Index num_cells(int r) const { return size(r); }
  /// Highest rank (the domain concept's name for max_rank()); -1 when empty.
  int dim() const { return max_rank(); }
  /// Cell counts of ranks 0..max_rank(), as TopoNetX's `shape`.
  std::vector<Index> shape() const {
    std::vector<Index> s;
    for (int r = 0; r <= max_rank(); ++r) s.push_back(size(r));
    return s;
  }

  /// Sorted node ids of cell `id` of rank `r`.
  std::vector<Index> cell_nodes(int r, Index id) const {
    check_cell(r, id, "cell_nodes");
    const Rank& R = ranks_[static_cast<std::size_t>(r)];
    return {R.nodes.begin() + R.offsets[static_cast<std::size_t>(id)],
            R.nodes.begin() + R.offsets[static_cast<std::size_t>(id) + 1]};
  }
  /// Node ids of a cell in the order given when it was added (its orientation).
  std::vector<Index> oriented_nodes(int r, Index id) const {
    check_cell(r, id, "oriented_nodes");
    const Rank& R = ranks_[static_cast<std::size_t>(r)];
    return {R.oriented_nodes.begin() + R.offsets[static_cast<std::size_t>(id)],
            R.oriented_nodes.begin() + R.offsets[static_cast<std::size_t>(id) + 1]};
  }
  /// All cells of rank r, in id order (TopoNetX's skeleton).
  std::vector<std::vector<Index>> skeleton(int r) const {
    require_rank(r, "skeleton");
    std::vector<std::vector<Index>> cells;
    cells.reserve(static_cast<std::size_t>(size(r)));
    for (Index i = 0; i < size(r); ++i) cells.push_back(cell_nodes(r, i));
    return cells;
  }
  /// Looks a cell up by its nodes (any order); returns its handle if it exists.
  std::optional<Cell> find(std::vector<Index> nodes) const {
    std::sort(nodes.begin(), nodes.end());
    return find_sorted(nodes, hash_nodes(nodes.data(), nodes.size()));
  }
  /// Values and roles that cells of rank r declared for their lower cells.
  std::vector<Declared> declared_incidences(int r, Index id) const {
    check_cell(r, id, "declared_incidences");
    const Rank& R = ranks_[static_cast<std::size_t>(r)];
    return {R.declared.begin() + R.declared_offsets[static_cast<std::size_t>(id)],
            R.declared.begin() + R.declared_offsets[static_cast<std::size_t>(id) + 1]};
  }

  // ----- operators ----------------------------------------------------------------------------

  /// Visits every inclusion (lower cell i of rank lo) ⊂ (upper cell j of rank hi), lo < hi, with
  /// the value of the incidence (1 or the value the upper cell declared) and its role.
  /// Visit order: upper cells in id order, then lower cells in ascending id.
  template <class F>
  void for_each_inclusion(int lo, int hi, F&& visit) const {
    require_rank(lo, "incidence");
    require_rank(hi, "incidence");
    if (lo >= hi)
      throw ComplexError("incidence: lower rank " + std::to_string(lo) + " must be below " +
                         std::to_string(hi));
    const Rank& U = ranks_[static_cast<std::size_t>(hi)];
    if (lo == 0 && U.declared.empty()) {
      // Every node of a cell, ascending (cells store their nodes sorted), value 1: no buffer.
      for (Index j = 0; j + 1 < static_cast<Index>(U.offsets.size()); ++j)
        for (Index k = U.offsets[static_cast<std::size_t>(j)];
             k < U.offsets[static_cast<std::size_t>(j) + 1]; ++k)
          visit(U.nodes[static_cast<std::size_t>(k)], j, Scalar(1), 0);
      return;
    }
    const MinIndex* M = lo > 0 ? &min_index(lo) : nullptr;
    const Rank& L = ranks_[static_cast<std::size_t>(lo)];
    std::vector<std::pair<Index, std::pair<Scalar, int>>> found;
    for (Index j = 0; j + 1 < static_cast<Index>(U.offsets.size()); ++j) {
      found.clear();
      const Index* b = U.nodes.data() + U.offsets[static_cast<std::size_t>(j)];
      const Index* e = U.nodes.data() + U.offsets[static_cast<std::size_t>(j) + 1];
      if (lo == 0) {
        for (const Index* p = b; p != e; ++p) found.push_back({*p, {Scalar(1), 0}});
      } else {
        // Each subset is found once: through its smallest node.
        for (const Index* p = b; p != e; ++p) {
          for (Index k = M->offsets[static_cast<std::size_t>(*p)];
               k < M->offsets[static_cast<std::size_t>(*p) + 1]; ++k) {
            const Index id = M->ids[static_cast<std::size_t>(k)];
            const Index* lb = L.nodes.data() + L.offsets[static_cast<std::size_t>(id)];
            const Index* le = L.nodes.data() + L.offsets[static_cast<std::size_t>(id) + 1];
            if (includes(b, e, lb, le)) found.push_back({id, {Scalar(1), 0}});
          }
        }
        if (found.size() > 1)
          std::sort(found.begin(), found.end(), [](auto& x, auto& y) { return x.first < y.first; });
      }
      for (Index k = U.declared_offsets[static_cast<std::size_t>(j)];
           k < U.declared_offsets[static_cast<std::size_t>(j) + 1]; ++k) {
        const Declared& d = U.declared[static_cast<std::size_t>(k)];
        if (d.rank != lo) continue;
        auto it = std::lower_bound(found.begin(), found.end(), d.id,
                                   [](auto& x, Index v) { return x.first < v; });
        if (it != found.end() && it->first == d.id) it->second = {d.value, d.role};
      }
      for (auto& f : found) visit(f.first, j, f.second.first, f.second.second);
    }
  }

  /// Incidence matrix by set inclusion, n_r × n_s. For r < s entry (i, j) is 1 when cell i of
  /// rank r is a subset of cell j of rank s (or the value cell j declared); for r > s it is the
  /// transpose of incidence_matrix(s, r).
  SparseMatrix incidence_matrix(int r, int s) const {
    if (r == s)
      throw ComplexError("incidence_matrix: ranks must differ (got " + std::to_string(r) +
                         " twice)");
    const int lo = std::min(r, s), hi = std::max(r, s);
    require_rank(lo, "incidence_matrix");  // before ranks_[hi] is read below
    require_rank(hi, "incidence_matrix");
    // The visit order (upper cells in order, lower ids ascending) is the CSR of the hi × lo
    // matrix: fill it directly; the lo × hi one is its transpose (Eigen's counting sort).
    // Filled in place (no intermediate arrays to copy: at 50k nodes the copies and their page
    // faults cost as much as the enumeration).
    SparseMatrix up(size(hi), size(lo));
    auto& data = up.data();
    data.reserve(lo == 0
                     ? static_cast<Eigen::Index>(ranks_[static_cast<std::size_t>(hi)].nodes.size())
                     : 3 * static_cast<Eigen::Index>(size(hi)));
    std::int64_t* outer = up.outerIndexPtr();
    for_each_inclusion(lo, hi, [&](Index i, Index j, Scalar v, int) {
      data.append(v, static_cast<Eigen::Index>(i));
      ++outer[j + 1];
    });
    for (Index j = 0; j < size(hi); ++j) outer[j + 1] += outer[j];
    if (r > s) return up;
    return SparseMatrix(up.transpose());
  }

  /// Signed incidence between simplicial cells of rank r and r+1 (cells of k+1 nodes at rank k),
  /// from the orientation given at insertion: removing node i of (v0..vk) gives sign (-1)^i times
  /// the parity between that face and the stored orientation of the lower cell. So B1·B2 = 0.
  SparseMatrix signed_incidence_matrix(int r, int s) const {
    if (s != r + 1)
      throw ComplexError("signed_incidence_matrix: needs s = r + 1 (got " + std::to_string(r) +
                         ", " + std::to_string(s) + ")");
    require_rank(r, "signed_incidence_matrix");
    require_rank(s, "signed_incidence_matrix");
    std::vector<Eigen::Triplet<Scalar, std::int64_t>> t;
    const Rank& U = ranks_[static_cast<std::size_t>(s)];
    for (Index j = 0; j < size(s); ++j) {
      const std::vector<Index> up = oriented_nodes(s, j);
      if (static_cast<int>(up.size()) != s + 1) {
        throw ComplexError("signed_incidence_matrix: cell " + std::to_string(j) + " of rank " +
                           std::to_string(s) + " has " + std::to_string(up.size()) +
                           " nodes; signed incidence needs simplicial cells");
      }
      (void)U;
      for (std::size_t i = 0; i < up.size(); ++i) {
        std::vector<Index> face;
        for (std::size_t k = 0; k < up.size(); ++k)
          if (k != i) face.push_back(up[k]);
        auto c = find(face);
        if (!c || c->rank != r) continue;
        const std::vector<Index> lo = oriented_nodes(r, c->id);
        const int sign = ((i % 2) ? -1 : 1) * permutation_parity(face, lo);
        t.emplace_back(c->id, j, static_cast<Scalar>(sign));
      }
    }
    SparseMatrix m(size(r), size(s));
    m.setFromTriplets(t.begin(), t.end());
    return m;
  }

  /// Cells of rank r adjacent through cells of rank via > r: (B Bᵀ) with the diagonal removed,
  /// where B = |incidence_matrix(r, via)|; entry = number of shared upper cells.
  SparseMatrix adjacency_matrix(int r, int via) const {
    if (via <= r)
      throw ComplexError("adjacency_matrix: via rank " + std::to_string(via) +
                         " must be above rank " + std::to_string(r));
    std::vector<Index> group_offsets{0}, members;
    Index current = 0;
    for_each_inclusion(r, via, [&](Index lo, Index hi, Scalar, int) {
      while (current < hi) {
        group_offsets.push_back(static_cast<Index>(members.size()));
        ++current;
      }
      members.push_back(lo);
    });
    while (current < size(via)) {
      group_offsets.push_back(static_cast<Index>(members.size()));
      ++current;
    }
    group_offsets.push_back(static_cast<Index>(members.size()));
    return pair_counts(group_offsets, members, size(r));
  }
  /// Cells of rank r coadjacent through cells of rank via < r: (Bᵀ B) with the diagonal removed,
  /// where B = |incidence_matrix(via, r)|; entry = number of shared lower cells.
  SparseMatrix coadjacency_matrix(int r, int via) const {
    if (via >= r)
      throw ComplexError("coadjacency_matrix: via rank " + std::to_string(via) +
                         " must be below rank " + std::to_string(r));
    // Group the upper cells (rank r) by each shared lower cell (rank via): a counting sort.
    std::vector<std::pair<Index, Index>> inc;
    for_each_inclusion(via, r, [&](Index lo, Index hi, Scalar, int) { inc.push_back({lo, hi}); });
    std::vector<Index> group_offsets(static_cast<std::size_t>(size(via)) + 1, 0),
        members(inc.size());
    for (auto& p : inc) ++group_offsets[static_cast<std::size_t>(p.first) + 1];
    for (std::size_t i = 0; i + 1 < group_offsets.size(); ++i)
      group_offsets[i + 1] += group_offsets[i];
    std::vector<Index> fill(group_offsets.begin(), group_offsets.end() - 1);
    for (auto& p : inc)
      members[static_cast<std::size_t>(fill[static_cast<std::size_t>(p.first)]++)] = p.second;
    return pair_counts(group_offsets, members, size(r));
  }
  /// The Domain concept's names of the three above (domain.hpp): the simplicial and cell complexes
  /// answer to these, their incidence_matrix(rank, Signed) being TopoNetX's oriented one.
  SparseMatrix inclusion_matrix(int r, int s) const { return incidence_matrix(r, s); }
  SparseMatrix adjacency_matrix_via(int r, int via) const { return adjacency_matrix(r, via); }
  SparseMatrix coadjacency_matrix_via(int r, int via) const { return coadjacency_matrix(r, via); }

 private:
  struct Rank {
    std::vector<Index> nodes;           // sorted node ids, CSR
    std::vector<Index> oriented_nodes;  // node ids in insertion order, same offsets
    std::vector<Index> offsets{0};
    std::vector<Declared> declared;
    std::vector<Index> declared_offsets{0};
  };

  // Open-addressing table from a cell's node-set hash to its handle (no allocation per cell).
  class CellTable {
   public:
    void reserve(std::size_t extra) { grow_to(2 * (used_ + extra) + 16); }
    void insert(std::uint64_t h, Cell c) {
      if (2 * (used_ + 1) > slots_.size()) grow_to(2 * slots_.size() + 16);
      std::size_t i = h & (slots_.size() - 1);
      while (slots_[i].rank >= 0) i = (i + 1) & (slots_.size() - 1);
      if (slots_[i].rank == kEmpty) ++used_;
      slots_[i] = {h, c.id, c.rank};
    }
    template <class Pred>
    std::optional<Cell> find(std::uint64_t h, Pred&& matches) const {
      if (slots_.empty()) return std::nullopt;
      for (std::size_t i = h & (slots_.size() - 1); slots_[i].rank != kEmpty;
           i = (i + 1) & (slots_.size() - 1)) {
        if (slots_[i].rank >= 0 && slots_[i].hash == h &&
            matches(Cell{slots_[i].rank, slots_[i].id}))
          return Cell{slots_[i].rank, slots_[i].id};
      }
      return std::nullopt;
    }
    void erase(std::uint64_t h, Cell c) {
      if (slots_.empty()) return;
      for (std::size_t i = h & (slots_.size() - 1); slots_[i].rank != kEmpty;
           i = (i + 1) & (slots_.size() - 1)) {
        if (slots_[i].rank == c.rank && slots_[i].id == c.id) {
          slots_[i].rank = kTombstone;
          return;
        }
      }
    }

   private:
    static constexpr int kEmpty = -1, kTombstone = -2;
    struct Slot {
      std::uint64_t hash = 0;
      Index id = 0;
      int rank = kEmpty;
    };
    void grow_to(std::size_t want) {
      std::size_t cap = 16;
      while (cap < want) cap *= 2;
      if (cap <= slots_.size()) return;
      std::vector<Slot> old;
      old.swap(slots_);
      slots_.assign(cap, Slot{});
      used_ = 0;
      for (const Slot& sl : old)
        if (sl.rank >= 0) insert(sl.hash, Cell{sl.rank, sl.id});
    }
    std::vector<Slot> slots_;
    std::size_t used_ = 0;  // live + tombstones
  };

  std::vector<Rank> ranks_;
  mutable CellTable lookup_;
  mutable bool lookup_dirty_ = false;

  void ensure_lookup() const {
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
  // Per rank: node v -> ids of the cells of that rank whose smallest node is v (every cell once,
  // ids ascending). What enumerating subsets needs, at a fraction of the full node index's size;
  // built lazily per rank, dropped when the rank changes.
  struct MinIndex {
    std::vector<Index> offsets, ids;
    bool valid = false;
  };
  mutable std::vector<MinIndex> min_index_;
  void invalidate_min_index(int r) {
    if (static_cast<std::size_t>(r) < min_index_.size())
      min_index_[static_cast<std::size_t>(r)].valid = false;
  }
  const MinIndex& min_index(int r) const {
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

  // Node -> cells index: a CSR over the first indexed_counts_[r] cells of each rank, built lazily,
  // plus a small map for cells added one by one since (per-frame cells). Rebuilt when stale.
  mutable std::vector<Index> index_offsets_;
  mutable std::vector<Cell> index_cells_;
  mutable std::vector<Index> indexed_counts_;
  mutable bool index_dirty_ = true;
  std::unordered_map<Index, std::vector<Cell>> tail_index_;
  Index tail_entries_ = 0;

  Index indexed_count(int r) const {
    return static_cast<std::size_t>(r) < indexed_counts_.size()
               ? indexed_counts_[static_cast<std::size_t>(r)]
               : 0;
  }
  void ensure_index() const {
    if (!index_dirty_ && 4 * tail_entries_ <= static_cast<Index>(index_cells_.size()) + 4096)
      return;
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
  /// Calls f(cell) for every cell containing node v (index must be current).
  template <class F>
  void for_each_cell_of_node(Index v, F&& f) const {
    for (Index k = index_offsets_[static_cast<std::size_t>(v)];
         k < index_offsets_[static_cast<std::size_t>(v) + 1]; ++k)
      f(index_cells_[static_cast<std::size_t>(k)]);
    if (tail_entries_ == 0) return;
    auto it = tail_index_.find(v);
    if (it != tail_index_.end())
      for (const Cell& c : it->second) f(c);
  }

  static std::uint64_t hash_nodes(const Index* p, std::size_t n) {
    std::uint64_t h = 1469598103934665603ULL ^ n;
    for (std::size_t i = 0; i < n; ++i) {
      std::uint64_t x = static_cast<std::uint64_t>(p[i]) + 0x9e3779b97f4a7c15ULL;
      x = (x ^ (x >> 30)) * 0xbf58476d1ce4e5b9ULL;
      x = (x ^ (x >> 27)) * 0x94d049bb133111ebULL;
      h = (h ^ (x ^ (x >> 31))) * 1099511628211ULL;
    }
    return h;
  }

  std::optional<Cell> find_sorted(const std::vector<Index>& sorted, std::uint64_t h) const {
    ensure_lookup();
    return lookup_.find(h, [&](const Cell& c) {
      const Rank& R = ranks_[static_cast<std::size_t>(c.rank)];
      const auto b = R.offsets[static_cast<std::size_t>(c.id)],
                 e = R.offsets[static_cast<std::size_t>(c.id) + 1];
      return static_cast<std::size_t>(e - b) == sorted.size() &&
             std::equal(sorted.begin(), sorted.end(), R.nodes.begin() + b);
    });
  }

  // Does sorted [b, e) include sorted [lb, le)? Binary search when the big set is much larger.
  static bool includes(const Index* b, const Index* e, const Index* lb, const Index* le) {
    const auto n = e - b, k = le - lb;
    if (k > n) return false;
    if (n > 16 * k) {
      for (const Index* p = lb; p != le; ++p)
        if (!std::binary_search(b, e, *p)) return false;
      return true;
    }
    return std::includes(b, e, lb, le);
  }
  static bool is_subset(const std::vector<Index>& small, const std::vector<Index>& big) {
    return includes(big.data(), big.data() + big.size(), small.data(), small.data() + small.size());
  }

  void check_rank_condition(const std::vector<Index>& sorted, int rank,
                            const std::vector<Index>& given) const {
    const Index* b = sorted.data();
    const Index* e = b + sorted.size();
    // Supersets contain sorted[0]; subsets have their smallest node in the cell.
    ensure_index();
    for_each_cell_of_node(sorted.front(), [&](const Cell& c) {
      const Rank& R = ranks_[static_cast<std::size_t>(c.rank)];
      const Index* cb = R.nodes.data() + R.offsets[static_cast<std::size_t>(c.id)];
      const Index* ce = R.nodes.data() + R.offsets[static_cast<std::size_t>(c.id) + 1];
      if ((c.rank < rank) && (ce - cb) > (e - b) && includes(cb, ce, b, e)) {
        throw ComplexError("add_cell: cell " + describe(given) + " at rank " +
                           std::to_string(rank) + " is a subset of cell " + std::to_string(c.id) +
                           " of lower rank " + std::to_string(c.rank) + " (rank condition)");
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

  void ensure_rank(int r) {
    while (max_rank() < r) ranks_.emplace_back();
  }
  void require_rank(int r, const char* what) const {
    if (r < 0 || r > max_rank()) {
      throw ComplexError(std::string(what) + ": rank " + std::to_string(r) +
                         " holds no cells (the complex has ranks 0.." + std::to_string(max_rank()) +
                         ")");
    }
  }
  void check_cell(int r, Index id, const char* what) const {
    require_rank(r, what);
    if (id < 0 || id >= size(r)) {
      throw ComplexError(std::string(what) + ": cell " + std::to_string(id) + " of rank " +
                         std::to_string(r) + " does not exist (rank has " +
                         std::to_string(size(r)) + " cells)");
    }
  }
  static std::string describe(const std::vector<Index>& nodes) {
    std::ostringstream s;
    s << '{';
    for (std::size_t i = 0; i < nodes.size() && i < 8; ++i) s << (i ? "," : "") << nodes[i];
    if (nodes.size() > 8) s << ",…(" << nodes.size() << " nodes)";
    s << '}';
    return s.str();
  }
  static int permutation_parity(const std::vector<Index>& a, const std::vector<Index>& b) {
    // Parity of the permutation taking b to a (same node set).
    std::vector<Index> p(a.size());
    for (std::size_t i = 0; i < a.size(); ++i)
      p[i] = static_cast<Index>(std::find(b.begin(), b.end(), a[i]) - b.begin());
    int parity = 1;
    for (std::size_t i = 0; i < p.size(); ++i)
      for (std::size_t j = i + 1; j < p.size(); ++j)
        if (p[i] > p[j]) parity = -parity;
    return parity;
  }
  // Counts, for every ordered pair (i, k), i != k, the groups that hold both: the off-diagonal
  // part of the Gram matrix of the group-membership matrix, without forming the product.
  static SparseMatrix pair_counts(const std::vector<Index>& offsets,
                                  const std::vector<Index>& members, Index n) {
    // Invert the membership (cell -> its groups) by a counting sort, then emit each row's
    // co-members sorted and counted: CSR directly, no triplet sort.
    std::vector<Index> gstart(static_cast<std::size_t>(n) + 1, 0), groups(members.size());
    for (Index m : members) ++gstart[static_cast<std::size_t>(m) + 1];
    for (std::size_t i = 0; i + 1 < gstart.size(); ++i) gstart[i + 1] += gstart[i];
    {
      std::vector<Index> fill(gstart.begin(), gstart.end() - 1);
      for (std::size_t g = 0; g + 1 < offsets.size(); ++g)
        for (Index a = offsets[g]; a < offsets[g + 1]; ++a)
          groups[static_cast<std::size_t>(
              fill[static_cast<std::size_t>(members[static_cast<std::size_t>(a)])]++)] =
              static_cast<Index>(g);
    }
    // At most Σ_g |g|(|g| - 1) entries (before merging repeats): reserve that, fill in place.
    std::int64_t bound = 0;
    for (std::size_t g = 0; g + 1 < offsets.size(); ++g)
      bound += (offsets[g + 1] - offsets[g]) * (offsets[g + 1] - offsets[g] - 1);
    SparseMatrix m(n, n);
    auto& data = m.data();
    data.reserve(static_cast<Eigen::Index>(bound));
    std::int64_t* outer = m.outerIndexPtr();
    std::vector<Index> row;
    for (Index i = 0; i < n; ++i) {
      row.clear();
      for (Index k = gstart[static_cast<std::size_t>(i)];
           k < gstart[static_cast<std::size_t>(i) + 1]; ++k) {
        const auto g = static_cast<std::size_t>(groups[static_cast<std::size_t>(k)]);
        for (Index a = offsets[g]; a < offsets[g + 1]; ++a)
          if (members[static_cast<std::size_t>(a)] != i)
            row.push_back(members[static_cast<std::size_t>(a)]);
      }
      std::sort(row.begin(), row.end());
      for (std::size_t a = 0; a < row.size();) {
        std::size_t b = a;
        while (b < row.size() && row[b] == row[a]) ++b;
        data.append(static_cast<Scalar>(b - a), static_cast<Eigen::Index>(row[a]));
        a = b;
      }
      outer[i + 1] = static_cast<std::int64_t>(data.size());
    }
    return m;
  }
};

// The default complex is compiled once in topos::core_compiled (src/core.cpp), which topos::nn
// links; TOPOS_CORE_COMPILED, which it sets, keeps each translation unit from instantiating it.
#ifdef TOPOS_CORE_COMPILED
extern template class CombinatorialComplex<DefaultComplexOptions>;
#endif

}  // namespace topos
