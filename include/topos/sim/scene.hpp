// topos/sim/scene.hpp
// A rigid-body scene as every simulator sees it (HOPNet, FIGNet, MeshGraphNet): the objects of a
// Kubric scene with their canonical meshes (KuBasic assets merged as trimesh loads them, or the
// built-in shapes), scaled by `size`, plus the floor appended last, as the HOPNet reference does:
// 4 nodes (±20, ±20, 0), faces [0,1,2] and [1,2,3], mass 0, friction 0.3, restitution 0.5,
// identity pose at every frame; the objects' poses at one frame (Poses) and a candidate contact
// between two of their faces (ContactCandidate). No LibTorch.
#pragma once

#include "topos/core/mesh_lifting.hpp"
#include "topos/io/obj_io.hpp"
#include "topos/mesh/primitives.hpp"
#include "topos/mesh/rigid.hpp"
#include "topos/sim/graph_frame.hpp"  // RowMatrix
#include "topos/data/kubric.hpp"

#include <Eigen/Dense>

#include <cstdint>
#include <filesystem>
#include <map>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

namespace topos::sim {

struct SceneObject {
  std::string asset_id, shape;
  double mass = 0, friction = 0, restitution = 0;
  bool is_floor = false;
  TriangleMesh mesh;               ///< canonical (scaled) mesh in the object frame
  Eigen::Vector3d center_of_mass;  ///< volumetric centre of mass of `mesh`
};

struct Scene {
  std::vector<SceneObject> objects;                                 ///< metadata order, floor last
  Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic> positions;  ///< frames × 3·O
  Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic> quaternions;  ///< frames × 4·O (w x y z)
  std::int64_t num_frames = 0;
  std::string source;

  std::size_t num_objects() const { return objects.size(); }
  Eigen::Vector3d position(std::int64_t frame, std::size_t o) const {
    return positions.block<1, 3>(frame, 3 * static_cast<Eigen::Index>(o)).transpose();
  }
  Eigen::Vector4d quaternion(std::int64_t frame, std::size_t o) const {
    return quaternions.block<1, 4>(frame, 4 * static_cast<Eigen::Index>(o)).transpose();
  }
};

inline TriangleMesh floor_mesh() {
  TriangleMesh m;
  m.name = "floor";
  m.vertices.resize(4, 3);
  m.vertices << -20, -20, 0, -20, 20, 0, 20, -20, 0, 20, 20, 0;
  m.faces.resize(2, 3);
  m.faces << 0, 1, 2, 1, 2, 3;
  return m;
}

/// The floor as a scene object: floor_mesh, mass 0, friction 0.3, restitution 0.5, static.
inline SceneObject floor_object() {
  SceneObject fl;
  fl.asset_id = fl.shape = "floor";
  fl.mass = 0.0;
  fl.friction = 0.3;
  fl.restitution = 0.5;
  fl.is_floor = true;
  fl.mesh = floor_mesh();
  fl.center_of_mass = Eigen::Vector3d::Zero();
  return fl;
}

/// Loads canonical meshes by shape name from a KuBasic-layout folder
/// (`<shape>/collision_geometry.obj`,
/// merged as trimesh does), or the built-in shapes when `assets` is empty. Caches per shape.
class MeshLibrary {
 public:
  explicit MeshLibrary(std::filesystem::path assets = {}) : assets_(std::move(assets)) {
    if (!assets_.empty() && !std::filesystem::is_directory(assets_))
      throw data::DataError(assets_.string() + ": asset folder does not exist");
  }
  const TriangleMesh& unit_mesh(const std::string& shape) {
    auto it = cache_.find(shape);
    if (it != cache_.end()) return it->second;
    TriangleMesh m;
    if (assets_.empty()) {
      m = builtin_shape(shape);
    } else {
      const auto path = assets_ / shape / "collision_geometry.obj";
      if (!std::filesystem::exists(path))
        throw data::DataError(path.string() + ": missing asset for shape '" + shape + "'");
      m = io::read_obj(path.string(), io::ObjReadOptions().merge(true)).mesh;
      m.name = shape;
    }
    return cache_.emplace(shape, std::move(m)).first->second;
  }

 private:
  std::filesystem::path assets_;
  std::map<std::string, TriangleMesh> cache_;
};

inline Scene make_scene(const data::KubricScene& k, MeshLibrary& meshes) {
  Scene s;
  s.num_frames = k.num_frames;
  s.source = k.source;
  const std::size_t O = k.instances.size() + 1;
  s.positions.setZero(k.num_frames, 3 * static_cast<Eigen::Index>(O));
  s.quaternions.setZero(k.num_frames, 4 * static_cast<Eigen::Index>(O));
  for (std::size_t i = 0; i < k.instances.size(); ++i) {
    const auto& in = k.instances[i];
    SceneObject o;
    o.asset_id = in.asset_id;
    o.shape = in.shape;
    o.mass = in.mass;
    o.friction = in.friction;
    o.restitution = in.restitution;
    o.mesh = meshes.unit_mesh(in.shape);
    o.mesh.vertices *= in.size;
    o.center_of_mass = volumetric_center_of_mass(o.mesh.vertices, o.mesh.faces);
    s.objects.push_back(std::move(o));
    s.positions.middleCols(3 * static_cast<Eigen::Index>(i), 3) = in.positions;
    s.quaternions.middleCols(4 * static_cast<Eigen::Index>(i), 4) = in.quaternions;
  }
  s.objects.push_back(floor_object());
  s.quaternions.col(4 * static_cast<Eigen::Index>(O - 1)).setOnes();
  return s;
}

/// World vertices of every object at frame t (the floor stays where it is).
inline std::vector<PosedObject> pose_scene(const Scene& s, std::int64_t t) {
  std::vector<PosedObject> out(s.num_objects());
  for (std::size_t o = 0; o < s.num_objects(); ++o) {
    out[o].faces = &s.objects[o].mesh.faces;
    out[o].vertices = s.objects[o].is_floor ? s.objects[o].mesh.vertices
                                            : pose_vertices(s.objects[o].mesh.vertices,
                                                            s.position(t, o), s.quaternion(t, o));
  }
  return out;
}

/// Object poses at one frame: positions O×3, quaternions O×4 (w x y z).
struct Poses {
  RowMatrix positions, quaternions;
};

/// A candidate contact between two objects at one frame: a face of each, by local face id
/// (obj0's face is "face0"). HOPNet turns them into contact cells.
struct ContactCandidate {
  std::int64_t obj0, face0, obj1, face1;
};

/// The ground-truth poses of frame t.
inline Poses scene_poses(const Scene& s, std::int64_t t) {
  if (t < 0 || t >= s.num_frames)
    throw std::out_of_range("scene_poses: frame " + std::to_string(t) + " outside 0.." +
                            std::to_string(s.num_frames - 1));
  const auto O = static_cast<Eigen::Index>(s.num_objects());
  Poses p;
  p.positions.resize(O, 3);
  p.quaternions.resize(O, 4);
  for (Eigen::Index o = 0; o < O; ++o) {
    p.positions.row(o) = s.position(t, static_cast<std::size_t>(o)).transpose();
    p.quaternions.row(o) = s.quaternion(t, static_cast<std::size_t>(o)).transpose();
  }
  return p;
}

}  // namespace topos::sim
