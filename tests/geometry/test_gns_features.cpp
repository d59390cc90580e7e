// Tests of topos/models/fignet/features.hpp and topos/models/mgn/features.hpp: FIGNet's face-face
// hyperedges on hand-placed triangles and cubes (values worked out by hand), its node, object
// and mesh-object columns on analytic motions, the floor box; MeshGraphNet's world edges
// against a brute-force search and its virtual floor nodes; bad input.
#include <catch2/catch.hpp>

#include "topos/models/fignet/features.hpp"
#include "topos/models/mgn/features.hpp"

#include <cmath>
#include <functional>
#include <limits>
#include <map>
#include <random>
#include <set>

using namespace topos;
using sim::Poses;
using sim::Scene;
using sim::SceneObject;

namespace {

constexpr double kTol = 1e-12;

// A scene of the given objects with HOPNet's floor appended last, as make_scene builds it.
Scene scene_of(std::vector<SceneObject> objects) {
  Scene s;
  s.objects = std::move(objects);
  s.objects.push_back(sim::floor_object());
  return s;
}

SceneObject object_of(const std::string& shape, TriangleMesh mesh, double mass = 1.0,
                      double friction = 0.4, double restitution = 0.6) {
  SceneObject o;
  o.asset_id = o.shape = shape;
  o.mass = mass;
  o.friction = friction;
  o.restitution = restitution;
  o.mesh = std::move(mesh);
  o.center_of_mass = volumetric_center_of_mass(o.mesh.vertices, o.mesh.faces);
  return o;
}

SceneObject builtin(const std::string& shape, double size, double mass = 1.0) {
  TriangleMesh m = builtin_shape(shape);
  m.vertices *= size;
  return object_of(shape, m, mass);
}

TriangleMesh triangle(const Eigen::Vector3d& a, const Eigen::Vector3d& b,
                      const Eigen::Vector3d& c) {
  TriangleMesh m;
  m.name = "triangle";
  m.vertices.resize(3, 3);
  m.vertices << a.transpose(), b.transpose(), c.transpose();
  m.faces.resize(1, 3);
  m.faces << 0, 1, 2;
  return m;
}

// Poses of the non-floor objects; the floor (last) gets the identity at the origin.
Poses poses_of(const std::vector<std::pair<Eigen::Vector3d, Eigen::Vector4d>>& p) {
  Poses out;
  const auto O = static_cast<Eigen::Index>(p.size()) + 1;
  out.positions.setZero(O, 3);
  out.quaternions.setZero(O, 4);
  for (Eigen::Index o = 0; o + 1 < O; ++o) {
    out.positions.row(o) = p[static_cast<std::size_t>(o)].first.transpose();
    out.quaternions.row(o) = p[static_cast<std::size_t>(o)].second.transpose();
  }
  out.quaternions(O - 1, 0) = 1.0;
  return out;
}

const Eigen::Vector4d kIdentity(1, 0, 0, 0);

Eigen::Vector3d vec(const sim::RowMatrix& m, Eigen::Index r, Eigen::Index c) {
  return m.block<1, 3>(r, c).transpose();
}

// Rotation of a (w, x, y, z) quaternion, independently of the library's helper.
Eigen::Matrix3d rotation(const Eigen::Vector4d& q) {
  return Eigen::Quaterniond(q[0], q[1], q[2], q[3]).normalized().toRotationMatrix();
}

// World vertices of every object, stacked in node order (the floor unmoved).
sim::RowMatrix world_nodes(const sim::SceneMeshes& g, const Poses& p) {
  sim::RowMatrix x(g.num_nodes(), 3);
  for (std::int64_t o = 0; o < g.num_objects(); ++o) {
    const auto& obj = g.objects[static_cast<std::size_t>(o)];
    for (Eigen::Index v = 0; v < obj.mesh.vertices.rows(); ++v) {
      const Eigen::Vector3d X = obj.mesh.vertices.row(v).transpose();
      const Eigen::Vector3d y =
          obj.is_floor ? X
                       : Eigen::Vector3d(rotation(p.quaternions.row(o).transpose()) * X +
                                         p.positions.row(o).transpose());
      x.row(g.node_offset[static_cast<std::size_t>(o)] + v) = y.transpose();
    }
  }
  return x;
}

// Checks one ff hyperedge against the node positions: rows ascending, each row's vertex is its
// slot's node, the rows' closest points agree, d_rs = p_r - p_s, normals of the slot faces.
void check_hyperedge(const sim::EdgeSetData& ff, Eigen::Index e, const sim::RowMatrix& x) {
  const auto& F = ff.features;
  Eigen::Vector3d p[2];
  for (int side = 0; side < 2; ++side) {
    const Eigen::Index base = side == 0 ? 4 : 16;
    const auto& idx = side == 0 ? ff.senders : ff.receivers;
    std::array<Eigen::Vector3d, 3> v;
    for (int k = 0; k < 3; ++k) {
      v[static_cast<std::size_t>(k)] = x.row(idx(e, k)).transpose();
      const Eigen::Vector3d row = vec(F, e, base + 4 * k);
      CHECK(F(e, base + 4 * k + 3) == Approx(row.norm()).margin(kTol));
      if (k > 0) CHECK(F(e, base + 4 * k - 1) <= F(e, base + 4 * k + 3));
      const Eigen::Vector3d pk = v[static_cast<std::size_t>(k)] - row;
      if (k == 0) p[side] = pk;
      CHECK((pk - p[side]).norm() < 1e-9);
    }
    // The normal is the slot face's, up to the orientation the rows' order gives it.
    const Eigen::Vector3d n = vec(F, e, side == 0 ? 28 : 31);
    CHECK(n.norm() == Approx(1.0));
    CHECK(std::abs(n.dot(v[1] - v[0])) < 1e-9);
    CHECK(std::abs(n.dot(v[2] - v[0])) < 1e-9);
  }
  CHECK((vec(F, e, 0) - (p[1] - p[0])).norm() < 1e-9);
  CHECK(F(e, 3) == Approx(vec(F, e, 0).norm()).margin(kTol));
}

// Every hyperedge 2c + 1 is hyperedge 2c with sender and receiver swapped.
void check_reversed_pairs(const sim::EdgeSetData& ff) {
  REQUIRE(ff.size() % 2 == 0);
  const auto& F = ff.features;
  for (Eigen::Index c = 0; 2 * c < ff.size(); ++c) {
    const Eigen::Index a = 2 * c, b = 2 * c + 1;
    CHECK(ff.senders.row(a) == ff.receivers.row(b));
    CHECK(ff.receivers.row(a) == ff.senders.row(b));
    CHECK((vec(F, a, 0) + vec(F, b, 0)).norm() < kTol);
    CHECK(F(a, 3) == F(b, 3));
    CHECK(F.block(a, 4, 1, 12) == F.block(b, 16, 1, 12));
    CHECK(F.block(a, 16, 1, 12) == F.block(b, 4, 1, 12));
    CHECK(vec(F, a, 28) == vec(F, b, 31));
    CHECK(vec(F, a, 31) == vec(F, b, 28));
  }
}

template <class F>
void require_invalid(F f, const std::string& part) {
  try {
    f();
    FAIL("no std::invalid_argument; expected one naming '" << part << "'");
  } catch (const std::invalid_argument& e) {
    INFO(e.what());
    CHECK(std::string(e.what()).find(part) != std::string::npos);
  }
}

}  // namespace

