// topos/sim/rollout.hpp
// The autoregressive rollout every simulator shares and the paper's per-frame metrics. Frames
// 0..3 come from the ground truth; each step predicts the poses at t+1 from the poses so far
// (rollout_loop; a Simulator's rollout: sim/simulator.hpp). Metrics: position RMSE and MAE (m),
// orientation RMSE and MAE (deg) over the dynamic objects. No LibTorch.
#pragma once

#include "topos/sim/scene.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <functional>
#include <limits>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

namespace topos::sim {

struct RolloutOptions {
  int steps = 102;  ///< predicted frames (the reference's ROLLOUT_DURATION)
  /// d_c of models::hopnet::rollout (a Simulator uses its model's own)
  double collision_radius = 0.1;
  /// The contacts of the first step (HOPNet's, as the reference takes collisions.json["3"]);
  /// models that detect no contact candidates ignore them.
  std::optional<std::vector<ContactCandidate>> first_contacts;
  std::function<void(int, int)> on_step;  ///< called after each step with (done, total)
};

/// One predicted step: the poses at t+1 and, for a model that detects contacts, the share of the
/// detected pairs it dropped as intersecting (0 otherwise).
struct Prediction {
  Poses poses;
  double invalid_ratio = 0;
};

struct RolloutResult {
  std::vector<Poses> poses;  ///< frame 0.. (history, then predictions)
  std::vector<double>
      invalid_ratio;   ///< per frame: unsafe / detected pairs of the step at that frame
  double seconds = 0;  ///< wall time of the rollout loop
  std::int64_t num_frames() const { return static_cast<std::int64_t>(poses.size()); }
};

/// The autoregressive loop every rigid-body model shares (HOPNet's, FIGNet's, MeshGraphNet's):
/// ground-truth frames 0..3, then opt.steps frames, each `step(t, result)` -> the poses at t+1
/// from the poses so far (result.poses[0..t]); a non-finite position is an error naming the frame.
template <class Step>
RolloutResult rollout_loop(const Scene& scene, const RolloutOptions& opt, Step&& step) {
  if (scene.num_frames < 4)
    throw std::invalid_argument(scene.source +
                                ": a rollout needs at least 4 ground-truth frames, the scene has " +
                                std::to_string(scene.num_frames));
  if (opt.steps < 1) throw std::invalid_argument("rollout: steps must be positive");
  RolloutResult r;
  for (int t = 0; t < 4; ++t) r.poses.push_back(scene_poses(scene, t));
  r.invalid_ratio.assign(static_cast<std::size_t>(opt.steps) + 4, 0.0);
  const auto start = std::chrono::steady_clock::now();
  for (int k = 0; k < opt.steps; ++k) {
    const std::size_t t = r.poses.size() - 1;
    Poses next = step(t, r);
    for (Eigen::Index i = 0; i < next.positions.size(); ++i)
      if (!std::isfinite(next.positions.data()[i]))
        throw std::runtime_error("rollout diverged at frame " + std::to_string(t + 1) +
                                 " (non-finite position)");
    r.poses.push_back(std::move(next));
    if (opt.on_step) opt.on_step(k + 1, opt.steps);
  }
  r.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return r;
}

/// Per-frame errors over the dynamic objects: position RMSE and MAE (m), orientation
/// MAE and RMSE (deg) of 2·asin|vec(q_gt ⊗ conj(q̂))|, NaN angles skipped as the reference does.
struct RolloutMetrics {
  std::vector<double> pos_rmse, pos_mae, ori_rmse, ori_mae;
};

inline double orientation_error_deg(const Eigen::Vector4d& gt, const Eigen::Vector4d& pred) {
  const double w1 = gt[0], w2 = pred[0];
  const Eigen::Vector3d v1 = gt.tail<3>(), v2 = -pred.tail<3>();
  const Eigen::Vector3d vec = w1 * v2 + w2 * v1 + v1.cross(v2);
  return 2.0 * std::asin(vec.norm()) * 180.0 / M_PI;
}

/// `poses` against the scene's ground truth, frames 0..poses.size()-1 (`dynamic`: objects scored).
inline RolloutMetrics rollout_metrics(const std::vector<Poses>& poses, const Scene& scene) {
  RolloutMetrics m;
  const auto frames =
      std::min<std::int64_t>(static_cast<std::int64_t>(poses.size()), scene.num_frames);
  for (std::int64_t k = 0; k < frames; ++k) {
    double se = 0, ae = 0, a2 = 0, a1 = 0;
    int n = 0, na = 0;
    for (std::size_t o = 0; o < scene.num_objects(); ++o) {
      if (scene.objects[o].is_floor) continue;
      const double d = (poses[static_cast<std::size_t>(k)]
                            .positions.row(static_cast<Eigen::Index>(o))
                            .transpose() -
                        scene.position(k, o))
                           .norm();
      se += d * d;
      ae += d;
      ++n;
      const double ang = orientation_error_deg(scene.quaternion(k, o),
                                               poses[static_cast<std::size_t>(k)]
                                                   .quaternions.row(static_cast<Eigen::Index>(o))
                                                   .transpose());
      if (!std::isnan(ang)) a1 += ang, a2 += ang * ang, ++na;
    }
    const double nan = std::numeric_limits<double>::quiet_NaN();
    m.pos_rmse.push_back(n ? std::sqrt(se / n) : nan);
    m.pos_mae.push_back(n ? ae / n : nan);
    m.ori_mae.push_back(na ? a1 / na : nan);
    m.ori_rmse.push_back(na ? std::sqrt(a2 / na) : nan);
  }
  return m;
}

}  // namespace topos::sim
