// topos/models/baselines.hpp
// HOPNet's paper baselines as one interface: FIGNet and MeshGraphNet (`fignet`, `mgn`,
// `mgn-large-radius`) built from a JSON configuration, their features of a scene's timesteps,
// checkpoints that record the model (a checkpoint of one model loaded as another is an error
// naming both), and the rollout that turns predicted node accelerations into rigid poses: the
// vertices integrated (x_{t+1} = a + 2x_t - x_{t-1}) and each moving object fitted by HOPNet's
// shape matching, so every model is scored through the same pose update and metrics. Frames 0..3
// are ground truth, as for HOPNet (the shared loop: topos/sim/rollout.hpp).
#pragma once

#include "topos/models/fignet/features.hpp"
#include "topos/models/fignet/model.hpp"
#include "topos/models/hopnet/variants.hpp"
#include "topos/models/mgn/features.hpp"
#include "topos/models/mgn/model.hpp"
#include "topos/models/namespace_aliases.hpp"
#include "topos/nn/serialization.hpp"
#include "topos/sim/simulator.hpp"

#include <cstdio>
#include <map>
#include <memory>
#include <optional>
#include <variant>

namespace topos::models::baselines {

/// Whether a configuration's "model" names a baseline.
inline bool is_baseline_model(const std::string& model) {
  return model == "fignet" || model == "mgn";
}

/// One baseline's options: FIGNet's or MeshGraphNet's.
class BaselineConfig {
 public:
  static BaselineConfig from_json(const nlohmann::json& j) {
    if (!j.is_object() || !j.contains("model") || !j["model"].is_string())
      throw std::invalid_argument("baseline configuration: no \"model\" (fignet or mgn)");
    const auto model = j["model"].get<std::string>();
    if (model == "fignet") return BaselineConfig(fignet::FignetOptions::from_json(j));
    if (model == "mgn") return BaselineConfig(mgn::MgnOptions::from_json(j));
    throw std::invalid_argument("baseline configuration: unknown model '" + model +
                                "' (fignet or mgn)");
  }
  explicit BaselineConfig(fignet::FignetOptions o) : options_(o) {}
  explicit BaselineConfig(mgn::MgnOptions o) : options_(o) {}

  std::string model() const { return is_fignet() ? "fignet" : "mgn"; }
  /// The preset's name when the configuration is one ("mgn-large-radius"), else the model's.
  std::string name() const {
    const auto j = to_json();
    for (const auto& [preset, fields] : hopnet::baseline_presets())
      if (fields.value("model", "") == model() && from_json(fields).to_json() == j) return preset;
    return model();
  }
  bool is_fignet() const { return std::holds_alternative<fignet::FignetOptions>(options_); }
  const fignet::FignetOptions& fignet() const { return std::get<fignet::FignetOptions>(options_); }
  const mgn::MgnOptions& mgn() const { return std::get<mgn::MgnOptions>(options_); }
  nlohmann::json to_json() const { return is_fignet() ? fignet().to_json() : mgn().to_json(); }
  gns::GraphNetworkSpec spec() const {
    return is_fignet() ? fignet::fignet_spec(fignet()) : mgn::mgn_spec(mgn());
  }

