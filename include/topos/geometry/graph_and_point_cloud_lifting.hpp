// topos/geometry/graph_and_point_cloud_lifting.hpp
// Liftings that need Boost.Graph or CGAL (the std + Eigen ones are in core/domain_lifting.hpp):
//   clique_complex(g, max_rank)          any undirected Boost.Graph graph (vertex_index map) ->
//                                        clique complex, lexicographic order (as core's)
//   cell_complex_from_cycle_basis(g)     graph -> cell complex: nodes and edges of g (TopoNetX
//                                        order: edges sorted, low -> high) plus one 2-cell per
//                                        fundamental cycle of a breadth-first spanning forest
//                                        (roots: the lowest unvisited vertex; cells in the order
//                                        of their non-tree edges (u, v), u < v, sorted), each
//                                        cycle running u -> ... -> v along the tree, closed by v ->
//                                          u
//   delaunay_complex(points)             2-D points (n x 2): the Delaunay triangulation's
//                                        triangles; 3-D points (n x 3): its tetrahedra; all faces
//                                        added, lexicographic order, nodes = point rows
//   alpha_complex(points, alpha2)        2-D or 3-D points: the alpha complex for squared radius
//                                        alpha2 (CGAL's Alpha_shape_2 / Alpha_shape_3 in GENERAL
//                                        mode: every Delaunay simplex whose alpha filtration value
//                                        is <= alpha2), all faces, lexicographic order, every
//                                        point a node
#pragma once

#include "topos/core/cell_complex.hpp"
#include "topos/core/domain_lifting.hpp"
#include "topos/core/simplicial_complex.hpp"

#include <CGAL/Alpha_shape_2.h>
#include <CGAL/Alpha_shape_3.h>
#include <CGAL/Alpha_shape_face_base_2.h>
#include <CGAL/Alpha_shape_vertex_base_2.h>
#include <CGAL/Alpha_shape_cell_base_3.h>
#include <CGAL/Alpha_shape_vertex_base_3.h>
#include <CGAL/Delaunay_triangulation_2.h>
#include <CGAL/Delaunay_triangulation_3.h>
#include <CGAL/Exact_predicates_inexact_constructions_kernel.h>
#include <CGAL/Triangulation_vertex_base_with_info_2.h>
#include <CGAL/Triangulation_vertex_base_with_info_3.h>
#include <boost/graph/graph_traits.hpp>
#include <boost/graph/properties.hpp>

#include <Eigen/Dense>

#include <algorithm>
#include <array>
#include <cstdint>
#include <queue>
#include <string>
#include <vector>

