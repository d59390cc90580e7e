// topos/mesh/rigid.hpp
// Rigid-body helpers on triangle meshes: world poses from position + quaternion (w, x, y, z),
// volumetric centre of mass (divergence theorem, as trimesh computes it), and rigid shape
// matching by polar decomposition (how HOPNet re-rigidifies each body after a predicted step).
// Std + Eigen only.
#pragma once

#include "topos/mesh/triangle_mesh.hpp"

#include <Eigen/Geometry>
#include <Eigen/SVD>

#include <cmath>
#include <limits>
#include <stdexcept>

namespace topos {

using Vertices = TriangleMesh::Vertices;

/// Rotation of a quaternion given as (w, x, y, z), normalised first (trimesh rescales by 2/|q|²).
inline Eigen::Matrix3d rotation_from_wxyz(const Eigen::Vector4d& q) {
  const double n = q.norm();
  if (!(n > 0) || !std::isfinite(n))
    throw std::invalid_argument("rotation_from_wxyz: quaternion has zero or non-finite norm");
  return Eigen::Quaterniond(q[0] / n, q[1] / n, q[2] / n, q[3] / n).toRotationMatrix();
}

/// Quaternion (w, x, y, z) of a rotation matrix.
inline Eigen::Vector4d wxyz_from_rotation(const Eigen::Matrix3d& R) {
  const Eigen::Quaterniond q(R);
  return {q.w(), q.x(), q.y(), q.z()};
}

/// x = R(q) v + p for every row v.
inline Vertices pose_vertices(const Vertices& v, const Eigen::Vector3d& position,
                              const Eigen::Vector4d& wxyz) {
  const Eigen::Matrix3d R = rotation_from_wxyz(wxyz);
  Vertices out = v * R.transpose();
  out.rowwise() += position.transpose();
  return out;
}

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
inline Vertices pose_vertices_trimesh(const Vertices& v, const Eigen::Vector3d& position,
                                      const Eigen::Vector4d& wxyz) {
  double q[4] = {wxyz[0], wxyz[1], wxyz[2], wxyz[3]};
  double sq[4];
  for (int i = 0; i < 4; ++i) sq[i] = q[i] * q[i];
  const double n = (sq[0] + sq[2]) + (sq[1] + sq[3]);
  if (!(n >= 4 * std::numeric_limits<double>::epsilon()) || !std::isfinite(n))
    throw std::invalid_argument("pose_vertices_trimesh: quaternion has zero or non-finite norm");
  const double k = std::sqrt(2.0 / n);
  for (double& x : q) x *= k;
  double Q[4][4];
  for (int a = 0; a < 4; ++a)
    for (int b = 0; b < 4; ++b) Q[a][b] = q[a] * q[b];
  const double m[3][4] = {
      {1.0 - Q[2][2] - Q[3][3], Q[1][2] - Q[3][0], Q[1][3] + Q[2][0], position.x()},
      {Q[1][2] + Q[3][0], 1.0 - Q[1][1] - Q[3][3], Q[2][3] - Q[1][0], position.y()},
      {Q[1][3] - Q[2][0], Q[2][3] + Q[1][0], 1.0 - Q[1][1] - Q[2][2], position.z()}};
  bool identity = true;
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 4; ++j)
      identity = identity && std::abs(m[i][j] - (i == j ? 1.0 : 0.0)) < 1e-8;
  if (identity) return v;
  Vertices out(v.rows(), 3);
  for (Eigen::Index r = 0; r < v.rows(); ++r)
    for (int i = 0; i < 3; ++i)
      out(r, i) = std::fma(
          m[i][3], 1.0, std::fma(m[i][2], v(r, 2), std::fma(m[i][1], v(r, 1), m[i][0] * v(r, 0))));
  return out;
}

/// Volumetric centre of mass by the divergence theorem (trimesh's formula). Returns 0 when the
/// enclosed volume is below 1e-13 in magnitude (open surfaces such as the floor).
inline Eigen::Vector3d volumetric_center_of_mass(const Vertices& v, const TriangleMesh::Faces& f) {
  double vol = 0;
  Eigen::Vector3d acc = Eigen::Vector3d::Zero();
  for (Eigen::Index i = 0; i < f.rows(); ++i) {
    const Eigen::Vector3d a = v.row(f(i, 0)), b = v.row(f(i, 1)), c = v.row(f(i, 2));
    const Eigen::Vector3d k = (b - a).cross(c - a);
    const Eigen::Vector3d f1 = a + b + c;
    const Eigen::Vector3d f2 =
        a.cwiseProduct(a) + b.cwiseProduct(b) + a.cwiseProduct(b) + c.cwiseProduct(f1);
    vol += k.x() * f1.x() / 6.0;
    acc += k.cwiseProduct(f2) / 24.0;
  }
  if (std::abs(vol) < 1e-13) return Eigen::Vector3d::Zero();
  return acc / vol;
}

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
inline RigidPose shape_match(const Vertices& X, const Eigen::Vector3d& com_canonical,
                             const Vertices& x, const TriangleMesh::Faces& f) {
  if (X.rows() != x.rows() || X.rows() == 0)
    throw std::invalid_argument("shape_match: vertex counts differ or are zero");
  const Eigen::Vector3d c = volumetric_center_of_mass(x, f);
  Eigen::Matrix3d A = Eigen::Matrix3d::Zero();
  for (Eigen::Index i = 0; i < X.rows(); ++i)
    A += (x.row(i).transpose() - c) * (X.row(i).transpose() - com_canonical).transpose();
  A /= static_cast<double>(X.rows());
  const Eigen::JacobiSVD<Eigen::Matrix3d> svd(A, Eigen::ComputeFullU | Eigen::ComputeFullV);
  const Eigen::Matrix3d R = svd.matrixU() * svd.matrixV().transpose();
  return {c - R * com_canonical, wxyz_from_rotation(R)};
}

}  // namespace topos
