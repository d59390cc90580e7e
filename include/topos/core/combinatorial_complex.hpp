// topos/core/combinatorial_complex.hpp
// A rank-indexed combinatorial complex (CC): cells are sets of node ids, each with a rank, and
// the rank function is monotone under inclusion (a subset never has a higher rank). Ids are
// dense per rank in insertion order, so row i of every operator is the i-th cell of that rank.
// Operators (incidence, adjacency, coadjacency) are Eigen sparse matrices with 64-bit indices.
// Std + Eigen only. The member definitions: combinatorial_complex-inl.hpp (building, queries, the
// look-up tables) and combinatorial_complex_operators-inl.hpp (the operators), included below.
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
  Index add_nodes(Index n);

  /// Adds a cell of rank `rank` >= 1 over `nodes`. The node order given is kept as the cell's
  /// orientation (used by signed_incidence_matrix); the set itself is what identifies the cell.
  /// Returns (id, inserted): inserting an existing set at the same rank returns its id and false.
  std::pair<Index, bool> add_cell(const std::vector<Index>& nodes, int rank,
                                  const std::vector<Declared>& declared = {});

  /// Appends a cell without any check. For bulk builders (mesh lifting) that guarantee
  /// themselves that the nodes are valid, distinct, new as a set, and respect the rank condition.
  Index add_cell_trusted(const Index* oriented, std::size_t n, int rank);

  /// Appends `count` cells of `arity` nodes each (flat, oriented) without any check, as
  /// add_cell_trusted does one by one; returns the id of the first.
  Index add_cells_trusted(const Index* oriented, std::size_t count, std::size_t arity, int rank);

  /// Reserves storage for `cells` cells of total `nodes` node entries at rank r.
  void reserve(int rank, std::size_t cells, std::size_t nodes);

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
  void rollback(const Mark& m);

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
  std::vector<Index> cell_nodes(int r, Index id) const;
  /// Node ids of a cell in the order given when it was added (its orientation).
  std::vector<Index> oriented_nodes(int r, Index id) const;
  /// All cells of rank r, in id order (TopoNetX's skeleton).
  std::vector<std::vector<Index>> skeleton(int r) const;
  /// Looks a cell up by its nodes (any order); returns its handle if it exists.
  std::optional<Cell> find(std::vector<Index> nodes) const {
    std::sort(nodes.begin(), nodes.end());
    return find_sorted(nodes, hash_nodes(nodes.data(), nodes.size()));
  }
  /// Values and roles that cells of rank r declared for their lower cells.
  std::vector<Declared> declared_incidences(int r, Index id) const;

  // ----- operators ----------------------------------------------------------------------------

  /// Visits every inclusion (lower cell i of rank lo) ⊂ (upper cell j of rank hi), lo < hi, with
  /// the value of the incidence (1 or the value the upper cell declared) and its role.
  /// Visit order: upper cells in id order, then lower cells in ascending id.
  template <class F>
  void for_each_inclusion(int lo, int hi, F&& visit) const;

  /// Incidence matrix by set inclusion, n_r × n_s. For r < s entry (i, j) is 1 when cell i of
  /// rank r is a subset of cell j of rank s (or the value cell j declared); for r > s it is the
  /// transpose of incidence_matrix(s, r).
  SparseMatrix incidence_matrix(int r, int s) const;

  /// Signed incidence between simplicial cells of rank r and r+1 (cells of k+1 nodes at rank k),
  /// from the orientation given at insertion: removing node i of (v0..vk) gives sign (-1)^i times
  /// the parity between that face and the stored orientation of the lower cell. So B1·B2 = 0.
  SparseMatrix signed_incidence_matrix(int r, int s) const;

  /// Cells of rank r adjacent through cells of rank via > r: (B Bᵀ) with the diagonal removed,
  /// where B = |incidence_matrix(r, via)|; entry = number of shared upper cells.
  SparseMatrix adjacency_matrix(int r, int via) const;
  /// Cells of rank r coadjacent through cells of rank via < r: (Bᵀ B) with the diagonal removed,
  /// where B = |incidence_matrix(via, r)|; entry = number of shared lower cells.
  SparseMatrix coadjacency_matrix(int r, int via) const;
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

  void ensure_lookup() const;
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
  const MinIndex& min_index(int r) const;

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
  void ensure_index() const;
  /// Calls f(cell) for every cell containing node v (index must be current).
  template <class F>
  void for_each_cell_of_node(Index v, F&& f) const;

  static std::uint64_t hash_nodes(const Index* p, std::size_t n);

  std::optional<Cell> find_sorted(const std::vector<Index>& sorted, std::uint64_t h) const;

  // Does sorted [b, e) include sorted [lb, le)? Binary search when the big set is much larger.
  static bool includes(const Index* b, const Index* e, const Index* lb, const Index* le);
  static bool is_subset(const std::vector<Index>& small, const std::vector<Index>& big) {
    return includes(big.data(), big.data() + big.size(), small.data(), small.data() + small.size());
  }

  void check_rank_condition(const std::vector<Index>& sorted, int rank,
                            const std::vector<Index>& given) const;

  void ensure_rank(int r) {
    while (max_rank() < r) ranks_.emplace_back();
  }
  void require_rank(int r, const char* what) const;
  void check_cell(int r, Index id, const char* what) const;
  static std::string describe(const std::vector<Index>& nodes);
  static int permutation_parity(const std::vector<Index>& a, const std::vector<Index>& b);
  // Counts, for every ordered pair (i, k), i != k, the groups that hold both: the off-diagonal
  // part of the Gram matrix of the group-membership matrix, without forming the product.
  static SparseMatrix pair_counts(const std::vector<Index>& offsets,
                                  const std::vector<Index>& members, Index n);
};

}  // namespace topos

#include "topos/core/combinatorial_complex-inl.hpp"
#include "topos/core/combinatorial_complex_operators-inl.hpp"

namespace topos {

// The default complex is compiled once in topos::core_compiled (src/core.cpp), which topos::nn
// links; TOPOS_CORE_COMPILED, which it sets, keeps each translation unit from instantiating it.
#ifdef TOPOS_CORE_COMPILED
extern template class CombinatorialComplex<DefaultComplexOptions>;
#endif

}  // namespace topos
