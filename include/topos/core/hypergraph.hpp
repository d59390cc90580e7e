// topos/core/hypergraph.hpp
// A hypergraph: nodes 0..n-1 (rank 0) and hyperedges (rank 1), each a non-empty set of distinct
// nodes, with optional positive weights. Hyperedges keep their insertion order (column order of
// the incidence) and may repeat a node set (separate columns). Views both ways: the node x
// hyperedge 0/1 incidence matrix, and a hypergraph from any incidence matrix (nonzero =
// membership). Operators are the combinatorial ones of the domain concept (counts of shared
// cells, TopoNetX's incidence_to_adjacency). Std + Eigen only.
#pragma once

#include "topos/core/operators.hpp"
#include "topos/core/sparse_matrix.hpp"

#include <algorithm>
#include <cstdint>
#include <sstream>
#include <string>
#include <vector>

namespace topos {

class Hypergraph {
 public:
  using Index = std::int64_t;

  Hypergraph() = default;
  explicit Hypergraph(Index num_nodes) {
    if (num_nodes < 0)
      throw ComplexError("Hypergraph: negative node count " + std::to_string(num_nodes));
    num_nodes_ = num_nodes;
  }

  /// The hypergraph whose hyperedge j holds the rows i with b(i, j) != 0 (node x hyperedge).
  static Hypergraph from_incidence_matrix(const SparseMatrix& b) {
    Hypergraph h(b.rows());
    const SparseMatrix bt = sparse::pruned(sparse::transpose(b));
    for (Eigen::Index j = 0; j < bt.outerSize(); ++j) {
      std::vector<Index> e;
      for (SparseMatrix::InnerIterator it(bt, j); it; ++it) e.push_back(it.col());
      if (e.empty())
        throw ComplexError("Hypergraph::from_incidence_matrix: column " + std::to_string(j) +
                           " is empty (an empty hyperedge)");
      h.add_hyperedge(e);
    }
    return h;
  }

  Index add_nodes(Index n) {
    if (n < 0) throw ComplexError("Hypergraph::add_nodes: negative count " + std::to_string(n));
    const Index first = num_nodes_;
    num_nodes_ += n;
    return first;
  }
  /// Adds a hyperedge; returns its id.
  Index add_hyperedge(const std::vector<Index>& nodes, double weight = 1.0) {
    const std::string what = "Hypergraph::add_hyperedge: hyperedge " +
                             std::to_string(num_hyperedges()) + " " + describe(nodes);
    if (nodes.empty())
      throw ComplexError("Hypergraph::add_hyperedge: hyperedge " +
                         std::to_string(num_hyperedges()) + " is empty");
    std::vector<Index> s(nodes);
    std::sort(s.begin(), s.end());
    if (s.front() < 0 || s.back() >= num_nodes_) {
      const Index bad = s.front() < 0 ? s.front() : s.back();
      throw ComplexError(what + " uses node " + std::to_string(bad) +
                         ", which is not in the hypergraph (nodes 0.." +
                         std::to_string(num_nodes_ - 1) + ")");
    }
    if (auto it = std::adjacent_find(s.begin(), s.end()); it != s.end())
      throw ComplexError(what + " repeats node " + std::to_string(*it));
    if (!(weight > 0.0))
      throw ComplexError(what + " has weight " + std::to_string(weight) +
                         "; weights must be positive");
    nodes_.insert(nodes_.end(), s.begin(), s.end());
    offsets_.push_back(static_cast<Index>(nodes_.size()));
    weights_.push_back(weight);
    return num_hyperedges() - 1;
  }

