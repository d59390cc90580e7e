// topos/models/hopnet/variants.hpp
// The HOPNet family as configurations (models/ablations.py): named presets that compose,
// JSON configuration files, and the name of the variant a configuration or checkpoint is. The
// paper's baselines are presets of the same language (fignet, mgn, mgn-large-radius: their
// "model" field picks models/baselines.hpp; a HOPNet field beside them is a conflict).
//
//   standard        HOPNet                          nox4            no object cells (virtual nodes)
//   noseq           non-sequential MP (64, 3 layers) no-cm-distance  x0 without r0, rt (8 columns)
//   mlp3            3 Linear layers per MLP          mp2             two message-passing layers
//   hidden64        64-channel embeddings
//
// A configuration string is a comma-separated list of presets and JSON files
// ("nox4,mlp3", "noseq", "my.json"). A preset sets some fields; two items that set the same
// field to different values conflict ("nox4,noseq": two architectures; "noseq,mp2": 3 vs 2
// layers), which is an error naming both. A JSON file holds HopnetOptions fields (to_json's
// keys: architecture, center_mass_distance, hidden, mlp_layers, num_layers, activation,
// collision_radius, mode), and may list "presets" applied before its own fields.
#pragma once

#include "topos/data/json.hpp"
#include "topos/models/hopnet/model.hpp"
#include "topos/models/namespace_aliases.hpp"

#include <filesystem>
#include <map>
#include <set>
#include <sstream>
#include <string>
#include <vector>

