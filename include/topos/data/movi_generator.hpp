// topos/data/movi_generator.hpp
// Seed-exact regeneration of the MOVi-spheres / MOVi-A / MOVi-B scenes with Bullet (double
// precision, `bullet-float64`), following Kubric's MOVi recipe (movi_def_worker.py):
//  - the scene draws of Kubric's movi_ab_worker replayed with NumpyRandomState (lights, camera,
//    object count, per object shape / size / colour / material, the overlap-rejection
//    placement loop, the toss velocity);
//  - PyBullet's world: btMultiBodyDynamicsWorld + btMultiBodyConstraintSolver, Kubric's solver
//    settings, one convex hull per `o` block as a compound (margins 0.001), compound-AABB
//    inertia, contact processing threshold 0, no sleeping, the dome floor added first;
//  - 2400 Hz (A, B) or 1200 Hz (spheres) steps, states recorded at 240 Hz, 480 frames,
//    rounded to float32 as Kubric writes them.
// Without an asset folder, built-in meshes stand in (cube, sphere, cylinder at ±0.5, with
// KuBasic's unit masses) and a flat 256-gon disc of the dome's size replaces the dome.
#pragma once

#include "topos/mesh/primitives.hpp"
#include "topos/data/kubric.hpp"
#include "topos/data/numpy_random.hpp"

#include <btBulletDynamicsCommon.h>
#include <BulletDynamics/Featherstone/btMultiBodyConstraintSolver.h>
#include <BulletDynamics/Featherstone/btMultiBodyDynamicsWorld.h>

#include <nlohmann/json.hpp>

#include <array>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <map>
#include <memory>
#include <sstream>
#include <string>
#include <vector>

extern btScalar gDbvtMargin;

