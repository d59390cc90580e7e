// topos/models/zoo/config.hpp
// A zoo model's constructor arguments read from JSON: ZooError, Config (typed access that rejects
// unknown arguments) and the parsers of torch.nn class names, aggregations and initialisations.
#pragma once

#include "topos/models/hypergraph/allset.hpp"  // MlpNorm
#include "topos/nn/functional.hpp"             // nn::Activation, nn::Aggr

#include <nlohmann/json.hpp>

#include <initializer_list>
#include <map>
#include <optional>
#include <set>
#include <stdexcept>
#include <string>

namespace topos::models::zoo {

class ZooError : public std::invalid_argument {
 public:
  using std::invalid_argument::invalid_argument;
};

namespace detail {

/// Typed access to a constructor-argument object; finish() rejects arguments nobody read.
class Config {
 public:
  Config(const nlohmann::json& j, std::string model) : j_(j), model_(std::move(model)) {
    if (!j_.is_object()) throw ZooError(model_ + ": config must be a JSON object");
  }
  bool has(const std::string& k) const { return j_.contains(k) && !j_.at(k).is_null(); }
  /// Given as null (Python's None), which can differ from absent (the default).
  bool is_null(const std::string& k) const { return j_.contains(k) && j_.at(k).is_null(); }
  template <class T>
  T get(const std::string& k, T fallback) {
    used_.insert(k);
    return has(k) ? as<T>(k) : fallback;
  }
  template <class T>
  T need(const std::string& k) {
    used_.insert(k);
    if (!has(k)) throw ZooError(model_ + ": config lacks '" + k + "'");
    return as<T>(k);
  }
  nn::Activation update(const std::string& k, nn::Activation fallback) {
    used_.insert(k);
    if (!has(k)) return fallback;
    try {
      return nn::activation_from_string(as<std::string>(k));
    } catch (const std::invalid_argument& e) {
      throw ZooError(model_ + ": config '" + k + "': " + e.what());
    }
  }
  void finish() const {
    for (const auto& [k, v] : j_.items())
      if (!used_.count(k)) throw ZooError(model_ + ": unknown config parameter '" + k + "'");
  }

 private:
  template <class T>
  T as(const std::string& k) const {
    try {
      return j_.at(k).get<T>();
    } catch (const nlohmann::json::exception&) {
      throw ZooError(model_ + ": config '" + k + "' has the wrong type (" + j_.at(k).dump() + ")");
    }
  }
  const nlohmann::json& j_;
  std::string model_;
  std::set<std::string> used_;
};

/// A torch.nn activation class named in a config ("torch.nn.ReLU"); absent or null: `fallback`
/// (std::nullopt: TopoModelX received None).
inline std::optional<nn::Activation> torch_activation(Config& c, const std::string& k,
                                                      std::optional<nn::Activation> fallback) {
  const auto name = c.get<std::string>(k, "");
  if (name.empty()) return fallback;
  static const std::map<std::string, nn::Activation> known = {
      {"ReLU", nn::Activation::relu},
      {"Sigmoid", nn::Activation::sigmoid},
      {"Tanh", nn::Activation::tanh},
      {"ELU", nn::Activation::elu},
      {"LeakyReLU", nn::Activation::leaky_relu},
      {"Identity", nn::Activation::none}};
  const auto bare = name.rfind("torch.nn.", 0) == 0 ? name.substr(9) : name;
  auto it = known.find(bare);
  if (it == known.end())
    throw ZooError("config '" + k + "': unsupported activation '" + name +
                   "' (torch.nn.ReLU, Sigmoid, Tanh, ELU, LeakyReLU, Identity)");
  return it->second;
}

/// A torch.nn normalisation class named in a config (AllSet's mlp_norm); absent or null: none.
inline MlpNorm torch_norm(Config& c, const std::string& k) {
  const auto name = c.get<std::string>(k, "");
  if (name.empty()) return MlpNorm::none;
  if (name == "torch.nn.LayerNorm" || name == "LayerNorm") return MlpNorm::layer_norm;
  if (name == "torch.nn.BatchNorm1d" || name == "BatchNorm1d") return MlpNorm::batch_norm;
  throw ZooError("config '" + k + "': unsupported normalisation '" + name +
                 "' (torch.nn.LayerNorm, torch.nn.BatchNorm1d)");
}

inline nn::Aggr aggr_of(Config& c, const std::string& k, const std::string& fallback) {
  const auto s = c.get<std::string>(k, fallback);
  if (s == "sum" || s == "add") return nn::Aggr::sum;
  if (s == "mean") return nn::Aggr::mean;
  throw ZooError("config '" + k + "': unknown aggregation '" + s + "' (sum, mean)");
}

/// Weight initialisations TopoModelX offers; they only matter before weights are loaded.
inline std::string initialization_of(Config& c, const std::string& k, const std::string& fallback,
                                     std::initializer_list<const char*> allowed) {
  const auto s = c.get<std::string>(k, fallback);
  for (const char* a : allowed)
    if (s == a) return s;
  throw ZooError("config '" + k + "': unknown initialization '" + s + "'");
}

}  // namespace detail

}  // namespace topos::models::zoo

namespace topos::models {
// Deprecated: the zoo's old names. Write zoo::ZooError (etc.).
using zoo::ZooError;
}  // namespace topos::models
