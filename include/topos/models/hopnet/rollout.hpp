// topos/models/hopnet/rollout.hpp
// Autoregressive HOPNet rollout (utils/rollout.py) and the paper's per-frame metrics.
// Frames 0..3 come from the ground truth; step t (= 3..) detects contacts on the pose at t
// (the first step may take given contacts, as the reference takes collisions.json["3"]),
// builds the features from the poses at t-2, t-1, t and GT frame 0, runs the model, integrates
// the node accelerations (x_{t+1} = a + 2x_t − x_{t−1}) and re-rigidifies every object by
// shape matching on its volumetric centre of mass. Static objects keep their pose.
#pragma once

#include "topos/models/hopnet/model.hpp"

#include <chrono>
#include <cmath>
#include <functional>
#include <limits>
#include <optional>

namespace topos::hopnet {

struct RolloutOptions {
  int steps = 102;                ///< predicted frames (the reference's ROLLOUT_DURATION)
  double collision_radius = 0.1;  ///< d_c
  std::optional<std::vector<ContactCandidate>> first_contacts;  ///< contacts of the first step
  std::function<void(int, int)> on_step;  ///< called after each step with (done, total)
};

struct RolloutResult {
  std::vector<Poses> poses;  ///< frame 0.. (history, then predictions)
  std::vector<double>
      invalid_ratio;   ///< per frame: unsafe / detected pairs of the step at that frame
  double seconds = 0;  ///< wall time of the rollout loop
  std::int64_t num_frames() const { return static_cast<std::int64_t>(poses.size()); }
};

/// One model step: the predicted poses at t+1 from poses at t-2, t-1, t.
inline Poses predict_next(HopnetImpl& model, const Normalizer& norm, const HopnetGeometry& g,
                          const Poses& first, const Poses& p2, const Poses& p1, const Poses& pt,
                          const std::vector<ContactCandidate>& contacts,
                          HopnetFrame* frame_out = nullptr) {
  HopnetFrame frame = build_frame(g, first, p2, p1, pt, contacts);
  // The model's device decides where it runs (CPU or GPU); the pose update stays on the host.
  const auto params = model.parameters();
  const torch::Device device =
      params.empty() ? torch::Device(torch::kCPU) : params.front().device();
  const HopnetBatch batch = device.is_cpu() ? make_batch({{&g, &frame}}, norm)
                                            : make_batch({{&g, &frame}}, norm).to(device);
  torch::NoGradGuard no_grad;
  const auto out = model.forward(batch, norm);
  const torch::Tensor acc =
      norm.denormalize("t0", out.a0).to(torch::kCPU, torch::kDouble).contiguous();
  const auto* a = acc.data_ptr<double>();
  const auto now = pose_objects(g, pt), before = pose_objects(g, p1);
  Poses next = pt;
  for (std::size_t o = 0; o < g.objects.size(); ++o) {
    const auto& obj = *g.objects[o];
    if (obj.is_floor) continue;
    Vertices x = 2.0 * now[o].vertices - before[o].vertices;
    for (Eigen::Index v = 0; v < x.rows(); ++v)
      for (int c = 0; c < 3; ++c) x(v, c) += a[3 * (g.node_offset[o] + v) + c];
    const RigidPose r = shape_match(obj.mesh.vertices, obj.center_of_mass, x, obj.mesh.faces);
    next.positions.row(static_cast<Eigen::Index>(o)) = r.position.transpose();
    next.quaternions.row(static_cast<Eigen::Index>(o)) = r.wxyz.transpose();
  }
  if (frame_out) *frame_out = std::move(frame);
  return next;
}

/// The autoregressive loop every rigid-body model shares (HOPNet's, the baselines'): ground-truth
/// frames 0..3, then opt.steps frames, each `step(t, result)` -> the poses at t+1 from the poses
/// so far (result.poses[0..t]); a non-finite position is an error naming the frame.
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

/// Rolls out from GT frames 0..3 of `scene` for opt.steps frames.
inline RolloutResult rollout(HopnetImpl& model, const Normalizer& norm, const Scene& scene,
                             const HopnetGeometry& g, const RolloutOptions& opt = {}) {
  return rollout_loop(scene, opt, [&](std::size_t t, RolloutResult& r) {
    const auto posed = pose_objects(g, r.poses[t]);
    const auto contacts = (t == 3 && opt.first_contacts)
                              ? *opt.first_contacts
                              : detect_contacts(g, posed, opt.collision_radius);
    HopnetFrame frame;
    Poses next = predict_next(model, norm, g, r.poses[0], r.poses[t - 2], r.poses[t - 1],
                              r.poses[t], contacts, &frame);
    r.invalid_ratio[t] = frame.invalid_ratio();
    return next;
  });
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

}  // namespace topos::hopnet
