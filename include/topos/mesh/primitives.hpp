// topos/mesh/primitives.hpp
// Built-in closed, consistently outward-oriented triangle meshes of unit scale (the embedded
// default shapes when no KuBasic assets are given):
//   uv_sphere(8, 8)   radius 1, 58 vertices, 112 faces;
//   box_mesh(3)       cube [-1,1]^3, each side a 3x3 grid: 56 vertices, 108 faces;
//   cylinder_mesh(20, 3)  radius 1, z in [-1,1], 3 rings of 20 plus 2 cap centres: 62 vertices, 120
//     faces.
// builtin_shape() halves them to KuBasic's ±0.5 convention (a `size` multiplies the mesh).
// Std + Eigen only.
#pragma once

#include "topos/config.hpp"
#include "topos/mesh/triangle_mesh.hpp"

#include <cmath>
#include <array>
#include <map>
#include <string>
#include <tuple>
#include <vector>

namespace topos {

TOPOS_CORE_INLINE TriangleMesh uv_sphere(int rings = 8, int segments = 8);

TOPOS_CORE_INLINE TriangleMesh box_mesh(int k = 3);

TOPOS_CORE_INLINE TriangleMesh cylinder_mesh(int segments = 20, int rings = 3);

/// The built-in shape by name ("sphere", "cube", "cylinder") at KuBasic's scale: inside
/// [-0.5, 0.5]^3 like the KuBasic meshes, so `size` means the same (edge, diameter).
/// Throws MeshError for other names.
TOPOS_CORE_INLINE TriangleMesh builtin_shape(const std::string& name);

}  // namespace topos

#if !defined(TOPOS_CORE_COMPILED) || defined(TOPOS_CORE_COMPILED_SOURCE)
#include "topos/mesh/primitives-inl.hpp"
#endif
