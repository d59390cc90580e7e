// topos/models/hopnet/rollout.hpp
// Autoregressive HOPNet rollout (utils/rollout.py) on the shared loop (topos/sim/rollout.hpp).
// Frames 0..3 come from the ground truth; step t (= 3..) detects contacts on the pose at t
// (the first step may take given contacts, as the reference takes collisions.json["3"]),
// builds the features from the poses at t-2, t-1, t and GT frame 0, runs the model, integrates
// the node accelerations (x_{t+1} = a + 2x_t − x_{t−1}) and re-rigidifies every object by
// shape matching on its volumetric centre of mass. Static objects keep their pose. Native mode
// may multiply in bfloat16 (nn::set_float32_matmul_precision(medium)); reference mode runs in
// float32 only, so that it stays the published model's numbers.
#pragma once

#include "topos/models/hopnet/model.hpp"
#include "topos/models/namespace_aliases.hpp"
#include "topos/nn/kernels/packed_weights.hpp"
#include "topos/nn/mlp.hpp"
#include "topos/sim/meshes.hpp"
#include "topos/sim/rollout.hpp"

#include <optional>
#include <stdexcept>

namespace topos::models::hopnet {

// Deprecated aliases: the rollout loop, its options and result and the metrics moved to
// topos/sim/rollout.hpp (namespace topos::sim); write sim::NAME.
using sim::orientation_error_deg;
using sim::rollout_loop;
using sim::rollout_metrics;
using sim::RolloutMetrics;
using sim::RolloutOptions;
using sim::RolloutResult;

/// Reference mode reproduces the published model, in float32: bfloat16 products
/// (MatmulPrecision::medium) are for native mode only.
inline void check_rollout_precision(const HopnetImpl& model) {
  if (model.options.mode() == FeatureMode::reference &&
      nn::get_float32_matmul_precision() != nn::MatmulPrecision::highest)
    throw std::invalid_argument(
        "HOPNet's reference mode runs in float32 only (it reproduces the published model): "
        "roll out in native mode for bfloat16 products (matmul precision medium), or set the "
        "precision to highest");
}

/// One model step: the predicted poses at t+1 from poses at t-2, t-1, t (at the process's
/// matmul precision; reference mode: highest only, check_rollout_precision).
inline Poses predict_next(HopnetImpl& model, const Normalizer& norm, const HopnetGeometry& g,
                          const Poses& first, const Poses& p2, const Poses& p1, const Poses& pt,
                          const std::vector<ContactCandidate>& contacts,
                          HopnetFrame* frame_out = nullptr) {
  check_rollout_precision(model);
  HopnetFrame frame = build_frame(g, first, p2, p1, pt, contacts);
  // The model's device decides where it runs (CPU or GPU); the pose update stays on the host.
  const torch::Device device = model.device();
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
    const RigidPose r = sim::integrate_object(
        obj, now[o].vertices, before[o].vertices,
        [&](Eigen::Index v, int c) { return a[3 * (g.node_offset[o] + v) + c]; });
    next.positions.row(static_cast<Eigen::Index>(o)) = r.position.transpose();
    next.quaternions.row(static_cast<Eigen::Index>(o)) = r.wxyz.transpose();
  }
  if (frame_out) *frame_out = std::move(frame);
  return next;
}

/// Step t = poses.size() - 1 of a rollout: the contacts at t (`first_contacts` at t = 3 when
/// given, else detected within `collision_radius`), then predict_next.
inline sim::Prediction rollout_step(
    HopnetImpl& model, const Normalizer& norm, const HopnetGeometry& g,
    const std::vector<Poses>& poses, double collision_radius,
    const std::optional<std::vector<ContactCandidate>>& first_contacts = std::nullopt) {
  const std::size_t t = poses.size() - 1;
  const auto posed = pose_objects(g, poses[t]);
  const auto contacts =
      (t == 3 && first_contacts) ? *first_contacts : detect_contacts(g, posed, collision_radius);
  HopnetFrame frame;
  sim::Prediction p;
  p.poses = predict_next(model, norm, g, poses[0], poses[t - 2], poses[t - 1], poses[t], contacts,
                         &frame);
  p.invalid_ratio = frame.invalid_ratio();
  return p;
}

/// Rolls out from GT frames 0..3 of `scene` for opt.steps frames.
inline RolloutResult rollout(HopnetImpl& model, const Normalizer& norm, const Scene& scene,
                             const HopnetGeometry& g, const RolloutOptions& opt = {}) {
  const nn::PackedWeightsScope packed;  // the same weights at every step
  return rollout_loop(scene, opt, [&](std::size_t t, RolloutResult& r) {
    sim::Prediction p =
        rollout_step(model, norm, g, r.poses, opt.collision_radius, opt.first_contacts);
    r.invalid_ratio[t] = p.invalid_ratio;
    return std::move(p.poses);
  });
}

}  // namespace topos::models::hopnet