TEST_CASE("FIGNet face-face features of two hand-placed triangles", "[gns][fignet]") {
  // A in the plane z = 5; B's lowest vertex 5 cm above A's point (0.2, 0.3, 5), B posed by a
  // 90-degree turn about z: canonical (x, y, z) goes to (-y, x, z).
  const Scene scene =
      scene_of({object_of("A", triangle({0, 0, 0}, {1, 0, 0}, {0, 1, 0})),
                object_of("B", triangle({0, 0, 0}, {0, -0.3, 0.4}, {0.6, 0, 0.5}))});
  const auto g = models::fignet::make_fignet_geometry(scene);
  REQUIRE(g.num_nodes() == 3 + 3 + 8);
  const double h = std::sqrt(0.5);
  const Eigen::Vector3d a0(0, 0, 5), a1(1, 0, 5), a2(0, 1, 5);
  const Eigen::Vector3d pA(0.2, 0.3, 5);

  SECTION("disjoint: the closest points are A's interior point and B's vertex") {
    const Poses p = poses_of({{{0, 0, 5}, kIdentity}, {{0.2, 0.3, 5.05}, {h, 0, 0, h}}});
    const auto f = models::fignet::fignet_frame(g, p, p, p, nullptr);
    const auto& ff = f.edge_set("ff");
    REQUIRE(ff.size() == 2);
    REQUIRE(ff.features.cols() == 34);
    REQUIRE(ff.senders.cols() == 3);
    const Eigen::Vector3d w0(0.2, 0.3, 5.05), w1(0.5, 0.3, 5.45), w2(0.2, 0.9, 5.55);
    const Eigen::Vector3d& pB = w0;
    const Eigen::Vector3d nA(0, 0, 1), nB = (w1 - w0).cross(w2 - w0).normalized();
    // Distances to pA: a0 0.36, a2 0.73, a1 0.85; to pB: w0 0, w1 0.5, w2 0.78.
    const std::array<Eigen::Vector3d, 3> rowsA{a0 - pA, a2 - pA, a1 - pA},
        rowsB{w0 - pB, w1 - pB, w2 - pB};
    const auto expect = [&](Eigen::Index e, const Eigen::Vector3d& d,
                            const std::array<Eigen::Vector3d, 3>& rs,
                            const std::array<Eigen::Vector3d, 3>& rr, const Eigen::Vector3d& ns,
                            const Eigen::Vector3d& nr) {
      const auto& F = ff.features;
      CHECK((vec(F, e, 0) - d).norm() < kTol);
      CHECK(F(e, 3) == Approx(0.05).margin(kTol));
      for (int k = 0; k < 3; ++k) {
        CHECK((vec(F, e, 4 + 4 * k) - rs[static_cast<std::size_t>(k)]).norm() < kTol);
        CHECK(F(e, 7 + 4 * k) == Approx(rs[static_cast<std::size_t>(k)].norm()).margin(kTol));
        CHECK((vec(F, e, 16 + 4 * k) - rr[static_cast<std::size_t>(k)]).norm() < kTol);
        CHECK(F(e, 19 + 4 * k) == Approx(rr[static_cast<std::size_t>(k)].norm()).margin(kTol));
      }
      CHECK((vec(F, e, 28) - ns).norm() < kTol);
      CHECK((vec(F, e, 31) - nr).norm() < kTol);
    };
    // Hyperedge 0 sends A -> B; A's nodes are 0..2 and B's 3..5, slots in the rows' order.
    expect(0, {0, 0, 0.05}, rowsA, rowsB, nA, nB);
    CHECK(ff.senders.row(0) == (sim::IndexMatrix(1, 3) << 0, 2, 1).finished());
    CHECK(ff.receivers.row(0) == (sim::IndexMatrix(1, 3) << 3, 4, 5).finished());
    expect(1, {0, 0, -0.05}, rowsB, rowsA, nB, nA);
    CHECK(ff.senders.row(1) == (sim::IndexMatrix(1, 3) << 3, 4, 5).finished());
    CHECK(ff.receivers.row(1) == (sim::IndexMatrix(1, 3) << 0, 2, 1).finished());
    check_reversed_pairs(ff);

    // Outside the radius: no hyperedge.
    models::fignet::FignetFeatureOptions o;
    o.collision_radius = 0.04;
    CHECK(models::fignet::fignet_frame(g, p, p, p, nullptr, o).edge_set("ff").size() == 0);
  }

  SECTION("intersecting: one common point, d_rs = 0") {
    // B lowered to 4.9: its edge w0-w1 crosses A at (0.275, 0.3, 5).
    const Poses p = poses_of({{{0, 0, 5}, kIdentity}, {{0.2, 0.3, 4.9}, {h, 0, 0, h}}});
    const auto f = models::fignet::fignet_frame(g, p, p, p, nullptr);
    const auto& ff = f.edge_set("ff");
    REQUIRE(ff.size() == 2);
    const auto x = world_nodes(g, p);
    const Eigen::Vector3d w0(0.2, 0.3, 4.9), w1(0.5, 0.3, 5.3), w2(0.2, 0.9, 5.4);
    const Eigen::Vector3d nB = (w1 - w0).cross(w2 - w0).normalized();
    for (Eigen::Index e = 0; e < 2; ++e) {
      CHECK(vec(ff.features, e, 0) == Eigen::Vector3d::Zero());
      CHECK(ff.features(e, 3) == 0.0);
      check_hyperedge(ff, e, x);
      // The common point lies on both planes.
      const Eigen::Index s = ff.senders(e, 0);
      const Eigen::Vector3d common = x.row(s).transpose() - vec(ff.features, e, 4);
      CHECK(common.z() == Approx(5.0).margin(1e-9));
      CHECK(std::abs((common - w0).dot(nB)) < 1e-9);
    }
    check_reversed_pairs(ff);
  }
}

