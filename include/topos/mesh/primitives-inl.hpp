// topos/mesh/primitives-inl.hpp
// The definitions of primitives.hpp's functions: compiled once in topos::core_compiled
// (src/core.cpp), or inline in every translation unit with topos::core alone (topos/config.hpp).
#pragma once

#include "topos/mesh/primitives.hpp"

namespace topos {

TOPOS_CORE_INLINE TriangleMesh uv_sphere(int rings, int segments) {
  if (rings < 2 || segments < 3) throw MeshError("uv_sphere: needs rings >= 2 and segments >= 3");
  const double pi = std::acos(-1.0);
  TriangleMesh m;
  m.name = "sphere";
  const int nv = 2 + (rings - 1) * segments;
  m.vertices.resize(nv, 3);
  m.vertices.row(0) << 0, 0, 1;
  for (int r = 1; r < rings; ++r) {
    const double th = pi * r / rings;
    for (int s = 0; s < segments; ++s) {
      const double ph = 2 * pi * s / segments;
      m.vertices.row(1 + (r - 1) * segments + s) << std::sin(th) * std::cos(ph),
          std::sin(th) * std::sin(ph), std::cos(th);
    }
  }
  m.vertices.row(nv - 1) << 0, 0, -1;
  std::vector<std::array<std::int64_t, 3>> f;
  auto ring = [&](int r, int s) {
    return static_cast<std::int64_t>(1 + (r - 1) * segments + (s % segments));
  };
  for (int s = 0; s < segments; ++s) f.push_back({0, ring(1, s), ring(1, s + 1)});
  for (int r = 1; r < rings - 1; ++r) {
    for (int s = 0; s < segments; ++s) {
      f.push_back({ring(r, s), ring(r + 1, s), ring(r + 1, s + 1)});
      f.push_back({ring(r, s), ring(r + 1, s + 1), ring(r, s + 1)});
    }
  }
  for (int s = 0; s < segments; ++s)
    f.push_back({ring(rings - 1, s), nv - 1, ring(rings - 1, s + 1)});
  m.faces.resize(static_cast<Eigen::Index>(f.size()), 3);
  for (std::size_t i = 0; i < f.size(); ++i)
    m.faces.row(static_cast<Eigen::Index>(i)) << f[i][0], f[i][1], f[i][2];
  return m;
}

TOPOS_CORE_INLINE TriangleMesh box_mesh(int k) {
  if (k < 1) throw MeshError("box_mesh: needs k >= 1");
  TriangleMesh m;
  m.name = "cube";
  std::map<std::tuple<int, int, int>, std::int64_t> index;  // integer lattice point -> vertex
  std::vector<Eigen::Vector3d> verts;
  std::vector<std::array<std::int64_t, 3>> faces;
  auto vid = [&](int x, int y, int z) {
    auto [it, fresh] =
        index.emplace(std::make_tuple(x, y, z), static_cast<std::int64_t>(verts.size()));
    if (fresh) verts.emplace_back(2.0 * x / k - 1, 2.0 * y / k - 1, 2.0 * z / k - 1);
    return it->second;
  };
  // For each axis and side, a k x k grid; (u, v) axes chosen so that u x v points outward.
  for (int axis = 0; axis < 3; ++axis) {
    for (int side = 0; side < 2; ++side) {
      const int ua = (axis + 1) % 3, va = (axis + 2) % 3;
      for (int i = 0; i < k; ++i) {
        for (int j = 0; j < k; ++j) {
          auto P = [&](int a, int b) {
            int c[3];
            c[axis] = side * k;
            c[ua] = a;
            c[va] = b;
            return vid(c[0], c[1], c[2]);
          };
          const auto p00 = P(i, j), p10 = P(i + 1, j), p11 = P(i + 1, j + 1), p01 = P(i, j + 1);
          if (side == 1) {
            faces.push_back({p00, p10, p11});
            faces.push_back({p00, p11, p01});
          } else {
            faces.push_back({p00, p11, p10});
            faces.push_back({p00, p01, p11});
          }
        }
      }
    }
  }
  m.vertices.resize(static_cast<Eigen::Index>(verts.size()), 3);
  for (std::size_t i = 0; i < verts.size(); ++i)
    m.vertices.row(static_cast<Eigen::Index>(i)) = verts[i].transpose();
  m.faces.resize(static_cast<Eigen::Index>(faces.size()), 3);
  for (std::size_t i = 0; i < faces.size(); ++i)
    m.faces.row(static_cast<Eigen::Index>(i)) << faces[i][0], faces[i][1], faces[i][2];
  return m;
}

TOPOS_CORE_INLINE TriangleMesh cylinder_mesh(int segments, int rings) {
  if (segments < 3 || rings < 2)
    throw MeshError("cylinder_mesh: needs segments >= 3 and rings >= 2");
  const double pi = std::acos(-1.0);
  TriangleMesh m;
  m.name = "cylinder";
  const int nv = rings * segments + 2;
  m.vertices.resize(nv, 3);
  for (int r = 0; r < rings; ++r)
    for (int s = 0; s < segments; ++s)
      m.vertices.row(r * segments + s) << std::cos(2 * pi * s / segments),
          std::sin(2 * pi * s / segments), -1.0 + 2.0 * r / (rings - 1);
  const std::int64_t bottom = nv - 2, top = nv - 1;
  m.vertices.row(bottom) << 0, 0, -1;
  m.vertices.row(top) << 0, 0, 1;
  auto V = [&](int r, int s) { return static_cast<std::int64_t>(r * segments + (s % segments)); };
  std::vector<std::array<std::int64_t, 3>> f;
  for (int r = 0; r + 1 < rings; ++r)
    for (int s = 0; s < segments; ++s) {
      f.push_back({V(r, s), V(r, s + 1), V(r + 1, s + 1)});
      f.push_back({V(r, s), V(r + 1, s + 1), V(r + 1, s)});
    }
  for (int s = 0; s < segments; ++s) {
    f.push_back({bottom, V(0, s + 1), V(0, s)});
    f.push_back({top, V(rings - 1, s), V(rings - 1, s + 1)});
  }
  m.faces.resize(static_cast<Eigen::Index>(f.size()), 3);
  for (std::size_t i = 0; i < f.size(); ++i)
    m.faces.row(static_cast<Eigen::Index>(i)) << f[i][0], f[i][1], f[i][2];
  return m;
}

TOPOS_CORE_INLINE TriangleMesh builtin_shape(const std::string& name) {
  TriangleMesh m;
  if (name == "sphere")
    m = uv_sphere();
  else if (name == "cube")
    m = box_mesh();
  else if (name == "cylinder")
    m = cylinder_mesh();
  else
    throw MeshError("unknown built-in shape '" + name + "' (known: sphere, cube, cylinder)");
  m.vertices *= 0.5;
  m.name = name;
  return m;
}

}  // namespace topos
