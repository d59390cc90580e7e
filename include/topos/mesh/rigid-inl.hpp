// topos/mesh/rigid-inl.hpp
// The definitions of rigid.hpp's functions: compiled once in topos::core_compiled
// (src/core.cpp), or inline in every translation unit with topos::core alone (topos/config.hpp).
#pragma once

#include "topos/mesh/rigid.hpp"

#include <Eigen/SVD>

namespace topos {

TOPOS_CORE_INLINE Eigen::Matrix3d rotation_from_wxyz(const Eigen::Vector4d& q) {
  const double n = q.norm();
  if (!(n > 0) || !std::isfinite(n))
    throw std::invalid_argument("rotation_from_wxyz: quaternion has zero or non-finite norm");
  return Eigen::Quaterniond(q[0] / n, q[1] / n, q[2] / n, q[3] / n).toRotationMatrix();
}

TOPOS_CORE_INLINE Eigen::Vector4d wxyz_from_rotation(const Eigen::Matrix3d& R) {
  const Eigen::Quaterniond q(R);
  return {q.w(), q.x(), q.y(), q.z()};
}

TOPOS_CORE_INLINE Vertices pose_vertices(const Vertices& v, const Eigen::Vector3d& position,
                                         const Eigen::Vector4d& wxyz) {
  const Eigen::Matrix3d R = rotation_from_wxyz(wxyz);
  Vertices out = v * R.transpose();
  out.rowwise() += position.transpose();
  return out;
}

TOPOS_CORE_INLINE Vertices pose_vertices_trimesh(const Vertices& v, const Eigen::Vector3d& position,
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

TOPOS_CORE_INLINE Eigen::Vector3d volumetric_center_of_mass(const Vertices& v,
                                                            const TriangleMesh::Faces& f) {
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

TOPOS_CORE_INLINE RigidPose shape_match(const Vertices& X, const Eigen::Vector3d& com_canonical,
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
