// topos/models/fignet/features.hpp
// FIGNet's graph at one timestep (docs/design/baselines.md 1.2-1.5, 4.2), as sim::GraphFrame
// data without LibTorch: mesh nodes and object nodes with the reimplementation's 12 columns,
// mesh-object edges both ways, optional mesh-mesh edges, and face-face hyperedges (3 slots) from
// the exact contact detector.
//
// FignetGeometry holds what is static in a scene: its objects in scene order, but with HOPNet's
// floor quad replaced by the reimplementation's floor box (8 vertices, 12 outward triangles,
// 20 x 20 x 0.5, z in [-0.5, 0]), the global mesh-node numbering and the unique mesh edges.
// fignet_frame() adds what changes per frame. Deviations from the reimplementation (4.2): poses
// read as (w, x, y, z); face pairs are every exact pair within the radius, with no broad-phase
// restriction to overlapping object boxes; intersecting pairs get one common point (d_rs = 0).
//
// The mesh helpers (sim::SceneMeshes, sim::pose_meshes, ...) and the mesh-node and mesh-edge
// columns (sim/mesh_graph.hpp) are shared with MeshGraphNet (models/mgn/features.hpp).
#pragma once

#include "topos/core/mesh_lifting.hpp"
#include "topos/geometry/contacts.hpp"
#include "topos/models/hopnet/scene.hpp"  // the deprecated hopnet:: names of the scene
#include "topos/models/namespace_aliases.hpp"
#include "topos/sim/graph_frame.hpp"
#include "topos/sim/mesh_graph.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <stdexcept>
#include <string>
#include <vector>

