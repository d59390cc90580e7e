// topos/core/domain_lifting.hpp
// Liftings between domains (std + Eigen; the Boost.Graph and CGAL ones are in
// geometry/graph_and_point_cloud_lifting.hpp), each with its cell order:
//   clique_complex(n, edges, max_rank)   graph -> clique complex: every clique of up to
//                                        max_rank + 1 nodes is a simplex (TopoNetX's
//                                        graph_to_clique_complex); lexicographic order
//   simplicial_complex_from_mesh(mesh)   triangle mesh -> simplicial complex (faces, their edges
//                                        and vertices; orientation by sorted nodes, as every
//                                        SimplicialComplex), lexicographic order
//   to_hypergraph(sc)                    every simplex of rank >= 1 a hyperedge, by rank then id
//                                        (TopoNetX's SimplicialComplex.to_hypergraph)
//   to_combinatorial_complex(sc)         the same cells, rank = dimension, same ids per rank
//   neighborhood_hypergraph(n, edges)    graph -> hypergraph: hyperedge v = {v} and its
//                                        neighbours, one per node in node order
//   to_cell_complex(sc)                  nodes, edges and triangles (as 2-cells) of a simplicial
//                                        complex, in its order, edges oriented low -> high
// TopoBench's graph liftings (topobench/transforms/liftings/graph2*), on the graph TopoBench
// builds from a PyG edge_index (nodes 0..n-1 in order, coalesced symmetric edges, so every
// networkx adjacency iterates in ascending node order):
//   clique_lifting(n, edges, complex_dim) SimplicialCliqueLifting: every clique of up to
//                                        complex_dim + 1 nodes (= clique_complex), lexicographic
//   cycle_basis(n, edges)                networkx >= 3.2's nx.cycle_basis(G), cycles as it
//                                        lists them
//   cycle_lifting(n, edges, max_len)     CellCycleLifting: the graph plus one 2-cell per basis
//                                        cycle of at most max_len nodes, in basis order
//   khop_lifting(n, edges, k)            HypergraphKHopLifting: hyperedge v = the nodes within
//                                        k hops of v (v included), one per node in node order
#pragma once

#include "topos/core/cell_complex.hpp"
#include "topos/core/combinatorial_complex.hpp"
#include "topos/core/hypergraph.hpp"
#include "topos/core/simplicial_complex.hpp"
#include "topos/mesh/triangle_mesh.hpp"

#include <algorithm>
#include <array>
#include <cstdint>
#include <stdexcept>
#include <string>
#include <vector>

