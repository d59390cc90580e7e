// topos/geometry/graph.hpp
// Boost.Graph views of a combinatorial complex: RankGraph exposes the adjacency of one rank
// (cells of rank r sharing a cell of rank `via`) as a BGL graph through graph_traits, so BFS,
// shortest paths and connected components work on it directly. Also: splitting a triangle soup
// into its connected objects.
#pragma once

#include "topos/core/combinatorial_complex.hpp"
#include "topos/core/mesh_lifting.hpp"
#include "topos/mesh/triangle_mesh.hpp"

#include <boost/graph/connected_components.hpp>
#include <boost/graph/graph_traits.hpp>
#include <boost/graph/properties.hpp>
#include <boost/iterator/counting_iterator.hpp>
#include <boost/iterator/iterator_facade.hpp>
#include <boost/property_map/property_map.hpp>

#include <cstdint>
#include <map>
#include <vector>

namespace topos {

/// Cells of one rank as vertices, (co)adjacency through another rank as edges (both directions).
class RankGraph {
 public:
  using Vertex = std::int64_t;
  struct Edge {
    Vertex source;
    std::int64_t slot;  // position in the CSR neighbor array
    friend bool operator==(const Edge& a, const Edge& b) {
      return a.source == b.source && a.slot == b.slot;
    }
    friend bool operator!=(const Edge& a, const Edge& b) { return !(a == b); }
  };

  RankGraph() = default;

  /// Adjacency of rank r through rank `via` (via > r: shared upper cells; via < r: shared lower
  /// cells).
  template <class Options>
  RankGraph(const CombinatorialComplex<Options>& cc, int r, int via) : rank_(r) {
    const auto m = via > r ? cc.adjacency_matrix(r, via) : cc.coadjacency_matrix(r, via);
    offsets_.assign(m.outerIndexPtr(), m.outerIndexPtr() + m.outerSize() + 1);
    neighbors_.assign(m.innerIndexPtr(), m.innerIndexPtr() + m.nonZeros());
  }

  int rank() const { return rank_; }
  std::int64_t num_vertices() const { return static_cast<std::int64_t>(offsets_.size()) - 1; }
  std::int64_t num_directed_edges() const { return static_cast<std::int64_t>(neighbors_.size()); }
  const std::int64_t* neighbors_begin(Vertex v) const {
    return neighbors_.data() + offsets_[static_cast<std::size_t>(v)];
  }
  const std::int64_t* neighbors_end(Vertex v) const {
    return neighbors_.data() + offsets_[static_cast<std::size_t>(v) + 1];
  }
  std::int64_t slot_begin(Vertex v) const { return offsets_[static_cast<std::size_t>(v)]; }
  std::int64_t slot_end(Vertex v) const { return offsets_[static_cast<std::size_t>(v) + 1]; }
  Vertex neighbor_at(std::int64_t slot) const { return neighbors_[static_cast<std::size_t>(slot)]; }

 private:
  int rank_ = 0;
  std::vector<std::int64_t> offsets_{0};
  std::vector<std::int64_t> neighbors_;
};

class RankGraphOutEdgeIterator
    : public boost::iterator_facade<RankGraphOutEdgeIterator, RankGraph::Edge,
                                    boost::random_access_traversal_tag, RankGraph::Edge> {
 public:
  RankGraphOutEdgeIterator() = default;
  RankGraphOutEdgeIterator(RankGraph::Vertex s, std::int64_t slot) : s_(s), slot_(slot) {}

 private:
  friend class boost::iterator_core_access;
  RankGraph::Edge dereference() const { return {s_, slot_}; }
  bool equal(const RankGraphOutEdgeIterator& o) const { return slot_ == o.slot_; }
  void increment() { ++slot_; }
  void decrement() { --slot_; }
  void advance(std::ptrdiff_t n) { slot_ += n; }
  std::ptrdiff_t distance_to(const RankGraphOutEdgeIterator& o) const { return o.slot_ - slot_; }
  RankGraph::Vertex s_ = 0;
  std::int64_t slot_ = 0;
};

struct RankGraphTraversalCategory : boost::incidence_graph_tag,
                                    boost::adjacency_graph_tag,
                                    boost::vertex_list_graph_tag {};

}  // namespace topos

namespace boost {

template <>
struct graph_traits<topos::RankGraph> {
  using vertex_descriptor = topos::RankGraph::Vertex;
  using edge_descriptor = topos::RankGraph::Edge;
  using directed_category = directed_tag;  // both directions are stored
  using edge_parallel_category = disallow_parallel_edge_tag;
  using traversal_category = topos::RankGraphTraversalCategory;
  using out_edge_iterator = topos::RankGraphOutEdgeIterator;
  using adjacency_iterator = const std::int64_t*;
  using vertex_iterator = boost::counting_iterator<std::int64_t>;
  using vertices_size_type = std::int64_t;
  using edges_size_type = std::int64_t;
  using degree_size_type = std::int64_t;
  using in_edge_iterator = void;
  using edge_iterator = void;
  static vertex_descriptor null_vertex() { return -1; }
};

template <>
struct property_map<topos::RankGraph, vertex_index_t> {
  using type = typed_identity_property_map<std::int64_t>;
  using const_type = type;
};

}  // namespace boost

