// topos/models/mgn/features.hpp
// MeshGraphNet's graph at one timestep (docs/design/baselines.md part 3, topos's choices), as
// sim::GraphFrame data without LibTorch: mesh nodes with FIGNet's 12 columns, mesh edges both
// ways with FIGNet's 8 mesh-mesh columns, and world edges [x_s - x_r, |x_s - x_r|] between
// nodes of different objects within the world-edge radius.
//
// The floor is HOPNet's quad (4 static nodes at ±20 m), whose nodes are too far apart for any
// node-based contact to see it. So every non-floor node less than the radius above the plane
// z = 0 (or below it) gets a virtual static floor node at its projection (x, y, 0), appended
// after the mesh nodes, joined to it by one world edge each way: what a densely tessellated
// floor would give, without 10^5 nodes.
#pragma once

#include "topos/models/namespace_aliases.hpp"
#include "topos/sim/mesh_graph.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

namespace topos::models::mgn {

using sim::GraphFrame;
using sim::RowMatrix;

/// Feature widths: nodes 12, mesh edges 8, world edges 4.
inline constexpr int kNodeWidth = sim::kMeshNodeWidth, kMeshEdgeWidth = sim::kMeshEdgeWidth,
                     kWorldEdgeWidth = 4;

/// The scene's objects as they are, HOPNet's floor quad included (static nodes).
struct MgnGeometry : sim::SceneMeshes {};

struct MgnFeatureOptions {
  double world_edge_radius = 0.1;  ///< node pairs within this distance get world edges
};

namespace detail {

/// Pairs (i, j), i < j, of rows of x in different groups with |x_i - x_j| <= r, ascending: a
/// uniform grid of cell size r, so each point only looks at its own and the 26 neighbour cells.
inline std::vector<std::array<std::int64_t, 2>> radius_pairs(const RowMatrix& x,
                                                             const std::vector<std::int64_t>& group,
                                                             double r) {
  using Cell = std::array<std::int64_t, 3>;
  std::vector<std::pair<Cell, std::int64_t>> cells;
  cells.reserve(static_cast<std::size_t>(x.rows()));
  for (Eigen::Index i = 0; i < x.rows(); ++i) {
    Cell c;
    for (int k = 0; k < 3; ++k) {
      const double q = std::floor(x(i, k) / r);
      // Cell ids must fit an int64 with room for the ±1 of the neighbours.
      if (!(std::abs(q) < 1e15))
        throw std::invalid_argument("mgn_frame: node " + std::to_string(i) + " at " +
                                    std::to_string(x(i, k)) + " is too far out for radius " +
                                    std::to_string(r));
      c[static_cast<std::size_t>(k)] = static_cast<std::int64_t>(q);
    }
    cells.emplace_back(c, static_cast<std::int64_t>(i));
  }
  std::sort(cells.begin(), cells.end());
  const auto by_cell = [](const std::pair<Cell, std::int64_t>& a,
                          const std::pair<Cell, std::int64_t>& b) { return a.first < b.first; };
  std::vector<std::array<std::int64_t, 2>> out;
  for (const auto& [c, i] : cells) {
    for (std::int64_t dx = -1; dx <= 1; ++dx)
      for (std::int64_t dy = -1; dy <= 1; ++dy)
        for (std::int64_t dz = -1; dz <= 1; ++dz) {
          const std::pair<Cell, std::int64_t> key{{c[0] + dx, c[1] + dy, c[2] + dz}, 0};
          const auto [lo, hi] = std::equal_range(cells.begin(), cells.end(), key, by_cell);
          for (auto it = lo; it != hi; ++it) {
            const std::int64_t j = it->second;
            if (j <= i || group[static_cast<std::size_t>(i)] == group[static_cast<std::size_t>(j)])
              continue;
            if ((x.row(i) - x.row(j)).squaredNorm() <= r * r) out.push_back({i, j});
          }
        }
  }
  std::sort(out.begin(), out.end());
  return out;
}

}  // namespace detail

inline MgnGeometry make_mgn_geometry(const sim::Scene& scene) {
  MgnGeometry g;
  g.objects = scene.objects;
  sim::index_meshes(g, "make_mgn_geometry");
  return g;
}

/// The graph at t from the poses at t-2 (p2), t-1 (p1) and t (pt); `next` (t+1), when given,
/// sets the target. Node set "mesh": the N vertices in global order, then one virtual floor
/// node per non-floor vertex with z < o.world_edge_radius at t, in vertex order (zero
/// velocities, the floor's properties, kinematic 0, not dynamic, the floor's object, target 0).
/// Edge sets "mesh_edges" (unique mesh edges, 2i: a -> b, 2i + 1: b -> a) and "world_edges":
/// the node pairs ordered by (sender, receiver), then per virtual node (vertex -> virtual,
/// virtual -> vertex). A scene without a floor object gets no virtual nodes.
inline GraphFrame mgn_frame(const MgnGeometry& g, const sim::Poses& p2, const sim::Poses& p1,
                            const sim::Poses& pt, const sim::Poses* next,
                            const MgnFeatureOptions& o = {}) {
  const double r = o.world_edge_radius;
  sim::check_radius(r, true, "mgn_frame: world_edge_radius");
  const RowMatrix x2 = sim::stack_vertices(g, sim::pose_meshes(g, p2, "mgn_frame: poses at t-2")),
                  x1 = sim::stack_vertices(g, sim::pose_meshes(g, p1, "mgn_frame: poses at t-1")),
                  xt = sim::stack_vertices(g, sim::pose_meshes(g, pt, "mgn_frame: poses at t"));
  const std::int64_t N = g.num_nodes();

  std::vector<std::int64_t> near_floor;  // vertex of each virtual node
  if (g.floor >= 0)
    for (std::int64_t n = 0; n < N; ++n)
      if (!g.is_static(g.node_object[static_cast<std::size_t>(n)]) && xt(n, 2) < r)
        near_floor.push_back(n);
  const auto V = static_cast<std::int64_t>(near_floor.size());
  RowMatrix pos(N + V, 3);  // world positions at t, virtual nodes included
  pos.topRows(N) = xt;
  for (std::int64_t v = 0; v < V; ++v)
    pos.row(N + v) << xt(near_floor[static_cast<std::size_t>(v)], 0),
        xt(near_floor[static_cast<std::size_t>(v)], 1), 0.0;

  GraphFrame f;
  RowMatrix& mesh = f.nodes["mesh"].features;
  mesh.resize(N + V, kNodeWidth);
  mesh.topRows(N) = sim::mesh_node_features(g, x2, x1, xt);
  for (std::int64_t v = 0; v < V; ++v)
    sim::put_node(mesh, N + v, Eigen::Vector3d::Zero(), Eigen::Vector3d::Zero(),
                  g.objects[static_cast<std::size_t>(g.floor)], false);

  f.edges["mesh_edges"] = sim::mesh_edge_set(g, xt);

  std::vector<std::array<std::int64_t, 2>> world;
  for (const auto& [i, j] : detail::radius_pairs(xt, g.node_object, r)) {
    world.push_back({i, j});
    world.push_back({j, i});
  }
  std::sort(world.begin(), world.end());
  for (std::int64_t v = 0; v < V; ++v) {
    world.push_back({near_floor[static_cast<std::size_t>(v)], N + v});
    world.push_back({N + v, near_floor[static_cast<std::size_t>(v)]});
  }
  sim::EdgeSetData& we = f.edges["world_edges"];
  const auto E = static_cast<Eigen::Index>(world.size());
  we.features.resize(E, kWorldEdgeWidth);
  we.senders.resize(E, 1);
  we.receivers.resize(E, 1);
  for (Eigen::Index e = 0; e < E; ++e) {
    const auto [s, d] = world[static_cast<std::size_t>(e)];
    sim::put_vector(we.features, e, 0, (pos.row(s) - pos.row(d)).transpose());
    we.senders(e, 0) = s;
    we.receivers(e, 0) = d;
  }

  f.node_object = g.node_object;
  f.node_object.resize(static_cast<std::size_t>(N + V), g.floor);
  f.dynamic.assign(static_cast<std::size_t>(N + V), 0);
  for (std::int64_t n = 0; n < N; ++n)
    f.dynamic[static_cast<std::size_t>(n)] =
        !g.is_static(g.node_object[static_cast<std::size_t>(n)]);
  if (next) {
    const RowMatrix xn =
        sim::stack_vertices(g, sim::pose_meshes(g, *next, "mgn_frame: poses at t+1"));
    f.target.setZero(N + V, 3);
    f.target.topRows(N) = sim::accelerations(x1, xt, xn);
  }
  return f;
}

}  // namespace topos::models::mgn