namespace topos {

namespace detail {
// Sorted, de-duplicated neighbour lists (CSR) of an undirected simple graph; self-loops rejected.
struct GraphCsr {
  std::vector<std::int64_t> offsets, neighbors;
};
inline GraphCsr graph_csr(std::int64_t n, const std::vector<std::array<std::int64_t, 2>>& edges,
                          bool forward_only) {
  GraphCsr g;
  g.offsets.assign(static_cast<std::size_t>(n) + 1, 0);
  for (const auto& e : edges) {
    for (auto v : e)
      if (v < 0 || v >= n)
        throw ComplexError("graph: edge [" + std::to_string(e[0]) + ", " + std::to_string(e[1]) +
                           "] uses node " + std::to_string(v) + ", outside [0, " +
                           std::to_string(n) + ")");
    if (e[0] == e[1])
      throw ComplexError("graph: edge [" + std::to_string(e[0]) + ", " + std::to_string(e[1]) +
                         "] is a self-loop");
    ++g.offsets[static_cast<std::size_t>(std::min(e[0], e[1])) + 1];
    if (!forward_only) ++g.offsets[static_cast<std::size_t>(std::max(e[0], e[1])) + 1];
  }
  for (std::size_t v = 0; v < static_cast<std::size_t>(n); ++v) g.offsets[v + 1] += g.offsets[v];
  g.neighbors.resize(static_cast<std::size_t>(g.offsets.back()));
  std::vector<std::int64_t> fill(g.offsets.begin(), g.offsets.end() - 1);
  for (const auto& e : edges) {
    const auto a = std::min(e[0], e[1]), b = std::max(e[0], e[1]);
    g.neighbors[static_cast<std::size_t>(fill[static_cast<std::size_t>(a)]++)] = b;
    if (!forward_only)
      g.neighbors[static_cast<std::size_t>(fill[static_cast<std::size_t>(b)]++)] = a;
  }
  // Sort and de-duplicate each list in place, compacting.
  std::int64_t w = 0;
  for (std::size_t v = 0; v < static_cast<std::size_t>(n); ++v) {
    auto b = g.neighbors.begin() + g.offsets[v], e = g.neighbors.begin() + g.offsets[v + 1];
    std::sort(b, e);
    const auto end = std::unique(b, e);
    const std::int64_t start = w;
    for (auto it = b; it != end; ++it) g.neighbors[static_cast<std::size_t>(w++)] = *it;
    g.offsets[v] = start;
  }
  g.offsets[static_cast<std::size_t>(n)] = w;
  g.neighbors.resize(static_cast<std::size_t>(w));
  return g;
}
}  // namespace detail

/// The clique complex of a graph on nodes 0..n-1: every clique of k + 1 <= max_rank + 1 nodes
/// is a k-simplex. Cliques are enumerated depth-first over ascending forward neighbours, which
/// yields every rank directly in lexicographic order (no sort).
inline SimplicialComplex clique_complex(std::int64_t num_nodes,
                                        const std::vector<std::array<std::int64_t, 2>>& edges,
                                        int max_rank) {
  if (max_rank < 0)
    throw ComplexError("clique_complex: max_rank " + std::to_string(max_rank) + " must be >= 0");
  if (max_rank > 30)
    throw ComplexError("clique_complex: max_rank " + std::to_string(max_rank) +
                       " is above the supported 30");
  const detail::GraphCsr g = detail::graph_csr(num_nodes, edges, true);
  std::vector<std::vector<std::int64_t>> flat(static_cast<std::size_t>(max_rank));
  // candidates[d]: common forward neighbours of the current d+1 nodes.
  std::vector<std::vector<std::int64_t>> candidates(static_cast<std::size_t>(max_rank) + 1);
  std::vector<std::int64_t> clique(static_cast<std::size_t>(max_rank) + 1);
  const auto emit = [&](int depth) {  // clique[0..depth] is a depth-simplex
    auto& out = flat[static_cast<std::size_t>(depth) - 1];
    out.insert(out.end(), clique.begin(), clique.begin() + depth + 1);
  };
  // Iterative DFS: at depth d we extend clique[0..d] by each candidate in turn.
  std::vector<std::size_t> pos(static_cast<std::size_t>(max_rank) + 1);
  for (std::int64_t v = 0; v < num_nodes && max_rank > 0; ++v) {
    clique[0] = v;
    candidates[0].assign(g.neighbors.begin() + g.offsets[static_cast<std::size_t>(v)],
                         g.neighbors.begin() + g.offsets[static_cast<std::size_t>(v) + 1]);
    int d = 0;
    pos[0] = 0;
    while (d >= 0) {
      auto& cand = candidates[static_cast<std::size_t>(d)];
      if (pos[static_cast<std::size_t>(d)] == cand.size()) {
        --d;
        continue;
      }
      const std::int64_t u = cand[pos[static_cast<std::size_t>(d)]++];
      clique[static_cast<std::size_t>(d) + 1] = u;
      emit(d + 1);
      if (d + 1 < max_rank) {
        auto& next = candidates[static_cast<std::size_t>(d) + 1];
        // Candidates after u in cand (all > u) that are forward neighbours of u: a merge of two
        // sorted lists into a buffer sized once (no push_back checks).
        const std::int64_t* x = cand.data() + pos[static_cast<std::size_t>(d)];
        const std::int64_t* xe = cand.data() + cand.size();
        const std::int64_t* y = g.neighbors.data() + g.offsets[static_cast<std::size_t>(u)];
        const std::int64_t* ye = g.neighbors.data() + g.offsets[static_cast<std::size_t>(u) + 1];
        next.resize(static_cast<std::size_t>(std::min(xe - x, ye - y)));
        std::int64_t* out = next.data();
        while (x != xe && y != ye) {
          if (*x < *y)
            ++x;
          else if (*y < *x)
            ++y;
          else
            *out++ = *x++, ++y;
        }
        next.resize(static_cast<std::size_t>(out - next.data()));
        if (!next.empty()) {
          ++d;
          pos[static_cast<std::size_t>(d)] = 0;
        }
      }
    }
  }
  return SimplicialComplex::from_canonical_trusted(num_nodes, std::move(flat));
}

/// The simplicial complex of a triangle mesh (its faces and all their edges and vertices).
inline SimplicialComplex simplicial_complex_from_mesh(const TriangleMesh& mesh) {
  mesh.validate();
  return SimplicialComplex::from_flat(mesh.faces.data(), static_cast<std::size_t>(mesh.num_faces()),
                                      3, mesh.num_vertices());
}

/// Every simplex of rank >= 1 as a hyperedge (rank by rank, id order), nodes kept.
inline Hypergraph to_hypergraph(const SimplicialComplex& sc) {
  Hypergraph h(sc.num_nodes());
  for (int k = 1; k <= sc.dim(); ++k)
    for (std::int64_t i = 0; i < sc.num_cells(k); ++i) h.add_hyperedge(sc.simplex(k, i));
  return h;
}

/// The simplices as cells of a combinatorial complex (rank = dimension, same ids, orientation =
/// sorted nodes, so its signed_incidence_matrix equals the simplicial incidence).
inline CombinatorialComplex<> to_combinatorial_complex(const SimplicialComplex& sc) {
  CombinatorialComplex<> cc(sc.num_nodes());
  for (int k = 1; k <= sc.dim(); ++k) {
    cc.reserve(k, static_cast<std::size_t>(sc.num_cells(k)),
               static_cast<std::size_t>(sc.num_cells(k) * (k + 1)));
    cc.add_cells_trusted(sc.num_cells(k) ? sc.data(k, 0) : nullptr,
                         static_cast<std::size_t>(sc.num_cells(k)), static_cast<std::size_t>(k) + 1,
                         k);
  }
  return cc;
}

/// Nodes, edges and triangles of a simplicial complex as a cell complex (same ids per rank).
inline CellComplex to_cell_complex(const SimplicialComplex& sc) {
  std::vector<CellComplex::Edge> edges;
  for (std::int64_t e = 0; e < sc.num_cells(1); ++e)
    edges.push_back({sc.data(1, e)[0], sc.data(1, e)[1]});
  std::vector<std::vector<std::int64_t>> cells;
  for (std::int64_t t = 0; t < sc.num_cells(2); ++t) cells.push_back(sc.simplex(2, t));
  return CellComplex::from_ordered(sc.num_nodes(), edges, cells);
}

/// One hyperedge per node v: {v} and its neighbours (closed neighbourhood), in node order.
inline Hypergraph neighborhood_hypergraph(std::int64_t num_nodes,
                                          const std::vector<std::array<std::int64_t, 2>>& edges) {
  const detail::GraphCsr g = detail::graph_csr(num_nodes, edges, false);
  Hypergraph h(num_nodes);
  for (std::int64_t v = 0; v < num_nodes; ++v) {
    std::vector<std::int64_t> e(g.neighbors.begin() + g.offsets[static_cast<std::size_t>(v)],
                                g.neighbors.begin() + g.offsets[static_cast<std::size_t>(v) + 1]);
    e.push_back(v);
    h.add_hyperedge(e);
  }
  return h;
}

// ----- TopoBench's graph liftings -------------------------------------------------------------

/// TopoBench's SimplicialCliqueLifting: the graph's nodes and edges (TopoNetX's
/// SimplicialComplex(graph)) plus every subset of 3..complex_dim + 1 nodes of every maximal
/// clique (nx.find_cliques). A subset of a clique is a clique and every clique lies in a maximal
/// one, so this is the clique complex truncated at rank max(complex_dim, 1): complex_dim 3
/// (TopoBench's default) gives triangles and tetrahedra. Isolated nodes are nodes of the
/// complex; the order is lexicographic, TopoNetX's skeleton order.
inline SimplicialComplex clique_lifting(std::int64_t num_nodes,
                                        const std::vector<std::array<std::int64_t, 2>>& edges,
                                        int complex_dim = 3) {
  if (complex_dim < 0)
    throw ComplexError("clique_lifting: complex_dim " + std::to_string(complex_dim) +
                       " must be >= 0");
  return clique_complex(num_nodes, edges, std::max(complex_dim, 1));
}

namespace detail {
// networkx >= 3.2's cycle_basis (networkx/algorithms/cycles.py) on a graph whose adjacency lists
// are ascending (g: graph_csr(..., false)). networkx keeps, per discovered node x, a set used[x]
// = {the node that discovered x} + {every node z that closed a cycle through the edge z-x}; here
// used[x] is one flag per adjacency slot of x, so "y in used[x]" is a binary search in x's list.
inline std::vector<std::vector<std::int64_t>> cycle_basis(std::int64_t n, const GraphCsr& g) {
  const auto slot = [&](std::int64_t x, std::int64_t y) -> std::int64_t {
    const auto b = g.neighbors.begin() + g.offsets[static_cast<std::size_t>(x)],
               e = g.neighbors.begin() + g.offsets[static_cast<std::size_t>(x) + 1];
    const auto it = std::lower_bound(b, e, y);
    return it != e && *it == y ? it - g.neighbors.begin() : -1;
  };
  std::vector<char> used(g.neighbors.size(), 0), discovered(static_cast<std::size_t>(n), 0);
  std::vector<std::int64_t> pred(static_cast<std::size_t>(n), -1), stack;
  std::vector<std::vector<std::int64_t>> cycles;
  // Roots: gnodes = dict.fromkeys(G); root = gnodes.popitem()[0] takes the last node still in
  // the dict, i.e. the highest unvisited id (networkx 3.0 and 3.1 popped a set instead).
  for (std::int64_t root = n - 1; root >= 0; --root) {
    if (discovered[static_cast<std::size_t>(root)]) continue;
    discovered[static_cast<std::size_t>(root)] = 1;
    pred[static_cast<std::size_t>(root)] = root;
    stack.assign(1, root);
    while (!stack.empty()) {
      const std::int64_t z = stack.back();  // last in, first out
      stack.pop_back();
      for (std::int64_t k = g.offsets[static_cast<std::size_t>(z)];
           k < g.offsets[static_cast<std::size_t>(z) + 1]; ++k) {
        const std::int64_t nbr = g.neighbors[static_cast<std::size_t>(k)];
        if (!discovered[static_cast<std::size_t>(nbr)]) {  // new node: used[nbr] = {z}
          discovered[static_cast<std::size_t>(nbr)] = 1;
          pred[static_cast<std::size_t>(nbr)] = z;
          stack.push_back(nbr);
          used[static_cast<std::size_t>(slot(nbr, z))] = 1;
        } else if (!used[static_cast<std::size_t>(k)]) {  // nbr not in used[z]: a cycle
          std::vector<std::int64_t> cycle{nbr, z};
          std::int64_t p = pred[static_cast<std::size_t>(z)];
          for (;;) {  // up the tree from z until a node in used[nbr]
            const std::int64_t s = slot(nbr, p);
            if (s >= 0 && used[static_cast<std::size_t>(s)]) break;
            cycle.push_back(p);
            if (p == pred[static_cast<std::size_t>(p)])  // the root, yet not in used[nbr]
              throw std::logic_error("cycle_basis: the tree walk from node " + std::to_string(z) +
                                     " missed node " + std::to_string(nbr));
            p = pred[static_cast<std::size_t>(p)];
          }
          cycle.push_back(p);
          cycles.push_back(std::move(cycle));
          used[static_cast<std::size_t>(slot(nbr, z))] = 1;
        }
      }
    }
  }
  return cycles;
}
}  // namespace detail

/// networkx's cycle_basis(G) (Paton's algorithm, networkx >= 3.2) for the graph TopoBench builds:
/// nodes 0..n-1 inserted in order, adjacency in ascending node order (PyG's coalesced, symmetric
/// edge_index). Roots are taken from the highest unvisited node down; each cycle is listed as
/// networkx does, [nbr, z, pred(z), ..., p], closed by p -> nbr. Edges may come in any order and
/// orientation, repeats count once; self-loops are rejected (PyG's TU loader removes them).
inline std::vector<std::vector<std::int64_t>> cycle_basis(
    std::int64_t num_nodes, const std::vector<std::array<std::int64_t, 2>>& edges) {
  return detail::cycle_basis(num_nodes, detail::graph_csr(num_nodes, edges, false));
}

/// TopoBench's CellCycleLifting: nodes and edges of the graph plus, as 2-cells, the cycles of
/// cycle_basis with at most max_cell_length nodes (a negative value keeps every cycle:
/// TopoBench's None), in basis order, each oriented as networkx lists it. Cell order is
/// TopoNetX's (edges sorted low -> high), as TopoBench's CellComplex(G) indexes them.
inline CellComplex cycle_lifting(std::int64_t num_nodes,
                                 const std::vector<std::array<std::int64_t, 2>>& edges,
                                 int max_cell_length = 10) {
  const detail::GraphCsr g = detail::graph_csr(num_nodes, edges, false);
  CellComplex cx(num_nodes);
  for (std::int64_t u = 0; u < num_nodes; ++u)
    for (std::int64_t k = g.offsets[static_cast<std::size_t>(u)];
         k < g.offsets[static_cast<std::size_t>(u) + 1]; ++k)
      if (g.neighbors[static_cast<std::size_t>(k)] > u)
        cx.add_edge(u, g.neighbors[static_cast<std::size_t>(k)]);
  for (const auto& c : detail::cycle_basis(num_nodes, g))
    if (max_cell_length < 0 || c.size() <= static_cast<std::size_t>(max_cell_length))
      cx.add_cell(c);
  return cx;
}

/// TopoBench's HypergraphKHopLifting: hyperedge v (v = 0..n-1, one per node, repeats kept) holds
/// v and every node within k hops of it (torch_geometric's k_hop_subgraph on the symmetrised
/// edge_index); an isolated node's hyperedge is {v}. k = 1 is neighborhood_hypergraph.
inline Hypergraph khop_lifting(std::int64_t num_nodes,
                               const std::vector<std::array<std::int64_t, 2>>& edges, int k = 1) {
  if (k < 0) throw ComplexError("khop_lifting: k " + std::to_string(k) + " must be >= 0");
  const detail::GraphCsr g = detail::graph_csr(num_nodes, edges, false);
  Hypergraph h(num_nodes);
  std::vector<std::int64_t> mark(static_cast<std::size_t>(num_nodes), -1), ball;
  for (std::int64_t v = 0; v < num_nodes; ++v) {
    ball.assign(1, v);
    mark[static_cast<std::size_t>(v)] = v;
    std::size_t frontier = 0;  // ball[frontier..] were reached at the last hop
    for (int hop = 0; hop < k && frontier < ball.size(); ++hop) {
      const std::size_t end = ball.size();
      for (std::size_t i = frontier; i < end; ++i) {
        const std::int64_t u = ball[i];
        for (std::int64_t s = g.offsets[static_cast<std::size_t>(u)];
             s < g.offsets[static_cast<std::size_t>(u) + 1]; ++s) {
          const std::int64_t w = g.neighbors[static_cast<std::size_t>(s)];
          if (mark[static_cast<std::size_t>(w)] != v) {
            mark[static_cast<std::size_t>(w)] = v;
            ball.push_back(w);
          }
        }
      }
      frontier = end;
    }
    h.add_hyperedge(ball);
  }
  return h;
}

}  // namespace topos
