// topos/models/hopnet/geometry.hpp
// The static part of a scene's HOPNet complex (HopnetGeometry: node, edge and face numbering,
// make_geometry) and the objects posed at one frame as HOPNet poses them (pose_objects).
#pragma once

#include "topos/core/mesh_lifting.hpp"
#include "topos/geometry/contacts.hpp"
#include "topos/mesh/rigid.hpp"
#include "topos/models/hopnet/lifting_options.hpp"
#include "topos/models/hopnet/scene.hpp"
#include "topos/models/namespace_aliases.hpp"

#include <Eigen/Dense>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <stdexcept>
#include <string>
#include <vector>

namespace topos::models::hopnet {

/// CPython's iteration order of frozenset({a, b}) built from [a, b] (a inserted first), for
/// small non-negative ints (hash = value, table of 8 slots): returns true when a comes first.
inline bool frozenset_a_first(std::int64_t a, std::int64_t b) {
  const std::uint64_t ia = static_cast<std::uint64_t>(a) & 7u,
                      ib = static_cast<std::uint64_t>(b) & 7u;
  if (ia != ib) return ia < ib;
  std::uint64_t perturb = static_cast<std::uint64_t>(b), i = ib;
  while (i == ia) {
    perturb >>= 5;
    i = (i * 5 + 1 + perturb) & 7u;
  }
  return ia < i;
}

/// The static part of a scene's complex.
struct HopnetGeometry {
  std::vector<const SceneObject*> objects;
  std::vector<std::int64_t> node_offset, face_offset;  ///< O+1 each
  std::vector<std::int64_t> node_object;               ///< object of each node
  std::vector<std::array<std::int64_t, 2>> edges;      ///< (s, d) as the features use it
  Eigen::Matrix<std::int64_t, Eigen::Dynamic, 3, Eigen::RowMajor>
      face_nodes;  ///< global face -> nodes
  Eigen::Matrix<std::int64_t, Eigen::Dynamic, 3, Eigen::RowMajor>
      face_edges;                             ///< global face -> edge ids
  std::vector<VertexFaceIndex> vertex_faces;  ///< per object, for the reference detector
  FeatureMode mode = FeatureMode::reference;
  SceneLiftingOptions lifting;  ///< lifting.mode == mode
  /// no_object_cells: per mesh node, whether its spoke edge runs virtual node -> node (the
  /// frozenset rule on [9900 + object, node]); the spoke's features are then negated.
  std::vector<char> spoke_virtual_first;

