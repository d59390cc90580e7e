// topos/models/topobench/lifting.hpp
// A graph lifted as TopoBench lifts it for one model domain (std here; lifting-inl.hpp, compiled
// in topos::topobench, + Eigen; no LibTorch): the
// lifting (graph -> hypergraph by 1-hop neighbourhoods, -> cell complex by the cycle basis, ->
// simplicial complex by cliques), the features of every rank (TopoBench's ProjectionSum:
// x_r = |B_r|ᵀ x_{r-1}, or the graph's edge labels one-hot as x_1 where TopoBench keeps edge
// attributes), and the named neighbourhood matrices its wrappers hand to the backbones, each as
// row-major triplets ready to be stacked block-diagonally into a batch (topobench/batch.hpp).
//
// Operator names (all float32 values, rows = target cells, columns = source cells):
//   graph       gcn_adjacency            D̂^-1/2 (A + I) D̂^-1/2 (PyG's GCNConv normalisation)
//   hypergraph  incidence_1              H, nodes × hyperedges (1 where node ∈ hyperedge)
//               incidence_1_norm         D_v^-1/2 H D_e^-1/2, d_e the mean degree of e's nodes
//               node_degree              diag(d_v)
//   cell        incidence_1, incidence_2 |B_1|, |B_2| (TopoBench's cell operators are unsigned)
//               incidence_1_t, incidence_2_t   their transposes
//               adjacency_0, adjacency_1 |B_1||B_1|ᵀ and |B_2||B_2|ᵀ off the diagonal
//               down_laplacian_1         |B_1ᵀ B_1|,  up_laplacian_1  |B_2 B_2ᵀ| (signed inside)
//               down_laplacian_1_gcn, up_laplacian_1_gcn   D^-1/2 M D^-1/2, D the row sums of M
//                                        (PyG's GCNConv given a weighted matrix, no self-loops)
//   simplicial  incidence_1, incidence_2 B_1, B_2 (signed, or |B| when not `signed_incidence`)
//               hodge_laplacian_r (r = 0..2), down_laplacian_r (1, 2), up_laplacian_r (1, 2)
//               hodge_laplacian_r_norm   D^-1/2 L_r D^-1/2, D the row sums of |L_r| (SCN)
//   cell and simplicial: TopoTune's neighbourhoods (up_adjacency-1, down_incidence-2,
//               2-up_adjacency-0, ...: topobench/routes.hpp), patterns with every value 1, for
//               ranks up to `max_rank`
//
// The rank-1 Laplacians pair every two edges that share a node: Σ_v deg(v)² entries, 372 million
// over REDDIT-BINARY. Named in `GraphLiftingOptions::factored`, they are kept as their factors
// instead (FactoredTriplets; cell: down_laplacian_1 = |B_1|ᵀ|B_1|, and its _gcn form; simplicial,
// signed: down_laplacian_1 = B_1ᵀB_1, hodge_laplacian_1 = B_1ᵀB_1 + B_2B_2ᵀ, and its _norm form,
// whose D is summed row by row without forming L_1): the same operator, four entries per edge.
#pragma once

#include "topos/config.hpp"
#include "topos/models/topobench/routes.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <functional>
#include <map>
#include <set>
#include <stdexcept>
#include <string>
#include <vector>

namespace topos::models::topobench {

enum class Domain { graph, hypergraph, cell, simplicial };

inline const char* domain_name(Domain d) {
  switch (d) {
    case Domain::graph:
      return "graph";
    case Domain::hypergraph:
      return "hypergraph";
    case Domain::cell:
      return "cell";
    case Domain::simplicial:
      return "simplicial";
  }
  return "?";
}

/// How TopoBench lifts a graph: the clique, cycle and k-hop liftings' parameters, the features
/// kept and the operators built.
struct GraphLiftingOptions {
  int complex_dim = 3;           ///< clique lifting: simplices of up to complex_dim + 1 nodes
  bool signed_incidence = true;  ///< simplicial operators signed (TopoBench's rows set it)
  int max_cell_length = 10;      ///< cycle lifting: longer basis cycles are no 2-cells
  int khop = 1;                  ///< hypergraph: k of the k-hop neighbourhoods
  bool edge_features = false;    ///< x_1 = the edge labels one-hot (cell and simplicial)
  std::int64_t num_edge_labels = 0;
  int max_rank = 2;  ///< ranks whose features and sizes are kept (cell, simplicial)
  /// The operators to build (names above); empty: every one of the domain. A model needs few,
  /// and some are large: REDDIT-BINARY's rank-1 down Laplacian has Σ_v deg(v)² entries.
  std::set<std::string> operators;
  /// Of the operators, those kept as factors (see above; others cannot be and are an error).
  std::set<std::string> factored;
};

/// Deprecated: the earlier name, which HOPNet's scene lifting used too.
using LiftingOptions = GraphLiftingOptions;

/// The rank-1 operators lift_graph can keep as factors in `domain`.
inline std::set<std::string> factorable_operators(Domain domain, bool signed_incidence = true) {
  if (domain == Domain::cell) return {"down_laplacian_1", "down_laplacian_1_gcn"};
  if (domain == Domain::simplicial && signed_incidence)
    return {"down_laplacian_1", "hodge_laplacian_1", "hodge_laplacian_1_norm"};
  return {};
}

/// A sparse matrix as row-major sorted triplets (no duplicates), float values.
struct Triplets {
  std::int64_t rows = 0, cols = 0;
  std::vector<std::int64_t> row, col;
  std::vector<float> value;
  std::int64_t nnz() const { return static_cast<std::int64_t>(row.size()); }
};

/// An operator kept as its factors: diag(left) · Σ_k products[k][0] · products[k][1] ⋯ ·
/// diag(right) (left, right empty: no scale); nn::SparseOperator::product_sum once batched.
struct FactoredTriplets {
  std::int64_t rows = 0, cols = 0;
  std::vector<std::vector<Triplets>> products;
  std::vector<float> left, right;
};

/// One lifted graph: cells per rank, features per rank (row-major, `widths[r]` columns), the
/// named operators (explicit, or factored) and the graph's class.
struct LiftedGraph {
  std::vector<std::int64_t> sizes, widths;
  std::vector<std::vector<float>> x;
  std::map<std::string, Triplets> operators;
  std::map<std::string, FactoredTriplets> factored;
  std::int64_t label = 0;
};

/// Lifts one graph (nodes 0..n-1, undirected edges u < v, unique) with node features `x`
/// (row-major, `num_features` columns) and optional per-edge labels (aligned with `edges`).
LiftedGraph lift_graph(std::int64_t num_nodes,
                       const std::vector<std::array<std::int64_t, 2>>& edges,
                       const std::vector<float>& x, std::int64_t num_features,
                       const std::vector<std::int64_t>& edge_labels, Domain domain,
                       const GraphLiftingOptions& o);

}  // namespace topos::models::topobench

#ifdef TOPOS_HEADER_ONLY
#include "topos/models/topobench/lifting-inl.hpp"
#endif
