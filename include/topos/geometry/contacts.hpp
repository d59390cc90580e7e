// topos/geometry/contacts.hpp
// Contact detection between posed triangle meshes (HOPNet's rank-3 cells).
//
// find_contacts (native): every pair of faces of different objects whose exact distance is at
// most d_c, each pair once, with its closest points. Broad phase: object boxes, then CGAL's
// box_intersection_d on the face boxes (inflated by d_c) inside the other object's box; narrow
// phase: a conservative separating-axis filter, then closest_points (EPICK).
// Order: by (obj0, obj1) with obj0 < obj1, then (face0, face1) ascending.
//
// reference_contacts (reference-compatible): the HOPNet reference's vertex-proximity method
// (utils/collisions.py with trimesh's closest point), quirks included: for each
// ordered object pair (i, k), each vertex of k within d_c of mesh i pairs its closest triangle of
// i with every face of k that holds the vertex; a pair whose only close vertex is index 0 is
// skipped; reversed entries are merged into the earlier one. Ties between closest triangles use
// trimesh's rule (two best squared distances within 1e-8: the larger normal·direction wins);
// trimesh's rtree candidate order is replaced by ascending face id.
#pragma once

#include "topos/mesh/rigid.hpp"
#include "topos/geometry/triangle_distance.hpp"

#include <CGAL/Exact_predicates_inexact_constructions_kernel.h>
#include <CGAL/box_intersection_d.h>

#include <algorithm>
#include <cmath>
#include <array>
#include <vector>