TEST_CASE("FIGNet face-face features of two cubes and of a cube above the floor box",
          "[gns][fignet]") {
  // Built-in cubes of edge 1: each side a 3 x 3 grid of 18 triangles.
  const Scene scene = scene_of({builtin("cube", 1.0), builtin("cube", 1.0)});
  const auto g = models::fignet::make_fignet_geometry(scene);
  const auto floor_offset = g.node_offset[2];

  // The faces of object o with a vertex on the plane coordinate `axis` = value (world).
  const auto faces_touching = [&](const sim::RowMatrix& x, std::int64_t o, int axis, double value) {
    std::set<std::array<std::int64_t, 3>> out;
    const auto& F = g.objects[static_cast<std::size_t>(o)].mesh.faces;
    for (Eigen::Index f = 0; f < F.rows(); ++f) {
      std::array<std::int64_t, 3> t;
      bool touches = false;
      for (int k = 0; k < 3; ++k) {
        t[static_cast<std::size_t>(k)] = g.node_offset[static_cast<std::size_t>(o)] + F(f, k);
        touches = touches || std::abs(x(t[static_cast<std::size_t>(k)], axis) - value) < 1e-9;
      }
      std::sort(t.begin(), t.end());
      if (touches) out.insert(t);
    }
    return out;
  };
  const auto sorted_row = [](const sim::IndexMatrix& m, Eigen::Index e) {
    std::array<std::int64_t, 3> t{m(e, 0), m(e, 1), m(e, 2)};
    std::sort(t.begin(), t.end());
    return t;
  };

  SECTION("side by side, 5 cm apart along x") {
    const Poses p = poses_of({{{0, 0, 3}, kIdentity}, {{1.05, 0, 3}, kIdentity}});
    const auto f = models::fignet::fignet_frame(g, p, p, p, nullptr);
    const auto& ff = f.edge_set("ff");
    const auto x = world_nodes(g, p);
    REQUIRE(ff.size() > 0);
    check_reversed_pairs(ff);
    // A (object 0) spans x <= 0.5, B x >= 0.55: any pair within 0.1 of each other is 5 cm apart
    // (non-adjacent grid triangles are over 0.23 apart sideways), straight along x.
    std::set<std::array<std::int64_t, 3>> faces_a;
    for (Eigen::Index e = 0; e < ff.size(); ++e) {
      check_hyperedge(ff, e, x);
      const auto so = f.node_object[static_cast<std::size_t>(ff.senders(e, 0))];
      const auto ro = f.node_object[static_cast<std::size_t>(ff.receivers(e, 0))];
      REQUIRE(so != ro);
      REQUIRE(so < 2);
      REQUIRE(ro < 2);
      const Eigen::Vector3d d(so == 0 ? 0.05 : -0.05, 0, 0);
      CHECK((vec(ff.features, e, 0) - d).norm() < 1e-9);
      // The slot vertices all belong to the sender's object; normals point out of the cube.
      for (int k = 0; k < 3; ++k)
        CHECK(f.node_object[static_cast<std::size_t>(ff.senders(e, k))] == so);
      const Eigen::Vector3d centre =
          so == 0 ? Eigen::Vector3d(0, 0, 3) : Eigen::Vector3d(1.05, 0, 3);
      Eigen::Vector3d centroid = Eigen::Vector3d::Zero();
      for (int k = 0; k < 3; ++k) centroid += x.row(ff.senders(e, k)).transpose() / 3.0;
      CHECK(vec(ff.features, e, 28).dot(centroid - centre) > 0);
      if (so == 0) faces_a.insert(sorted_row(ff.senders, e));
    }
    // A's faces in contact: the 18 of its +x side and, on each of the 4 sides around it, the 6
    // of the column of cells along the edge x = 0.5 (each triangle holds a vertex on that edge).
    const auto expected = faces_touching(x, 0, 0, 0.5);
    CHECK(expected.size() == 18 + 4 * 6);
    CHECK(faces_a == expected);
  }

  SECTION("a cube 3 cm above the floor box") {
    const Poses p = poses_of({{{0, 0, 0.53}, kIdentity}, {{5, 0, 3}, kIdentity}});
    const auto f = models::fignet::fignet_frame(g, p, p, p, nullptr);
    const auto& ff = f.edge_set("ff");
    const auto x = world_nodes(g, p);
    REQUIRE(ff.size() > 0);
    check_reversed_pairs(ff);
    std::set<std::array<std::int64_t, 3>> cube_faces, floor_faces;
    for (Eigen::Index e = 0; e < ff.size(); ++e) {
      check_hyperedge(ff, e, x);
      const bool cube_sends = f.node_object[static_cast<std::size_t>(ff.senders(e, 0))] == 0;
      const auto& floor_slots = cube_sends ? ff.receivers : ff.senders;
      const auto& cube_slots = cube_sends ? ff.senders : ff.receivers;
      for (int k = 0; k < 3; ++k) {
        CHECK(floor_slots(e, k) >= floor_offset);
        CHECK(f.node_object[static_cast<std::size_t>(cube_slots(e, k))] == 0);
        CHECK(x(floor_slots(e, k), 2) == 0.0);  // the top face
      }
      const Eigen::Vector3d d(0, 0, cube_sends ? -0.03 : 0.03);
      CHECK((vec(ff.features, e, 0) - d).norm() < 1e-9);
      CHECK((vec(ff.features, e, cube_sends ? 31 : 28) - Eigen::Vector3d(0, 0, 1)).norm() < kTol);
      cube_faces.insert(sorted_row(cube_slots, e));
      floor_faces.insert(sorted_row(floor_slots, e));
    }
    CHECK(floor_faces.size() == 2);
    const auto expected = faces_touching(x, 0, 2, 0.03);
    CHECK(expected.size() == 18 + 4 * 6);
    CHECK(cube_faces == expected);
  }
}

