// topos/models/hopnet/features.hpp
// HOPNet's complex and input features at one timestep (data/create_ccs.py), no LibTorch.
//
// HopnetGeometry holds what is static in a scene: the global node numbering (objects in order,
// floor last), the unique edges in first-seen order with their feature direction, each global
// face's nodes and edges. build_frame() adds what changes per frame: the faces in contact and
// the contact cells (ranks 2 and 3), their incidences, and the raw features x0..x4 in double.
//
// Two modes (FeatureMode):
//  - reference: the published model's inputs, quirks included: contacts from the reference
//    vertex-proximity detector, PhysX's triangle distance (sometimes squared), the CPython
//    frozenset edge direction, last-write-wins face normals, and the role-mixing buffer of
//    B23 (a face that is face0 in one contact and face1 in another sends into both halves).
//  - native: exact face pairs within d_c with their Euclidean distance, edge direction from the
//    mesh's orientation, each face's normal from its closest partner, and B23's two halves by
//    the pair's own role.
#pragma once

#include "topos/core/lifting.hpp"
#include "topos/core/neighborhood.hpp"
#include "topos/geometry/contacts.hpp"
#include "topos/geometry/physx_triangle_distance.hpp"
#include "topos/models/hopnet/scene.hpp"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <array>
#include <fstream>
#include <map>
#include <set>
#include <stdexcept>
#include <string>
#include <vector>

namespace topos::hopnet {

enum class FeatureMode { reference, native };

inline FeatureMode feature_mode_from_string(const std::string& s) {
  if (s == "reference") return FeatureMode::reference;
  if (s == "native") return FeatureMode::native;
  throw std::invalid_argument("unknown mode '" + s + "' (reference or native)");
}
inline const char* to_string(FeatureMode m) {
  return m == FeatureMode::reference ? "reference" : "native";
}

/// Feature widths (data/create_ccs.py): x0 16, x1 8, x2 3, x3 28, x4 13; targets 3.
inline constexpr std::array<int, 5> kFeatureWidth{16, 8, 3, 28, 13};

/// The member of the HOPNet family a complex is lifted for (the reference's models/ablations.py):
/// hopnet (object cells, sequential layer), no_object_cells (a virtual node per object joined to
/// its nodes by spoke edges, no rank-4 features) or no_sequential (every rank pair at once, with
/// the extra adjacencies and incidences that needs).
enum class Architecture { hopnet, no_object_cells, no_sequential };

inline Architecture architecture_from_string(const std::string& s) {
  if (s == "hopnet") return Architecture::hopnet;
  if (s == "no_object_cells") return Architecture::no_object_cells;
  if (s == "no_sequential") return Architecture::no_sequential;
  throw std::invalid_argument("unknown architecture '" + s +
                              "' (hopnet, no_object_cells, no_sequential)");
}
inline const char* to_string(Architecture a) {
  return a == Architecture::hopnet
             ? "hopnet"
             : (a == Architecture::no_object_cells ? "no_object_cells" : "no_sequential");
}

/// How a scene is lifted: feature mode, architecture, and whether x0 keeps the centre-mass
/// distances r0, rt (columns 8..15; the "no centre-mass distance" ablation drops them).
struct LiftingOptions {
  FeatureMode mode = FeatureMode::reference;
  Architecture architecture = Architecture::hopnet;
  bool center_mass_distance = true;
  /// x0's columns: 16 (8 without the centre-mass distances), plus the 5 object columns of x4
  /// (type, mass, friction, restitution) when objects are virtual nodes.
  std::int64_t x0_width() const {
    return (center_mass_distance ? 16 : 8) +
           (architecture == Architecture::no_object_cells ? 5 : 0);
  }
  bool object_cells() const { return architecture != Architecture::no_object_cells; }
};

/// CPython's iteration order of frozenset({a, b}) built from [a, b] (a inserted first), for
/// small non-negative ints (hash = value, table of 8 slots): returns true when a comes first.
inline bool frozenset_a_first(std::int64_t a, std::int64_t b) {
  const std::uint64_t ia = static_cast<std::uint64_t>(a) & 7u,
                      ib = static_cast<std::uint64_t>(b) & 7u;
  if (ia != ib) return ia < ib;
  std::uint64_t perturb = static_cast<std::uint64_t>(b), i = ib;
  while (i == ia) {
    perturb >>= 5;
    i = (i * 5 + 1 + perturb) & 7u;
  }
  return ia < i;
}

using RowMatrix = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;

/// The static part of a scene's complex.
struct HopnetGeometry {
  std::vector<const SceneObject*> objects;
  std::vector<std::int64_t> node_offset, face_offset;  ///< O+1 each
  std::vector<std::int64_t> node_object;               ///< object of each node
  std::vector<std::array<std::int64_t, 2>> edges;      ///< (s, d) as the features use it
  Eigen::Matrix<std::int64_t, Eigen::Dynamic, 3, Eigen::RowMajor>
      face_nodes;  ///< global face -> nodes
  Eigen::Matrix<std::int64_t, Eigen::Dynamic, 3, Eigen::RowMajor>
      face_edges;                             ///< global face -> edge ids
  std::vector<VertexFaceIndex> vertex_faces;  ///< per object, for the reference detector
  FeatureMode mode = FeatureMode::reference;
  LiftingOptions lifting;  ///< lifting.mode == mode
  /// no_object_cells: per mesh node, whether its spoke edge runs virtual node -> node (the
  /// frozenset rule on [9900 + object, node]); the spoke's features are then negated.
  std::vector<char> spoke_virtual_first;

