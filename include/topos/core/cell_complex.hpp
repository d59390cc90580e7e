// topos/core/cell_complex.hpp
// A regular 2-dimensional cell complex: nodes 0..n-1, oriented edges, and 2-cells given as
// closed vertex cycles (v0, v1, ..., v_{m-1}; the edge v_{m-1} -> v0 closes it) with at least 3
// distinct vertices. Several 2-cells may share one boundary (each is its own column).
// Cell order and orientation, as TopoNetX's CellComplex (the default):
//   edges sorted by (min, max) node, oriented min -> max (B_1 has -1 at min, +1 at max);
//   2-cells in insertion order, except that a cell with exactly the same vertex sequence as an
//   earlier one is placed right after it (TopoNetX groups them so);
// or, with from_ordered(), edges and cells in exactly the given order, each edge oriented as
// given. B_2 entry (edge e, cell c) = +1 when the cycle traverses e along its orientation, -1
// against it. Unsigned operators are |.| of the signed ones; adjacency / coadjacency are
// TopoNetX's incidence_to_adjacency (off-diagonal of |B|^T|B|: counts, whatever `signed`).
// Std + Eigen only.
#pragma once

#include "topos/core/operators.hpp"
#include "topos/core/sparse_matrix.hpp"

#include <algorithm>
#include <array>
#include <cstdint>
#include <optional>
#include <sstream>
#include <string>
#include <unordered_map>
#include <vector>

namespace topos {

class CellComplex : private detail::SignArgument {
 public:
  using Index = std::int64_t;
  using Edge = std::array<Index, 2>;

  CellComplex() = default;
  explicit CellComplex(Index num_nodes) { add_nodes(num_nodes); }

  /// Edges and cells in exactly the given order; each edge oriented as given. Every
  /// consecutive pair of a cell's cycle (and its closing pair) must be a listed edge.
  static CellComplex from_ordered(Index num_nodes, const std::vector<Edge>& edges,
                                  const std::vector<std::vector<Index>>& cells) {
    CellComplex cx(num_nodes);
    cx.given_order_ = true;
    for (const Edge& e : edges) {
      cx.check_edge(e[0], e[1], "from_ordered");
      if (!cx.edge_index_.emplace(key(e[0], e[1]), static_cast<Index>(cx.edges_.size())).second) {
        throw ComplexError("CellComplex::from_ordered: edge [" + std::to_string(e[0]) + ", " +
                           std::to_string(e[1]) + "] is listed twice");
      }
      cx.edges_.push_back(e);
    }
    for (std::size_t c = 0; c < cells.size(); ++c) {
      const std::vector<Index> cycle =
          cx.check_cycle(cells[c], "from_ordered: cell " + std::to_string(c));
      for (std::size_t i = 0; i < cycle.size(); ++i) {
        const Index u = cycle[i], v = cycle[(i + 1) % cycle.size()];
        if (!cx.edge_index_.count(key(u, v))) {
          throw ComplexError("CellComplex::from_ordered: cell " + std::to_string(c) + " " +
                             describe(cells[c]) + " is not a closed cycle of listed edges: edge [" +
                             std::to_string(u) + ", " + std::to_string(v) +
                             "] is not in the edge list");
        }
      }
      cx.append_cell(cycle);
    }
    return cx;
  }

  // ----- building ---------------------------------------------------------------------------

