// topos/sim/open_model.hpp
// Every checkpoint the programs run, opened one way: open_model reads the file once, tells its
// format from what it holds and returns the model as a sim::Simulator. Formats: a topos
// checkpoint ("topos.config" names the model: hopnet, fignet or mgn; a baseline carries its
// statistics as "topos.statistics") and a reference HOPNet state dict (the authors'; tensors
// prefixed '_HOPNet__', '_HOPNet_NoObjectCells__' or '_HOPNet_NoSequential__'). make_model is
// its counterpart for a configuration (presets and JSON files): a fresh, untrained model. This
// is the one place that knows every model.
#pragma once

#include "topos/models/baselines.hpp"
#include "topos/models/hopnet/simulator.hpp"
#include "topos/models/hopnet/variants.hpp"
#include "topos/nn/serialization.hpp"
#include "topos/sim/simulator.hpp"

#include <map>
#include <memory>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

namespace topos::sim {

/// How to open a checkpoint. The HOPNet fields (statistics, feature mode, activation, collision
/// radius) do not apply to the baselines, whose checkpoints record all of theirs.
struct OpenOptions {
  std::string stats;  ///< HOPNet's normalisation statistics (JSON)
  /// false: opened to describe it (hopnet info), so HOPNet's statistics may be missing.
  bool require_statistics = true;
  std::optional<models::hopnet::FeatureMode> mode;  ///< the feature mode HOPNet runs in
  /// HOPNet's activation (a reference state dict does not record it; without one, a reference
  /// file named after an activation, "gelu_seed0_e39.pt", runs with it and a note says so).
  std::optional<nn::Activation> activation;
  std::optional<double> collision_radius;  ///< HOPNet's d_c (default: the checkpoint's)
};

/// An opened checkpoint.
struct OpenedModel {
  std::string path;
  /// "topos", or "reference (HOPNet authors' state dict, class HOPNet, 92 tensors)".
  std::string format;
  std::vector<std::string> notes;        ///< for the user: what was read off the file's name
  std::unique_ptr<Simulator> simulator;  ///< the model, on the CPU
};

/// The formats open_model accepts, for its errors.
inline constexpr const char* kCheckpointFormats =
    "a topos checkpoint (a 'topos.config' entry naming hopnet, fignet or mgn) or a reference "
    "HOPNet state dict (tensors prefixed '_HOPNet__', '_HOPNet_NoObjectCells__' or "
    "'_HOPNet_NoSequential__')";

inline OpenedModel open_model(const std::string& path, const OpenOptions& o = {}) {
  auto dict =
      std::make_shared<const std::map<std::string, torch::Tensor>>(nn::read_tensor_dict(path));
  OpenedModel m;
  m.path = path;
  const auto reference = models::hopnet::reference_architecture(*dict);
  if (!dict->count("topos.config") && !reference)
    throw std::invalid_argument(path + ": not a model checkpoint; expected " + kCheckpointFormats);
  const std::string model =
      models::baselines::checkpoint_config(*dict, path).value("model", "hopnet");
  if (models::baselines::is_baseline_model(model)) {
    m.format = "topos";
    m.simulator = std::make_unique<models::baselines::BaselineSimulator>(dict, path);
    return m;
  }
  if (model != "hopnet")
    throw std::invalid_argument(path + ": a checkpoint of model '" + model +
                                "', which no simulator runs; expected " + kCheckpointFormats);
  models::hopnet::CheckpointOverrides ov;
  ov.mode = o.mode;
  ov.collision_radius = o.collision_radius;
  ov.activation = o.activation;
  if (!ov.activation && reference) {
    ov.activation = models::hopnet::activation_from_reference_name(path);
    if (ov.activation) {
      const std::string a = nn::activation_name(*ov.activation);
      m.notes.push_back(path + " is a reference checkpoint named after activation " + a +
                        "; running it with " + a + " (--activation overrides)");
    }
  }
  m.format = reference ? "reference (HOPNet authors' state dict, class " +
                             models::hopnet::reference_class(*reference) + ", " +
                             std::to_string(dict->size()) + " tensors)"
                       : "topos";
  if (o.stats.empty() && o.require_statistics)
    throw std::invalid_argument(path + " is a HOPNet checkpoint: --stats is required");
  auto hop = std::make_unique<models::hopnet::HopnetSimulator>(dict, path, ov, std::nullopt);
  if (!o.stats.empty()) {  // checked against the model's options, so after loading it
    const auto stats = models::hopnet::read_stats_json(o.stats);
    models::hopnet::check_stats_fit(hop->net()->options, stats, o.stats);
    hop->set_normalizer(models::hopnet::Normalizer(stats));
  }
  m.simulator = std::move(hop);
  return m;
}

/// A fresh, untrained model of a configuration: presets and/or JSON files, comma-separated
/// (hopnet/variants.hpp; empty: HOPNet's standard). `o.activation` and `o.collision_radius` set
/// HOPNet's; the baselines' fields are set in their configuration.
inline std::unique_ptr<Simulator> make_model(const std::string& config, const OpenOptions& o = {}) {
  if (!config.empty() && models::baselines::is_baseline_model(models::hopnet::config_model(config)))
    return std::make_unique<models::baselines::BaselineSimulator>(
        models::baselines::parse_baseline_config(config));
  models::hopnet::HopnetOptions opt =
      config.empty() ? models::hopnet::HopnetOptions{} : models::hopnet::parse_config(config);
  if (o.activation) opt.activation(*o.activation);
  if (o.collision_radius) opt.collision_radius(*o.collision_radius);
  opt.validate();
  return std::make_unique<models::hopnet::HopnetSimulator>(models::hopnet::Hopnet(opt),
                                                           std::nullopt);
}

}  // namespace topos::sim