  std::int64_t num_nodes() const { return node_offset.back(); }
  std::int64_t num_edges() const { return static_cast<std::int64_t>(edges.size()); }
  std::int64_t num_objects() const { return static_cast<std::int64_t>(objects.size()); }
  /// Rank-0 and rank-1 cells the network sees: mesh nodes and edges, plus one virtual node per
  /// object and one spoke per mesh node when objects are virtual nodes.
  std::int64_t num_rank0() const {
    return num_nodes() + (lifting.object_cells() ? 0 : num_objects());
  }
  std::int64_t num_rank1() const {
    return num_edges() + (lifting.object_cells() ? 0 : num_nodes());
  }
};

/// Id of object i's virtual node in the reference's NoObjectCells complex (9900 + i); the
/// construction breaks for scenes of 9900 or more mesh nodes, which are refused.
inline constexpr std::int64_t kVirtualNodeId = 9900;

inline HopnetGeometry make_geometry(const Scene& scene, const LiftingOptions& lifting);

inline HopnetGeometry make_geometry(const Scene& scene, FeatureMode mode) {
  LiftingOptions l;
  l.mode = mode;
  return make_geometry(scene, l);
}

inline HopnetGeometry make_geometry(const Scene& scene, const LiftingOptions& lifting) {
  HopnetGeometry g;
  const FeatureMode mode = lifting.mode;
  g.mode = mode;
  g.lifting = lifting;
  std::vector<TriangleMesh> meshes;
  for (const auto& o : scene.objects) {
    g.objects.push_back(&o);
    meshes.push_back(o.mesh);
  }
  const auto lifted = lift_meshes(meshes, LiftOptions().with_faces(false).with_object_rank(0));
  g.node_offset.assign(lifted.node_offset.begin(), lifted.node_offset.end());
  g.face_offset.assign(lifted.face_offset.begin(), lifted.face_offset.end());
  g.node_object.assign(lifted.node_object.begin(), lifted.node_object.end());
  g.face_nodes = lifted.faces;
  topos::detail::FlatKeyMap edge_id(lifted.edges.size() * 2 + 8);
  const auto key = [](std::int64_t a, std::int64_t b) {
    return (static_cast<std::uint64_t>(std::min(a, b)) << 32) |
           static_cast<std::uint64_t>(std::max(a, b));
  };
  for (std::size_t e = 0; e < lifted.edges.size(); ++e) {
    auto [a, b] = lifted.edges[e];
    edge_id.emplace(key(a, b), static_cast<std::int64_t>(e));
    const bool a_first = mode == FeatureMode::native || frozenset_a_first(a, b);
    g.edges.push_back(a_first ? std::array<std::int64_t, 2>{a, b}
                              : std::array<std::int64_t, 2>{b, a});
  }
  g.face_edges.resize(g.face_nodes.rows(), 3);
  for (Eigen::Index f = 0; f < g.face_nodes.rows(); ++f)
    for (int k = 0; k < 3; ++k)
      g.face_edges(f, k) =
          edge_id.emplace(key(g.face_nodes(f, k), g.face_nodes(f, (k + 1) % 3)), -1).first;
  for (const auto& o : scene.objects)
    g.vertex_faces.emplace_back(o.mesh.faces, o.mesh.vertices.rows());
  if (!lifting.object_cells()) {
    if (g.num_nodes() >= kVirtualNodeId)
      throw std::invalid_argument(
          scene.source + ": " + std::to_string(g.num_nodes()) +
          " mesh nodes; the reference's virtual node ids (9900 + object) would collide with them");
    for (std::int64_t n = 0; n < g.num_nodes(); ++n) {
      const auto o = g.node_object[static_cast<std::size_t>(n)];
      g.spoke_virtual_first.push_back(mode == FeatureMode::reference &&
                                      frozenset_a_first(kVirtualNodeId + o, n));
    }
  }
  return g;
}

/// Object poses at one frame: positions O×3, quaternions O×4 (w x y z).
struct Poses {
  RowMatrix positions, quaternions;
};

inline Poses scene_poses(const Scene& s, std::int64_t t) {
  if (t < 0 || t >= s.num_frames)
    throw std::out_of_range("scene_poses: frame " + std::to_string(t) + " outside 0.." +
                            std::to_string(s.num_frames - 1));
  const auto O = static_cast<Eigen::Index>(s.num_objects());
  Poses p;
  p.positions.resize(O, 3);
  p.quaternions.resize(O, 4);
  for (Eigen::Index o = 0; o < O; ++o) {
    p.positions.row(o) = s.position(t, static_cast<std::size_t>(o)).transpose();
    p.quaternions.row(o) = s.quaternion(t, static_cast<std::size_t>(o)).transpose();
  }
  return p;
}

/// World vertices of every object for one set of poses (static objects stay as they are).
/// Reference mode poses with trimesh's arithmetic bit for bit (pose_vertices_trimesh): the
/// reference's contact features of faces resting flat on each other depend on the last ulp.
inline std::vector<PosedObject> pose_objects(const HopnetGeometry& g, const Poses& p) {
  std::vector<PosedObject> out(g.objects.size());
  for (std::size_t o = 0; o < g.objects.size(); ++o) {
    const auto& obj = *g.objects[o];
    for (int c = 0; c < 3; ++c)
      if (!std::isfinite(p.positions(static_cast<Eigen::Index>(o), c)))
        throw std::invalid_argument("pose of object " + std::to_string(o) + " is not finite");
    out[o].faces = &obj.mesh.faces;
    const Eigen::Vector3d position = p.positions.row(static_cast<Eigen::Index>(o)).transpose();
    const Eigen::Vector4d quaternion = p.quaternions.row(static_cast<Eigen::Index>(o)).transpose();
    if (obj.is_floor)
      out[o].vertices = obj.mesh.vertices;
    else if (g.mode == FeatureMode::reference)
      out[o].vertices = pose_vertices_trimesh(obj.mesh.vertices, position, quaternion);
    else
      out[o].vertices = pose_vertices(obj.mesh.vertices, position, quaternion);
  }
  return out;
}

/// A candidate contact: local face ids of two objects (obj0's face is "face0", role -1).
struct ContactCandidate {
  std::int64_t obj0, face0, obj1, face1;
};

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

/// The ablations' node and edge features from the standard ones (models/ablations.py):
/// without centre-mass distances x0 keeps columns 0..7; with virtual object nodes every mesh
/// node gets its object's columns x4[8:13] (type, mass, friction, restitution), object o's
/// virtual node (row N+o) is [x4[o, 0:8], zeros, x4[o, 8:13]], and the spoke of node n (row E+n)
/// is [r0, |r0|, rt, |rt|] of that node (x0[n, 8:16]), negated when the virtual node comes first.
inline void lift_variant_features(const HopnetGeometry& g, HopnetFrame& f) {
  const LiftingOptions& l = g.lifting;
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

/// The neighbourhoods HOPNet's schedule reads, with explicit directions:
///   B02 (0→2), B12 (1→2), B42 (4→2: each face receives its object), B23neg / B23pos (2→3,
///   values: the half of the contact's face message this pair feeds), B32 (3→2, roles −1/+1),
///   B24 (2→4), B04 (0→4), B40 (4→0).
/// In reference mode B23neg/B23pos carry the reference's role-mixing buffer (neg(f), pos(f) per
/// face) and, as backward values, the reference's gradient multiplicity (the number of
/// contacts in which the face has that role); in native mode the pair's own role.
/// The ablations add (models/ablations.py): A010 (0→0, nodes sharing a rank-1 cell,
/// spokes included; the reference's explicit zeros on the diagonal contribute nothing and are
/// left out) and B20 (2→0) for both; no_sequential also A101 (1→1), A232 (2→2, faces sharing a
/// contact), B01/B10, B14/B41, B03/B30 (the 6 nodes of a contact), B13/B31 (its 6 edges), B21,
/// and the signed incidence as values, B23signed (2→3) and B32signed (3→2): −1 face0, +1 face1.
/// With virtual object nodes, rank 0 and 1 hold N+O and E+N cells; virtual nodes and spokes
/// are in no face, and B04/B40 list mesh nodes only (the reference's empty virtual rows).
inline std::map<std::string, Neighborhood> hopnet_neighborhoods(const HopnetGeometry& g,
                                                                const HopnetFrame& f) {
  const std::int64_t N = g.num_nodes(), E = g.num_edges(), O = g.num_objects(), F = f.num_faces(),
                     C = f.num_contacts();
  const std::int64_t N0 = g.num_rank0(), E1 = g.num_rank1();
  const Architecture arch = g.lifting.architecture;
  std::map<std::string, Neighborhood> out;
  const auto make = [&](const char* name, int sr, int tr, std::int64_t ns,
                        std::int64_t nt) -> Neighborhood& {
    auto& n = out[name];
    n.name = name;
    n.source_rank = sr;
    n.target_rank = tr;
    n.num_source = ns;
    n.num_target = nt;
    return n;
  };
  const auto link = [](Neighborhood& n, std::int64_t s, std::int64_t t) {
    n.source.push_back(s), n.target.push_back(t);
  };
  auto& b04 = make("B04", 0, 4, N0, O);
  auto& b40 = make("B40", 4, 0, O, N0);
  for (std::int64_t n = 0; n < N; ++n) {
    const auto o = g.node_object[static_cast<std::size_t>(n)];
    link(b04, n, o), link(b40, o, n);
  }
  auto& b02 = make("B02", 0, 2, N0, F);
  auto& b12 = make("B12", 1, 2, E1, F);
  auto& b42 = make("B42", 4, 2, O, F);
  auto& b24 = make("B24", 2, 4, F, O);
  for (std::int64_t r = 0; r < F; ++r) {
    const auto gf = f.faces[static_cast<std::size_t>(r)];
    for (int k = 0; k < 3; ++k)
      link(b02, g.face_nodes(gf, k), r), link(b12, g.face_edges(gf, k), r);
    const auto o = g.node_object[static_cast<std::size_t>(g.face_nodes(gf, 0))];
    link(b42, o, r), link(b24, r, o);
  }
  auto& neg = make("B23neg", 2, 3, F, C);
  auto& pos = make("B23pos", 2, 3, F, C);
  auto& b32 = make("B32", 3, 2, C, F);
  // Reference: a face's message into each half is computed once per contact in which the face has
  // that role and written with index_put_, so its gradient comes back that many times (k_neg,
  // k_pos): the backward values. Native mode keeps the true gradient.
  std::vector<std::int64_t> k_neg(static_cast<std::size_t>(F), 0),
      k_pos(static_cast<std::size_t>(F), 0);
  for (const auto& c : f.contacts)
    ++k_neg[static_cast<std::size_t>(c[0])], ++k_pos[static_cast<std::size_t>(c[1])];
  const bool mixed = g.mode == FeatureMode::reference;
  for (std::int64_t c = 0; c < C; ++c) {
    for (int k = 0; k < 2; ++k) {
      const auto face = f.contacts[static_cast<std::size_t>(c)][static_cast<std::size_t>(k)];
      const auto kn = static_cast<double>(k_neg[static_cast<std::size_t>(face)]),
                 kp = static_cast<double>(k_pos[static_cast<std::size_t>(face)]);
      const double role_neg = k == 0, role_pos = k == 1;
      neg.source.push_back(face), neg.target.push_back(c),
          neg.values.push_back(mixed ? (kn > 0) : role_neg);
      pos.source.push_back(face), pos.target.push_back(c),
          pos.values.push_back(mixed ? (kp > 0) : role_pos);
      if (mixed) neg.backward_values.push_back(kn), pos.backward_values.push_back(kp);
      b32.source.push_back(c), b32.target.push_back(face),
          b32.roles.push_back(static_cast<std::int8_t>(k == 0 ? -1 : 1));
    }
  }
  if (arch == Architecture::hopnet) return out;

  auto& a010 = make("A010", 0, 0, N0, N0);
  for (std::int64_t e = 0; e < E; ++e) {
    const auto [s, d] = g.edges[static_cast<std::size_t>(e)];
    link(a010, s, d), link(a010, d, s);
  }
  if (arch == Architecture::no_object_cells)
    for (std::int64_t n = 0; n < N; ++n)
      link(a010, n, N + g.node_object[static_cast<std::size_t>(n)]),
          link(a010, N + g.node_object[static_cast<std::size_t>(n)], n);
  auto& b20 = make("B20", 2, 0, F, N0);
  for (std::size_t k = 0; k < b02.source.size(); ++k) link(b20, b02.target[k], b02.source[k]);
  if (arch != Architecture::no_sequential) return out;

  auto& b01 = make("B01", 0, 1, N, E);
  auto& b10 = make("B10", 1, 0, E, N);
  auto& b14 = make("B14", 1, 4, E, O);
  auto& b41 = make("B41", 4, 1, O, E);
  std::vector<std::vector<std::int64_t>> node_edges(static_cast<std::size_t>(N));
  for (std::int64_t e = 0; e < E; ++e) {
    for (auto n : g.edges[static_cast<std::size_t>(e)])
      link(b01, n, e), link(b10, e, n), node_edges[static_cast<std::size_t>(n)].push_back(e);
    const auto o = g.node_object[static_cast<std::size_t>(g.edges[static_cast<std::size_t>(e)][0])];
    link(b14, e, o), link(b41, o, e);
  }
  auto& a101 = make("A101", 1, 1, E, E);
  for (const auto& es : node_edges)
    for (auto a : es)
      for (auto b : es)
        if (a != b) link(a101, a, b);
  auto& b21 = make("B21", 2, 1, F, E);
  for (std::size_t k = 0; k < b12.source.size(); ++k) link(b21, b12.target[k], b12.source[k]);
  auto& a232 = make("A232", 2, 2, F, F);
  std::set<std::pair<std::int64_t, std::int64_t>> faces_in_contact;  // adjacency is 0/1
  for (const auto& c : f.contacts)
    if (c[0] != c[1]) faces_in_contact.insert({c[0], c[1]}), faces_in_contact.insert({c[1], c[0]});
  for (const auto& [a, b] : faces_in_contact) link(a232, a, b);
  auto& b03 = make("B03", 0, 3, N, C);
  auto& b30 = make("B30", 3, 0, C, N);
  auto& b13 = make("B13", 1, 3, E, C);
  auto& b31 = make("B31", 3, 1, C, E);
  auto& b23 = make("B23signed", 2, 3, F, C);
  auto& b32s = make("B32signed", 3, 2, C, F);
  for (std::int64_t c = 0; c < C; ++c)
    for (int k = 0; k < 2; ++k) {
      const auto face = f.contacts[static_cast<std::size_t>(c)][static_cast<std::size_t>(k)];
      const auto gf = f.faces[static_cast<std::size_t>(face)];
      for (int v = 0; v < 3; ++v)
        link(b03, g.face_nodes(gf, v), c), link(b30, c, g.face_nodes(gf, v)),
            link(b13, g.face_edges(gf, v), c), link(b31, c, g.face_edges(gf, v));
      link(b23, face, c), link(b32s, c, face);
      b23.values.push_back(k == 0 ? -1.0 : 1.0), b32s.values.push_back(k == 0 ? -1.0 : 1.0);
    }
  return out;
}

}  // namespace topos::hopnet