TEST_CASE("FIGNet's floor box: 8 vertices, 12 outward faces, the scene floor's properties",
          "[gns][fignet]") {
  const Scene scene = scene_of({builtin("cube", 0.5), builtin("sphere", 0.7)});
  const auto g = models::fignet::make_fignet_geometry(scene);
  REQUIRE(g.num_objects() == 3);
  CHECK(g.objects[0].shape == "cube");
  CHECK(g.objects[1].shape == "sphere");
  CHECK(g.floor == 2);
  const auto& fl = g.objects[2];
  CHECK(fl.is_floor);
  CHECK(fl.mass == 0.0);
  CHECK(fl.friction == 0.3);
  CHECK(fl.restitution == 0.5);
  REQUIRE(fl.mesh.vertices.rows() == 8);
  REQUIRE(fl.mesh.faces.rows() == 12);
  CHECK(g.node_offset[2] == 56 + 58);
  CHECK(g.num_nodes() == 56 + 58 + 8);
  // Vertices: the 8 corners of [-10, 10]^2 x [-0.5, 0].
  std::set<std::array<double, 3>> corners;
  for (Eigen::Index v = 0; v < 8; ++v) {
    const Eigen::Vector3d c = fl.mesh.vertices.row(v).transpose();
    CHECK(std::abs(c.x()) == 10.0);
    CHECK(std::abs(c.y()) == 10.0);
    CHECK((c.z() == 0.0 || c.z() == -0.5));
    corners.insert({c.x(), c.y(), c.z()});
  }
  CHECK(corners.size() == 8);
  const Eigen::Vector3d centre(0, 0, -0.25);
  CHECK(fl.center_of_mass == centre);
  CHECK((volumetric_center_of_mass(fl.mesh.vertices, fl.mesh.faces) - centre).norm() < 1e-12);
  double area = 0;
  for (Eigen::Index f = 0; f < 12; ++f) {
    const Eigen::Vector3d a = fl.mesh.vertices.row(fl.mesh.faces(f, 0)).transpose(),
                          b = fl.mesh.vertices.row(fl.mesh.faces(f, 1)).transpose(),
                          c = fl.mesh.vertices.row(fl.mesh.faces(f, 2)).transpose();
    const Eigen::Vector3d n = (b - a).cross(c - a);
    CHECK(n.dot((a + b + c) / 3.0 - centre) > 0);  // outward
    area += 0.5 * n.norm();
  }
  CHECK(area == Approx(2 * (20 * 20 + 20 * 0.5 + 20 * 0.5)));
  // The canonical cube and sphere are untouched.
  CHECK(g.objects[0].mesh.vertices == scene.objects[0].mesh.vertices);
  CHECK(g.objects[1].center_of_mass == scene.objects[1].center_of_mass);
}

