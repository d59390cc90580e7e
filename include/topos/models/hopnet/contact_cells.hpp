// topos/models/hopnet/contact_cells.hpp
// HOPNet's contact cells: the candidate face pairs of a frame (detected, or read from the
// reference's collisions.json) and the geometry of a contact that its rank-3 features describe.
#pragma once

#include "topos/data/json.hpp"
#include "topos/geometry/contacts.hpp"
#include "topos/geometry/physx_triangle_distance.hpp"
#include "topos/geometry/triangle_distance.hpp"
#include "topos/models/hopnet/geometry.hpp"
#include "topos/models/namespace_aliases.hpp"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <map>
#include <string>
#include <vector>

namespace topos::models::hopnet {

/// A candidate contact: local face ids of two objects (obj0's face is "face0", role -1); the
/// type lives in topos/sim/scene.hpp, this alias is kept for HOPNet's code and its users.
using sim::ContactCandidate;

/// Contacts at one frame: reference mode runs the reference detector; native mode the exact one.
inline std::vector<ContactCandidate> detect_contacts(const HopnetGeometry& g,
                                                     const std::vector<PosedObject>& posed,
                                                     double d_c) {
  std::vector<ContactCandidate> out;
  if (g.mode == FeatureMode::reference) {
    for (const auto& e : reference_contacts(posed, d_c, &g.vertex_faces))
      for (const auto& p : e.pairs) out.push_back({e.obj0, p[0], e.obj1, p[1]});
  } else {
    for (const auto& c : find_contacts(posed, d_c))
      out.push_back({c.obj0, c.face0, c.obj1, c.face1});
  }
  return out;
}

/// The reference's collisions.json text: frame -> entries, flattened into candidates in list
/// order; `path` names it in errors.
inline std::map<std::int64_t, std::vector<ContactCandidate>> parse_collisions_json(
    const std::string& text, const std::string& path) {
  const nlohmann::json j = data::parse_json(text, path);
  if (!j.is_object())
    throw data::DataError(path + ": expected an object mapping frame numbers to contact lists");
  std::map<std::int64_t, std::vector<ContactCandidate>> out;
  try {
    for (const auto& [frame, entries] : j.items()) {
      auto& v = out[std::stoll(frame)];
      for (const auto& e : entries)
        for (const auto& p : e.at("pairs"))
          v.push_back({data::get_integer(e.at("obj0"), path + ": obj0"),
                       data::get_integer(p.at(0), path + ": a pair's face"),
                       data::get_integer(e.at("obj1"), path + ": obj1"),
                       data::get_integer(p.at(1), path + ": a pair's face")});
    }
  } catch (const std::exception& e) {
    throw data::DataError(path + ": unexpected layout: " + e.what());
  }
  return out;
}

/// The reference's collisions.json (parse_collisions_json).
inline std::map<std::int64_t, std::vector<ContactCandidate>> read_collisions_json(
    const std::string& path) {
  return parse_collisions_json(data::read_text_file(path), path);
}

/// The reference's contacts beside a Kubric scene (collisions.json in the folder of its
/// metadata.json, `scene_source`), or "" when there is none. Reference mode takes the first
/// step's contacts from it, as the reference does.
inline std::string collisions_json_beside(const std::string& scene_source) {
  const auto p = std::filesystem::path(scene_source).parent_path() / "collisions.json";
  return std::filesystem::exists(p) ? p.string() : std::string();
}

namespace detail {
struct ContactGeometry {
  Eigen::Vector3d nP, nQ, dir;
  double dist;
  std::array<std::array<double, 4>, 3> rowsP, rowsQ;
  bool safe;
};

inline std::array<std::array<double, 4>, 3> sorted_rows(const std::array<Eigen::Vector3d, 3>& T,
                                                        const Eigen::Vector3d& c) {
  std::array<std::array<double, 4>, 3> r;
  for (int k = 0; k < 3; ++k) {
    const Eigen::Vector3d d = T[static_cast<std::size_t>(k)] - c;
    r[static_cast<std::size_t>(k)] = {d.x(), d.y(), d.z(), d.norm()};
  }
  std::stable_sort(r.begin(), r.end(), [](const auto& a, const auto& b) { return a[3] < b[3]; });
  return r;
}

// Spec 4.4 for faces P (face0) and Q (face1).
inline ContactGeometry contact_geometry(const std::array<Eigen::Vector3d, 3>& P,
                                        const std::array<Eigen::Vector3d, 3>& Q, FeatureMode mode) {
  ContactGeometry g;
  g.nP = (P[1] - P[0]).cross(P[2] - P[0]).normalized();
  g.nQ = (Q[1] - Q[0]).cross(Q[2] - Q[0]).normalized();
  const Eigen::Vector3d cP = (P[0] + P[1] + P[2]) / 3.0, cQ = (Q[0] + Q[1] + Q[2]) / 3.0;
  if ((cQ - cP).dot(g.nP) < 0) g.nP = -g.nP;
  if ((cP - cQ).dot(g.nQ) < 0) g.nQ = -g.nQ;
  Eigen::Vector3d cp, cq;
  if (mode == FeatureMode::reference) {
    const auto r = physx_triangle_triangle(P, Q);
    cp = r.cp;
    cq = r.cq;
    g.dist = r.distance;
    g.safe = r.distance != 0.0;
  } else {
    using V = topos::detail::V3<double>;
    const auto conv = [](const std::array<Eigen::Vector3d, 3>& t) {
      return std::array<V, 3>{V{t[0].x(), t[0].y(), t[0].z()}, V{t[1].x(), t[1].y(), t[1].z()},
                              V{t[2].x(), t[2].y(), t[2].z()}};
    };
    using K = CGAL::Exact_predicates_inexact_constructions_kernel;
    const auto tri = [](const std::array<Eigen::Vector3d, 3>& t) {
      return K::Triangle_3({t[0].x(), t[0].y(), t[0].z()}, {t[1].x(), t[1].y(), t[1].z()},
                           {t[2].x(), t[2].y(), t[2].z()});
    };
    const bool intersect = CGAL::do_intersect(tri(P), tri(Q));
    const auto [pts, sq] = closest_points_raw<double>(conv(P), conv(Q), intersect);
    cp = {pts[0].x, pts[0].y, pts[0].z};
    cq = {pts[1].x, pts[1].y, pts[1].z};
    g.dist = std::sqrt(sq);
    g.safe = !intersect && g.dist > 0.0;
  }
  g.dir = cq - cp;
  g.rowsP = sorted_rows(P, cp);
  g.rowsQ = sorted_rows(Q, cq);
  if (g.dir.dot(g.nP) < 0) g.nP = -g.nP;
  if ((-g.dir).dot(g.nQ) < 0) g.nQ = -g.nQ;
  return g;
}
}  // namespace detail

/// The contact cells X(3) a frame's complex gets from `candidates`: the safe pairs (build_frame
/// skips the others), without building any feature.
inline std::int64_t count_contact_cells(const HopnetGeometry& g,
                                        const std::vector<PosedObject>& posed,
                                        const std::vector<ContactCandidate>& candidates) {
  std::int64_t n = 0;
  for (const auto& c : candidates) {
    const auto P = topos::detail::face_points(posed[static_cast<std::size_t>(c.obj0)], c.face0);
    const auto Q = topos::detail::face_points(posed[static_cast<std::size_t>(c.obj1)], c.face1);
    n += detail::contact_geometry(P, Q, g.mode).safe;
  }
  return n;
}

}  // namespace topos::models::hopnet
