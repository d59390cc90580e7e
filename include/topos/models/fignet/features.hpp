// topos/models/fignet/features.hpp
// FIGNet's graph at one timestep (docs/design/baselines.md 1.2-1.5, 4.2), as gns::GraphFrame
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
// SceneMeshes and the detail helpers are shared with MeshGraphNet (models/mgn/features.hpp),
// whose node and mesh-edge columns are FIGNet's.
#pragma once

#include "topos/core/mesh_lifting.hpp"
#include "topos/geometry/contacts.hpp"
#include "topos/models/gns/graph.hpp"
#include "topos/models/hopnet/features.hpp"
#include "topos/models/hopnet/scene.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <stdexcept>
#include <string>
#include <vector>

namespace topos::fignet {

using gns::GraphFrame;
using gns::RowMatrix;

/// Feature widths: nodes (both sets) 12, mesh-object and mesh-mesh edges 8, face-face 34.
inline constexpr int kNodeWidth = 12, kEdgeWidth = 8, kFaceEdgeWidth = 34;

/// A scene's objects with their global mesh-node numbering: what a graph of mesh nodes needs
/// that does not change over a trajectory. The floor (is_floor) is the one static object.
struct SceneMeshes {
  std::vector<hopnet::SceneObject> objects;  ///< scene order: canonical mesh X, centre of mass
  std::vector<std::int64_t> node_offset;     ///< O+1: object o owns nodes [off[o], off[o+1])
  std::vector<std::int64_t> node_object;     ///< object of each mesh node
  std::vector<std::array<std::int64_t, 2>> edges;  ///< unique mesh edges, global ids, first seen
  std::int64_t floor = -1;                         ///< the floor object, -1 when there is none