TEST_CASE("FIGNet node, object and mesh-object features on an analytic motion", "[gns][fignet]") {
  SceneObject cube = builtin("cube", 0.5, 2.0), sphere = builtin("sphere", 0.7, 3.0);
  cube.friction = 0.25;
  cube.restitution = 0.75;
  sphere.friction = 0.125;
  sphere.restitution = 0.375;
  const Scene scene = scene_of({cube, sphere});
  const auto g = models::fignet::make_fignet_geometry(scene);
  // Positions a + u t + w t^2 with constant rotations: every vertex moves like its body's origin,
  // so v_{t-1} = p(1) - p(0) = u + w, v_t = p(2) - p(1) = u + 3 w, the target 2 w.
  const std::array<Eigen::Vector3d, 2> a{Eigen::Vector3d(0.1, -0.2, 1.0),
                                         Eigen::Vector3d(0.7, 0.3, 0.4)},
      u{Eigen::Vector3d(0.01, 0.02, -0.03), Eigen::Vector3d(-0.02, 0.0, 0.01)},
      w{Eigen::Vector3d(0.0, 0.0, -0.002), Eigen::Vector3d(0.001, -0.001, 0.0)};
  const std::array<Eigen::Vector4d, 2> q{Eigen::Vector4d(std::cos(0.3), 0, std::sin(0.3), 0),
                                         Eigen::Vector4d(0.5, 0.5, -0.5, 0.5)};
  std::array<Poses, 4> P;
  for (int t = 0; t < 4; ++t)
    P[static_cast<std::size_t>(t)] =
        poses_of({{a[0] + u[0] * double(t) + w[0] * double(t * t), q[0]},
                  {a[1] + u[1] * double(t) + w[1] * double(t * t), q[1]}});
  const auto f = models::fignet::fignet_frame(g, P[0], P[1], P[2], &P[3]);
  const std::int64_t N = g.num_nodes();
  const auto& mesh = f.node_set("mesh").features;
  const auto& obj = f.node_set("object").features;
  REQUIRE(mesh.rows() == N);
  REQUIRE(mesh.cols() == 12);
  REQUIRE(obj.rows() == 3);
  REQUIRE(obj.cols() == 12);
  REQUIRE(f.target.rows() == N);
  REQUIRE(f.dynamic.size() == static_cast<std::size_t>(N));
  REQUIRE(f.node_object == g.node_object);
  CHECK(f.edges.count("mm") == 0);

  const auto check_row = [](const sim::RowMatrix& m, Eigen::Index r, const Eigen::Vector3d& v1,
                            const Eigen::Vector3d& v2, double restitution, double friction,
                            double mass, double kinematic) {
    CHECK((vec(m, r, 0) - v1).norm() < 1e-12);
    CHECK((vec(m, r, 3) - v2).norm() < 1e-12);
    CHECK(m(r, 6) == restitution);
    CHECK(m(r, 7) == friction);
    CHECK(m(r, 8) == friction);
    CHECK(m(r, 9) == friction);
    CHECK(m(r, 10) == mass);
    CHECK(m(r, 11) == kinematic);
  };
  for (std::int64_t n = 0; n < N; ++n) {
    const auto o = g.node_object[static_cast<std::size_t>(n)];
    if (o < 2) {
      const auto& so = scene.objects[static_cast<std::size_t>(o)];
      check_row(mesh, n, u[o] + w[o], u[o] + 3.0 * w[o], so.restitution, so.friction, so.mass, 1.0);
      CHECK((f.target.row(n).transpose() - 2.0 * w[o]).norm() < 1e-12);
      CHECK(f.dynamic[static_cast<std::size_t>(n)] == 1);
    } else {
      check_row(mesh, n, Eigen::Vector3d::Zero(), Eigen::Vector3d::Zero(), 0.5, 0.3, 0.0, 0.0);
      CHECK(f.target.row(n).isZero());
      CHECK(f.dynamic[static_cast<std::size_t>(n)] == 0);
    }
  }
  for (std::int64_t o = 0; o < 2; ++o) {
    const auto& so = scene.objects[static_cast<std::size_t>(o)];
    check_row(obj, o, u[o] + w[o], u[o] + 3.0 * w[o], so.restitution, so.friction, so.mass, 1.0);
  }
  check_row(obj, 2, Eigen::Vector3d::Zero(), Eigen::Vector3d::Zero(), 0.5, 0.3, 0.0, 0.0);

  // Mesh-object edges: d = x - x_com at t, d_ref = X - X_com; om is their negation, reversed.
  const auto x = world_nodes(g, P[2]);
  const auto& mo = f.edge_set("mo");
  const auto& om = f.edge_set("om");
  REQUIRE(mo.size() == N);
  REQUIRE(om.size() == N);
  REQUIRE(mo.features.cols() == 8);
  for (std::int64_t n = 0; n < N; ++n) {
    const auto o = g.node_object[static_cast<std::size_t>(n)];
    const auto& ob = g.objects[static_cast<std::size_t>(o)];
    const Eigen::Vector3d X =
        ob.mesh.vertices.row(n - g.node_offset[static_cast<std::size_t>(o)]).transpose();
    const Eigen::Vector3d d_ref = X - ob.center_of_mass;
    const Eigen::Matrix3d R =
        o < 2 ? rotation(q[static_cast<std::size_t>(o)]) : Eigen::Matrix3d::Identity();
    const Eigen::Vector3d com =
        o < 2 ? Eigen::Vector3d(R * ob.center_of_mass + P[2].positions.row(o).transpose())
              : Eigen::Vector3d(0, 0, -0.25);
    CHECK(mo.senders(n, 0) == n);
    CHECK(mo.receivers(n, 0) == o);
    CHECK(om.senders(n, 0) == o);
    CHECK(om.receivers(n, 0) == n);
    CHECK((vec(mo.features, n, 0) - (x.row(n).transpose() - com)).norm() < 1e-12);
    CHECK((vec(mo.features, n, 0) - R * d_ref).norm() < 1e-12);
    CHECK(vec(mo.features, n, 4) == d_ref);
    CHECK(mo.features(n, 3) == Approx(mo.features(n, 7)).margin(1e-12));  // rigid: |d| = |d_ref|
    CHECK(mo.features(n, 7) == Approx(d_ref.norm()).margin(1e-15));
    CHECK(om.features.block<1, 3>(n, 0) == -mo.features.block<1, 3>(n, 0));
    CHECK(om.features(n, 3) == mo.features(n, 3));
    CHECK(om.features.block<1, 3>(n, 4) == -mo.features.block<1, 3>(n, 4));
    CHECK(om.features(n, 7) == mo.features(n, 7));
  }
  // The object nodes' velocities are their centres of mass's: rotations are constant, so u + 3w.
  CHECK(f.node_set("object").size() == 3);

  SECTION("no next poses: no target") {
    CHECK(models::fignet::fignet_frame(g, P[0], P[1], P[2], nullptr).target.size() == 0);
  }
  SECTION("mesh-mesh edges: every unique edge both ways, [x_s - x_r, |.|, X_s - X_r, |.|]") {
    models::fignet::FignetFeatureOptions o;
    o.mesh_edges = true;
    const auto fm = models::fignet::fignet_frame(g, P[0], P[1], P[2], nullptr, o);
    const auto& mm = fm.edge_set("mm");
    // Closed meshes: 3F/2 edges; cube 108 faces, sphere 112, floor box 12.
    REQUIRE(mm.size() == 2 * (162 + 168 + 18));
    std::set<std::pair<std::int64_t, std::int64_t>> seen;
    for (Eigen::Index e = 0; e < mm.size(); ++e) {
      const auto s = mm.senders(e, 0), r = mm.receivers(e, 0);
      const auto o = g.node_object[static_cast<std::size_t>(s)];
      CHECK(g.node_object[static_cast<std::size_t>(r)] == o);
      seen.insert({s, r});
      const auto off = g.node_offset[static_cast<std::size_t>(o)];
      const auto& V = g.objects[static_cast<std::size_t>(o)].mesh.vertices;
      CHECK((vec(mm.features, e, 0) - (x.row(s) - x.row(r)).transpose()).norm() < 1e-12);
      CHECK(vec(mm.features, e, 4) == (V.row(s - off) - V.row(r - off)).transpose());
      CHECK(mm.features(e, 3) == Approx(mm.features(e, 7)).margin(1e-12));
    }
    CHECK(seen.size() == static_cast<std::size_t>(mm.size()));
    for (const auto& [s, r] : seen) CHECK(seen.count({r, s}) == 1);
  }
}