namespace topos::data {

enum class MoviKind { spheres, a, b };

inline MoviKind movi_kind_from_string(const std::string& s) {
  if (s == "movi-spheres") return MoviKind::spheres;
  if (s == "movi-a") return MoviKind::a;
  if (s == "movi-b") return MoviKind::b;
  throw DataError("unknown dataset '" + s + "' (movi-spheres, movi-a, movi-b)");
}
inline const char* to_string(MoviKind k) {
  return k == MoviKind::spheres ? "movi-spheres" : (k == MoviKind::a ? "movi-a" : "movi-b");
}
inline int step_rate(MoviKind k) {
  return k == MoviKind::spheres ? 1200 : 2400;
}

/// A physics asset: convex parts as the face corners of each `o` block (float32-parsed, in
/// file order), data.json bounds and unit-density mass.
struct MoviAsset {
  std::string name;
  std::vector<std::vector<std::array<double, 3>>> parts;
  std::array<float, 3> bounds_lo{-0.5f, -0.5f, -0.5f}, bounds_hi{0.5f, 0.5f, 0.5f};
  double unit_mass = 1.0;
};

namespace detail {
// Face corners per `o`/`g` block, as tinyobj hands them to PyBullet's hull builder.
inline std::vector<std::vector<std::array<double, 3>>> obj_corner_parts(
    const std::filesystem::path& path) {
  std::ifstream in(path);
  if (!in) throw DataError(path.string() + ": cannot open file");
  std::vector<std::array<double, 3>> v;
  std::vector<std::vector<std::array<double, 3>>> parts(1);
  std::string line;
  int lineno = 0;
  while (std::getline(in, line)) {
    ++lineno;
    std::istringstream ss(line);
    std::string tag;
    ss >> tag;
    if (tag == "v") {
      float x, y, z;
      if (!(ss >> x >> y >> z))
        throw DataError(path.string() + ":" + std::to_string(lineno) + ": malformed vertex");
      v.push_back({x, y, z});
    } else if ((tag == "o" || tag == "g") && !parts.back().empty()) {
      parts.emplace_back();
    } else if (tag == "f") {
      std::string tok;
      while (ss >> tok) {
        long idx = std::strtol(tok.c_str(), nullptr, 10);
        if (idx < 0) idx += static_cast<long>(v.size()) + 1;
        if (idx < 1 || idx > static_cast<long>(v.size()))
          throw DataError(path.string() + ":" + std::to_string(lineno) +
                          ": face index out of range");
        parts.back().push_back(v[static_cast<std::size_t>(idx - 1)]);
      }
    }
  }
  if (parts.back().empty()) parts.pop_back();
  if (parts.empty()) throw DataError(path.string() + ": no faces");
  return parts;
}
}  // namespace detail

/// Loads `<assets>/<name>/{collision_geometry.obj, data.json}`, or the built-in stand-in.
inline MoviAsset load_movi_asset(const std::filesystem::path& assets, const std::string& name) {
  MoviAsset a;
  a.name = name;
  if (assets.empty()) {
    static const std::map<std::string, double> unit_mass{
        {"cube", 0.9936}, {"sphere", 0.5225}, {"cylinder", 0.7808}};
    if (name == "dome") {
      // A flat disc like the dome's collision hull (radius 39.70, z in [-0.412, 0]).
      std::vector<std::array<double, 3>> pts;
      for (int k = 0; k < 256; ++k) {
        const double t = 2 * M_PI * k / 256.0;
        pts.push_back({39.70 * std::cos(t), 39.70 * std::sin(t), 0.0});
        pts.push_back({39.70 * std::cos(t), 39.70 * std::sin(t), -0.412});
      }
      a.parts.push_back(pts);
      a.unit_mass = 0;
      return a;
    }
    auto it = unit_mass.find(name);
    if (it == unit_mass.end())
      throw DataError("shape '" + name +
                      "' has no built-in mesh (built-ins: cube, sphere, cylinder); give --assets");
    const TriangleMesh m = builtin_shape(name);
    std::vector<std::array<double, 3>> pts;
    for (Eigen::Index f = 0; f < m.faces.rows(); ++f)
      for (int c = 0; c < 3; ++c) {
        const auto r = m.vertices.row(m.faces(f, c));
        pts.push_back(
            {static_cast<float>(r(0)), static_cast<float>(r(1)), static_cast<float>(r(2))});
      }
    a.parts.push_back(pts);
    a.unit_mass = it->second;
    return a;
  }
  const auto dir = assets / name;
  if (!std::filesystem::exists(dir / "collision_geometry.obj"))
    throw DataError((dir / "collision_geometry.obj").string() + ": missing asset for shape '" +
                    name + "'");
  a.parts = detail::obj_corner_parts(dir / "collision_geometry.obj");
  if (name == "dome")
    return a;  // static: no mass or bounds needed (and its data.json is not strict JSON)
  std::ifstream in(dir / "data.json");
  if (!in) throw DataError((dir / "data.json").string() + ": missing asset description");
  try {
    const auto j = nlohmann::json::parse(in);
    const auto& kw = j.at("kwargs");
    for (int c = 0; c < 3; ++c) {
      a.bounds_lo[static_cast<std::size_t>(c)] = kw.at("bounds").at(0).at(c).get<float>();
      a.bounds_hi[static_cast<std::size_t>(c)] = kw.at("bounds").at(1).at(c).get<float>();
    }
    a.unit_mass = kw.at("mass").get<double>();
  } catch (const nlohmann::json::exception& e) {
    throw DataError((dir / "data.json").string() + ": unexpected layout: " + e.what());
  }
  return a;
}

struct MoviObject {
  std::string shape, material, size_label, color_label;
  double size = 1, mass = 0, friction = 0, restitution = 0;
  std::array<double, 3> color{};
  std::array<double, 3> position{}, velocity{};
  std::array<double, 4> wxyz{1, 0, 0, 0};
};

struct MoviScene {
  MoviKind kind = MoviKind::a;
  std::uint32_t seed = 0;
  int step_rate = 2400, frame_rate = 240, num_frames = 480;
  std::vector<MoviObject> objects;
  /// per object: frames × 3 positions, frames × 4 quaternions (w x y z), velocities (m/s).
  std::vector<std::vector<std::array<double, 3>>> positions, velocities, angular_velocities;
  std::vector<std::vector<std::array<double, 4>>> quaternions;
};

/// Owns a Bullet world set up as PyBullet + Kubric do (Kubric's simulator setup).
class MoviWorld {
 public:
  explicit MoviWorld(double dt) : dt_(dt) {
    gDbvtMargin = 0;
    config_ = std::make_unique<btDefaultCollisionConfiguration>();
    dispatcher_ = std::make_unique<btCollisionDispatcher>(config_.get());
    pair_cache_ = std::make_unique<btHashedOverlappingPairCache>();
    broadphase_ = std::make_unique<btDbvtBroadphase>(pair_cache_.get());
    broadphase_->setVelocityPrediction(0);
    solver_ = std::make_unique<btMultiBodyConstraintSolver>();
    world_ = std::make_unique<btMultiBodyDynamicsWorld>(dispatcher_.get(), broadphase_.get(),
                                                        solver_.get(), config_.get());
    world_->setGravity(btVector3(0, 0, -10));
    world_->setForceUpdateAllAabbs(false);
    world_->getDispatchInfo().m_deterministicOverlappingPairs = true;
    auto& si = world_->getSolverInfo();
    si.m_numIterations = 50;
    si.m_erp2 = 0.08;
    si.m_linearSlop = 0;
    si.m_warmstartingFactor = 0;
    si.m_restitutionVelocityThreshold = 0;
    si.m_splitImpulse = 1;
    si.m_minimumSolverBatchSize = 0;
    si.m_leastSquaresResidualThreshold = 1e-7;
  }
  ~MoviWorld() {
    for (auto& b : bodies_) world_->removeRigidBody(b.get());
  }
  MoviWorld(const MoviWorld&) = delete;
  MoviWorld& operator=(const MoviWorld&) = delete;