namespace topos {

// BGL free functions, found by argument-dependent lookup.
inline std::pair<boost::counting_iterator<std::int64_t>, boost::counting_iterator<std::int64_t>>
vertices(const RankGraph& g) {
  return {boost::counting_iterator<std::int64_t>(0),
          boost::counting_iterator<std::int64_t>(g.num_vertices())};
}
inline std::int64_t num_vertices(const RankGraph& g) {
  return g.num_vertices();
}
inline std::pair<RankGraphOutEdgeIterator, RankGraphOutEdgeIterator> out_edges(RankGraph::Vertex v,
                                                                               const RankGraph& g) {
  return {RankGraphOutEdgeIterator(v, g.slot_begin(v)), RankGraphOutEdgeIterator(v, g.slot_end(v))};
}
inline std::int64_t out_degree(RankGraph::Vertex v, const RankGraph& g) {
  return g.slot_end(v) - g.slot_begin(v);
}
inline RankGraph::Vertex source(const RankGraph::Edge& e, const RankGraph&) {
  return e.source;
}
inline RankGraph::Vertex target(const RankGraph::Edge& e, const RankGraph& g) {
  return g.neighbor_at(e.slot);
}
inline std::pair<const std::int64_t*, const std::int64_t*> adjacent_vertices(RankGraph::Vertex v,
                                                                             const RankGraph& g) {
  return {g.neighbors_begin(v), g.neighbors_end(v)};
}
inline boost::typed_identity_property_map<std::int64_t> get(boost::vertex_index_t,
                                                            const RankGraph&) {
  return {};
}

/// Connected components of the cells of rank r through rank `via`; returns (count, label per cell).
template <class Options>
std::pair<int, std::vector<int>> connected_components(const CombinatorialComplex<Options>& cc,
                                                      int r, int via) {
  const RankGraph g(cc, r, via);
  std::vector<int> label(static_cast<std::size_t>(g.num_vertices()));
  const int n = boost::connected_components(g, label.data());
  return {n, std::move(label)};
}

/// Splits a triangle soup into its edge-connected parts, in order of each part's first face;
/// vertices keep their relative order and unreferenced vertices are dropped.
inline std::vector<TriangleMesh> split_connected(const TriangleMesh& soup) {
  auto lifted = lift_meshes(std::vector<TriangleMesh>{soup},
                            LiftOptions().with_faces(false).with_object_rank(0));
  auto [count, label] = connected_components(lifted.complex, 0, 1);
  std::map<int, int> part_of_label;  // label -> part index in order of first face
  for (Eigen::Index f = 0; f < soup.faces.rows(); ++f) {
    part_of_label.emplace(label[static_cast<std::size_t>(soup.faces(f, 0))],
                          static_cast<int>(part_of_label.size()));
  }
  std::vector<TriangleMesh> parts(part_of_label.size());
  std::vector<std::int64_t> local(static_cast<std::size_t>(soup.vertices.rows()), -1);
  std::vector<std::vector<std::int64_t>> verts(parts.size());
  for (Eigen::Index v = 0; v < soup.vertices.rows(); ++v) {
    auto it = part_of_label.find(label[static_cast<std::size_t>(v)]);
    if (it == part_of_label.end()) continue;  // isolated vertex
    local[static_cast<std::size_t>(v)] =
        static_cast<std::int64_t>(verts[static_cast<std::size_t>(it->second)].size());
    verts[static_cast<std::size_t>(it->second)].push_back(v);
  }
  std::vector<std::vector<std::int64_t>> faces(parts.size());
  for (Eigen::Index f = 0; f < soup.faces.rows(); ++f)
    faces[static_cast<std::size_t>(
              part_of_label[label[static_cast<std::size_t>(soup.faces(f, 0))]])]
        .push_back(f);
  for (std::size_t p = 0; p < parts.size(); ++p) {
    parts[p].name = soup.name + "#" + std::to_string(p);
    parts[p].vertices.resize(static_cast<Eigen::Index>(verts[p].size()), 3);
    for (std::size_t k = 0; k < verts[p].size(); ++k)
      parts[p].vertices.row(static_cast<Eigen::Index>(k)) = soup.vertices.row(verts[p][k]);
    parts[p].faces.resize(static_cast<Eigen::Index>(faces[p].size()), 3);
    for (std::size_t k = 0; k < faces[p].size(); ++k)
      for (int c = 0; c < 3; ++c)
        parts[p].faces(static_cast<Eigen::Index>(k), c) =
            local[static_cast<std::size_t>(soup.faces(faces[p][k], c))];
  }
  return parts;
}

}  // namespace topos
