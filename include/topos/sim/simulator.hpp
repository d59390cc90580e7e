// topos/sim/simulator.hpp
// What every learned simulator offers the programs (HOPNet, FIGNet, MeshGraphNet): predict the
// poses at t+1 from a history window, reset for a new scene, name, variant, configuration,
// parameter count, a description, a copy for another worker thread. sim::rollout(Simulator&)
// runs one on the shared loop (sim/rollout.hpp); sim::open_model (sim/open_model.hpp) opens any
// checkpoint as one.
//
//   auto opened = sim::open_model("mgn.pt");
//   const auto r = sim::rollout(*opened.simulator, scene, options);
#pragma once

#include "topos/nn/kernels/packed_weights.hpp"
#include "topos/sim/rollout.hpp"

#include <nlohmann/json.hpp>
#include <torch/torch.h>

#include <cstdint>
#include <memory>
#include <ostream>
#include <string>
#include <utility>
#include <vector>

namespace topos::sim {

class Simulator {
 public:
  virtual ~Simulator() = default;
  /// The model's name in tables and reports: "hopnet", or a baseline's preset ("fignet", "mgn",
  /// "mgn-large-radius"; the model's name for another configuration).
  virtual std::string name() const = 0;
  /// HOPNet's variant ("standard", "nox4", ...), a baseline's preset.
  virtual std::string variant() const = 0;
  /// The configuration, as its checkpoint records it in "topos.config".
  virtual nlohmann::json config() const = 0;
  virtual std::int64_t num_parameters() const = 0;
  /// The model described from its variant on (variant, configuration, parameters, schedule).
  virtual void describe(std::ostream& out) const = 0;
  /// Readies the model for `scene` (its static graph data); the scene must outlive the
  /// predictions made on it.
  virtual void reset(const Scene& scene) = 0;
  /// The poses at t+1 from the window poses[0..t] of the scene of the last reset, t =
  /// poses.size() - 1 >= 3 (frame 0 is the ground truth's first). `opt.first_contacts`, when
  /// given, are the contacts of the step at t = 3 for a model that detects contacts.
  virtual Prediction predict(const std::vector<Poses>& poses, const RolloutOptions& opt) = 0;
  /// Moves the model to `device` (the baselines run on the CPU: they stay there).
  virtual void to(torch::Device device) = 0;
  /// Threads that the independent steps of a prediction's network share
  /// (nn::OperatorNetworkImpl::step_threads; 1, the default: the calling thread alone).
  virtual void step_threads(int n) = 0;
  /// Another simulator with the same weights, on the CPU (one per worker thread).
  virtual std::unique_ptr<Simulator> clone() const = 0;
};

/// Rolls `simulator` out from the ground-truth frames 0..3 of `scene` for opt.steps frames.
inline RolloutResult rollout(Simulator& simulator, const Scene& scene,
                             const RolloutOptions& opt = {}) {
  const nn::PackedWeightsScope packed;  // the same weights at every step
  simulator.reset(scene);
  return rollout_loop(scene, opt, [&](std::size_t t, RolloutResult& r) {
    Prediction p = simulator.predict(r.poses, opt);
    r.invalid_ratio[t] = p.invalid_ratio;
    return std::move(p.poses);
  });
}

}  // namespace topos::sim
