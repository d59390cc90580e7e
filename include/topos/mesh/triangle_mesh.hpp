// topos/mesh/triangle_mesh.hpp
// A plain triangle mesh (vertices and faces as Eigen matrices) and its validation. Std + Eigen.
#pragma once

#include <Eigen/Core>

#include <cmath>
#include <cstdint>
#include <stdexcept>
#include <string>

namespace topos {

/// Thrown for malformed meshes; the message names the mesh, and the face or vertex.
class MeshError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

struct TriangleMesh {
  using Vertices = Eigen::Matrix<double, Eigen::Dynamic, 3, Eigen::RowMajor>;
  using Faces = Eigen::Matrix<std::int64_t, Eigen::Dynamic, 3, Eigen::RowMajor>;
  Vertices vertices;
  Faces faces;
  std::string name;  ///< used in error messages

  std::int64_t num_vertices() const { return vertices.rows(); }
  std::int64_t num_faces() const { return faces.rows(); }

  /// Throws MeshError on an empty mesh, non-finite coordinates, face indices out of range or
  /// faces that repeat a vertex.
  void validate() const {
    const std::string who = name.empty() ? std::string("mesh") : "mesh '" + name + "'";
    if (vertices.rows() == 0 || faces.rows() == 0)
      throw MeshError(who + " is empty (" + std::to_string(vertices.rows()) + " vertices, " +
                      std::to_string(faces.rows()) + " faces)");
    for (Eigen::Index i = 0; i < vertices.rows(); ++i) {
      if (!vertices.row(i).allFinite())
        throw MeshError(who + ": vertex " + std::to_string(i) + " has a non-finite coordinate");
    }
    for (Eigen::Index f = 0; f < faces.rows(); ++f) {
      for (int k = 0; k < 3; ++k) {
        const auto v = faces(f, k);
        if (v < 0 || v >= vertices.rows())
          throw MeshError(who + ": face " + std::to_string(f) + " uses vertex " +
                          std::to_string(v) + ", out of range [0, " +
                          std::to_string(vertices.rows()) + ")");
      }
      if (faces(f, 0) == faces(f, 1) || faces(f, 1) == faces(f, 2) || faces(f, 0) == faces(f, 2)) {
        throw MeshError(who + ": face " + std::to_string(f) + " repeats a vertex");
      }
    }
  }
};

}  // namespace topos