  Index add_nodes(Index n) {
    if (n < 0) throw ComplexError("CellComplex::add_nodes: negative count " + std::to_string(n));
    const Index first = num_nodes_;
    num_nodes_ += n;
    return first;
  }
  /// Adds the edge {u, v} if new (in TopoNetX order it is re-oriented min -> max).
  void add_edge(Index u, Index v) {
    check_edge(u, v, "add_edge");
    if (edge_index_.count(key(u, v))) return;
    edge_index_.emplace(key(u, v), static_cast<Index>(edges_.size()));
    edges_.push_back({u, v});
    if (!given_order_) edges_sorted_ = false;
  }
  /// Adds a 2-cell given as a vertex cycle (a closing repeat of the first vertex is allowed);
  /// its boundary edges are added if missing. Returns nothing: ids follow the cell order above.
  void add_cell(const std::vector<Index>& cycle) {
    const std::vector<Index> c = check_cycle(cycle, "add_cell");
    for (std::size_t i = 0; i < c.size(); ++i) add_edge(c[i], c[(i + 1) % c.size()]);
    append_cell(c);
  }
  /// Adds a 2-cell given by its boundary as a chain of edges (u0,u1), (u1,u2), ..., (uk,u0);
  /// a chain that does not close is an error.
  void add_cell_from_edges(const std::vector<Edge>& boundary) {
    if (boundary.size() < 3)
      throw ComplexError("add_cell_from_edges: a 2-cell needs at least 3 boundary edges, got " +
                         std::to_string(boundary.size()));
    std::vector<Index> cycle;
    for (std::size_t i = 0; i < boundary.size(); ++i) {
      const Edge& e = boundary[i];
      const Edge& next = boundary[(i + 1) % boundary.size()];
      if (e[1] != next[0]) {
        throw ComplexError("add_cell_from_edges: the boundary is not a closed cycle: edge " +
                           std::to_string(i) + " [" + std::to_string(e[0]) + ", " +
                           std::to_string(e[1]) + "] is followed by [" + std::to_string(next[0]) +
                           ", " + std::to_string(next[1]) + "]");
      }
      cycle.push_back(e[0]);
    }
    add_cell(cycle);
  }

  // ----- queries ----------------------------------------------------------------------------

  Index num_nodes() const { return num_nodes_; }
  Index num_edges() const { return static_cast<Index>(edges_.size()); }
  Index num_2cells() const { return static_cast<Index>(cell_offsets_.size()) - 1; }
  /// 2 with 2-cells, 1 with edges only, 0 with nodes only, -1 when empty (TopoNetX's dim).
  int dim() const { return num_2cells() > 0 ? 2 : num_edges() > 0 ? 1 : num_nodes_ > 0 ? 0 : -1; }
  Index num_cells(int rank) const {
    return rank == 0 ? num_nodes_ : rank == 1 ? num_edges() : rank == 2 ? num_2cells() : 0;
  }
  std::vector<Index> shape() const { return {num_nodes_, num_edges(), num_2cells()}; }
  bool explicit_order() const { return given_order_; }

  /// Edge `id` as (tail, head).
  Edge edge(Index id) const {
    sort_edges();
    if (id < 0 || id >= num_edges())
      throw ComplexError("edge: edge " + std::to_string(id) + " does not exist (" +
                         std::to_string(num_edges()) + " edges)");
    return edges_[static_cast<std::size_t>(id)];
  }
  std::vector<Edge> edges() const {
    sort_edges();
    return edges_;
  }
  std::optional<Index> edge_id(Index u, Index v) const {
    sort_edges();
    auto it = edge_index_.find(key(u, v));
    return it == edge_index_.end() ? std::nullopt : std::optional<Index>(it->second);
  }
  /// The vertex cycle of 2-cell `id`.
  std::vector<Index> cell(Index id) const {
    if (id < 0 || id >= num_2cells())
      throw ComplexError("cell: 2-cell " + std::to_string(id) + " does not exist (" +
                         std::to_string(num_2cells()) + " 2-cells)");
    return {cell_nodes_.begin() + cell_offsets_[static_cast<std::size_t>(id)],
            cell_nodes_.begin() + cell_offsets_[static_cast<std::size_t>(id) + 1]};
  }
  /// Cells of a rank as node lists (nodes: [v]; edges: [tail, head]; 2-cells: their cycles).
  std::vector<std::vector<Index>> skeleton(int rank) const {
    std::vector<std::vector<Index>> out;
    if (rank == 0)
      for (Index v = 0; v < num_nodes_; ++v) out.push_back({v});
    else if (rank == 1)
      for (const Edge& e : edges()) out.push_back({e[0], e[1]});
    else if (rank == 2)
      for (Index c = 0; c < num_2cells(); ++c) out.push_back(cell(c));
    else
      throw ComplexError("skeleton: a cell complex has ranks 0..2, got " + std::to_string(rank));
    return out;
  }
  Index euler_characteristic() const { return num_nodes_ - num_edges() + num_2cells(); }