  std::int64_t num_nodes() const { return node_offset.back(); }
  std::int64_t num_edges() const { return static_cast<std::int64_t>(edges.size()); }
  std::int64_t num_objects() const { return static_cast<std::int64_t>(objects.size()); }
  /// Rank-0 and rank-1 cells the network sees: mesh nodes and edges, plus one virtual node per
  /// object and one spoke per mesh node when objects are virtual nodes.
  std::int64_t num_rank0() const {
    return num_nodes() + (lifting.object_cells() ? 0 : num_objects());
  }
  std::int64_t num_rank1() const {
    return num_edges() + (lifting.object_cells() ? 0 : num_nodes());
  }
};

/// Id of object i's virtual node in the reference's NoObjectCells complex (9900 + i); the
/// construction breaks for scenes of 9900 or more mesh nodes, which are refused.
inline constexpr std::int64_t kVirtualNodeId = 9900;

inline HopnetGeometry make_geometry(const Scene& scene, const SceneLiftingOptions& lifting);

inline HopnetGeometry make_geometry(const Scene& scene, FeatureMode mode) {
  SceneLiftingOptions l;
  l.mode = mode;
  return make_geometry(scene, l);
}

inline HopnetGeometry make_geometry(const Scene& scene, const SceneLiftingOptions& lifting) {
  HopnetGeometry g;
  const FeatureMode mode = lifting.mode;
  g.mode = mode;
  g.lifting = lifting;
  std::vector<TriangleMesh> meshes;
  for (const auto& o : scene.objects) {
    g.objects.push_back(&o);
    meshes.push_back(o.mesh);
  }
  const auto lifted = lift_meshes(meshes, LiftOptions().with_faces(false).with_object_rank(0));
  g.node_offset.assign(lifted.node_offset.begin(), lifted.node_offset.end());
  g.face_offset.assign(lifted.face_offset.begin(), lifted.face_offset.end());
  g.node_object.assign(lifted.node_object.begin(), lifted.node_object.end());
  g.face_nodes = lifted.faces;
  topos::detail::FlatKeyMap edge_id(lifted.edges.size() * 2 + 8);
  const auto key = [](std::int64_t a, std::int64_t b) {
    return (static_cast<std::uint64_t>(std::min(a, b)) << 32) |
           static_cast<std::uint64_t>(std::max(a, b));
  };
  for (std::size_t e = 0; e < lifted.edges.size(); ++e) {
    auto [a, b] = lifted.edges[e];
    edge_id.emplace(key(a, b), static_cast<std::int64_t>(e));
    const bool a_first = mode == FeatureMode::native || frozenset_a_first(a, b);
    g.edges.push_back(a_first ? std::array<std::int64_t, 2>{a, b}
                              : std::array<std::int64_t, 2>{b, a});
  }
  g.face_edges.resize(g.face_nodes.rows(), 3);
  for (Eigen::Index f = 0; f < g.face_nodes.rows(); ++f)
    for (int k = 0; k < 3; ++k)
      g.face_edges(f, k) =
          edge_id.emplace(key(g.face_nodes(f, k), g.face_nodes(f, (k + 1) % 3)), -1).first;
  for (const auto& o : scene.objects)
    g.vertex_faces.emplace_back(o.mesh.faces, o.mesh.vertices.rows());
  if (!lifting.object_cells()) {
    if (g.num_nodes() >= kVirtualNodeId)
      throw std::invalid_argument(
          scene.source + ": " + std::to_string(g.num_nodes()) +
          " mesh nodes; the reference's virtual node ids (9900 + object) would collide with them");
    for (std::int64_t n = 0; n < g.num_nodes(); ++n) {
      const auto o = g.node_object[static_cast<std::size_t>(n)];
      g.spoke_virtual_first.push_back(mode == FeatureMode::reference &&
                                      frozenset_a_first(kVirtualNodeId + o, n));
    }
  }
  return g;
}

/// World vertices of every object for one set of poses (static objects stay as they are).
/// Reference mode poses with trimesh's arithmetic bit for bit (pose_vertices_trimesh): the
/// reference's contact features of faces resting flat on each other depend on the last ulp.
inline std::vector<PosedObject> pose_objects(const HopnetGeometry& g, const Poses& p) {
  std::vector<PosedObject> out(g.objects.size());
  for (std::size_t o = 0; o < g.objects.size(); ++o) {
    const auto& obj = *g.objects[o];
    for (int c = 0; c < 3; ++c)
      if (!std::isfinite(p.positions(static_cast<Eigen::Index>(o), c)))
        throw std::invalid_argument("pose of object " + std::to_string(o) + " is not finite");
    out[o].faces = &obj.mesh.faces;
    const Eigen::Vector3d position = p.positions.row(static_cast<Eigen::Index>(o)).transpose();
    const Eigen::Vector4d quaternion = p.quaternions.row(static_cast<Eigen::Index>(o)).transpose();
    if (obj.is_floor)
      out[o].vertices = obj.mesh.vertices;
    else if (g.mode == FeatureMode::reference)
      out[o].vertices = pose_vertices_trimesh(obj.mesh.vertices, position, quaternion);
    else
      out[o].vertices = pose_vertices(obj.mesh.vertices, position, quaternion);
  }
  return out;
}

}  // namespace topos::models::hopnet