 private:
  std::variant<fignet::FignetOptions, mgn::MgnOptions> options_;
};

/// The baseline a configuration string names (presets and JSON files, variants.hpp).
inline BaselineConfig parse_baseline_config(const std::string& text) {
  const auto fields = hopnet::config_fields(text);
  if (!is_baseline_model(fields.value("model", "hopnet")))
    throw std::invalid_argument("configuration '" + text + "' is not a baseline (fignet or mgn)");
  return BaselineConfig::from_json(fields);
}

/// A scene's static graph data for one baseline, and its timesteps' graphs.
class SceneGraphs {
 public:
  SceneGraphs(const BaselineConfig& config, const sim::Scene& scene) : config_(config) {
    if (config.is_fignet())
      geometry_ = fignet::make_fignet_geometry(scene);
    else
      geometry_ = mgn::make_mgn_geometry(scene);
  }
  /// The graph of the step from poses at t-2, t-1, t (`next`: t+1, for a training target).
  sim::GraphFrame frame(const sim::Poses& p2, const sim::Poses& p1, const sim::Poses& pt,
                        const sim::Poses* next = nullptr) const {
    if (config_.is_fignet()) {
      fignet::FignetFeatureOptions o;
      o.collision_radius = config_.fignet().collision_radius;
      o.mesh_edges = config_.fignet().mesh_edges;
      return fignet::fignet_frame(std::get<fignet::FignetGeometry>(geometry_), p2, p1, pt, next, o);
    }
    mgn::MgnFeatureOptions o;
    o.world_edge_radius = config_.mgn().world_edge_radius;
    return mgn::mgn_frame(std::get<mgn::MgnGeometry>(geometry_), p2, p1, pt, next, o);
  }
  /// The graph of frame t's step in a ground-truth scene (t >= 2; with its target when t+1 exists).
  sim::GraphFrame frame(const sim::Scene& scene, std::int64_t t) const {
    const auto next = t + 1 < scene.num_frames
                          ? std::optional<sim::Poses>(sim::scene_poses(scene, t + 1))
                          : std::nullopt;
    return frame(sim::scene_poses(scene, t - 2), sim::scene_poses(scene, t - 1),
                 sim::scene_poses(scene, t), next ? &*next : nullptr);
  }
  const sim::SceneMeshes& meshes() const {
    return std::visit([](const auto& g) -> const sim::SceneMeshes& { return g; }, geometry_);
  }