namespace topos::models::hopnet {

/// Fields a preset sets, as a JSON object of HopnetOptions keys.
inline const std::map<std::string, nlohmann::json>& hopnet_presets() {
  static const std::map<std::string, nlohmann::json> p{
      {"standard", {{"architecture", "hopnet"}}},
      {"nox4", {{"architecture", "no_object_cells"}}},
      {"noseq", {{"architecture", "no_sequential"}, {"hidden", 64}, {"num_layers", 3}}},
      {"no-cm-distance", {{"center_mass_distance", false}}},
      {"mlp3", {{"mlp_layers", 3}}},
      {"mp2", {{"num_layers", 2}}},
      {"hidden64", {{"hidden", 64}}},
  };
  return p;
}

/// The paper's baselines (models/baselines.hpp) as presets of the same language: FIGNet and
/// MeshGraphNet with its small and large world-edge radius.
inline const std::map<std::string, nlohmann::json>& baseline_presets() {
  static const std::map<std::string, nlohmann::json> p{
      {"fignet", {{"model", "fignet"}}},
      {"mgn", {{"model", "mgn"}, {"world_edge_radius", 0.1}}},
      {"mgn-large-radius", {{"model", "mgn"}, {"world_edge_radius", 0.3}}},
  };
  return p;
}

/// The configuration fields each model has ("model" included).
inline const std::set<std::string>& model_fields(const std::string& model) {
  static const std::map<std::string, std::set<std::string>> f{
      {"hopnet",
       {"model", "architecture", "center_mass_distance", "hidden", "mlp_layers", "num_layers",
        "activation", "collision_radius", "mode"}},
      // The baselines' "mlp_layers": the earlier name of "hidden_layers", still read.
      {"fignet",
       {"model", "latent", "steps", "hidden_layers", "mlp_layers", "mesh_edges",
        "collision_radius"}},
      {"mgn", {"model", "latent", "steps", "hidden_layers", "mlp_layers", "world_edge_radius"}},
  };
  auto it = f.find(model);
  if (it == f.end())
    throw std::invalid_argument("unknown model '" + model + "' (hopnet, fignet or mgn)");
  return it->second;
}

inline std::string preset_names() {
  std::string s;
  for (const auto* presets : {&hopnet_presets(), &baseline_presets()})
    for (const auto& [k, v] : *presets) s += (s.empty() ? "" : ", ") + k;
  return s;
}

namespace detail {
inline std::vector<std::string> split_config(const std::string& text) {
  std::vector<std::string> items;
  std::stringstream ss(text);
  for (std::string item; std::getline(ss, item, ',');) {
    const auto b = item.find_first_not_of(" \t"), e = item.find_last_not_of(" \t");
    if (b == std::string::npos)
      throw std::invalid_argument("configuration '" + text + "': empty item");
    items.push_back(item.substr(b, e - b + 1));
  }
  if (items.empty())
    throw std::invalid_argument("empty configuration (presets: " + preset_names() +
                                ", or a JSON file)");
  return items;
}

/// Merges `fields` (from item `who`) into `into`, remembering which item set each field.
inline void merge_fields(nlohmann::json& into, std::map<std::string, std::string>& set_by,
                         const nlohmann::json& fields, const std::string& who) {
  static const std::set<std::string> known = [] {
    std::set<std::string> k{"presets"};
    for (const char* m : {"hopnet", "fignet", "mgn"})
      k.insert(model_fields(m).begin(), model_fields(m).end());
    return k;
  }();
  for (const auto& [k, v] : fields.items()) {
    if (!known.count(k))
      throw std::invalid_argument(who + ": unknown configuration field '" + k + "'");
    if (k == "presets") continue;
    auto it = set_by.find(k);
    if (it != set_by.end() && into[k] != v)
      throw std::invalid_argument("conflicting configuration: " + it->second + " sets " + k +
                                  " = " + into[k].dump() + ", " + who + " sets " + k + " = " +
                                  v.dump());
    into[k] = v;
    set_by.emplace(k, who);
  }
}

inline void add_config_item(nlohmann::json& cfg, std::map<std::string, std::string>& set_by,
                            const std::string& item, int depth) {
  for (const auto* presets : {&hopnet_presets(), &baseline_presets()}) {
    auto p = presets->find(item);
    if (p != presets->end()) return merge_fields(cfg, set_by, p->second, "preset '" + item + "'");
  }
  const bool looks_like_file =
      item.find('/') != std::string::npos || item.find('.') != std::string::npos;
  if (!looks_like_file || !std::filesystem::exists(item))
    throw std::invalid_argument("unknown configuration '" + item + "': not a preset (" +
                                preset_names() + ")" +
                                (looks_like_file ? " and no such file" : ""));
  if (depth > 4) throw std::invalid_argument(item + ": configuration files nest too deeply");
  const nlohmann::json j = data::read_json_file(item);
  if (!j.is_object())
    throw std::invalid_argument(item + ": a configuration file must hold a JSON object");
  if (j.contains("presets")) {
    if (!j["presets"].is_array() && !j["presets"].is_string())
      throw std::invalid_argument(item + ": 'presets' must be a string or a list of strings");
    std::vector<std::string> names;
    if (j["presets"].is_string())
      names = split_config(j["presets"].get<std::string>());
    else
      for (const auto& n : j["presets"]) {
        if (!n.is_string()) throw std::invalid_argument(item + ": 'presets' must list strings");
        names.push_back(n.get<std::string>());
      }
    for (const auto& n : names) add_config_item(cfg, set_by, n, depth + 1);
  }
  merge_fields(cfg, set_by, j, "file '" + item + "'");
}
}  // namespace detail

/// The configuration named by `text` (presets and JSON files, comma-separated), on top of `base`
/// for the fields nothing sets. Unknown presets, unreadable files, unknown fields and
/// conflicting items are errors.
/// The fields the items of `text` set, checked against the model they name ("hopnet" unless
/// one sets "model"): a field of another model is an error naming the item that set it.
inline nlohmann::json config_fields(const std::string& text) {
  nlohmann::json set = nlohmann::json::object();
  std::map<std::string, std::string> set_by;
  for (const auto& item : detail::split_config(text)) detail::add_config_item(set, set_by, item, 0);
  if (set.contains("model") && !set["model"].is_string())
    throw std::invalid_argument(set_by["model"] + ": \"model\" must be a string");
  const std::string model = set.value("model", "hopnet");
  const auto& fields = model_fields(model);
  for (const auto& [k, v] : set.items())
    if (!fields.count(k))
      throw std::invalid_argument(
          "conflicting configuration: " + set_by[k] + " sets " + k + ", which model " + model +
          (set_by.count("model") ? " (set by " + set_by["model"] + ")" : std::string()) +
          " does not have");
  return set;
}

/// The model a configuration names: "hopnet", "fignet" or "mgn".
inline std::string config_model(const std::string& text) {
  return config_fields(text).value("model", "hopnet");
}

inline HopnetOptions parse_config(const std::string& text, const HopnetOptions& base = {}) {
  nlohmann::json cfg = base.to_json();
  const nlohmann::json fields = config_fields(text);  // items() refers to it: keep it alive
  for (const auto& [k, v] : fields.items()) cfg[k] = v;
  return HopnetOptions::from_json(cfg);
}

/// The variant's name as presets (and the fields no preset names): "standard", "nox4",
/// "noseq", "mlp3,no-cm-distance", "standard (activation gelu)", ...
inline std::string variant_name(const HopnetOptions& o) {
  std::vector<std::string> parts;
  std::int64_t hidden = 128;
  int layers = 1;
  switch (o.architecture()) {
    case Architecture::hopnet:
      parts.push_back("standard");
      break;
    case Architecture::no_object_cells:
      parts.push_back("nox4");
      break;
    case Architecture::no_sequential:
      parts.push_back("noseq"), hidden = 64, layers = 3;
      break;
  }
  if (!o.center_mass_distance()) parts.push_back("no-cm-distance");
  if (o.mlp_layers() == 3) parts.push_back("mlp3");
  if (o.num_layers() == 2 && layers == 1) parts.push_back("mp2");
  if (o.hidden() == 64 && hidden == 128) parts.push_back("hidden64");
  if (parts.size() > 1 && parts[0] == "standard") parts.erase(parts.begin());
  std::string s;
  for (const auto& p : parts) s += (s.empty() ? "" : ",") + p;
  std::vector<std::string> extra;
  if (o.hidden() != hidden && !(o.hidden() == 64 && hidden == 128))
    extra.push_back("hidden " + std::to_string(o.hidden()));
  if (o.mlp_layers() != 2 && o.mlp_layers() != 3)
    extra.push_back("mlp_layers " + std::to_string(o.mlp_layers()));
  if (o.num_layers() != layers && !(o.num_layers() == 2 && layers == 1))
    extra.push_back("num_layers " + std::to_string(o.num_layers()));
  if (o.activation() != nn::Activation::relu)
    extra.push_back(std::string("activation ") + nn::activation_name(o.activation()));
  if (o.collision_radius() != 0.1) {
    std::ostringstream r;
    r << "collision radius " << o.collision_radius();
    extra.push_back(r.str());
  }
  if (!extra.empty()) {
    s += " (";
    for (std::size_t i = 0; i < extra.size(); ++i) s += (i ? ", " : "") + extra[i];
    s += ")";
  }
  return s;
}

}  // namespace topos::models::hopnet
