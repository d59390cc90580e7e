// Fuzz harness: the reference's collisions.json (models/hopnet/features.hpp), and its frame-3
// contacts fed to build_frame on a two-cube scene as `hopnet rollout` does: an index out of
// range must be an error, never a read out of bounds.
#include "fuzz_target.hpp"

#include "topos/models/hopnet/features.hpp"

namespace {
struct TwoCubes {
  topos::sim::Scene scene;
  topos::models::hopnet::HopnetGeometry geometry;
  TwoCubes() {
    topos::data::KubricScene k;
    k.num_frames = 4;
    for (int i = 0; i < 2; ++i) {
      topos::data::KubricInstance in;
      in.asset_id = in.shape = "cube";
      in.size = 0.5, in.mass = 1, in.friction = 0.5, in.restitution = 0.5;
      in.positions.resize(4, 3);
      in.quaternions.resize(4, 4);
      for (int t = 0; t < 4; ++t) {
        in.positions.row(t) << 0.6 * i, 0.01 * t, 0.3;
        in.quaternions.row(t) << 1, 0, 0, 0;
      }
      k.instances.push_back(in);
    }
    topos::sim::MeshLibrary lib;
    scene = topos::sim::make_scene(k, lib);
    geometry =
        topos::models::hopnet::make_geometry(scene, topos::models::hopnet::FeatureMode::reference);
  }
};
}  // namespace

TOPOS_FUZZ_TARGET(collisions) {
  using namespace topos_fuzz;
  namespace h = topos::models::hopnet;
  std::map<std::int64_t, std::vector<h::ContactCandidate>> all;
  try {
    all = h::parse_collisions_json(text(data, size), source());
  } catch (const topos::data::DataError& e) {
    expect_error(e.what());
    return 0;
  }
  static const TwoCubes cubes;
  const auto it = all.find(3);
  if (it == all.end() || it->second.size() > 64) return 0;
  try {
    const auto f = h::build_frame(cubes.geometry, h::scene_poses(cubes.scene, 0),
                                  h::scene_poses(cubes.scene, 1), h::scene_poses(cubes.scene, 2),
                                  h::scene_poses(cubes.scene, 3), it->second);
    check(f.num_contacts() <= static_cast<std::int64_t>(it->second.size()),
          "no more contacts than candidates");
  } catch (const std::invalid_argument&) {
    // build_frame's message names the offending contact (the caller adds the file).
  }
  return 0;
}
