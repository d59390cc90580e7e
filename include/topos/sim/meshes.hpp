// topos/sim/meshes.hpp
// The mesh helpers the simulators share: a scene's objects with their global mesh-node numbering
// (SceneMeshes, index_meshes), the objects posed at one frame (pose_meshes, stack_vertices,
// centers_of_mass), node accelerations x_{t+1} - 2 x_t + x_{t-1} (the training target) and the
// rigid update that turns predicted accelerations back into a pose (integrate_object: the
// vertices integrated, then the object fitted by shape matching). No LibTorch.
#pragma once

#include "topos/core/mesh_lifting.hpp"
#include "topos/mesh/rigid.hpp"
#include "topos/sim/scene.hpp"

#include <array>
#include <cmath>
#include <cstdint>
#include <stdexcept>
#include <string>
#include <vector>

namespace topos::sim {

/// A scene's objects with their global mesh-node numbering: what a graph of mesh nodes needs
/// that does not change over a trajectory. The floor (is_floor) is the one static object.
struct SceneMeshes {
  std::vector<SceneObject> objects;       ///< scene order: canonical mesh X, centre of mass
  std::vector<std::int64_t> node_offset;  ///< O+1: object o owns nodes [off[o], off[o+1])
  std::vector<std::int64_t> node_object;  ///< object of each mesh node
  std::vector<std::array<std::int64_t, 2>> edges;  ///< unique mesh edges, global ids, first seen
  std::int64_t floor = -1;                         ///< the floor object, -1 when there is none

  std::int64_t num_nodes() const { return node_offset.back(); }
  std::int64_t num_objects() const { return static_cast<std::int64_t>(objects.size()); }
  bool is_static(std::int64_t o) const { return objects[static_cast<std::size_t>(o)].is_floor; }
};

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
inline std::vector<PosedObject> pose_meshes(const SceneMeshes& g, const Poses& p,
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
inline RowMatrix centers_of_mass(const SceneMeshes& g, const Poses& p) {
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

/// Targets x_{t+1} - 2 x_t + x_{t-1} per mesh node (N x 3).
inline RowMatrix accelerations(const RowMatrix& x1, const RowMatrix& xt, const RowMatrix& xn) {
  return xn - 2.0 * xt + x1;
}

/// One object's pose at t+1 from its world vertices at t (`now`) and t-1 (`before`) and the
/// predicted acceleration `a(v, c)` of vertex v, coordinate c: x_{t+1} = 2 x_t - x_{t-1} + a,
/// then the rigid pose closest to x_{t+1} (shape matching on the volumetric centre of mass).
template <class Acceleration>
RigidPose integrate_object(const SceneObject& obj, const Vertices& now, const Vertices& before,
                           Acceleration&& a) {
  Vertices x = 2.0 * now - before;
  for (Eigen::Index v = 0; v < x.rows(); ++v)
    for (int c = 0; c < 3; ++c) x(v, c) += a(v, c);
  return shape_match(obj.mesh.vertices, obj.center_of_mass, x, obj.mesh.faces);
}

}  // namespace topos::sim