namespace topos {

struct FaceContact {
  std::int64_t obj0, face0, obj1, face1;  ///< local face ids of each object's mesh
  Eigen::Vector3d p, q;                   ///< closest points on face0 and face1
  double distance;                        ///< Euclidean, 0 when the faces intersect
  bool intersecting;
};

namespace detail {
inline std::array<Eigen::Vector3d, 3> face_points(const PosedObject& o, std::int64_t f) {
  const auto& F = *o.faces;
  return {o.vertices.row(F(f, 0)).transpose(), o.vertices.row(F(f, 1)).transpose(),
          o.vertices.row(F(f, 2)).transpose()};
}
inline CGAL::Bbox_3 face_box(const PosedObject& o, std::int64_t f, double inflate) {
  const auto t = face_points(o, f);
  Eigen::Vector3d lo = t[0].cwiseMin(t[1]).cwiseMin(t[2]), hi = t[0].cwiseMax(t[1]).cwiseMax(t[2]);
  return CGAL::Bbox_3(lo.x() - inflate, lo.y() - inflate, lo.z() - inflate, hi.x() + inflate,
                      hi.y() + inflate, hi.z() + inflate);
}
// True when a separating axis proves the triangles more than d_c apart: on a unit axis u the
// distance between two sets is at least the gap between their projections. Axes: both planes'
// normals and the six in-plane edge normals (the axes that part a face from the far half of a
// floor quad). Conservative: the gap less a bound on its rounding (projections of coordinates up
// to M on an axis a err by under 11·eps·|a|·M) must pass d_c by a relative 1e-6 in the squares,
// so every pair it drops is beyond d_c by the exact test too, touching pairs at d_c = 0 included.
inline bool separated_beyond(const std::array<Eigen::Vector3d, 3>& P,
                             const std::array<Eigen::Vector3d, 3>& Q, double d_c) {
  double M = 0;
  for (const auto* T : {&P, &Q})
    for (const auto& v : *T) M = std::max(M, v.cwiseAbs().maxCoeff());
  const double limit = d_c * d_c * (1 + 1e-6), rounding = 16 * 2.220446049250313e-16 * M;
  const auto parts = [&](const Eigen::Vector3d& axis) {
    const double n2 = axis.squaredNorm();
    if (!(n2 > 0)) return false;
    double plo = axis.dot(P[0]), phi = plo, qlo = axis.dot(Q[0]), qhi = qlo;
    for (int i = 1; i < 3; ++i) {
      const double p = axis.dot(P[i]), q = axis.dot(Q[i]);
      plo = std::min(plo, p);
      phi = std::max(phi, p);
      qlo = std::min(qlo, q);
      qhi = std::max(qhi, q);
    }
    const double gap = std::max(qlo - phi, plo - qhi) - rounding * std::sqrt(n2);
    return gap > 0 && gap * gap > limit * n2;
  };
  for (const auto* T : {&P, &Q}) {
    const auto& A = *T;
    const Eigen::Vector3d n = (A[1] - A[0]).cross(A[2] - A[0]);
    if (parts(n)) return true;
    for (int i = 0; i < 3; ++i)
      if (parts((A[(i + 1) % 3] - A[i]).cross(n))) return true;
  }
  return false;
}
inline void check_objects(const std::vector<PosedObject>& objects, const char* who) {
  for (std::size_t o = 0; o < objects.size(); ++o) {
    if (objects[o].faces == nullptr)
      throw std::invalid_argument(std::string(who) + ": object " + std::to_string(o) +
                                  " has no faces");
    if (!objects[o].vertices.allFinite())
      throw std::invalid_argument(std::string(who) + ": object " + std::to_string(o) +
                                  " has non-finite vertices");
  }
}
}  // namespace detail

inline std::vector<FaceContact> find_contacts(const std::vector<PosedObject>& objects, double d_c) {
  using K = CGAL::Exact_predicates_inexact_constructions_kernel;
  using Box = CGAL::Box_intersection_d::Box_with_info_d<double, 3, std::int64_t,
                                                        CGAL::Box_intersection_d::ID_EXPLICIT>;
  if (!(d_c >= 0) || !std::isfinite(d_c))
    throw std::invalid_argument(
        "find_contacts: the contact distance d_c must be finite and >= 0, "
        "got " +
        std::to_string(d_c));
  detail::check_objects(objects, "find_contacts");
  const std::size_t n = objects.size();
  std::vector<CGAL::Bbox_3> object_box(n);
  std::vector<std::vector<Box>> boxes(n);
  for (std::size_t o = 0; o < n; ++o) {
    const auto& F = *objects[o].faces;
    boxes[o].reserve(static_cast<std::size_t>(F.rows()));
    CGAL::Bbox_3 all;
    for (Eigen::Index f = 0; f < F.rows(); ++f) {
      // Each side inflated by d_c / 2: the boxes of two faces within d_c always overlap.
      const CGAL::Bbox_3 b = detail::face_box(objects[o], f, 0.5 * d_c);
      boxes[o].emplace_back(b, static_cast<std::int64_t>(f));
      all += b;
    }
    object_box[o] = all;
  }
  std::vector<FaceContact> out;
  std::vector<Box> near_i, near_k;
  for (std::size_t i = 0; i < n; ++i) {
    for (std::size_t k = i + 1; k < n; ++k) {
      if (!CGAL::do_overlap(object_box[i], object_box[k])) continue;
      // Only faces inside the other object's box can meet its faces (exact: each face box lies
      // in its object's box); resting objects keep a few faces each.
      const auto inside = [&](std::size_t o, const CGAL::Bbox_3& other, std::vector<Box>& kept) {
        kept.clear();
        for (const Box& b : boxes[o])
          if (CGAL::do_overlap(b.bbox(), other)) kept.push_back(b);
      };
      inside(i, object_box[k], near_i);
      inside(k, object_box[i], near_k);
      std::vector<std::pair<std::int64_t, std::int64_t>> candidates;
      CGAL::box_intersection_d(
          near_i.begin(), near_i.end(), near_k.begin(), near_k.end(),
          [&](const Box& a, const Box& b) { candidates.emplace_back(a.info(), b.info()); });
      std::sort(candidates.begin(), candidates.end());
      for (auto [fi, fk] : candidates) {
        const auto P = detail::face_points(objects[i], fi), Q = detail::face_points(objects[k], fk);
        if (detail::separated_beyond(P, Q, d_c)) continue;
        const auto r = closest_points<K>(
            K::Triangle_3({P[0].x(), P[0].y(), P[0].z()}, {P[1].x(), P[1].y(), P[1].z()},
                          {P[2].x(), P[2].y(), P[2].z()}),
            K::Triangle_3({Q[0].x(), Q[0].y(), Q[0].z()}, {Q[1].x(), Q[1].y(), Q[1].z()},
                          {Q[2].x(), Q[2].y(), Q[2].z()}));
        if (r.squared_distance > d_c * d_c) continue;
        out.push_back({static_cast<std::int64_t>(i),
                       fi,
                       static_cast<std::int64_t>(k),
                       fk,
                       {r.p.x(), r.p.y(), r.p.z()},
                       {r.q.x(), r.q.y(), r.q.z()},
                       std::sqrt(r.squared_distance),
                       r.intersecting});
      }
    }
  }
  return out;
}

/// One entry of the reference's per-frame collision list: object pair and (face of obj0, face of
/// obj1) pairs.
struct ReferenceContactEntry {
  std::int64_t obj0, obj1;
  std::vector<std::array<std::int64_t, 2>> pairs;
  friend bool operator==(const ReferenceContactEntry& a, const ReferenceContactEntry& b) {
    return a.obj0 == b.obj0 && a.obj1 == b.obj1 && a.pairs == b.pairs;
  }
};

/// Per-object data the reference detector reuses across frames: which faces hold each vertex.
struct VertexFaceIndex {
  std::vector<std::vector<std::int64_t>> faces_of_vertex;  ///< ascending face ids
  explicit VertexFaceIndex(const TriangleMesh::Faces& F, std::int64_t n_vertices)
      : faces_of_vertex(static_cast<std::size_t>(n_vertices)) {
    for (Eigen::Index f = 0; f < F.rows(); ++f)
      for (int c = 0; c < 3; ++c) faces_of_vertex[static_cast<std::size_t>(F(f, c))].push_back(f);
  }
};

/// `ties`, when given, receives the number of kept vertices whose closest triangle was a tie of
/// three or more triangles within trimesh's 1e-8: there the rtree's candidate order decided in
/// the reference, and this port may pick another (equally close) triangle.
inline std::vector<ReferenceContactEntry> reference_contacts(
    const std::vector<PosedObject>& objects, double d_c,
    const std::vector<VertexFaceIndex>* indices = nullptr, std::int64_t* ties = nullptr) {
  using V = detail::V3<double>;
  detail::check_objects(objects, "reference_contacts");
  const std::size_t n = objects.size();
  std::vector<VertexFaceIndex> own;
  if (indices == nullptr) {
    for (const auto& o : objects) own.emplace_back(*o.faces, o.vertices.rows());
    indices = &own;
  }
  // Face boxes and unit normals of every object, and object boxes.
  std::vector<std::vector<CGAL::Bbox_3>> fbox(n);
  std::vector<std::vector<Eigen::Vector3d>> normals(n);
  std::vector<CGAL::Bbox_3> obox(n);
  const double margin = d_c + 1e-6;  // also catches a runner-up within trimesh's 1e-8 tie window
  for (std::size_t o = 0; o < n; ++o) {
    const auto& F = *objects[o].faces;
    CGAL::Bbox_3 all;
    for (Eigen::Index f = 0; f < F.rows(); ++f) {
      fbox[o].push_back(detail::face_box(objects[o], f, 0.0));
      all += fbox[o].back();
      const auto t = detail::face_points(objects[o], f);
      const Eigen::Vector3d nrm = (t[1] - t[0]).cross(t[2] - t[0]);
      const double len = nrm.norm();
      normals[o].push_back(len > 0 ? Eigen::Vector3d(nrm / len) : Eigen::Vector3d::Zero());
    }
    obox[o] = all;
  }
  std::vector<ReferenceContactEntry> entries;
  for (std::size_t i = 0; i < n; ++i) {
    const auto& Fi = *objects[i].faces;
    const CGAL::Bbox_3 bi(obox[i].xmin() - margin, obox[i].ymin() - margin, obox[i].zmin() - margin,
                          obox[i].xmax() + margin, obox[i].ymax() + margin,
                          obox[i].zmax() + margin);
    for (std::size_t k = 0; k < n; ++k) {
      if (k == i) continue;
      const auto& Vk = objects[k].vertices;
      std::vector<std::int64_t> close;   // vertex ids of k within d_c of mesh i
      std::vector<std::int64_t> tri_of;  // their closest triangle of i
      for (Eigen::Index p = 0; p < Vk.rows(); ++p) {
        const Eigen::Vector3d x = Vk.row(p).transpose();
        if (x.x() < bi.xmin() || x.x() > bi.xmax() || x.y() < bi.ymin() || x.y() > bi.ymax() ||
            x.z() < bi.zmin() || x.z() > bi.zmax())
          continue;
        // Two best (squared distance, face) over faces whose box is within the margin.
        double d0 = std::numeric_limits<double>::infinity(), d1 = d0;
        std::int64_t f0 = -1, f1 = -1;
        std::vector<double> all_d;
        // Per best face, its normal against the unit direction from the closest point to x: the
        // tie-break. Kept instead of the points (GCC 12 misreads Eigen 3-vectors copied in a loop
        // as maybe-uninitialized).
        double dot0 = 0, dot1 = 0;
        for (Eigen::Index f = 0; f < Fi.rows(); ++f) {
          const CGAL::Bbox_3& b = fbox[i][static_cast<std::size_t>(f)];
          if (x.x() < b.xmin() - margin || x.x() > b.xmax() + margin || x.y() < b.ymin() - margin ||
              x.y() > b.ymax() + margin || x.z() < b.zmin() - margin || x.z() > b.zmax() + margin)
            continue;
          const auto t = detail::face_points(objects[i], f);
          V on;
          if (!detail::closest_point_triangle(
                  V{x.x(), x.y(), x.z()}, V{t[0].x(), t[0].y(), t[0].z()},
                  V{t[1].x(), t[1].y(), t[1].z()}, V{t[2].x(), t[2].y(), t[2].z()}, on))
            continue;
          const Eigen::Vector3d c(on.x, on.y, on.z);
          const double d = (x - c).squaredNorm();
          if (ties) all_d.push_back(d);
          if (!(d < d1)) continue;  // neither of the two best (NaN included)
          const double dot =
              d > 0 ? normals[i][static_cast<std::size_t>(f)].dot((x - c) / std::sqrt(d)) : 0.0;
          if (d < d0) {
            d1 = d0;
            f1 = f0;
            dot1 = dot0;
            d0 = d;
            f0 = f;
            dot0 = dot;
          } else {
            d1 = d;
            f1 = f;
            dot1 = dot;
          }
        }
        if (f0 < 0) continue;
        std::int64_t best = f0;
        double best_d = d0;
        if (f1 >= 0 && std::abs(d0 - d1) < 1e-8 && std::abs(d0) > 1e-8 && std::abs(d1) > 1e-8) {
          if (dot1 > dot0) {
            best = f1;
            best_d = d1;
          }
        }
        if (std::sqrt(best_d) <= d_c) {
          if (ties && std::count_if(all_d.begin(), all_d.end(),
                                    [&](double d) { return std::abs(d - d0) < 1e-8; }) >= 3)
            ++*ties;
          close.push_back(p);
          tri_of.push_back(best);
        }
      }
      // The reference tests `indices.any()`: a list holding only vertex 0 counts as empty.
      if (close.empty() || (close.size() == 1 && close[0] == 0)) continue;
      ReferenceContactEntry e{static_cast<std::int64_t>(i), static_cast<std::int64_t>(k), {}};
      for (std::size_t m = 0; m < close.size(); ++m)
        for (std::int64_t fk : (*indices)[k].faces_of_vertex[static_cast<std::size_t>(close[m])]) {
          const std::array<std::int64_t, 2> pr{tri_of[m], fk};
          if (std::find(e.pairs.begin(), e.pairs.end(), pr) == e.pairs.end()) e.pairs.push_back(pr);
        }
      entries.push_back(std::move(e));
    }
  }
  // Merge reversed entries into the earlier one.
  std::vector<ReferenceContactEntry> merged;
  std::vector<char> removed(entries.size(), 0);
  for (std::size_t a = 0; a < entries.size(); ++a) {
    if (removed[a]) continue;
    ReferenceContactEntry e = entries[a];
    for (std::size_t b = a + 1; b < entries.size(); ++b) {
      if (removed[b] || entries[b].obj0 != e.obj1 || entries[b].obj1 != e.obj0) continue;
      for (const auto& pr : entries[b].pairs) {
        const std::array<std::int64_t, 2> rev{pr[1], pr[0]};
        if (std::find(e.pairs.begin(), e.pairs.end(), rev) == e.pairs.end()) e.pairs.push_back(rev);
      }
      removed[b] = 1;
    }
    merged.push_back(std::move(e));
  }
  return merged;
}

}  // namespace topos