  // ----- operators (TopoNetX's CellComplex methods) -----------------------------------------

  /// B_rank: rank 0 is 0 x n_0 (TopoNetX), rank 1 is n_0 x n_1, rank 2 is n_1 x n_2.
  SparseMatrix incidence_matrix(int rank, Signed sign = Signed::yes) const {
    const bool signed_ = sign == Signed::yes;
    SparseMatrix m;
    if (rank == 0) return SparseMatrix(0, num_nodes_);
    if (rank == 1)
      m = sparse::transpose(coboundary1());
    else if (rank == 2)
      m = boundary2();
    else
      throw ComplexError("incidence_matrix: a cell complex has ranks 0..2, got " +
                         std::to_string(rank));
    if (!signed_) sparse::make_abs(m);
    return m;
  }
  SparseMatrix coincidence_matrix(int rank, Signed sign = Signed::yes) const {
    return sparse::transpose(incidence_matrix(rank, sign));
  }
  /// Unsigned inclusion between two ranks (n_rank x n_to_rank).
  SparseMatrix inclusion_matrix(int rank, int to_rank) const {
    if (rank == to_rank)
      throw ComplexError("inclusion_matrix: ranks must differ (got " + std::to_string(rank) +
                         " twice)");
    const int lo = std::min(rank, to_rank), hi = std::max(rank, to_rank);
    if (lo < 0 || hi > 2)
      throw ComplexError("inclusion_matrix: a cell complex has ranks 0..2, got " +
                         std::to_string(rank) + " and " + std::to_string(to_rank));
    SparseMatrix m;
    if (hi == lo + 1) {
      m = sparse::abs(incidence_matrix(hi));
      // A non-closed walk would give 2; regular cells never do, but keep inclusion 0/1.
      for (Eigen::Index k = 0; k < m.nonZeros(); ++k) m.valuePtr()[k] = 1.0;
    } else {  // nodes x 2-cells: the cycle's vertex set
      std::vector<Eigen::Triplet<double, std::int64_t>> t;
      for (Index c = 0; c < num_2cells(); ++c)
        for (Index v : cell(c)) t.emplace_back(v, c, 1.0);
      m = sparse::from_triplets(num_nodes_, num_2cells(), t);
    }
    if (rank < to_rank) return m;
    return sparse::transpose(m);
  }

  SparseMatrix up_laplacian_matrix(int rank, bool signed_ = true) const {
    if (rank < 0 || rank >= std::max(dim(), 1))
      throw ComplexError("up_laplacian_matrix: rank " + std::to_string(rank) + " must be in [0, " +
                         std::to_string(dim() - 1) + "]");
    SparseMatrix l = up_laplacian(incidence_matrix(rank + 1));
    if (!signed_) sparse::make_abs(l);
    return l;
  }
  SparseMatrix down_laplacian_matrix(int rank, bool signed_ = true) const {
    if (rank < 1 || rank > dim())
      throw ComplexError("down_laplacian_matrix: rank " + std::to_string(rank) +
                         " must be in [1, " + std::to_string(dim()) + "]");
    SparseMatrix l = down_laplacian(incidence_matrix(rank));
    if (!signed_) sparse::make_abs(l);
    return l;
  }
  SparseMatrix hodge_laplacian_matrix(int rank, bool signed_ = true) const {
    SparseMatrix l = signed_hodge(rank);
    if (!signed_) sparse::make_abs(l);
    return l;
  }
  /// Cells of `rank` sharing a cell of rank + 1 (counts); `sign` is accepted as TopoNetX does
  /// and has no effect (its incidence_to_adjacency takes |B|).
  SparseMatrix adjacency_matrix(int rank, Signed sign = Signed::no) const {
    (void)sign;
    if (rank < 0 || rank > 1)
      throw ComplexError("adjacency_matrix: rank " + std::to_string(rank) +
                         " must be 0 or 1 (cells of rank + 1 must exist)");
    return incidence_to_adjacency(sparse::transpose(incidence_matrix(rank + 1)));
  }
  /// Cells of `rank` sharing a cell of rank - 1 (counts); `sign` has no effect, as in TopoNetX.
  SparseMatrix coadjacency_matrix(int rank, Signed sign = Signed::no) const {
    (void)sign;
    if (rank < 0 || rank > 2)
      throw ComplexError("coadjacency_matrix: rank " + std::to_string(rank) + " must be in [0, 2]");
    return incidence_to_adjacency(incidence_matrix(rank));
  }
  SparseMatrix adjacency_matrix_via(int rank, int via_rank) const {
    if (via_rank <= rank)
      throw ComplexError("adjacency_matrix_via: via rank " + std::to_string(via_rank) +
                         " must be above rank " + std::to_string(rank));
    return incidence_to_adjacency(inclusion_matrix(via_rank, rank));
  }
  SparseMatrix coadjacency_matrix_via(int rank, int via_rank) const {
    if (via_rank >= rank)
      throw ComplexError("coadjacency_matrix_via: via rank " + std::to_string(via_rank) +
                         " must be below rank " + std::to_string(rank));
    return incidence_to_adjacency(inclusion_matrix(via_rank, rank));
  }
  // The sign is Signed::yes or Signed::no, never an int or a bool (detail::SignArgument).
  using detail::SignArgument::adjacency_matrix;
  using detail::SignArgument::coadjacency_matrix;
  using detail::SignArgument::incidence_matrix;
  /// D^{-1/2} L D^{-1/2} of the signed Hodge Laplacian (as SimplicialComplex's).
  SparseMatrix normalized_laplacian_matrix(int rank) const {
    return normalized_laplacian(hodge_laplacian_matrix(rank, true));
  }