namespace topos::models::fignet {

using sim::GraphFrame;
using sim::RowMatrix;

/// Feature widths: nodes (both sets) 12, mesh-object and mesh-mesh edges 8, face-face 34.
inline constexpr int kNodeWidth = sim::kMeshNodeWidth, kEdgeWidth = sim::kMeshEdgeWidth,
                     kFaceEdgeWidth = 34;

/// Deprecated alias: the mesh numbering moved to topos/sim/meshes.hpp; write sim::SceneMeshes.
using SceneMeshes = sim::SceneMeshes;

struct FignetGeometry : SceneMeshes {};

struct FignetFeatureOptions {
  double collision_radius = 0.1;  ///< face pairs within this distance get ff hyperedges
  bool mesh_edges = false;        ///< add the "mm" edge set (off in the MOVi configurations)
};

/// The reimplementation's floor: trimesh.creation.box(extents=[20, 20, 0.5]) (trimesh's vertex
/// and face order, outward normals) moved down by 0.25, so its top face is the plane z = 0.
inline TriangleMesh floor_box_mesh() {
  TriangleMesh m;
  m.name = "floor";
  m.vertices.resize(8, 3);
  for (int i = 0; i < 8; ++i)
    m.vertices.row(i) << (i & 4 ? 10.0 : -10.0), (i & 2 ? 10.0 : -10.0), (i & 1 ? 0.0 : -0.5);
  m.faces.resize(12, 3);
  m.faces << 1, 3, 0, 4, 1, 0, 0, 3, 2, 2, 4, 0, 1, 7, 3, 5, 1, 4, 5, 7, 1, 3, 7, 2, 6, 4, 2, 2, 7,
      6, 6, 5, 4, 7, 5, 6;
  return m;
}

namespace detail {

// Deprecated aliases: these helpers moved to topos/sim/meshes.hpp and topos/sim/mesh_graph.hpp
// (namespace topos::sim), shared by every simulator; call them as sim::NAME.
using sim::accelerations;
using sim::centers_of_mass;
using sim::check_radius;
using sim::index_meshes;
using sim::mesh_edge_set;
using sim::mesh_node_features;
using sim::pose_meshes;
using sim::put_node;
using sim::put_vector;
using sim::stack_vertices;

/// The unit normal of a triangle as oriented ((b - a) x (c - a)); zero when degenerate.
inline Eigen::Vector3d unit_normal(const std::array<Eigen::Vector3d, 3>& t) {
  const Eigen::Vector3d n = (t[1] - t[0]).cross(t[2] - t[0]);
  const double len = n.norm();
  return len > 0 ? Eigen::Vector3d(n / len) : Eigen::Vector3d::Zero();
}

/// The order of a face's 3 vertices by distance to `p`, ascending (ties keep the face's order).
inline std::array<int, 3> order_by_distance(const std::array<Eigen::Vector3d, 3>& t,
                                            const Eigen::Vector3d& p) {
  std::array<int, 3> k{0, 1, 2};
  std::array<double, 3> d;
  for (int i = 0; i < 3; ++i)
    d[static_cast<std::size_t>(i)] = (t[static_cast<std::size_t>(i)] - p).norm();
  std::stable_sort(k.begin(), k.end(), [&](int a, int b) {
    return d[static_cast<std::size_t>(a)] < d[static_cast<std::size_t>(b)];
  });
  return k;
}

}  // namespace detail

/// The scene's objects in scene order, the floor's quad replaced by the floor box (centre of mass
/// (0, 0, -0.25); the scene floor's mass, friction and restitution kept).
inline FignetGeometry make_fignet_geometry(const sim::Scene& scene) {
  FignetGeometry g;
  g.objects = scene.objects;
  for (auto& obj : g.objects)
    if (obj.is_floor) {
      obj.mesh = floor_box_mesh();
      obj.center_of_mass = Eigen::Vector3d(0, 0, -0.25);
    }
  sim::index_meshes(g, "make_fignet_geometry");
  return g;
}

/// The graph at t from the poses at t-2 (p2), t-1 (p1) and t (pt); `next` (t+1), when given,
/// sets the target. Node sets "mesh" (every vertex, global order) and "object" (one per object,
/// at its posed centre of mass); edge sets "mo" (mesh -> object, edge n from mesh node n), "om"
/// (its reverse, same order), "ff" (3 slots) and, with o.mesh_edges, "mm".
///
/// ff: each face pair of different objects within o.collision_radius at t, in find_contacts'
/// order, as two hyperedges: 2c sends from the pair's first face to its second, 2c + 1 back.
/// Features [d_rs, |d_rs|, sender rows (12), receiver rows (12), n_s, n_r] with d_rs = p_r - p_s
/// (p the closest points) and a face's rows (v - p, |v - p|) for its vertices sorted by that
/// distance; slot k of senders/receivers is the global node of the k-th row.
inline GraphFrame fignet_frame(const FignetGeometry& g, const sim::Poses& p2, const sim::Poses& p1,
                               const sim::Poses& pt, const sim::Poses* next,
                               const FignetFeatureOptions& o = {}) {
  sim::check_radius(o.collision_radius, false, "fignet_frame: collision_radius");
  const auto posed2 = sim::pose_meshes(g, p2, "fignet_frame: poses at t-2");
  const auto posed1 = sim::pose_meshes(g, p1, "fignet_frame: poses at t-1");
  const auto posedt = sim::pose_meshes(g, pt, "fignet_frame: poses at t");
  const RowMatrix x2 = sim::stack_vertices(g, posed2), x1 = sim::stack_vertices(g, posed1),
                  xt = sim::stack_vertices(g, posedt);
  const std::int64_t N = g.num_nodes(), O = g.num_objects();
  GraphFrame f;
  f.nodes["mesh"].features = sim::mesh_node_features(g, x2, x1, xt);

  const RowMatrix c2 = sim::centers_of_mass(g, p2), c1 = sim::centers_of_mass(g, p1),
                  ct = sim::centers_of_mass(g, pt);
  RowMatrix& obj = f.nodes["object"].features;
  obj.resize(O, kNodeWidth);
  for (std::int64_t k = 0; k < O; ++k)
    sim::put_node(obj, k, (c1.row(k) - c2.row(k)).transpose(), (ct.row(k) - c1.row(k)).transpose(),
                  g.objects[static_cast<std::size_t>(k)], !g.is_static(k));

  // Mesh-object edges: d = x - x_com (world), d_ref = X - X_com (body frame); om negates both.
  sim::EdgeSetData& mo = f.edges["mo"];
  sim::EdgeSetData& om = f.edges["om"];
  for (auto* s : {&mo, &om}) {
    s->features.resize(N, kEdgeWidth);
    s->senders.resize(N, 1);
    s->receivers.resize(N, 1);
  }
  for (std::int64_t n = 0; n < N; ++n) {
    const auto k = g.node_object[static_cast<std::size_t>(n)];
    const auto& ob = g.objects[static_cast<std::size_t>(k)];
    const Eigen::Vector3d d = (xt.row(n) - ct.row(k)).transpose();
    const Eigen::Vector3d d_ref =
        ob.mesh.vertices.row(n - g.node_offset[static_cast<std::size_t>(k)]).transpose() -
        ob.center_of_mass;
    sim::put_vector(mo.features, n, 0, d);
    sim::put_vector(mo.features, n, 4, d_ref);
    sim::put_vector(om.features, n, 0, -d);
    sim::put_vector(om.features, n, 4, -d_ref);
    mo.senders(n, 0) = om.receivers(n, 0) = n;
    mo.receivers(n, 0) = om.senders(n, 0) = k;
  }
  if (o.mesh_edges) f.edges["mm"] = sim::mesh_edge_set(g, xt);

  // Face-face hyperedges, both directions of every pair.
  const auto contacts = find_contacts(posedt, o.collision_radius);
  sim::EdgeSetData& ff = f.edges["ff"];
  const auto F = static_cast<Eigen::Index>(2 * contacts.size());
  ff.features.resize(F, kFaceEdgeWidth);
  ff.senders.resize(F, 3);
  ff.receivers.resize(F, 3);
  for (std::size_t c = 0; c < contacts.size(); ++c) {
    const auto& pair = contacts[c];
    struct Side {
      std::array<Eigen::Vector3d, 3> t;
      std::array<std::int64_t, 3> node;
      Eigen::Vector3d p;
    };
    Side side[2];
    const std::int64_t objs[2] = {pair.obj0, pair.obj1}, faces[2] = {pair.face0, pair.face1};
    for (int s = 0; s < 2; ++s) {
      const auto ob = static_cast<std::size_t>(objs[s]);
      side[s].t = topos::detail::face_points(posedt[ob], faces[s]);
      for (int k = 0; k < 3; ++k)
        side[s].node[static_cast<std::size_t>(k)] =
            g.node_offset[ob] + (*posedt[ob].faces)(faces[s], k);
      side[s].p = s == 0 ? pair.p : pair.q;
    }
    if (pair.intersecting) side[1].p = side[0].p;  // one common point: d_rs = 0 exactly
    for (int dir = 0; dir < 2; ++dir) {
      const Side& snd = side[dir];
      const Side& rcv = side[1 - dir];
      const auto r = static_cast<Eigen::Index>(2 * c) + dir;
      sim::put_vector(ff.features, r, 0, rcv.p - snd.p);
      const auto ks = detail::order_by_distance(snd.t, snd.p);
      const auto kr = detail::order_by_distance(rcv.t, rcv.p);
      for (int k = 0; k < 3; ++k) {
        const auto is = static_cast<std::size_t>(ks[static_cast<std::size_t>(k)]);
        const auto ir = static_cast<std::size_t>(kr[static_cast<std::size_t>(k)]);
        sim::put_vector(ff.features, r, 4 + 4 * k, snd.t[is] - snd.p);
        sim::put_vector(ff.features, r, 16 + 4 * k, rcv.t[ir] - rcv.p);
        ff.senders(r, k) = snd.node[is];
        ff.receivers(r, k) = rcv.node[ir];
      }
      ff.features.block<1, 3>(r, 28) = detail::unit_normal(snd.t).transpose();
      ff.features.block<1, 3>(r, 31) = detail::unit_normal(rcv.t).transpose();
    }
  }

  f.node_object = g.node_object;
  f.dynamic.resize(static_cast<std::size_t>(N));
  for (std::int64_t n = 0; n < N; ++n)
    f.dynamic[static_cast<std::size_t>(n)] =
        !g.is_static(g.node_object[static_cast<std::size_t>(n)]);
  if (next) {
    const auto posedn = sim::pose_meshes(g, *next, "fignet_frame: poses at t+1");
    f.target = sim::accelerations(x1, xt, sim::stack_vertices(g, posedn));
  }
  return f;
}

}  // namespace topos::models::fignet
