// topos/models/gns/options.hpp
// The options every graph-network simulator shares (latent width, message-passing steps, MLP
// depth), read from and written to a checkpoint's JSON configuration with the model's name,
// so that a checkpoint of one model loaded as another is an error naming both.
#pragma once

#include "topos/data/json.hpp"
#include "topos/models/gns/network.hpp"
#include "topos/models/namespace_aliases.hpp"

#include <nlohmann/json.hpp>

#include <cmath>
#include <set>
#include <stdexcept>
#include <string>

namespace topos::models::gns {

struct NetworkOptions {
  std::int64_t latent = 128;
  int steps = 10;
  int mlp_layers = 2;  ///< hidden layers per MLP

  /// An empty spec of these sizes (the model adds its sets).
  GraphNetworkSpec spec() const {
    GraphNetworkSpec s;
    s.latent = latent;
    s.steps = steps;
    s.hidden_layers = mlp_layers;
    return s;
  }
  void to_json(nlohmann::json& j) const {
    j["latent"] = latent;
    j["steps"] = steps;
    j["mlp_layers"] = mlp_layers;
  }
  /// Reads the shared fields of `model`'s configuration `j`; refuses another model and keys
  /// outside `known` (with the shared ones) by name.
  void from_json(const nlohmann::json& j, const std::string& model, std::set<std::string> known) {
    if (!j.is_object())
      throw std::invalid_argument(model + " configuration: expected a JSON object");
    const std::string name = j.contains("model") && j["model"].is_string()
                                 ? j["model"].get<std::string>()
                                 : std::string("hopnet");
    if (name != model)
      throw std::invalid_argument("a " + name + " configuration (model '" + name + "') where a " +
                                  model + " configuration was expected");
    known.insert({"model", "latent", "steps", "mlp_layers"});
    for (const auto& [k, v] : j.items())
      if (!known.count(k))
        throw std::invalid_argument(model + " configuration: unknown field '" + k + "'");
    try {
      if (j.contains("latent"))
        latent = data::get_integer<std::int64_t>(j["latent"], model + " configuration: latent");
      if (j.contains("steps"))
        steps = data::get_integer<int>(j["steps"], model + " configuration: steps");
      if (j.contains("mlp_layers"))
        mlp_layers = data::get_integer<int>(j["mlp_layers"], model + " configuration: mlp_layers");
    } catch (const data::DataError& e) {
      throw std::invalid_argument(e.what());
    }
    // Untrusted (a checkpoint's configuration): refuse sizes that could not be allocated.
    if (latent < 1 || latent > 65536 || steps < 1 || steps > 64 || mlp_layers < 0 ||
        mlp_layers > 64)
      throw std::invalid_argument(model +
                                  " configuration: latent must be in 1..65536, steps in 1..64 "
                                  "and mlp_layers in 0..64");
  }
};

/// A positive finite radius from `j[key]` (default `dflt`), or an error naming the key.
inline double positive_radius(const nlohmann::json& j, const std::string& model, const char* key,
                              double dflt) {
  if (!j.contains(key)) return dflt;
  if (!j[key].is_number() || !(j[key].get<double>() > 0) || !std::isfinite(j[key].get<double>()))
    throw std::invalid_argument(model + " configuration: " + key + " must be a positive number");
  return j[key].get<double>();
}

}  // namespace topos::models::gns