TEST_CASE("MGN world edges equal a brute-force search, with virtual floor nodes below the radius",
          "[gns][mgn]") {
  std::mt19937 rng(20240607);
  std::uniform_real_distribution<double> U(0.0, 1.0);
  const char* shapes[] = {"cube", "sphere", "cylinder"};
  std::vector<SceneObject> objects;
  std::vector<std::pair<Eigen::Vector3d, Eigen::Vector4d>> pose;
  for (int i = 0; i < 6; ++i) {
    objects.push_back(builtin(shapes[i % 3], 0.3 + 0.5 * U(rng), 1.0 + i));
    Eigen::Vector4d q(U(rng) - 0.5, U(rng) - 0.5, U(rng) - 0.5, U(rng) - 0.5);
    // Object 0 low enough to reach the floor plane.
    pose.push_back(
        {{1.2 * U(rng), 1.2 * U(rng), i == 0 ? 0.1 : 0.1 + 0.8 * U(rng)}, q.normalized()});
  }
  const Scene scene = scene_of(objects);
  const auto g = models::mgn::make_mgn_geometry(scene);
  const std::int64_t N = g.num_nodes();
  REQUIRE(g.floor == 6);
  CHECK(g.objects[6].mesh.vertices == sim::floor_mesh().vertices);  // HOPNet's quad
  const Poses p = poses_of(pose);
  const auto x = world_nodes(g, p);

  for (double r : {0.1, 0.3}) {
    models::mgn::MgnFeatureOptions o;
    o.world_edge_radius = r;
    const auto f = models::mgn::mgn_frame(g, p, p, p, &p, o);
    // Brute force over all node pairs of different objects.
    std::set<std::pair<std::int64_t, std::int64_t>> expected;
    for (std::int64_t i = 0; i < N; ++i)
      for (std::int64_t j = 0; j < N; ++j)
        if (g.node_object[static_cast<std::size_t>(i)] !=
                g.node_object[static_cast<std::size_t>(j)] &&
            (x.row(i) - x.row(j)).squaredNorm() <= r * r)
          expected.insert({i, j});
    std::vector<std::int64_t> below;  // non-floor nodes under the radius
    for (std::int64_t n = 0; n < N; ++n)
      if (g.node_object[static_cast<std::size_t>(n)] != g.floor && x(n, 2) < r) below.push_back(n);
    INFO("radius " << r << ": " << expected.size() << " node pairs, " << below.size()
                   << " nodes near the floor");
    CHECK(!expected.empty());
    CHECK(!below.empty());
    const auto V = static_cast<std::int64_t>(below.size());

    const auto& mesh = f.node_set("mesh").features;
    REQUIRE(mesh.rows() == N + V);
    REQUIRE(f.dynamic.size() == static_cast<std::size_t>(N + V));
    REQUIRE(f.node_object.size() == static_cast<std::size_t>(N + V));
    REQUIRE(f.target.rows() == N + V);
    const auto& we = f.edge_set("world_edges");
    REQUIRE(we.features.cols() == 4);
    std::set<std::pair<std::int64_t, std::int64_t>> got;
    std::map<std::int64_t, std::vector<Eigen::Index>> virtual_edges;
    for (Eigen::Index e = 0; e < we.size(); ++e) {
      const auto s = we.senders(e, 0), d = we.receivers(e, 0);
      if (s >= N || d >= N) {
        virtual_edges[std::max(s, d)].push_back(e);
        continue;
      }
      CHECK(got.insert({s, d}).second);
      CHECK((vec(we.features, e, 0) - (x.row(s) - x.row(d)).transpose()).norm() < 1e-12);
      CHECK(we.features(e, 3) == Approx(vec(we.features, e, 0).norm()).margin(1e-15));
    }
    CHECK(got == expected);
    // One virtual node per node below the radius, in node order, joined to it both ways.
    REQUIRE(virtual_edges.size() == below.size());
    for (std::int64_t v = 0; v < V; ++v) {
      const std::int64_t vn = N + v, n = below[static_cast<std::size_t>(v)];
      const auto& es = virtual_edges[vn];
      REQUIRE(es.size() == 2);
      for (Eigen::Index e : es) {
        const bool up = we.senders(e, 0) == n;  // node -> virtual node
        CHECK((up ? we.receivers(e, 0) : we.senders(e, 0)) == vn);
        CHECK((up ? we.senders(e, 0) : we.receivers(e, 0)) == n);
        const Eigen::Vector3d dz(0, 0, up ? x(n, 2) : -x(n, 2));
        CHECK((vec(we.features, e, 0) - dz).norm() < 1e-12);
        CHECK(we.features(e, 3) == Approx(std::abs(x(n, 2))).margin(1e-15));
      }
      CHECK(mesh.block<1, 6>(vn, 0).isZero());
      CHECK(mesh(vn, 6) == 0.5);
      CHECK(mesh(vn, 7) == 0.3);
      CHECK(mesh(vn, 9) == 0.3);
      CHECK(mesh(vn, 10) == 0.0);
      CHECK(mesh(vn, 11) == 0.0);
      CHECK(f.dynamic[static_cast<std::size_t>(vn)] == 0);
      CHECK(f.node_object[static_cast<std::size_t>(vn)] == g.floor);
      CHECK(f.target.row(vn).isZero());
    }
    // Mesh edges: every object's unique edges both ways (floor quad: 5).
    std::int64_t unique = 5;
    for (int i = 0; i < 6; ++i)
      unique += 3 * scene.objects[static_cast<std::size_t>(i)].mesh.num_faces() / 2;
    CHECK(f.edge_set("mesh_edges").size() == 2 * unique);
    CHECK(f.edge_set("mesh_edges").features.cols() == 8);
  }
}

