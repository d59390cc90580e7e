// Scenes for tests that need no reference data, built from the built-in shapes.
#pragma once

#include "topos/sim/scene.hpp"

#include <algorithm>
#include <cmath>
#include <cstdint>

namespace topos::testing {

// A built-in scene (no reference data): a cube resting on the floor, a sphere falling onto it.
// With `cube_drop` > 0 the cube starts that much higher and falls onto the floor, so the first
// timesteps have no contact.
inline sim::Scene cube_and_sphere(std::int64_t frames = 12, double cube_drop = 0.0) {
  data::KubricScene k;
  k.num_frames = frames;
  k.source = "builtin";
  const char* shapes[] = {"cube", "sphere"};
  for (int i = 0; i < 2; ++i) {
    data::KubricInstance in;
    in.asset_id = in.shape = shapes[i];
    in.size = 1.0;
    in.mass = 1.0 + i;
    in.friction = 0.5;
    in.restitution = 0.5;
    in.positions.resize(frames, 3);
    in.quaternions.resize(frames, 4);
    for (std::int64_t t = 0; t < frames; ++t) {
      const double z = i == 0
                           ? std::max(0.53, 0.53 + cube_drop - 0.0025 * static_cast<double>(t * t))
                           : 2.9 - 0.5 * 1.7e-4 * static_cast<double>(t * t) *
                                       40;  // cube (±0.5) 3 cm above the floor
      in.positions.row(t) << 0.1 * i, 0.05 * i, z;
      const double a = 0.01 * static_cast<double>(t) * i;
      in.quaternions.row(t) << std::cos(a), 0, std::sin(a), 0;
    }
    k.instances.push_back(in);
  }
  sim::MeshLibrary lib;
  return sim::make_scene(k, lib);
}

}  // namespace topos::testing