  std::int64_t num_nodes() const { return node_offset.back(); }
  std::int64_t num_objects() const { return static_cast<std::int64_t>(objects.size()); }
  bool is_static(std::int64_t o) const { return objects[static_cast<std::size_t>(o)].is_floor; }
};

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

/// Validates the objects' meshes and fills the node numbering and unique edges of `g.objects`.
inline void index_meshes(SceneMeshes& g, const std::string& who) {
  std::vector<TriangleMesh> meshes;
  for (std::size_t o = 0; o < g.objects.size(); ++o) {
    const auto& obj = g.objects[o];
    const std::string name = "object " + std::to_string(o) + " ('" + obj.shape + "')";
    if (obj.mesh.faces.rows() == 0)
      throw std::invalid_argument(who + ": " + name + " has no faces");
    try {
      obj.mesh.validate();
    } catch (const MeshError& e) {
      throw std::invalid_argument(who + ": " + name + ": " + e.what());
    }
    if (!obj.center_of_mass.allFinite())
      throw std::invalid_argument(who + ": " + name + " has a non-finite centre of mass");
    if (obj.is_floor) {
      if (g.floor >= 0) throw std::invalid_argument(who + ": more than one floor object");
      g.floor = static_cast<std::int64_t>(o);
    }
    meshes.push_back(obj.mesh);
  }
  const auto lifted = lift_meshes(meshes, LiftOptions().with_faces(false).with_object_rank(0));
  g.node_offset.assign(lifted.node_offset.begin(), lifted.node_offset.end());
  g.node_object.assign(lifted.node_object.begin(), lifted.node_object.end());
  for (const auto& e : lifted.edges) g.edges.push_back({e[0], e[1]});
}

inline void check_radius(double r, bool positive, const std::string& who) {
  if (!std::isfinite(r) || r < 0 || (positive && r == 0))
    throw std::invalid_argument(who + " must be " + (positive ? "positive" : "non-negative") +
                                " and finite, got " + std::to_string(r));
}

/// World vertices of every object for one set of poses; the floor keeps its canonical vertices.
/// Throws std::invalid_argument naming `label` (which frame) and the object for bad poses.
inline std::vector<PosedObject> pose_meshes(const SceneMeshes& g, const hopnet::Poses& p,
                                            const std::string& label) {
  const auto O = static_cast<Eigen::Index>(g.objects.size());
  if (p.positions.rows() != O || p.positions.cols() != 3 || p.quaternions.rows() != O ||
      p.quaternions.cols() != 4)
    throw std::invalid_argument(label + ": " + std::to_string(p.positions.rows()) + "x" +
                                std::to_string(p.positions.cols()) + " positions and " +
                                std::to_string(p.quaternions.rows()) + "x" +
                                std::to_string(p.quaternions.cols()) + " quaternions for " +
                                std::to_string(O) + " objects (expected " + std::to_string(O) +
                                "x3 and " + std::to_string(O) + "x4)");
  std::vector<PosedObject> out(g.objects.size());
  for (Eigen::Index o = 0; o < O; ++o) {
    const auto& obj = g.objects[static_cast<std::size_t>(o)];
    const Eigen::Vector3d position = p.positions.row(o).transpose();
    const Eigen::Vector4d q = p.quaternions.row(o).transpose();
    if (!position.allFinite() || !q.allFinite())
      throw std::invalid_argument(label + ": the pose of object " + std::to_string(o) +
                                  " is not finite");
    if (!(q.norm() > 0))
      throw std::invalid_argument(label + ": the quaternion of object " + std::to_string(o) +
                                  " is zero");
    out[static_cast<std::size_t>(o)].faces = &obj.mesh.faces;
    out[static_cast<std::size_t>(o)].vertices =
        obj.is_floor ? obj.mesh.vertices : pose_vertices(obj.mesh.vertices, position, q);
  }
  return out;
}

/// The posed objects' vertices stacked in global node order (N x 3).
inline RowMatrix stack_vertices(const SceneMeshes& g, const std::vector<PosedObject>& posed) {
  RowMatrix x(g.num_nodes(), 3);
  for (std::size_t o = 0; o < posed.size(); ++o)
    x.middleRows(g.node_offset[o], posed[o].vertices.rows()) = posed[o].vertices;
  return x;
}

/// Each object's centre of mass in the world (O x 3); the floor's stays where it is.
inline RowMatrix centers_of_mass(const SceneMeshes& g, const hopnet::Poses& p) {
  RowMatrix c(g.num_objects(), 3);
  for (std::int64_t o = 0; o < g.num_objects(); ++o) {
    const auto& obj = g.objects[static_cast<std::size_t>(o)];
    Eigen::Vector3d x = obj.center_of_mass;
    if (!obj.is_floor)
      x = rotation_from_wxyz(p.quaternions.row(o).transpose()) * x + p.positions.row(o).transpose();
    c.row(o) = x.transpose();
  }
  return c;
}

/// One node row: [v_{t-1}, v_t, restitution, friction x3, mass, kinematic (1 dynamic, 0 static)].
inline void put_node(RowMatrix& m, Eigen::Index r, const Eigen::Vector3d& v_prev,
                     const Eigen::Vector3d& v_now, const hopnet::SceneObject& obj, bool moving) {
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
  RowMatrix m(g.num_nodes(), kNodeWidth);
  for (std::int64_t n = 0; n < g.num_nodes(); ++n) {
    const auto o = g.node_object[static_cast<std::size_t>(n)];
    put_node(m, n, (x1.row(n) - x2.row(n)).transpose(), (xt.row(n) - x1.row(n)).transpose(),
             g.objects[static_cast<std::size_t>(o)], !g.is_static(o));
  }
  return m;
}

/// Unique mesh edges in both directions (edge 2i: a -> b, 2i + 1: b -> a), features
/// [x_s - x_r, |.|, X_s - X_r, |.|] with X the canonical (body-frame) vertices.
inline gns::EdgeSetData mesh_edge_set(const SceneMeshes& g, const RowMatrix& xt) {
  const auto E = static_cast<Eigen::Index>(g.edges.size());
  gns::EdgeSetData s;
  s.features.resize(2 * E, kEdgeWidth);
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

/// Targets x_{t+1} - 2 x_t + x_{t-1} per mesh node (N x 3).
inline RowMatrix accelerations(const RowMatrix& x1, const RowMatrix& xt, const RowMatrix& xn) {
  return xn - 2.0 * xt + x1;
}

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
inline FignetGeometry make_fignet_geometry(const hopnet::Scene& scene) {
  FignetGeometry g;
  g.objects = scene.objects;
  for (auto& obj : g.objects)
    if (obj.is_floor) {
      obj.mesh = floor_box_mesh();
      obj.center_of_mass = Eigen::Vector3d(0, 0, -0.25);
    }
  detail::index_meshes(g, "make_fignet_geometry");
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
inline GraphFrame fignet_frame(const FignetGeometry& g, const hopnet::Poses& p2,
                               const hopnet::Poses& p1, const hopnet::Poses& pt,
                               const hopnet::Poses* next, const FignetFeatureOptions& o = {}) {
  detail::check_radius(o.collision_radius, false, "fignet_frame: collision_radius");
  const auto posed2 = detail::pose_meshes(g, p2, "fignet_frame: poses at t-2");
  const auto posed1 = detail::pose_meshes(g, p1, "fignet_frame: poses at t-1");
  const auto posedt = detail::pose_meshes(g, pt, "fignet_frame: poses at t");
  const RowMatrix x2 = detail::stack_vertices(g, posed2), x1 = detail::stack_vertices(g, posed1),
                  xt = detail::stack_vertices(g, posedt);
  const std::int64_t N = g.num_nodes(), O = g.num_objects();
  GraphFrame f;
  f.nodes["mesh"].features = detail::mesh_node_features(g, x2, x1, xt);

  const RowMatrix c2 = detail::centers_of_mass(g, p2), c1 = detail::centers_of_mass(g, p1),
                  ct = detail::centers_of_mass(g, pt);
  RowMatrix& obj = f.nodes["object"].features;
  obj.resize(O, kNodeWidth);
  for (std::int64_t k = 0; k < O; ++k)
    detail::put_node(obj, k, (c1.row(k) - c2.row(k)).transpose(),
                     (ct.row(k) - c1.row(k)).transpose(), g.objects[static_cast<std::size_t>(k)],
                     !g.is_static(k));

  // Mesh-object edges: d = x - x_com (world), d_ref = X - X_com (body frame); om negates both.
  gns::EdgeSetData& mo = f.edges["mo"];
  gns::EdgeSetData& om = f.edges["om"];
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
    detail::put_vector(mo.features, n, 0, d);
    detail::put_vector(mo.features, n, 4, d_ref);
    detail::put_vector(om.features, n, 0, -d);
    detail::put_vector(om.features, n, 4, -d_ref);
    mo.senders(n, 0) = om.receivers(n, 0) = n;
    mo.receivers(n, 0) = om.senders(n, 0) = k;
  }
  if (o.mesh_edges) f.edges["mm"] = detail::mesh_edge_set(g, xt);

  // Face-face hyperedges, both directions of every pair.
  const auto contacts = find_contacts(posedt, o.collision_radius);
  gns::EdgeSetData& ff = f.edges["ff"];
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
      detail::put_vector(ff.features, r, 0, rcv.p - snd.p);
      const auto ks = detail::order_by_distance(snd.t, snd.p);
      const auto kr = detail::order_by_distance(rcv.t, rcv.p);
      for (int k = 0; k < 3; ++k) {
        const auto is = static_cast<std::size_t>(ks[static_cast<std::size_t>(k)]);
        const auto ir = static_cast<std::size_t>(kr[static_cast<std::size_t>(k)]);
        detail::put_vector(ff.features, r, 4 + 4 * k, snd.t[is] - snd.p);
        detail::put_vector(ff.features, r, 16 + 4 * k, rcv.t[ir] - rcv.p);
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
    const auto posedn = detail::pose_meshes(g, *next, "fignet_frame: poses at t+1");
    f.target = detail::accelerations(x1, xt, detail::stack_vertices(g, posedn));
  }
  return f;
}

}  // namespace topos::fignet
