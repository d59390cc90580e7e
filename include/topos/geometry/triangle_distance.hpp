// topos/geometry/triangle_distance.hpp
// Closest points between two triangles, correct in every configuration (disjoint, parallel,
// coplanar, touching, intersecting, degenerate), generic over the number type and over CGAL
// kernels. CGAL 5.5 offers squared_distance(Triangle_3, Triangle_3) but no closest-point pair.
//
// Method: for disjoint triangles the minimum is attained by one of the 9 edge-edge pairs or the
// 6 vertex-face pairs; candidates are visited in a fixed order and only a strictly smaller
// distance replaces the best, so parallel and coplanar configurations get one deterministic
// pair. If the triangles intersect (CGAL's do_intersect predicate), the distance is exactly 0
// and both points are one common point (an edge crossing the other triangle's plane, or the
// best candidate in the coplanar case).
#pragma once

#include <CGAL/intersections.h>
#include <CGAL/Kernel/global_functions.h>

#include <array>
#include <limits>

namespace topos {

namespace detail {

template <class FT>
struct V3 {
  FT x, y, z;
  V3 operator+(const V3& o) const { return {x + o.x, y + o.y, z + o.z}; }
  V3 operator-(const V3& o) const { return {x - o.x, y - o.y, z - o.z}; }
  V3 operator*(const FT& s) const { return {x * s, y * s, z * s}; }
  FT dot(const V3& o) const { return x * o.x + y * o.y + z * o.z; }
  V3 cross(const V3& o) const { return {y * o.z - z * o.y, z * o.x - x * o.z, x * o.y - y * o.x}; }
};

template <class FT>
FT clamp01(const FT& t) {
  return t < FT(0) ? FT(0) : (t > FT(1) ? FT(1) : t);
}

// Closest points of segments p0 + s (p1 - p0) and q0 + t (q1 - q0), s, t in [0, 1]
// (Ericson, Real-Time Collision Detection 5.1.9), degenerate segments included.
template <class FT>
void closest_segment_segment(const V3<FT>& p0, const V3<FT>& p1, const V3<FT>& q0, const V3<FT>& q1,
                             V3<FT>& cp, V3<FT>& cq) {
  const V3<FT> d1 = p1 - p0, d2 = q1 - q0, r = p0 - q0;
  const FT a = d1.dot(d1), e = d2.dot(d2), f = d2.dot(r);
  FT s(0), t(0);
  if (a == FT(0) && e == FT(0)) {
    cp = p0;
    cq = q0;
    return;
  }
  if (a == FT(0)) {
    t = clamp01(f / e);
  } else {
    const FT c = d1.dot(r);
    if (e == FT(0)) {
      s = clamp01(-c / a);
    } else {
      const FT b = d1.dot(d2), denom = a * e - b * b;
      s = denom > FT(0) ? clamp01((b * f - c * e) / denom) : FT(0);
      t = (b * s + f) / e;
      if (t < FT(0)) {
        t = FT(0);
        s = clamp01(-c / a);
      } else if (t > FT(1)) {
        t = FT(1);
        s = clamp01((b - c) / a);
      }
    }
  }
  cp = p0 + d1 * s;
  cq = q0 + d2 * t;
}

// Closest point of triangle (a, b, c) to p by Voronoi regions (Ericson 5.1.5). Returns false
// for a zero-area triangle whose interior region would need a division by zero; its edges are
// then covered by the edge-edge candidates.
template <class FT>
bool closest_point_triangle(const V3<FT>& p, const V3<FT>& a, const V3<FT>& b, const V3<FT>& c,
                            V3<FT>& out) {
  const V3<FT> ab = b - a, ac = c - a, ap = p - a;
  const FT d1 = ab.dot(ap), d2 = ac.dot(ap);
  if (d1 <= FT(0) && d2 <= FT(0)) {
    out = a;
    return true;
  }
  const V3<FT> bp = p - b;
  const FT d3 = ab.dot(bp), d4 = ac.dot(bp);
  if (d3 >= FT(0) && d4 <= d3) {
    out = b;
    return true;
  }
  const FT vc = d1 * d4 - d3 * d2;
  if (vc <= FT(0) && d1 >= FT(0) && d3 <= FT(0)) {
    if (d1 - d3 == FT(0)) return false;
    out = a + ab * (d1 / (d1 - d3));
    return true;
  }
  const V3<FT> cp = p - c;
  const FT d5 = ab.dot(cp), d6 = ac.dot(cp);
  if (d6 >= FT(0) && d5 <= d6) {
    out = c;
    return true;
  }
  const FT vb = d5 * d2 - d1 * d6;
  if (vb <= FT(0) && d2 >= FT(0) && d6 <= FT(0)) {
    if (d2 - d6 == FT(0)) return false;
    out = a + ac * (d2 / (d2 - d6));
    return true;
  }
  const FT va = d3 * d6 - d5 * d4;
  if (va <= FT(0) && (d4 - d3) >= FT(0) && (d5 - d6) >= FT(0)) {
    if ((d4 - d3) + (d5 - d6) == FT(0)) return false;
    out = b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6)));
    return true;
  }
  const FT denom = va + vb + vc;
  if (!(denom > FT(0))) return false;
  out = a + ab * (vb / denom) + ac * (vc / denom);
  return true;
}

}  // namespace detail

