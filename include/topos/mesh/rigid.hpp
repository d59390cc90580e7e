// topos/mesh/rigid.hpp
// Rigid-body helpers on triangle meshes: world poses from position + quaternion (w, x, y, z),
// volumetric centre of mass (divergence theorem, as trimesh computes it), and rigid shape
// matching by polar decomposition (how HOPNet re-rigidifies each body after a predicted step).
// Std + Eigen only.
#pragma once

#include "topos/config.hpp"
#include "topos/mesh/triangle_mesh.hpp"

#include <Eigen/Geometry>

#include <cmath>
#include <limits>
#include <stdexcept>

namespace topos {

using Vertices = TriangleMesh::Vertices;

/// Rotation of a quaternion given as (w, x, y, z), normalised first (trimesh rescales by 2/|q|²).
TOPOS_CORE_INLINE Eigen::Matrix3d rotation_from_wxyz(const Eigen::Vector4d& q);

/// Quaternion (w, x, y, z) of a rotation matrix.
TOPOS_CORE_INLINE Eigen::Vector4d wxyz_from_rotation(const Eigen::Matrix3d& R);

/// x = R(q) v + p for every row v.
TOPOS_CORE_INLINE Vertices pose_vertices(const Vertices& v, const Eigen::Vector3d& position,
                                         const Eigen::Vector4d& wxyz);

/// x = R(q) v + p computed with trimesh's arithmetic, bit for bit, as the HOPNet reference poses
/// its meshes (`quaternion_matrix`, then `transform_points` through NumPy and OpenBLAS):
///  - |q|² as OpenBLAS's dot kernel adds the squares, (w² + y²) + (x² + z²); q scaled by
///    sqrt(2/|q|²); the matrix entries from the outer product q qᵀ in trimesh's order;
///  - each coordinate as the gemm kernel accumulates it, one fused multiply-add per term in
///    order: fma(t, 1, fma(r2, z, fma(r1, y, r0 x))).
///  - a transform within 1e-8 of the identity leaves the vertices as they are.
/// The result differs from pose_vertices() by an ulp or so, which is enough to flip the
/// reference's triangle-distance branches where faces rest flat on each other (reference mode
/// needs its contact features exactly). Assumes no floating-point contraction (the default
/// x86-64 build emits no FMA instructions of its own). Measured: the reference's node positions
/// of MOVi-A scene 8 at frames 1 to 3 (golden step000/nodes_pos_in.npy) reproduced bitwise.
TOPOS_CORE_INLINE Vertices pose_vertices_trimesh(const Vertices& v, const Eigen::Vector3d& position,
                                                 const Eigen::Vector4d& wxyz);

/// Volumetric centre of mass by the divergence theorem (trimesh's formula). Returns 0 when the
/// enclosed volume is below 1e-13 in magnitude (open surfaces such as the floor).
TOPOS_CORE_INLINE Eigen::Vector3d volumetric_center_of_mass(const Vertices& v,
                                                            const TriangleMesh::Faces& f);

/// One object of a scene in world coordinates; `faces` is borrowed (static across frames).
struct PosedObject {
  Vertices vertices;
  const TriangleMesh::Faces* faces = nullptr;
};

struct RigidPose {
  Eigen::Vector3d position;
  Eigen::Vector4d wxyz;
};

/// Best rigid pose mapping canonical vertices X (centre of mass `com_canonical`) onto moved
/// vertices x with the same faces: R is the orthogonal polar factor of A = (1/n) Σ p qᵀ with
/// p = x - c, q = X - c̄, c the volumetric centre of mass of x; position = c - R c̄.
/// Like the reference, a reflection (det R = -1) is not guarded against.
TOPOS_CORE_INLINE RigidPose shape_match(const Vertices& X, const Eigen::Vector3d& com_canonical,
                                        const Vertices& x, const TriangleMesh::Faces& f);

}  // namespace topos

#if !defined(TOPOS_CORE_COMPILED) || defined(TOPOS_CORE_COMPILED_SOURCE)
#include "topos/mesh/rigid-inl.hpp"
#endif