 private:
  BaselineConfig config_;
  std::variant<fignet::FignetGeometry, mgn::MgnGeometry> geometry_;
};

/// A baseline's network with its configuration.
struct Baseline {
  BaselineConfig config;
  gns::GraphNetwork net;
  explicit Baseline(BaselineConfig c)
      : config(std::move(c)), net(config.spec(), "_encode_process_decode") {}
  std::int64_t num_parameters() const {
    std::int64_t n = 0;
    for (const auto& p : net->parameters()) n += p.numel();
    return n;
  }
};

/// The "model" a checkpoint records in "topos.config" ("hopnet" for HOPNet's, and for reference
/// HOPNet files, which carry no configuration).
inline nlohmann::json checkpoint_config(const std::map<std::string, torch::Tensor>& dict,
                                        const std::string& source) {
  auto cfg = dict.find("topos.config");
  if (cfg == dict.end()) return {{"model", "hopnet"}};
  const auto t = cfg->second.to(torch::kUInt8).contiguous();
  const std::string text(reinterpret_cast<const char*>(t.data_ptr<std::uint8_t>()),
                         static_cast<std::size_t>(t.numel()));
  try {
    auto j = nlohmann::json::parse(text);
    if (!j.is_object()) throw std::invalid_argument("not a JSON object");
    if (!j.contains("model")) j["model"] = "hopnet";
    return j;
  } catch (const std::exception& e) {
    throw std::runtime_error(source + ": unreadable topos.config: " + e.what());
  }
}

/// Saves parameters, "topos.config" and the normalisation statistics ("topos.statistics"), so a
/// baseline checkpoint is self-contained. Atomic.
inline void save_baseline(const Baseline& b, const gns::Statistics& stats,
                          const std::string& path) {
  c10::Dict<std::string, torch::Tensor> dict;
  for (const auto& p : b.net->named_parameters()) dict.insert(p.key(), p.value().detach().cpu());
  auto bytes = [](const std::string& s) {
    return torch::tensor(std::vector<std::uint8_t>(s.begin(), s.end()), torch::kUInt8);
  };
  dict.insert("topos.config", bytes(b.config.to_json().dump()));
  dict.insert("topos.statistics", bytes(stats.to_json().dump()));
  nn::write_tensor_dict(dict, path);
}

/// A baseline checkpoint: its model (`expected`, when given, must be the one recorded: "a fignet
/// checkpoint ... --config asks for mgn"), its parameters and its statistics.
struct LoadedBaseline {
  Baseline model;
  gns::Statistics stats;
};

inline LoadedBaseline load_baseline(const std::map<std::string, torch::Tensor>& dict,
                                    const std::string& source, const std::string& expected = "") {
  const auto cfg = checkpoint_config(dict, source);
  const std::string model = cfg.value("model", "hopnet");
  if (!expected.empty() && model != expected)
    throw std::invalid_argument(source + ": a " + model + " checkpoint (topos.config model '" +
                                model + "'); the configuration asks for " + expected);
  if (!is_baseline_model(model))
    throw std::invalid_argument(source + ": a " + model +
                                " checkpoint, not a baseline (fignet or mgn)");
  BaselineConfig config = [&] {
    try {
      return BaselineConfig::from_json(cfg);
    } catch (const std::invalid_argument& e) {
      throw std::invalid_argument(source + ": " + e.what());
    }
  }();
  LoadedBaseline out{Baseline(config), {}};
  auto params = dict;
  params.erase("topos.config");
  auto st = params.find("topos.statistics");
  if (st == params.end())
    throw std::invalid_argument(source + ": missing 'topos.statistics' (the normalisation)");
  {
    const auto t = st->second.to(torch::kUInt8).contiguous();
    const std::string text(reinterpret_cast<const char*>(t.data_ptr<std::uint8_t>()),
                           static_cast<std::size_t>(t.numel()));
    try {
      out.stats = gns::Statistics::from_json(nlohmann::json::parse(text), source);
    } catch (const nlohmann::json::exception& e) {
      throw std::invalid_argument(source + ": unreadable topos.statistics: " + e.what());
    }
    params.erase(st);
  }
  out.stats.check_fits(out.model.config.spec(), source);
  nn::load_parameters(*out.model.net, params, source);
  return out;
}

/// One step: the poses at t+1 predicted from poses at t-2, t-1, t.
inline sim::Poses predict_next(Baseline& b, const gns::Statistics& stats, const SceneGraphs& graphs,
                               const sim::Poses& p2, const sim::Poses& p1, const sim::Poses& pt) {
  const auto frame = graphs.frame(p2, p1, pt);
  const auto batch = gns::collate(b.net->spec(), {&frame}, stats);
  torch::NoGradGuard no_grad;
  const auto out = b.net->forward(batch).at("mesh").to(torch::kDouble).contiguous();
  const auto& g = graphs.meshes();
  const auto& mean = stats.mean.at("acceleration");
  const auto& sd = stats.std.at("acceleration");
  const auto* a = out.data_ptr<double>();
  const auto now = sim::pose_meshes(g, pt, "pose at t"),
             before = sim::pose_meshes(g, p1, "pose at t-1");
  sim::Poses next = pt;
  for (std::int64_t o = 0; o < g.num_objects(); ++o) {
    if (g.is_static(o)) continue;
    const auto& obj = g.objects[static_cast<std::size_t>(o)];
    const auto k = static_cast<std::size_t>(o);
    const RigidPose r =
        sim::integrate_object(obj, now[k].vertices, before[k].vertices, [&](Eigen::Index v, int c) {
          return a[3 * (g.node_offset[k] + v) + c] * sd[static_cast<std::size_t>(c)] +
                 mean[static_cast<std::size_t>(c)];
        });
    next.positions.row(o) = r.position.transpose();
    next.quaternions.row(o) = r.wxyz.transpose();
  }
  return next;
}

/// Rolls out from GT frames 0..3 of `scene` for opt.steps frames (HOPNet's loop and result).
inline sim::RolloutResult rollout(Baseline& b, const gns::Statistics& stats,
                                  const sim::Scene& scene, const SceneGraphs& graphs,
                                  const sim::RolloutOptions& opt = {}) {
  return sim::rollout_loop(scene, opt, [&](std::size_t t, sim::RolloutResult& r) {
    return predict_next(b, stats, graphs, r.poses[t - 2], r.poses[t - 1], r.poses[t]);
  });
}

/// A baseline (FIGNet or MeshGraphNet) as a sim::Simulator: the network and its statistics;
/// reset() builds the scene's graph data (SceneGraphs), predict() is predict_next. It runs on the
/// CPU: to() leaves it there.
class BaselineSimulator : public sim::Simulator {
 public:
  using TensorDict = std::map<std::string, torch::Tensor>;