TEST_CASE("MGN node columns are FIGNet's, with virtual floor nodes on a cube's bottom face",
          "[gns][mgn]") {
  const Scene scene = scene_of({builtin("cube", 1.0, 2.0), builtin("sphere", 0.5)});
  const auto g = models::mgn::make_mgn_geometry(scene);
  const auto gf = models::fignet::make_fignet_geometry(scene);
  const Eigen::Vector4d turn(std::cos(0.2), 0, 0, std::sin(0.2));  // about z: the bottom stays flat
  for (double bottom : {0.05, -0.05}) {
    const Poses p0 = poses_of({{{0, 0, 0.5 + bottom + 0.02}, turn}, {{3, 0, 2}, kIdentity}});
    const Poses p1 = poses_of({{{0, 0, 0.5 + bottom + 0.01}, turn}, {{3, 0, 2}, kIdentity}});
    const Poses p2 = poses_of({{{0, 0, 0.5 + bottom}, turn}, {{3, 0, 2}, kIdentity}});
    const auto f = models::mgn::mgn_frame(g, p0, p1, p2, nullptr);
    const auto ff = models::fignet::fignet_frame(gf, p0, p1, p2, nullptr);
    // The cube's bottom side is a 4 x 4 grid of vertices at z = bottom; its next layer is a third
    // higher, and the sphere is 2 m up.
    const std::int64_t N = g.num_nodes();
    const auto& mesh = f.node_set("mesh").features;
    REQUIRE(mesh.rows() == N + 16);
    CHECK(f.target.size() == 0);
    const auto& ref = ff.node_set("mesh").features;
    const auto floor_offset = g.node_offset[2];
    CHECK(mesh.topRows(floor_offset) == ref.topRows(floor_offset));
    for (std::int64_t n = floor_offset; n < N; ++n) {
      CHECK(mesh.block<1, 6>(n, 0).isZero());
      CHECK(mesh(n, 11) == 0.0);
    }
    const auto& we = f.edge_set("world_edges");
    std::int64_t virtual_edges = 0;
    for (Eigen::Index e = 0; e < we.size(); ++e) {
      const auto s = we.senders(e, 0), d = we.receivers(e, 0);
      if (s < N && d < N) continue;
      ++virtual_edges;
      const auto n = std::min(s, d);
      CHECK(g.node_object[static_cast<std::size_t>(n)] == 0);
      CHECK(we.features(e, 2) == Approx(s == n ? bottom : -bottom).margin(1e-12));
      CHECK(we.features(e, 0) == 0.0);
      CHECK(we.features(e, 1) == 0.0);
    }
    CHECK(virtual_edges == 2 * 16);
  }
}

