// topos/models/hopnet/options.hpp
// HopnetOptions: a HOPNet's configuration (widths, layers, activation, feature mode,
// architecture, collision radius), its JSON form and its checks.
#pragma once

#include "topos/data/json.hpp"
#include "topos/models/hopnet/lifting_options.hpp"
#include "topos/models/namespace_aliases.hpp"
#include "topos/nn/mlp.hpp"

#include <nlohmann/json.hpp>
#include <torch/torch.h>

#include <cmath>
#include <cstdint>
#include <stdexcept>
#include <string>

namespace topos::models::hopnet {

struct HopnetOptions {
  nlohmann::json to_json() const {
    return {{"model", "hopnet"},
            {"architecture", to_string(architecture_)},
            {"center_mass_distance", center_mass_distance_},
            {"hidden", hidden_},
            {"mlp_layers", mlp_layers_},
            {"activation", nn::activation_name(activation_)},
            {"num_layers", num_layers_},
            {"collision_radius", collision_radius_},
            {"mode", to_string(mode_)}};
  }
  static HopnetOptions from_json(const nlohmann::json& j) {
    HopnetOptions o;
    if (!j.is_object()) throw std::invalid_argument("HOPNet configuration: expected a JSON object");
    try {
      if (j.value("model", "hopnet") != "hopnet")
        throw std::invalid_argument("not a HOPNet configuration: model '" + j.value("model", "") +
                                    "'");
      // Checked integers: j.value<int> converts 1e30 unchecked (undefined) and wraps 2^32 + 128.
      const auto integer = [&](const char* key, int dflt) -> int {
        if (!j.contains(key)) return dflt;
        try {
          return data::get_integer<int>(j[key], std::string("HOPNet configuration: ") + key);
        } catch (const data::DataError& e) {
          throw std::invalid_argument(e.what());
        }
      };
      o.hidden(integer("hidden", 128))
          .mlp_layers(integer("mlp_layers", 2))
          .num_layers(integer("num_layers", 1));
      o.activation(nn::activation_from_string(j.value("activation", "relu")));
      o.mode(feature_mode_from_string(j.value("mode", "reference")));
      o.architecture(architecture_from_string(j.value("architecture", "hopnet")));
      o.center_mass_distance(j.value("center_mass_distance", true))
          .collision_radius(j.value("collision_radius", 0.1));
    } catch (const nlohmann::json::exception& e) {
      throw std::invalid_argument(std::string("malformed HOPNet configuration: ") + e.what());
    }
    o.validate();
    return o;
  }
  void validate() const {
    if (hidden() <= 0 || mlp_layers() < 1 || num_layers() < 1)
      throw std::invalid_argument(
          "HOPNet configuration: hidden, mlp_layers and num_layers must be positive");
    // Untrusted (a checkpoint's topos.config): refuse sizes whose parameters could not be
    // allocated.
    if (hidden() > 65536 || mlp_layers() > 64 || num_layers() > 64)
      throw std::invalid_argument(
          "HOPNet configuration: hidden above 65536, or mlp_layers or num_layers above 64");
    const auto a = activation();
    if (a != nn::Activation::relu && a != nn::Activation::gelu && a != nn::Activation::elu &&
        a != nn::Activation::selu)
      throw std::invalid_argument("HOPNet configuration: activation " + nn::activation_name(a) +
                                  " is not one of the reference's (relu, gelu, elu, selu)");
    if (!(collision_radius() > 0) || !std::isfinite(collision_radius()))
      throw std::invalid_argument(
          "HOPNet configuration: the collision radius must be a positive number");
  }
  SceneLiftingOptions lifting() const {
    SceneLiftingOptions l;
    l.mode = mode_;
    l.architecture = architecture_;
    l.center_mass_distance = center_mass_distance_;
    return l;
  }

  TORCH_ARG(std::int64_t, hidden) = 128;  ///< width of every cochain and MLP
  TORCH_ARG(int, mlp_layers) = 2;         ///< Linear layers per MLP (the reference's L)
  TORCH_ARG(nn::Activation, activation) = nn::Activation::relu;  ///< relu, gelu, elu or selu
  TORCH_ARG(int, num_layers) = 1;                                ///< processor layers
  /// reference: the plus view of a contact negates the *normalised* direction (the published
  /// weights expect it); native: it is built from raw features, then normalised (input "x3_plus").
  TORCH_ARG(FeatureMode, mode) = FeatureMode::reference;
  TORCH_ARG(Architecture, architecture) = Architecture::hopnet;  ///< the member of the family
  TORCH_ARG(bool, center_mass_distance) = true;  ///< x0 keeps r0, rt (false: 8 columns)
  TORCH_ARG(double, collision_radius) = 0.1;     ///< d_c of contact detection (training, rollout)
};

}  // namespace topos::models::hopnet