namespace topos {

namespace detail {
template <class Graph>
std::vector<std::array<std::int64_t, 2>> boost_edges(const Graph& g) {
  // Unqualified calls (the BGL idiom): argument-dependent lookup finds the graph's free
  // functions in its own namespace, boost's or another's (boost:: would exclude graphs adapted
  // elsewhere, as topos::RankGraph is).
  const auto index = get(boost::vertex_index, g);
  std::vector<std::array<std::int64_t, 2>> out;
  for (auto [it, end] = edges(g); it != end; ++it)
    out.push_back({static_cast<std::int64_t>(get(index, source(*it, g))),
                   static_cast<std::int64_t>(get(index, target(*it, g)))});
  return out;
}
// Inserts the rows of `points` (n x D) into a Delaunay triangulation whose vertices carry their
// row index; repeated points are an error (they would merge into one vertex).
template <int D, class Dt>
void insert_indexed_points(Dt& dt, const Eigen::MatrixXd& points, const char* who) {
  using Point = typename Dt::Point;
  std::vector<std::pair<Point, std::int64_t>> pts;
  pts.reserve(static_cast<std::size_t>(points.rows()));
  for (std::int64_t i = 0; i < points.rows(); ++i) {
    if constexpr (D == 2)
      pts.push_back({Point(points(i, 0), points(i, 1)), i});
    else
      pts.push_back({Point(points(i, 0), points(i, 1), points(i, 2)), i});
  }
  dt.insert(pts.begin(), pts.end());
  if (static_cast<std::int64_t>(dt.number_of_vertices()) != points.rows())
    throw ComplexError(std::string(who) + ": the points are not distinct");
}
}  // namespace detail

/// The clique complex of an undirected Boost.Graph graph (nodes = vertex indices).
template <class Graph>
SimplicialComplex clique_complex(const Graph& g, int max_rank) {
  return clique_complex(static_cast<std::int64_t>(num_vertices(g)), detail::boost_edges(g),
                        max_rank);
}

/// The graph's nodes and edges plus one 2-cell per fundamental cycle of a BFS spanning forest.
template <class Graph>
CellComplex cell_complex_from_cycle_basis(const Graph& g) {
  const std::int64_t n = static_cast<std::int64_t>(num_vertices(g));
  auto edges = detail::boost_edges(g);
  for (auto& e : edges)
    if (e[0] > e[1]) std::swap(e[0], e[1]);
  std::sort(edges.begin(), edges.end());
  edges.erase(std::unique(edges.begin(), edges.end()), edges.end());
  const detail::GraphCsr adj = detail::graph_csr(n, edges, false);  // rejects self-loops
  std::vector<std::int64_t> parent(static_cast<std::size_t>(n), -2),
      depth(static_cast<std::size_t>(n), 0);
  for (std::int64_t root = 0; root < n; ++root) {
    if (parent[static_cast<std::size_t>(root)] != -2) continue;
    parent[static_cast<std::size_t>(root)] = -1;
    std::queue<std::int64_t> q;
    q.push(root);
    while (!q.empty()) {
      const std::int64_t u = q.front();
      q.pop();
      for (std::int64_t k = adj.offsets[static_cast<std::size_t>(u)];
           k < adj.offsets[static_cast<std::size_t>(u) + 1]; ++k) {
        const std::int64_t v = adj.neighbors[static_cast<std::size_t>(k)];
        if (parent[static_cast<std::size_t>(v)] != -2) continue;
        parent[static_cast<std::size_t>(v)] = u;
        depth[static_cast<std::size_t>(v)] = depth[static_cast<std::size_t>(u)] + 1;
        q.push(v);
      }
    }
  }
  CellComplex cx(n);
  for (const auto& e : edges) cx.add_edge(e[0], e[1]);
  for (const auto& e : edges) {
    const std::int64_t u = e[0], v = e[1];
    if (parent[static_cast<std::size_t>(v)] == u || parent[static_cast<std::size_t>(u)] == v)
      continue;  // tree edge
    // Walk both ends up to their lowest common ancestor.
    std::vector<std::int64_t> up_u{u}, up_v{v};
    std::int64_t a = u, b = v;
    while (a != b) {
      if (depth[static_cast<std::size_t>(a)] >= depth[static_cast<std::size_t>(b)])
        up_u.push_back(a = parent[static_cast<std::size_t>(a)]);
      else
        up_v.push_back(b = parent[static_cast<std::size_t>(b)]);
    }
    up_v.pop_back();  // the common ancestor is the last of up_u
    std::vector<std::int64_t> cycle(up_u);
    cycle.insert(cycle.end(), up_v.rbegin(), up_v.rend());  // u .. lca .. v, closed by v -> u
    cx.add_cell(cycle);
  }
  return cx;
}

/// The Delaunay triangulation of 2-D (n x 2) or 3-D (n x 3) points as a simplicial complex.
inline SimplicialComplex delaunay_complex(const Eigen::MatrixXd& points) {
  using K = CGAL::Exact_predicates_inexact_constructions_kernel;
  const std::int64_t n = points.rows();
  std::vector<std::int64_t> flat;
  if (points.cols() == 2) {
    using Vb = CGAL::Triangulation_vertex_base_with_info_2<std::int64_t, K>;
    using Tds = CGAL::Triangulation_data_structure_2<Vb>;
    CGAL::Delaunay_triangulation_2<K, Tds> dt;
    detail::insert_indexed_points<2>(dt, points, "delaunay_complex");
    for (auto f = dt.finite_faces_begin(); f != dt.finite_faces_end(); ++f)
      for (int k = 0; k < 3; ++k) flat.push_back(f->vertex(k)->info());
    if (flat.empty()) {  // collinear: the triangulation's edges
      for (auto e = dt.finite_edges_begin(); e != dt.finite_edges_end(); ++e)
        flat.insert(flat.end(), {e->first->vertex((e->second + 1) % 3)->info(),
                                 e->first->vertex((e->second + 2) % 3)->info()});
      return SimplicialComplex::from_flat(flat.data(), flat.size() / 2, 2, n);
    }
    return SimplicialComplex::from_flat(flat.data(), flat.size() / 3, 3, n);
  }
  if (points.cols() == 3) {
    using Vb = CGAL::Triangulation_vertex_base_with_info_3<std::int64_t, K>;
    using Tds = CGAL::Triangulation_data_structure_3<Vb>;
    CGAL::Delaunay_triangulation_3<K, Tds> dt;
    detail::insert_indexed_points<3>(dt, points, "delaunay_complex");
    if (dt.dimension() < 3)
      throw ComplexError("delaunay_complex: the 3-D points are coplanar (dimension " +
                         std::to_string(dt.dimension()) + "); pass them as 2-D");
    for (auto c = dt.finite_cells_begin(); c != dt.finite_cells_end(); ++c)
      for (int k = 0; k < 4; ++k) flat.push_back(c->vertex(k)->info());
    return SimplicialComplex::from_flat(flat.data(), flat.size() / 4, 4, n);
  }
  throw ComplexError("delaunay_complex: points must be n x 2 or n x 3, got n x " +
                     std::to_string(points.cols()));
}

/// The alpha complex of 2-D (n x 2) or 3-D (n x 3) points for squared radius alpha2: the
/// Delaunay simplices CGAL's Alpha_shape_2 / Alpha_shape_3 (GENERAL mode, exact comparison of
/// alpha values) does not classify EXTERIOR, i.e. those whose alpha filtration value is
/// <= alpha2, with all their faces; every point is a node.
inline SimplicialComplex alpha_complex(const Eigen::MatrixXd& points, double alpha2) {
  if (points.cols() != 2 && points.cols() != 3)
    throw ComplexError("alpha_complex: points must be n x 2 or n x 3, got n x " +
                       std::to_string(points.cols()));
  if (!(alpha2 >= 0))
    throw ComplexError("alpha_complex: alpha^2 must be >= 0, got " + std::to_string(alpha2));
  using K = CGAL::Exact_predicates_inexact_constructions_kernel;
  using Exact =
      CGAL::Tag_true;  // alpha values compared exactly (slivers' values are ill-conditioned)
  const std::int64_t n = points.rows();
  std::vector<std::vector<std::int64_t>> simplices;
  if (points.cols() == 2) {
    using Vb = CGAL::Alpha_shape_vertex_base_2<
        K, CGAL::Triangulation_vertex_base_with_info_2<std::int64_t, K>, Exact>;
    using Fb = CGAL::Alpha_shape_face_base_2<K, CGAL::Triangulation_face_base_2<K>, Exact>;
    using Dt = CGAL::Delaunay_triangulation_2<K, CGAL::Triangulation_data_structure_2<Vb, Fb>>;
    using Shape = CGAL::Alpha_shape_2<Dt, Exact>;
    Dt dt;
    detail::insert_indexed_points<2>(dt, points, "alpha_complex");
    if (dt.dimension() < 2)
      throw ComplexError("alpha_complex: the 2-D points are collinear (dimension " +
                         std::to_string(dt.dimension()) + ")");
    Shape as(dt, alpha2, Shape::GENERAL);
    for (auto f = as.finite_faces_begin(); f != as.finite_faces_end(); ++f)
      if (as.classify(f) != Shape::EXTERIOR)
        simplices.push_back({f->vertex(0)->info(), f->vertex(1)->info(), f->vertex(2)->info()});
    for (auto e = as.finite_edges_begin(); e != as.finite_edges_end(); ++e)
      if (as.classify(*e) != Shape::EXTERIOR)
        simplices.push_back({e->first->vertex(Dt::cw(e->second))->info(),
                             e->first->vertex(Dt::ccw(e->second))->info()});
    return SimplicialComplex::from_simplices(simplices, n);
  }
  using Vb = CGAL::Alpha_shape_vertex_base_3<
      K, CGAL::Triangulation_vertex_base_with_info_3<std::int64_t, K>, Exact>;
  using Cb = CGAL::Alpha_shape_cell_base_3<K, CGAL::Delaunay_triangulation_cell_base_3<K>, Exact>;
  using Dt = CGAL::Delaunay_triangulation_3<K, CGAL::Triangulation_data_structure_3<Vb, Cb>>;
  using Shape = CGAL::Alpha_shape_3<Dt, Exact>;
  Dt dt;
  detail::insert_indexed_points<3>(dt, points, "alpha_complex");
  if (dt.dimension() < 3)
    throw ComplexError("alpha_complex: the 3-D points are coplanar (dimension " +
                       std::to_string(dt.dimension()) + "); pass them as 2-D");
  Shape as(dt, alpha2, Shape::GENERAL);
  for (auto c = as.finite_cells_begin(); c != as.finite_cells_end(); ++c)
    if (as.classify(c) != Shape::EXTERIOR)
      simplices.push_back(
          {c->vertex(0)->info(), c->vertex(1)->info(), c->vertex(2)->info(), c->vertex(3)->info()});
  for (auto f = as.finite_facets_begin(); f != as.finite_facets_end(); ++f) {
    if (as.classify(*f) == Shape::EXTERIOR) continue;
    std::vector<std::int64_t> s;
    for (int k = 0; k < 4; ++k)
      if (k != f->second) s.push_back(f->first->vertex(k)->info());
    simplices.push_back(s);
  }
  for (auto e = as.finite_edges_begin(); e != as.finite_edges_end(); ++e)
    if (as.classify(*e) != Shape::EXTERIOR)
      simplices.push_back(
          {e->first->vertex(e->second)->info(), e->first->vertex(e->third)->info()});
  return SimplicialComplex::from_simplices(simplices,
                                           n);  // every point is a node (alpha = 0: isolated)
}

}  // namespace topos
