// topos/geometry/physx_triangle_distance.hpp
// The HOPNet reference's triangle-triangle distance, a port of PhysX's routine
// (utils/triangles.py), quirks included: on the early-exit edge path and on
// the disjoint fallback it returns the *squared* distance, and it returns 0 (the pair is then
// "unsafe") when it cannot prove the triangles disjoint. Used only in reference-compatible mode;
// the correct routine is closest_points() in triangle_distance.hpp. Eigen only.
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <array>
#include <cmath>
#include <limits>

namespace topos {

struct PhysxTriangleResult {
  Eigen::Vector3d cp, cq;
  double distance;  ///< Euclidean on the vertex-face paths, squared on the others, 0 if unsafe
};

namespace detail {
inline double physx_clamp01(double t) {
  return t < 0 ? 0 : (t > 1 ? 1 : t);
}

inline void physx_segments(const Eigen::Vector3d& p, const Eigen::Vector3d& a,
                           const Eigen::Vector3d& q, const Eigen::Vector3d& b, Eigen::Vector3d& x,
                           Eigen::Vector3d& y) {
  const Eigen::Vector3d T = q - p;
  const double A = a.dot(a), B = b.dot(b), D = a.dot(b), X = a.dot(T), Y = b.dot(T);
  const double den = A * B - D * D;
  double t = den != 0 ? physx_clamp01((X * B - Y * D) / den) : 0.0;
  double u;
  if (B != 0) {
    u = (t * D - Y) / B;
    if (u < 0) {
      u = 0;
      t = A != 0 ? physx_clamp01(X / A) : 0.0;
    } else if (u > 1) {
      u = 1;
      t = A != 0 ? physx_clamp01((D + X) / A) : 0.0;
    }
  } else {
    u = 0;
    t = A != 0 ? physx_clamp01(X / A) : 0.0;
  }
  x = p + t * a;
  y = q + u * b;
}

// Index of the smallest (or largest) of three values with the reference's tie order.
inline int physx_pick(const std::array<double, 3>& v, bool smallest) {
  int idx = smallest ? (v[0] < v[1] ? 0 : 1) : (v[0] > v[1] ? 0 : 1);
  if (smallest ? v[2] < v[idx] : v[2] > v[idx]) idx = 2;
  return idx;
}
}  // namespace detail

inline PhysxTriangleResult physx_triangle_triangle(const std::array<Eigen::Vector3d, 3>& P,
                                                   const std::array<Eigen::Vector3d, 3>& Q) {
  const std::array<Eigen::Vector3d, 3> S{P[1] - P[0], P[2] - P[1], P[0] - P[2]};
  const std::array<Eigen::Vector3d, 3> T{Q[1] - Q[0], Q[2] - Q[1], Q[0] - Q[2]};
  double mindd = std::numeric_limits<double>::infinity();
  bool disjoint = false;
  Eigen::Vector3d minP = P[0], minQ = Q[0], cp, cq;
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) {
      detail::physx_segments(P[i], S[i], Q[j], T[j], cp, cq);
      const Eigen::Vector3d v = cq - cp;
      const double dd = v.dot(v);
      // Only a new closest edge pair is tested for separation (as in PhysX and the reference):
      // in near-parallel configurations several pairs pass the test, and only the first that is
      // also the closest so far may return.
      if (dd > mindd) continue;
      minP = cp;
      minQ = cq;
      mindd = dd;
      double a = (P[(i + 2) % 3] - cp).dot(v);
      double b = (Q[(j + 2) % 3] - cq).dot(v);
      if (a <= 0 && b >= 0) return {cp, cq, dd};  // squared, as in the reference
      if (a <= 0)
        a = 0;
      else if (b > 0)
        b = 0;
      if (mindd - a + b > 0) disjoint = true;
    }
  }
  const auto vertex_face =
      [&](const std::array<Eigen::Vector3d, 3>& A, const std::array<Eigen::Vector3d, 3>& SA,
          const std::array<Eigen::Vector3d, 3>& B, bool b_is_q, PhysxTriangleResult& out) {
        const Eigen::Vector3d sn = SA[0].cross(SA[1]);
        const double snl = sn.dot(sn);
        if (!(snl > 1e-15)) return false;
        std::array<double, 3> tp;
        for (int k = 0; k < 3; ++k) tp[static_cast<std::size_t>(k)] = (A[0] - B[k]).dot(sn);
        int idx = -1;
        if (tp[0] > 0 && tp[1] > 0 && tp[2] > 0)
          idx = detail::physx_pick(tp, true);
        else if (tp[0] < 0 && tp[1] < 0 && tp[2] < 0)
          idx = detail::physx_pick(tp, false);
        if (idx < 0) return false;
        disjoint = true;
        const Eigen::Vector3d q = B[idx];
        for (int m = 0; m < 3; ++m)
          if (!((q - A[m]).dot(sn.cross(SA[m])) > 0)) return false;
        const Eigen::Vector3d on_a =
            q + (sn * tp[static_cast<std::size_t>(idx)]) / snl;  // the reference's rounding order
        out = b_is_q ? PhysxTriangleResult{on_a, q, (on_a - q).norm()}
                     : PhysxTriangleResult{q, on_a, (on_a - q).norm()};
        return true;
      };
  PhysxTriangleResult r;
  if (vertex_face(P, S, Q, true, r)) return r;
  if (vertex_face(Q, T, P, false, r)) return r;
  if (disjoint) return {minP, minQ, mindd};  // squared
  return {cp, cq, 0.0};
}

}  // namespace topos