  /// A compound of one convex hull per part, scaled by `size` (PyBullet's call order).
  btCompoundShape* make_shape(const MoviAsset& a, double size) {
    auto compound = std::make_unique<btCompoundShape>();
    compound->setMargin(0.001);
    for (const auto& part : a.parts) {
      auto hull = std::make_unique<btConvexHullShape>();
      hull->setMargin(0.001);
      for (const auto& p : part)
        hull->addPoint(btVector3(p[0] * size, p[1] * size, p[2] * size), false);
      hull->recalcLocalAabb();
      hull->optimizeConvexHull();
      btTransform id;
      id.setIdentity();
      compound->addChildShape(id, hull.get());
      shapes_.push_back(std::move(hull));
    }
    auto* raw = compound.get();
    shapes_.push_back(std::move(compound));
    return raw;
  }

  btRigidBody* add_body(btCollisionShape* shape, double mass, double friction, double restitution,
                        const std::array<double, 3>& pos, const std::array<double, 4>& wxyz) {
    btVector3 inertia(0, 0, 0);
    if (mass > 0) shape->calculateLocalInertia(mass, inertia);
    btTransform tr;
    tr.setIdentity();
    tr.setOrigin(btVector3(pos[0], pos[1], pos[2]));
    tr.setRotation(btQuaternion(wxyz[1], wxyz[2], wxyz[3], wxyz[0]));
    btRigidBody::btRigidBodyConstructionInfo info(mass, nullptr, shape, inertia);
    info.m_startWorldTransform = tr;
    auto body = std::make_unique<btRigidBody>(info);
    body->setFriction(friction);
    body->setRestitution(restitution);
    body->setContactProcessingThreshold(0);
    body->forceActivationState(DISABLE_DEACTIVATION);
    world_->addRigidBody(body.get());
    bodies_.push_back(std::move(body));
    return bodies_.back().get();
  }

  void remove_last_body() {
    world_->removeRigidBody(bodies_.back().get());
    bodies_.pop_back();
  }

  /// True when `b` touches any other body (PyBullet's getClosestPoints(distance = 0)).
  bool overlaps_any(btRigidBody* b) {
    struct Cb : btCollisionWorld::ContactResultCallback {
      bool hit = false;
      btScalar addSingleResult(btManifoldPoint& cp, const btCollisionObjectWrapper*, int, int,
                               const btCollisionObjectWrapper*, int, int) override {
        // Bullet also reports points within the contact breaking threshold; PyBullet's
        // getClosestPoints(distance = 0) keeps only those at distance <= 0.
        if (cp.getDistance() <= 0) hit = true;
        return 0;
      }
    };
    for (auto& other : bodies_) {
      if (other.get() == b) continue;
      Cb cb;
      cb.m_closestDistanceThreshold = 0;
      world_->contactPairTest(b, other.get(), cb);
      if (cb.hit) return true;
    }
    return false;
  }

  void step() { world_->stepSimulation(dt_, 0); }
  const std::vector<std::unique_ptr<btRigidBody>>& bodies() const { return bodies_; }

 private:
  double dt_;
  std::unique_ptr<btDefaultCollisionConfiguration> config_;
  std::unique_ptr<btCollisionDispatcher> dispatcher_;
  std::unique_ptr<btHashedOverlappingPairCache> pair_cache_;
  std::unique_ptr<btDbvtBroadphase> broadphase_;
  std::unique_ptr<btMultiBodyConstraintSolver> solver_;
  std::unique_ptr<btMultiBodyDynamicsWorld> world_;
  std::vector<std::unique_ptr<btCollisionShape>> shapes_;
  std::vector<std::unique_ptr<btRigidBody>> bodies_;
};

/// Asset cache keyed by shape name.
class MoviAssets {
 public:
  explicit MoviAssets(std::filesystem::path dir = {}) : dir_(std::move(dir)) {
    if (!dir_.empty() && !std::filesystem::is_directory(dir_))
      throw DataError(dir_.string() + ": asset folder does not exist");
  }
  const MoviAsset& get(const std::string& name) {
    auto it = cache_.find(name);
    if (it == cache_.end()) it = cache_.emplace(name, load_movi_asset(dir_, name)).first;
    return it->second;
  }

