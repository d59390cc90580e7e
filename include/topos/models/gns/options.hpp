// topos/models/gns/options.hpp
// The options every graph-network simulator shares (latent width, message-passing steps, MLP
// depth), read from and written to a checkpoint's JSON configuration with the model's name,
// so that a checkpoint of one model loaded as another is an error naming both. The MLP depth is
// written as "hidden_layers"; configurations and checkpoints written before call it
// "mlp_layers", which is read as the same field (HOPNet's "mlp_layers" counts Linear layers).
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
  int hidden_layers = 2;  ///< hidden layers per MLP (hidden_layers + 1 Linear layers)

  /// An empty spec of these sizes (the model adds its sets).
  GraphNetworkSpec spec() const {
    GraphNetworkSpec s;
    s.latent = latent;
    s.steps = steps;
    s.hidden_layers = hidden_layers;
    return s;
  }
  void to_json(nlohmann::json& j) const {
    j["latent"] = latent;
    j["steps"] = steps;
    j["hidden_layers"] = hidden_layers;
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
    known.insert({"model", "latent", "steps", "hidden_layers", "mlp_layers"});
    for (const auto& [k, v] : j.items())
      if (!known.count(k))
        throw std::invalid_argument(model + " configuration: unknown field '" + k + "'");
    try {
      if (j.contains("latent"))
        latent = data::get_integer<std::int64_t>(j["latent"], model + " configuration: latent");
      if (j.contains("steps"))
        steps = data::get_integer<int>(j["steps"], model + " configuration: steps");
      if (j.contains("hidden_layers") && j.contains("mlp_layers") &&
          j["hidden_layers"] != j["mlp_layers"])
        throw std::invalid_argument(model + " configuration: hidden_layers " +
                                    j["hidden_layers"].dump() + " and its old name mlp_layers " +
                                    j["mlp_layers"].dump() + " differ");
      for (const char* key : {"mlp_layers", "hidden_layers"})  // the old name, then the new
        if (j.contains(key))
          hidden_layers = data::get_integer<int>(j[key], model + " configuration: " + key);
    } catch (const data::DataError& e) {
      throw std::invalid_argument(e.what());
    }
    // Untrusted (a checkpoint's configuration): refuse sizes that could not be allocated.
    if (latent < 1 || latent > 65536 || steps < 1 || steps > 64 || hidden_layers < 0 ||
        hidden_layers > 64)
      throw std::invalid_argument(model +
                                  " configuration: latent must be in 1..65536, steps in 1..64 "
                                  "and hidden_layers in 0..64");
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