 private:
  Index num_nodes_ = 0;
  mutable std::vector<Edge> edges_;
  mutable std::unordered_map<std::uint64_t, Index> edge_index_;  // unordered pair -> id
  mutable bool edges_sorted_ = true;
  bool given_order_ = false;
  std::vector<Index> cell_nodes_;
  std::vector<Index> cell_offsets_{0};

  static std::uint64_t key(Index u, Index v) {
    const auto a = static_cast<std::uint64_t>(std::min(u, v)),
               b = static_cast<std::uint64_t>(std::max(u, v));
    return (a << 32) | b;
  }
  static std::string describe(const std::vector<Index>& c) {
    std::ostringstream s;
    s << '[';
    for (std::size_t i = 0; i < c.size(); ++i) s << (i ? ", " : "") << c[i];
    s << ']';
    return s.str();
  }
  void check_edge(Index u, Index v, const char* what) const {
    for (Index x : {u, v})
      if (x < 0 || x >= num_nodes_)
        throw ComplexError(std::string(what) + ": edge [" + std::to_string(u) + ", " +
                           std::to_string(v) + "] uses node " + std::to_string(x) +
                           ", which is not in the complex (nodes 0.." +
                           std::to_string(num_nodes_ - 1) + ")");
    if (u == v)
      throw ComplexError(std::string(what) + ": edge [" + std::to_string(u) + ", " +
                         std::to_string(v) + "] is a self-loop");
    if (num_nodes_ >= (Index(1) << 32))
      throw ComplexError(std::string(what) + ": more than 2^32 nodes");
  }
  std::vector<Index> check_cycle(std::vector<Index> c, const std::string& what) const {
    if (c.size() > 1 && c.front() == c.back()) c.pop_back();  // explicitly closed
    if (c.size() < 3)
      throw ComplexError(what + ": 2-cell " + describe(c) +
                         " needs a cycle of at least 3 distinct vertices");
    for (Index v : c)
      if (v < 0 || v >= num_nodes_)
        throw ComplexError(what + ": 2-cell " + describe(c) + " uses node " + std::to_string(v) +
                           ", which is not in the complex (nodes 0.." +
                           std::to_string(num_nodes_ - 1) + ")");
    std::vector<Index> s(c);
    std::sort(s.begin(), s.end());
    if (auto it = std::adjacent_find(s.begin(), s.end()); it != s.end()) {
      throw ComplexError(what + ": 2-cell " + describe(c) + " repeats node " + std::to_string(*it) +
                         " (a regular 2-cell is a simple cycle)");
    }
    return c;
  }
  void append_cell(const std::vector<Index>& c) {
    std::size_t at = cell_offsets_.size() - 1;  // cell position
    if (!given_order_) {
      // TopoNetX groups cells with the same vertex sequence: after the last such cell.
      for (std::size_t i = 0; i + 1 < cell_offsets_.size(); ++i) {
        const auto b = cell_nodes_.begin() + cell_offsets_[i],
                   e = cell_nodes_.begin() + cell_offsets_[i + 1];
        if (static_cast<std::size_t>(e - b) == c.size() && std::equal(b, e, c.begin())) at = i + 1;
      }
    }
    const Index pos = cell_offsets_[at];
    cell_nodes_.insert(cell_nodes_.begin() + pos, c.begin(), c.end());
    cell_offsets_.insert(cell_offsets_.begin() + static_cast<std::ptrdiff_t>(at) + 1,
                         pos + static_cast<Index>(c.size()));
    for (std::size_t i = at + 2; i < cell_offsets_.size(); ++i)
      cell_offsets_[i] += static_cast<Index>(c.size());
  }
  void sort_edges() const {
    if (edges_sorted_) return;
    for (Edge& e : edges_)
      if (e[0] > e[1]) std::swap(e[0], e[1]);
    std::sort(edges_.begin(), edges_.end());
    for (std::size_t i = 0; i < edges_.size(); ++i)
      edge_index_[key(edges_[i][0], edges_[i][1])] = static_cast<Index>(i);
    edges_sorted_ = true;
  }
  SparseMatrix signed_hodge(int rank) const {
    if (rank == 0) return up_laplacian(incidence_matrix(1));
    if (rank == 1 && dim() == 2) {
      const SparseMatrix b1 = incidence_matrix(1), b1t = sparse::transpose(b1);
      const SparseMatrix b2 = incidence_matrix(2), b2t = sparse::transpose(b2);
      return sparse::multiply_sum_symmetric({{&b1t, &b1}, {&b2, &b2t}});
    }
    if (rank == 1) return down_laplacian(incidence_matrix(1));
    if (rank == 2 && dim() == 2) return down_laplacian(incidence_matrix(2));
    throw ComplexError("hodge_laplacian_matrix: rank " + std::to_string(rank) + " must be in [0, " +
                       std::to_string(std::max(dim(), 0)) + "] (the complex has dimension " +
                       std::to_string(dim()) + ")");
  }