  Index num_nodes() const { return num_nodes_; }
  Index num_hyperedges() const { return static_cast<Index>(offsets_.size()) - 1; }
  /// 1 with hyperedges, 0 with nodes only, -1 when empty.
  int dim() const { return num_hyperedges() > 0 ? 1 : num_nodes_ > 0 ? 0 : -1; }
  Index num_cells(int rank) const {
    return rank == 0 ? num_nodes_ : rank == 1 ? num_hyperedges() : 0;
  }
  std::vector<Index> shape() const { return {num_nodes_, num_hyperedges()}; }
  /// Sorted nodes of hyperedge `id`.
  std::vector<Index> hyperedge(Index id) const {
    if (id < 0 || id >= num_hyperedges())
      throw ComplexError("hyperedge: " + std::to_string(id) + " does not exist (" +
                         std::to_string(num_hyperedges()) + " hyperedges)");
    return {nodes_.begin() + offsets_[static_cast<std::size_t>(id)],
            nodes_.begin() + offsets_[static_cast<std::size_t>(id) + 1]};
  }
  double weight(Index id) const { return weights_.at(static_cast<std::size_t>(id)); }
  Eigen::VectorXd weights() const {
    return Eigen::Map<const Eigen::VectorXd>(weights_.data(),
                                             static_cast<Eigen::Index>(weights_.size()));
  }
  std::vector<std::vector<Index>> skeleton(int rank) const {
    std::vector<std::vector<Index>> out;
    if (rank == 0)
      for (Index v = 0; v < num_nodes_; ++v) out.push_back({v});
    else if (rank == 1)
      for (Index e = 0; e < num_hyperedges(); ++e) out.push_back(hyperedge(e));
    else
      throw ComplexError("skeleton: a hypergraph has ranks 0 and 1, got " + std::to_string(rank));
    return out;
  }
  /// Number of hyperedges holding each node.
  Eigen::VectorXd node_degrees() const { return sparse::row_sums(incidence_matrix(0, 1)); }
  /// Size of each hyperedge.
  Eigen::VectorXd hyperedge_sizes() const {
    Eigen::VectorXd s(num_hyperedges());
    for (Index e = 0; e < num_hyperedges(); ++e)
      s[e] = static_cast<double>(offsets_[static_cast<std::size_t>(e) + 1] -
                                 offsets_[static_cast<std::size_t>(e)]);
    return s;
  }

  /// incidence_matrix(0, 1): node x hyperedge, 1 per membership (times the hyperedge's weight
  /// when `weighted`); incidence_matrix(1, 0) is its transpose.
  SparseMatrix incidence_matrix(int rank, int to_rank, bool weighted = false) const {
    if (!((rank == 0 && to_rank == 1) || (rank == 1 && to_rank == 0))) {
      throw ComplexError(
          "incidence_matrix: a hypergraph has ranks 0 (nodes) and 1 (hyperedges), got " +
          std::to_string(rank) + " -> " + std::to_string(to_rank));
    }
    SparseMatrix et(num_hyperedges(), num_nodes_);
    for (Index e = 0; e < num_hyperedges(); ++e) {
      for (Index k = offsets_[static_cast<std::size_t>(e)];
           k < offsets_[static_cast<std::size_t>(e) + 1]; ++k)
        et.data().append(weighted ? weights_[static_cast<std::size_t>(e)] : 1.0,
                         static_cast<Eigen::Index>(nodes_[static_cast<std::size_t>(k)]));
      et.outerIndexPtr()[e + 1] = offsets_[static_cast<std::size_t>(e) + 1];
    }
    if (rank == 1) return et;
    return sparse::transpose(et);
  }
  /// Nodes sharing hyperedges (via_rank 1): entry = number of shared hyperedges.
  SparseMatrix adjacency_matrix(int rank, int via_rank = 1) const {
    if (rank != 0 || via_rank != 1)
      throw ComplexError(
          "adjacency_matrix: a hypergraph has node adjacency via hyperedges only (rank 0 via 1), "
          "got rank " +
          std::to_string(rank) + " via " + std::to_string(via_rank));
    return incidence_to_adjacency(incidence_matrix(1, 0));
  }
  /// Hyperedges sharing nodes (rank 1 via 0): entry = number of shared nodes.
  SparseMatrix coadjacency_matrix(int rank, int via_rank = 0) const {
    if (rank != 1 || via_rank != 0)
      throw ComplexError(
          "coadjacency_matrix: a hypergraph has hyperedge coadjacency via nodes only (rank 1 via "
          "0), got rank " +
          std::to_string(rank) + " via " + std::to_string(via_rank));
    return incidence_to_adjacency(incidence_matrix(0, 1));
  }
  /// The Domain concept's names of the three above (domain.hpp).
  SparseMatrix inclusion_matrix(int rank, int to_rank) const {
    return incidence_matrix(rank, to_rank);
  }
  SparseMatrix adjacency_matrix_via(int rank, int via_rank) const {
    return adjacency_matrix(rank, via_rank);
  }
  SparseMatrix coadjacency_matrix_via(int rank, int via_rank) const {
    return coadjacency_matrix(rank, via_rank);
  }

 private:
  Index num_nodes_ = 0;
  std::vector<Index> nodes_;
  std::vector<Index> offsets_{0};
  std::vector<double> weights_;

  static std::string describe(const std::vector<Index>& c) {
    std::ostringstream s;
    s << '[';
    for (std::size_t i = 0; i < c.size() && i < 10; ++i) s << (i ? ", " : "") << c[i];
    if (c.size() > 10) s << ", ...";
    s << ']';
    return s.str();
  }
};

}  // namespace topos
