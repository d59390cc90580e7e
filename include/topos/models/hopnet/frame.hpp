// topos/models/hopnet/frame.hpp
// One timestep of a scene: build_frame() turns poses and contact candidates into the frame's
// faces and contact cells (ranks 2 and 3) and its raw features x0..x4 (HopnetFrame).
#pragma once

#include "topos/geometry/contacts.hpp"
#include "topos/models/hopnet/contact_cells.hpp"
#include "topos/models/hopnet/geometry.hpp"
#include "topos/models/namespace_aliases.hpp"

#include <Eigen/Dense>

#include <array>
#include <cstdint>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

namespace topos::models::hopnet {

/// One timestep's complex and raw (double) features. Row i of x2/x3 is face/contact i.
struct HopnetFrame {
  RowMatrix x0, x1, x2, x3, x3_plus,
      x4;                           ///< x3_plus: the contact seen from face1 (native dual encoding)
  std::vector<std::int64_t> faces;  ///< global face id of each rank-2 cell
  std::vector<std::array<std::int64_t, 2>> contacts;  ///< (face0 row, face1 row) of each contact
  std::int64_t candidates = 0, unsafe = 0;  ///< detected pairs, and those dropped as intersecting

  std::int64_t num_faces() const { return static_cast<std::int64_t>(faces.size()); }
  std::int64_t num_contacts() const { return static_cast<std::int64_t>(contacts.size()); }
  double invalid_ratio() const {
    return candidates == 0 ? 0.0 : static_cast<double>(unsafe) / static_cast<double>(candidates);
  }
};

/// The ablations' node and edge features from the standard ones (models/ablations.py):
/// without centre-mass distances x0 keeps columns 0..7; with virtual object nodes every mesh
/// node gets its object's columns x4[8:13] (type, mass, friction, restitution), object o's
/// virtual node (row N+o) is [x4[o, 0:8], zeros, x4[o, 8:13]], and the spoke of node n (row E+n)
/// is [r0, |r0|, rt, |rt|] of that node (x0[n, 8:16]), negated when the virtual node comes first.
inline void lift_variant_features(const HopnetGeometry& g, HopnetFrame& f) {
  const SceneLiftingOptions& l = g.lifting;
  if (l.center_mass_distance && l.object_cells()) return;
  const std::int64_t N = g.num_nodes(), E = g.num_edges(), O = g.num_objects();
  const RowMatrix full = f.x0;
  const Eigen::Index base = l.center_mass_distance ? 16 : 8;
  if (l.object_cells()) {
    f.x0 = full.leftCols(base);
    return;
  }
  f.x0.setZero(N + O, l.x0_width());
  f.x0.topLeftCorner(N, base) = full.leftCols(base);
  for (std::int64_t n = 0; n < N; ++n)
    f.x0.block<1, 5>(n, base) = f.x4.block<1, 5>(g.node_object[static_cast<std::size_t>(n)], 8);
  for (std::int64_t o = 0; o < O; ++o) {
    f.x0.block<1, 8>(N + o, 0) = f.x4.block<1, 8>(o, 0);
    f.x0.block<1, 5>(N + o, base) = f.x4.block<1, 5>(o, 8);
  }
  RowMatrix x1(E + N, 8);
  x1.topRows(E) = f.x1;
  for (std::int64_t n = 0; n < N; ++n) {
    x1.row(E + n) = full.block<1, 8>(n, 8);
    if (g.spoke_virtual_first[static_cast<std::size_t>(n)])
      for (int c : {0, 1, 2, 4, 5, 6}) x1(E + n, c) = -x1(E + n, c);
  }
  f.x1 = std::move(x1);
}

/// Builds the complex and raw features at frame t from poses at t-2, t-1, t and the trajectory's
/// first frame (`first`, the GT frame 0), and the contact candidates at t (detect_contacts, or
/// collisions.json in reference mode).
inline HopnetFrame build_frame(const HopnetGeometry& g, const Poses& first, const Poses& prev2,
                               const Poses& prev, const Poses& now,
                               const std::vector<ContactCandidate>& candidates) {
  const std::int64_t N = g.num_nodes(), E = g.num_edges(), O = g.num_objects();
  const auto posed0 = pose_objects(g, first), posed2 = pose_objects(g, prev2),
             posed1 = pose_objects(g, prev), posedt = pose_objects(g, now);
  HopnetFrame f;
  f.x0.resize(N, 16);
  f.x1.resize(E, 8);
  f.x4.resize(O, 13);
  const auto put = [](RowMatrix& m, Eigen::Index r, int c, const Eigen::Vector3d& v) {
    m(r, c) = v.x();
    m(r, c + 1) = v.y();
    m(r, c + 2) = v.z();
    m(r, c + 3) = v.norm();
  };
  const auto node = [&](const std::vector<PosedObject>& p, std::int64_t n) -> Eigen::Vector3d {
    const auto o = static_cast<std::size_t>(g.node_object[static_cast<std::size_t>(n)]);
    return p[o].vertices.row(n - g.node_offset[o]).transpose();
  };
  for (std::int64_t n = 0; n < N; ++n) {
    const auto o = static_cast<Eigen::Index>(g.node_object[static_cast<std::size_t>(n)]);
    const Eigen::Vector3d xt = node(posedt, n), x1 = node(posed1, n), x2 = node(posed2, n),
                          x0 = node(posed0, n);
    put(f.x0, n, 0, xt - x1);
    put(f.x0, n, 4, x1 - x2);
    put(f.x0, n, 8, x0 - first.positions.row(o).transpose());
    put(f.x0, n, 12, xt - now.positions.row(o).transpose());
  }
  for (std::int64_t e = 0; e < E; ++e) {
    const auto [s, d] = g.edges[static_cast<std::size_t>(e)];
    put(f.x1, e, 0, node(posed0, s) - node(posed0, d));
    put(f.x1, e, 4, node(posedt, s) - node(posedt, d));
  }
  for (std::int64_t o = 0; o < O; ++o) {
    const auto& obj = *g.objects[static_cast<std::size_t>(o)];
    put(f.x4, o, 0, (now.positions.row(o) - prev.positions.row(o)).transpose());
    put(f.x4, o, 4, (prev.positions.row(o) - prev2.positions.row(o)).transpose());
    f.x4(o, 8) = obj.is_floor ? 0.0 : 1.0;
    f.x4(o, 9) = obj.is_floor ? 1.0 : 0.0;
    f.x4(o, 10) = obj.mass;
    f.x4(o, 11) = obj.friction;
    f.x4(o, 12) = obj.restitution;
  }

  // Faces and contacts in candidate order: face0, then face1 (each if new), then the cell.
  std::vector<std::int64_t> face_row(static_cast<std::size_t>(g.face_offset.back()), -1);
  std::vector<Eigen::Vector3d> normals;
  std::vector<double> normal_dist;  // native: distance of the pair that set the normal
  std::vector<std::array<double, 28>> x3, x3p;
  f.candidates = static_cast<std::int64_t>(candidates.size());
  for (const auto& c : candidates) {
    if (c.obj0 < 0 || c.obj0 >= O || c.obj1 < 0 || c.obj1 >= O || c.obj0 == c.obj1)
      throw std::invalid_argument("contact between objects " + std::to_string(c.obj0) + " and " +
                                  std::to_string(c.obj1) + " is not valid for " +
                                  std::to_string(O) + " objects");
    const auto& m0 = *g.objects[static_cast<std::size_t>(c.obj0)];
    const auto& m1 = *g.objects[static_cast<std::size_t>(c.obj1)];
    if (c.face0 < 0 || c.face0 >= m0.mesh.faces.rows() || c.face1 < 0 ||
        c.face1 >= m1.mesh.faces.rows())
      throw std::invalid_argument("contact names face " + std::to_string(c.face0) + " of object " +
                                  std::to_string(c.obj0) + " / face " + std::to_string(c.face1) +
                                  " of object " + std::to_string(c.obj1) +
                                  ", which does not exist");
    const auto P = topos::detail::face_points(posedt[static_cast<std::size_t>(c.obj0)], c.face0);
    const auto Q = topos::detail::face_points(posedt[static_cast<std::size_t>(c.obj1)], c.face1);
    const auto cg = detail::contact_geometry(P, Q, g.mode);
    if (!cg.safe) {
      ++f.unsafe;
      continue;
    }
    const std::int64_t gf[2] = {g.face_offset[static_cast<std::size_t>(c.obj0)] + c.face0,
                                g.face_offset[static_cast<std::size_t>(c.obj1)] + c.face1};
    const Eigen::Vector3d* n[2] = {&cg.nP, &cg.nQ};
    std::int64_t rows[2];
    for (int k = 0; k < 2; ++k) {
      auto& r = face_row[static_cast<std::size_t>(gf[k])];
      if (r < 0) {
        r = f.num_faces();
        f.faces.push_back(gf[k]);
        normals.push_back(*n[k]);
        normal_dist.push_back(cg.dist);
      } else if (g.mode == FeatureMode::reference ||
                 cg.dist < normal_dist[static_cast<std::size_t>(r)]) {
        normals[static_cast<std::size_t>(r)] =
            *n[k];  // reference: last write wins; native: closest partner
        normal_dist[static_cast<std::size_t>(r)] = cg.dist;
      }
      rows[k] = r;
    }
    f.contacts.push_back({rows[0], rows[1]});
    std::array<double, 28> a{}, b{};
    for (int k = 0; k < 3; ++k)
      a[static_cast<std::size_t>(k)] = cg.dir[k], b[static_cast<std::size_t>(k)] = -cg.dir[k];
    a[3] = b[3] = cg.dist;
    for (int v = 0; v < 3; ++v)
      for (int k = 0; k < 4; ++k) {
        a[static_cast<std::size_t>(4 + 4 * v + k)] = b[static_cast<std::size_t>(16 + 4 * v + k)] =
            cg.rowsP[static_cast<std::size_t>(v)][static_cast<std::size_t>(k)];
        a[static_cast<std::size_t>(16 + 4 * v + k)] = b[static_cast<std::size_t>(4 + 4 * v + k)] =
            cg.rowsQ[static_cast<std::size_t>(v)][static_cast<std::size_t>(k)];
      }
    x3.push_back(a);
    x3p.push_back(b);
  }
  f.x2.resize(f.num_faces(), 3);
  for (std::int64_t r = 0; r < f.num_faces(); ++r)
    f.x2.row(r) = normals[static_cast<std::size_t>(r)].transpose();
  f.x3.resize(f.num_contacts(), 28);
  f.x3_plus.resize(f.num_contacts(), 28);
  for (std::int64_t r = 0; r < f.num_contacts(); ++r)
    for (int k = 0; k < 28; ++k)
      f.x3(r, k) = x3[static_cast<std::size_t>(r)][static_cast<std::size_t>(k)],
              f.x3_plus(r, k) = x3p[static_cast<std::size_t>(r)][static_cast<std::size_t>(k)];
  lift_variant_features(g, f);
  return f;
}

}  // namespace topos::models::hopnet
