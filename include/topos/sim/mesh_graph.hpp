// topos/sim/mesh_graph.hpp
// The graph features of mesh nodes and mesh edges that FIGNet and MeshGraphNet share (FIGNet's
// column layout, which the MeshGraphNet baseline reuses), as GraphFrame data without
// LibTorch: node rows [v_{t-1}, v_t, restitution, friction x3, mass, kinematic] and mesh edges
// both ways with [x_s - x_r, |.|, X_s - X_r, |.|].
#pragma once

#include "topos/sim/graph_frame.hpp"
#include "topos/sim/meshes.hpp"

namespace topos::sim {

/// Feature widths: mesh nodes 12, mesh edges 8.
inline constexpr int kMeshNodeWidth = 12, kMeshEdgeWidth = 8;

/// One node row: [v_{t-1}, v_t, restitution, friction x3, mass, kinematic (1 dynamic, 0 static)].
inline void put_node(RowMatrix& m, Eigen::Index r, const Eigen::Vector3d& v_prev,
                     const Eigen::Vector3d& v_now, const SceneObject& obj, bool moving) {
  m.block<1, 3>(r, 0) = v_prev.transpose();
  m.block<1, 3>(r, 3) = v_now.transpose();
  m(r, 6) = obj.restitution;
  m(r, 7) = m(r, 8) = m(r, 9) = obj.friction;
  m(r, 10) = obj.mass;
  m(r, 11) = moving ? 1.0 : 0.0;
}

/// (v, |v|) into columns c..c+3.
inline void put_vector(RowMatrix& m, Eigen::Index r, Eigen::Index c, const Eigen::Vector3d& v) {
  m.block<1, 3>(r, c) = v.transpose();
  m(r, c + 3) = v.norm();
}

/// Mesh nodes' rows: the three frames' world positions give the two velocities, oldest first.
inline RowMatrix mesh_node_features(const SceneMeshes& g, const RowMatrix& x2, const RowMatrix& x1,
                                    const RowMatrix& xt) {
  RowMatrix m(g.num_nodes(), kMeshNodeWidth);
  for (std::int64_t n = 0; n < g.num_nodes(); ++n) {
    const auto o = g.node_object[static_cast<std::size_t>(n)];
    put_node(m, n, (x1.row(n) - x2.row(n)).transpose(), (xt.row(n) - x1.row(n)).transpose(),
             g.objects[static_cast<std::size_t>(o)], !g.is_static(o));
  }
  return m;
}

/// Unique mesh edges in both directions (edge 2i: a -> b, 2i + 1: b -> a), features
/// [x_s - x_r, |.|, X_s - X_r, |.|] with X the canonical (body-frame) vertices.
inline EdgeSetData mesh_edge_set(const SceneMeshes& g, const RowMatrix& xt) {
  const auto E = static_cast<Eigen::Index>(g.edges.size());
  EdgeSetData s;
  s.features.resize(2 * E, kMeshEdgeWidth);
  s.senders.resize(2 * E, 1);
  s.receivers.resize(2 * E, 1);
  const auto canonical = [&](std::int64_t n) -> Eigen::Vector3d {
    const auto o = static_cast<std::size_t>(g.node_object[static_cast<std::size_t>(n)]);
    return g.objects[o].mesh.vertices.row(n - g.node_offset[o]).transpose();
  };
  for (Eigen::Index e = 0; e < E; ++e) {
    const auto [a, b] = g.edges[static_cast<std::size_t>(e)];
    for (int dir = 0; dir < 2; ++dir) {
      const std::int64_t snd = dir == 0 ? a : b, rcv = dir == 0 ? b : a;
      const Eigen::Index r = 2 * e + dir;
      put_vector(s.features, r, 0, (xt.row(snd) - xt.row(rcv)).transpose());
      put_vector(s.features, r, 4, canonical(snd) - canonical(rcv));
      s.senders(r, 0) = snd;
      s.receivers(r, 0) = rcv;
    }
  }
  return s;
}

}  // namespace topos::sim