/// Result of closest_points: a point on each triangle and their squared distance.
template <class Point, class FT>
struct TrianglePairClosest {
  Point p;              ///< on the first triangle
  Point q;              ///< on the second triangle
  FT squared_distance;  ///< |p - q|², exactly 0 when the triangles intersect
  bool intersecting;    ///< the triangles share at least one point
};

/// Closest points of two triangles given as arrays of 3 points each with number type FT.
/// `intersect` reports whether they intersect (exact for a CGAL kernel with exact predicates).
template <class FT>
std::pair<std::array<detail::V3<FT>, 2>, FT> closest_points_raw(
    const std::array<detail::V3<FT>, 3>& P, const std::array<detail::V3<FT>, 3>& Q,
    bool intersect) {
  using V = detail::V3<FT>;
  V bp = P[0], bq = Q[0], cp, cq;
  bool have = false;
  FT best(0);
  const auto consider = [&](const V& a, const V& b) {
    const V d = b - a;
    const FT dd = d.dot(d);
    if (!have || dd < best) {
      best = dd;
      bp = a;
      bq = b;
      have = true;
    }
  };
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) {
      detail::closest_segment_segment(P[i], P[(i + 1) % 3], Q[j], Q[(j + 1) % 3], cp, cq);
      consider(cp, cq);
    }
  for (int i = 0; i < 3; ++i)
    if (detail::closest_point_triangle(P[i], Q[0], Q[1], Q[2], cq)) consider(P[i], cq);
  for (int j = 0; j < 3; ++j)
    if (detail::closest_point_triangle(Q[j], P[0], P[1], P[2], cp)) consider(cp, Q[j]);
  if (intersect) {
    // A common point: where an edge of one triangle crosses the other's plane inside it. In the
    // coplanar case the best candidate above already has distance ~0.
    FT best_gap = best;
    V common = bp;
    for (int side = 0; side < 2; ++side) {
      const auto& A = side == 0 ? P : Q;
      const auto& B = side == 0 ? Q : P;
      const V n = (B[1] - B[0]).cross(B[2] - B[0]);
      for (int i = 0; i < 3; ++i) {
        const V a = A[i], b = A[(i + 1) % 3];
        const FT da = (a - B[0]).dot(n), db = (b - B[0]).dot(n);
        if ((da > FT(0) && db > FT(0)) || (da < FT(0) && db < FT(0)) || da == db) continue;
        const V x = a + (b - a) * (da / (da - db));
        V on;
        if (!detail::closest_point_triangle(x, B[0], B[1], B[2], on)) continue;
        const FT gap = (on - x).dot(on - x);
        if (gap < best_gap) {
          best_gap = gap;
          common = x;
        }
      }
    }
    return {{common, common}, FT(0)};
  }
  return {{bp, bq}, best};
}

/// Closest points between two CGAL triangles, for any CGAL kernel K (EPICK, EPECK,
/// Simple_cartesian<double> or <float>). Distance 0 exactly when the triangles intersect.
template <class K>
TrianglePairClosest<typename K::Point_3, typename K::FT> closest_points(
    const typename K::Triangle_3& P, const typename K::Triangle_3& Q) {
  using FT = typename K::FT;
  using V = detail::V3<FT>;
  const auto conv = [](const typename K::Point_3& p) { return V{p.x(), p.y(), p.z()}; };
  const std::array<V, 3> a{conv(P[0]), conv(P[1]), conv(P[2])},
      b{conv(Q[0]), conv(Q[1]), conv(Q[2])};
  const bool degenerate = P.is_degenerate() || Q.is_degenerate();
  // CGAL's do_intersect for triangles needs non-degenerate input; degenerate ones are handled by
  // the candidate search (a zero distance there means touching).
  const bool inter = !degenerate && CGAL::do_intersect(P, Q);
  auto [pts, d2] = closest_points_raw<FT>(a, b, inter);
  const auto back = [](const V& v) { return typename K::Point_3(v.x, v.y, v.z); };
  return {back(pts[0]), back(pts[1]), d2, inter || d2 == FT(0)};
}

}  // namespace topos