TEST_CASE("FIGNet and MGN features: bad input is a clear error", "[gns]") {
  const Scene scene = scene_of({builtin("cube", 0.5), builtin("sphere", 0.5)});
  const auto g = models::fignet::make_fignet_geometry(scene);
  const auto gm = models::mgn::make_mgn_geometry(scene);
  const Poses ok = poses_of({{{0, 0, 1}, kIdentity}, {{1, 0, 1}, kIdentity}});
  const Poses short_ = poses_of({{{0, 0, 1}, kIdentity}});
  Poses nan_position = ok, nan_quaternion = ok, zero_quaternion = ok;
  nan_position.positions(1, 2) = std::nan("");
  nan_quaternion.quaternions(0, 1) = std::numeric_limits<double>::infinity();
  zero_quaternion.quaternions.row(1).setZero();

  require_invalid([&] { models::fignet::fignet_frame(g, short_, ok, ok, nullptr); },
                  "poses at t-2");
  require_invalid([&] { models::fignet::fignet_frame(g, ok, ok, short_, nullptr); },
                  "for 3 objects");
  require_invalid([&] { models::fignet::fignet_frame(g, ok, ok, ok, &short_); }, "poses at t+1");
  require_invalid([&] { models::fignet::fignet_frame(g, ok, nan_position, ok, nullptr); },
                  "poses at t-1: the pose of object 1 is not finite");
  require_invalid([&] { models::fignet::fignet_frame(g, ok, ok, nan_quaternion, nullptr); },
                  "pose of object 0 is not finite");
  require_invalid([&] { models::fignet::fignet_frame(g, ok, ok, zero_quaternion, nullptr); },
                  "quaternion of object 1 is zero");
  models::fignet::FignetFeatureOptions fo;
  fo.collision_radius = -0.1;
  require_invalid([&] { models::fignet::fignet_frame(g, ok, ok, ok, nullptr, fo); },
                  "collision_radius");

  require_invalid([&] { models::mgn::mgn_frame(gm, ok, short_, ok, nullptr); }, "poses at t-1");
  require_invalid([&] { models::mgn::mgn_frame(gm, ok, ok, nan_position, nullptr); },
                  "the pose of object 1 is not finite");
  require_invalid([&] { models::mgn::mgn_frame(gm, ok, ok, ok, &zero_quaternion); },
                  "poses at t+1");
  models::mgn::MgnFeatureOptions mo;
  mo.world_edge_radius = 0.0;
  require_invalid([&] { models::mgn::mgn_frame(gm, ok, ok, ok, nullptr, mo); },
                  "world_edge_radius");
  mo.world_edge_radius = std::nan("");
  require_invalid([&] { models::mgn::mgn_frame(gm, ok, ok, ok, nullptr, mo); },
                  "world_edge_radius");

  // A mesh without faces, and one whose face points past its vertices.
  Scene bad = scene;
  bad.objects[1].mesh.faces.resize(0, 3);
  require_invalid([&] { models::fignet::make_fignet_geometry(bad); },
                  "object 1 ('sphere') has no faces");
  require_invalid([&] { models::mgn::make_mgn_geometry(bad); }, "object 1 ('sphere') has no faces");
  bad = scene;
  bad.objects[0].mesh.faces(3, 1) = 1000;
  require_invalid([&] { models::mgn::make_mgn_geometry(bad); }, "object 0 ('cube')");
}