 private:
  std::filesystem::path dir_;
  std::map<std::string, MoviAsset> cache_;
};

/// Generates one scene: the draws of Kubric's MOVi worker, then the simulation.
inline MoviScene generate_movi_scene(MoviKind kind, std::uint32_t seed, MoviAssets& assets,
                                     int num_frames = 480) {
  static const char* clevr_shapes[] = {"cube", "cylinder", "sphere"};
  static const char* kubasic_shapes[] = {"cube",  "cylinder", "sphere",     "cone",
                                         "torus", "gear",     "torus_knot", "sponge",
                                         "spot",  "teapot",   "suzanne"};
  static const char* colors[] = {"blue",  "brown",  "cyan", "gray",
                                 "green", "purple", "red",  "yellow"};
  NumpyRandomState rng(seed);
  MoviScene s;
  s.kind = kind;
  s.seed = seed;
  s.step_rate = step_rate(kind);
  s.num_frames = num_frames;
  for (int i = 0; i < 12; ++i) rng.random();  // 4 CLEVR lights × rand(3)
  if (kind != MoviKind::b)
    for (int i = 0; i < 3; ++i) rng.random();  // the "clevr" camera
  const auto n = rng.randint(3, 11);

  MoviWorld world(1.0 / s.step_rate);
  const auto& dome = assets.get("dome");
  world.add_body(world.make_shape(dome, 2.0), 0.0, 0.3, 0.5, {0, 0, 0}, {1, 0, 0, 0});
  for (std::int64_t i = 0; i < n; ++i) {
    MoviObject o;
    o.shape = kind == MoviKind::spheres ? "sphere"
                                        : (kind == MoviKind::a ? clevr_shapes[rng.choice(3)]
                                                               : kubasic_shapes[rng.choice(11)]);
    if (kind == MoviKind::b) {
      o.size = rng.uniform(0.7, 1.4);
      o.color = {rng.random(), 1.0, 1.0};  // hue (saturation and value are fixed, no draws)
    } else {
      const bool large = rng.choice(2) == 1;
      o.size = large ? 1.4 : 0.7;
      o.size_label = large ? "large" : "small";
      o.color_label = colors[rng.choice(8)];
    }
    const bool rubber = rng.choice(2) == 1;
    o.material = rubber ? "rubber" : "metal";
    o.friction = rubber ? 0.8 : 0.4;
    o.restitution = rubber ? 0.7 : 0.3;
    const auto& asset = assets.get(o.shape);
    o.mass = asset.unit_mass * (rubber ? 1.1 : 2.7) * o.size * o.size * o.size;
    btCollisionShape* shape = world.make_shape(asset, o.size);
    btRigidBody* body = nullptr;
    bool placed = false;
    for (int trial = 0; trial < 100 && !placed; ++trial) {
      const double r1 = rng.random(), r2 = rng.random(), r3 = rng.random();
      o.wxyz = {std::sqrt(1 - r1) * std::sin(2 * M_PI * r2),
                std::sqrt(1 - r1) * std::cos(2 * M_PI * r2),
                std::sqrt(r1) * std::sin(2 * M_PI * r3), std::sqrt(r1) * std::cos(2 * M_PI * r3)};
      // AABB of the rotated bounds corners (bounds × size in float32).
      const btMatrix3x3 R(btQuaternion(o.wxyz[1], o.wxyz[2], o.wxyz[3], o.wxyz[0]));
      std::array<double, 3> lo{1e30, 1e30, 1e30}, hi{-1e30, -1e30, -1e30};
      for (int c = 0; c < 8; ++c) {
        btVector3 p;
        for (int k = 0; k < 3; ++k) {
          const float b = ((c >> k) & 1) ? asset.bounds_hi[static_cast<std::size_t>(k)]
                                         : asset.bounds_lo[static_cast<std::size_t>(k)];
          p[k] = static_cast<double>(b * static_cast<float>(o.size));
        }
        const btVector3 q = R * p;
        for (int k = 0; k < 3; ++k)
          lo[static_cast<std::size_t>(k)] =
              std::min(lo[static_cast<std::size_t>(k)], static_cast<double>(q[k])),
          hi[static_cast<std::size_t>(k)] =
              std::max(hi[static_cast<std::size_t>(k)], static_cast<double>(q[k]));
      }
      const double region_lo[3] = {-5, -5, 1}, region_hi[3] = {5, 5, 5};
      for (int k = 0; k < 3; ++k)
        o.position[static_cast<std::size_t>(k)] =
            rng.uniform(region_lo[k] - lo[static_cast<std::size_t>(k)],
                        region_hi[k] - hi[static_cast<std::size_t>(k)]);
      if (body) world.remove_last_body();
      body = world.add_body(shape, o.mass, o.friction, o.restitution, o.position, o.wxyz);
      placed = !world.overlaps_any(body);
    }
    if (!placed)
      throw DataError("seed " + std::to_string(seed) + ": object " + std::to_string(i) +
                      " found no free place in 100 trials");
    const double vx = rng.uniform(-4, 4), vy = rng.uniform(-4, 4);
    rng.uniform(0, 0);  // the z draw is consumed though its range is 0
    o.velocity = {vx - o.position[0], vy - o.position[1], 0.0};
    body->setLinearVelocity(btVector3(o.velocity[0], o.velocity[1], o.velocity[2]));
    body->setAngularVelocity(btVector3(0, 0, 0));
    s.objects.push_back(o);
  }

  const int spf = s.step_rate / s.frame_rate;
  const std::size_t N = s.objects.size();
  s.positions.assign(N, {});
  s.quaternions.assign(N, {});
  s.velocities.assign(N, {});
  s.angular_velocities.assign(N, {});
  const auto f32 = [](double v) { return static_cast<double>(static_cast<float>(v)); };
  for (int step = 0; step < num_frames * spf; ++step) {
    if (step % spf == 0) {
      for (std::size_t i = 0; i < N; ++i) {
        const btRigidBody* b = world.bodies()[i + 1].get();
        const btTransform& t = b->getWorldTransform();
        const btQuaternion q = t.getRotation();
        const btVector3 &p = t.getOrigin(), &v = b->getLinearVelocity(),
                        &w = b->getAngularVelocity();
        s.positions[i].push_back({f32(p.x()), f32(p.y()), f32(p.z())});
        s.quaternions[i].push_back({f32(q.w()), f32(q.x()), f32(q.y()), f32(q.z())});
        s.velocities[i].push_back({f32(v.x()), f32(v.y()), f32(v.z())});
        s.angular_velocities[i].push_back({f32(w.x()), f32(w.y()), f32(w.z())});
      }
    }
    world.step();
  }
  return s;
}

/// Kubric's metadata.json schema (the fields the reference loaders read, and more).
inline nlohmann::json movi_scene_json(const MoviScene& s) {
  nlohmann::json j;
  const char* set =
      s.kind == MoviKind::spheres ? "spheres" : (s.kind == MoviKind::a ? "clevr" : "kubasic");
  j["flags"] = {{"floor_friction", 0.3},
                {"floor_restitution", 0.5},
                {"frame_rate", s.frame_rate},
                {"step_rate", s.step_rate},
                {"frame_start", 0},
                {"frame_end", s.num_frames - 1},
                {"min_num_objects", 3},
                {"max_num_objects", 10},
                {"objects_set", set},
                {"seed", s.seed},
                {"generator", "topos bullet-float64"}};
  j["metadata"] = {{"num_instances", s.objects.size()}, {"num_frames", s.num_frames},
                   {"frame_rate", s.frame_rate},        {"step_rate", s.step_rate},
                   {"gravity", {0.0, 0.0, -10.0}},      {"seed", s.seed},
                   {"resolution", {256, 256}},          {"background", "clevr"}};
  j["instances"] = nlohmann::json::array();
  for (std::size_t i = 0; i < s.objects.size(); ++i) {
    const auto& o = s.objects[i];
    nlohmann::json in;
    in["asset_id"] = o.shape;
    in["shape"] = o.shape;
    in["size"] = o.size;
    in["size_label"] = o.size_label.empty() ? nlohmann::json() : nlohmann::json(o.size_label);
    in["material"] = o.material;
    in["color_label"] = o.color_label.empty() ? nlohmann::json() : nlohmann::json(o.color_label);
    in["mass"] = o.mass;
    in["friction"] = o.friction;
    in["restitution"] = o.restitution;
    in["positions"] = s.positions[i];
    in["quaternions"] = s.quaternions[i];
    in["velocities"] = s.velocities[i];
    in["angular_velocities"] = s.angular_velocities[i];
    j["instances"].push_back(in);
  }
  return j;
}

}  // namespace topos::data