  /// The baseline of a checkpoint already read (load_baseline; `source` names it in errors).
  BaselineSimulator(std::shared_ptr<const TensorDict> dict, std::string source)
      : dict_(std::move(dict)), source_(std::move(source)) {
    auto loaded = load_baseline(*dict_, source_);
    model_ = std::make_shared<Baseline>(std::move(loaded.model));
    stats_ = std::move(loaded.stats);
    model_->net->eval();
  }
  /// A fresh (untrained) baseline, without statistics: it describes itself, it cannot predict.
  explicit BaselineSimulator(const BaselineConfig& config)
      : source_("a new " + config.name() + " model"), model_(std::make_shared<Baseline>(config)) {
    model_->net->eval();
  }

  std::string name() const override { return model_->config.name(); }
  std::string variant() const override { return model_->config.name(); }
  nlohmann::json config() const override { return model_->config.to_json(); }
  std::int64_t num_parameters() const override { return model_->num_parameters(); }
  /// Also the parameters per top-level module (encoders, each block's functions, decoders).
  void describe(std::ostream& out) const override {
    const auto named = model_->net->named_parameters();
    out << "model: " << model_->config.model() << "\nvariant: " << variant()
        << "\nconfiguration: " << config().dump() << "\nparameters: " << num_parameters()
        << "\ntensors: " << named.size() << "\n";
    std::map<std::string, std::pair<std::int64_t, int>> per;
    std::vector<std::string> order;
    for (const auto& p : named) {
      std::string key = p.key().substr(p.key().find('.') + 1);
      const auto block = key.find("gnn_stacks.");
      if (block != std::string::npos) {
        const auto a = key.find('.', block + 11) + 1;
        key = "_processor.gnn_stacks.*." + key.substr(a, key.find('.', a) - a);
      } else {
        key = key.substr(0, key.find('.'));
      }
      if (!per.count(key)) order.push_back(key);
      per[key].first += p.value().numel();
      per[key].second += 1;
    }
    char line[128];
    std::snprintf(line, sizeof line, "%-40s %12s %8s\n", "module", "parameters", "tensors");
    out << line;
    for (const auto& k : order) {
      std::snprintf(line, sizeof line, "%-40s %12lld %8d\n", k.c_str(),
                    static_cast<long long>(per[k].first), per[k].second);
      out << line;
    }
    out << "schedule:\n" << model_->net->network->schedule().str();
  }
  void reset(const sim::Scene& scene) override { graphs_.emplace(model_->config, scene); }
  sim::Prediction predict(const std::vector<sim::Poses>& poses,
                          const sim::RolloutOptions&) override {
    if (!stats_)
      throw std::invalid_argument(source_ +
                                  " has no normalisation statistics (an untrained model)");
    if (!graphs_) throw std::logic_error("BaselineSimulator::predict before reset");
    const std::size_t t = poses.size() - 1;
    return {predict_next(*model_, *stats_, *graphs_, poses[t - 2], poses[t - 1], poses[t]), 0.0};
  }
  void to(torch::Device) override {}
  void step_threads(int n) override { model_->net->network->step_threads(n); }
  std::unique_ptr<sim::Simulator> clone() const override {
    if (dict_) return std::make_unique<BaselineSimulator>(dict_, source_);
    auto copy = std::make_unique<BaselineSimulator>(model_->config);
    torch::NoGradGuard no_grad;
    auto from = model_->net->named_parameters();
    for (auto& p : copy->model_->net->named_parameters()) p.value().copy_(from[p.key()]);
    return copy;
  }

  const Baseline& model() const { return *model_; }

 private:
  std::shared_ptr<const TensorDict> dict_;  ///< the checkpoint as read (clone loads from it)
  std::string source_;
  std::shared_ptr<Baseline> model_;
  std::optional<gns::Statistics> stats_;
  std::optional<SceneGraphs> graphs_;  ///< the scene of the last reset
};

}  // namespace topos::models::baselines
