// topos/models/hopnet/simulator.hpp
// HOPNet as a sim::Simulator: a model (from a checkpoint as read, or a fresh one) with its
// normaliser; reset() builds the scene's HopnetGeometry in the model's lifting, predict() is one
// step of hopnet::rollout (contacts within the model's collision radius).
#pragma once

#include "topos/models/hopnet/rollout.hpp"
#include "topos/models/hopnet/variants.hpp"
#include "topos/models/namespace_aliases.hpp"
#include "topos/sim/simulator.hpp"

#include <map>
#include <memory>
#include <optional>
#include <stdexcept>
#include <string>

namespace topos::models::hopnet {

class HopnetSimulator : public sim::Simulator {
 public:
  using TensorDict = std::map<std::string, torch::Tensor>;

  /// The model of a checkpoint already read (`source` names it in errors), with the overrides
  /// applied; `norm`: its normaliser (none: the simulator can describe, not predict).
  HopnetSimulator(std::shared_ptr<const TensorDict> dict, std::string source,
                  CheckpointOverrides overrides, std::optional<Normalizer> norm)
      : dict_(std::move(dict)),
        source_(std::move(source)),
        overrides_(overrides),
        net_(load_hopnet(*dict_, source_, overrides_)),
        norm_(std::move(norm)) {
    reference_ = reference_architecture(*dict_);
    net_->eval();
  }
  /// A fresh (untrained) model.
  HopnetSimulator(Hopnet net, std::optional<Normalizer> norm)
      : source_("a new " + variant_name(net->options) + " model"),
        net_(std::move(net)),
        norm_(std::move(norm)) {
    net_->eval();
  }

  std::string name() const override { return "hopnet"; }
  std::string variant() const override { return variant_name(net_->options); }
  nlohmann::json config() const override { return net_->options.to_json(); }
  std::int64_t num_parameters() const override { return net_->num_parameters(); }
  void describe(std::ostream& out) const override {
    out << "variant: " << variant();
    if (reference_)
      out << " (recognised from the '_" << reference_class(*reference_)
          << "__' tensor names and shapes; the activation is not recorded)";
    out << "\nconfiguration: " << config().dump() << "\nparameters: " << num_parameters()
        << "\nschedule:\n"
        << net_->schedule().str();
  }
  void reset(const sim::Scene& scene) override {
    geometry_ = make_geometry(scene, net_->options.lifting());
  }
  sim::Prediction predict(const std::vector<Poses>& poses,
                          const sim::RolloutOptions& opt) override {
    if (!norm_)
      throw std::invalid_argument(source_ + " is a HOPNet checkpoint: --stats is required");
    if (!geometry_) throw std::logic_error("HopnetSimulator::predict before reset");
    return rollout_step(*net_, *norm_, *geometry_, poses, net_->options.collision_radius(),
                        opt.first_contacts);
  }
  void to(torch::Device device) override { net_->to(device); }
  void step_threads(int n) override { net_->step_threads(n); }
  std::unique_ptr<sim::Simulator> clone() const override {
    if (dict_) return std::make_unique<HopnetSimulator>(dict_, source_, overrides_, norm_);
    Hopnet net(net_->options);
    torch::NoGradGuard no_grad;
    auto from = net_->named_parameters();
    for (auto& p : net->named_parameters()) p.value().copy_(from[p.key()]);
    return std::make_unique<HopnetSimulator>(std::move(net), norm_);
  }

  /// The network (on its device) and its normaliser, for what only HOPNet does (hopnet grad).
  Hopnet net() const { return net_; }
  const std::optional<Normalizer>& normalizer() const { return norm_; }
  void set_normalizer(Normalizer norm) { norm_ = std::move(norm); }
  /// The reference architecture when the checkpoint is a reference state dict.
  std::optional<Architecture> reference_architecture_of() const { return reference_; }

 private:
  std::shared_ptr<const TensorDict> dict_;  ///< the checkpoint as read (clone loads from it)
  std::string source_;
  CheckpointOverrides overrides_;
  Hopnet net_;
  std::optional<Normalizer> norm_;
  std::optional<Architecture> reference_;
  std::optional<HopnetGeometry> geometry_;  ///< the scene of the last reset
};

}  // namespace topos::models::hopnet