  // B_1^T: row e has -1 at the tail, +1 at the head.
  SparseMatrix coboundary1() const {
    sort_edges();
    SparseMatrix m(num_edges(), num_nodes_);
    auto& d = m.data();
    for (Index e = 0; e < num_edges(); ++e) {
      const Edge& ed = edges_[static_cast<std::size_t>(e)];
      const bool tail_first = ed[0] < ed[1];
      d.append(tail_first ? -1.0 : 1.0, static_cast<Eigen::Index>(std::min(ed[0], ed[1])));
      d.append(tail_first ? 1.0 : -1.0, static_cast<Eigen::Index>(std::max(ed[0], ed[1])));
      m.outerIndexPtr()[e + 1] = 2 * (e + 1);
    }
    return m;
  }
  // B_2: +1 / -1 per traversal along / against the edge's orientation (summed, as TopoNetX).
  SparseMatrix boundary2() const {
    sort_edges();
    std::vector<Eigen::Triplet<double, std::int64_t>> t;
    t.reserve(cell_nodes_.size());
    for (Index c = 0; c < num_2cells(); ++c) {
      const Index b = cell_offsets_[static_cast<std::size_t>(c)],
                  n = cell_offsets_[static_cast<std::size_t>(c) + 1] - b;
      for (Index i = 0; i < n; ++i) {
        const Index u = cell_nodes_[static_cast<std::size_t>(b + i)],
                    v = cell_nodes_[static_cast<std::size_t>(b + (i + 1) % n)];
        const Index e = edge_index_.at(key(u, v));
        t.emplace_back(e, c, edges_[static_cast<std::size_t>(e)][0] == u ? 1.0 : -1.0);
      }
    }
    return sparse::from_triplets(num_edges(), num_2cells(), t);
  }
};

}  // namespace topos
