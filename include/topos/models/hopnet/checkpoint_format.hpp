// topos/models/hopnet/checkpoint_format.hpp
// What a HOPNet checkpoint says before it is loaded: the reference (authors') name of each topos
// parameter, a reference state dict's architecture, and the HopnetOptions it was saved with.
#pragma once

#include "topos/models/hopnet/lifting_options.hpp"
#include "topos/models/hopnet/options.hpp"
#include "topos/models/namespace_aliases.hpp"

#include <nlohmann/json.hpp>
#include <torch/torch.h>

#include <algorithm>
#include <cstdint>
#include <map>
#include <optional>
#include <regex>
#include <stdexcept>
#include <string>

namespace topos::models::hopnet {

/// The reference class of an architecture, as its checkpoints prefix their tensors
/// ("_HOPNet__", "_HOPNet_NoObjectCells__", "_HOPNet_NoSequential__").
inline std::string reference_class(Architecture a) {
  return a == Architecture::hopnet ? "HOPNet"
                                   : (a == Architecture::no_object_cells ? "HOPNet_NoObjectCells"
                                                                         : "HOPNet_NoSequential");
}

/// The reference checkpoint's name of a topos parameter ("modules.layer0_2to3.0.weight" ->
/// "_HOPNet__layers.0._HOPNet_Layer__mlp_processor_2to3.0.weight"). The NoObjectCells layer
/// class is spelt "HOPNet_NoObjcetCells_Layer" in the reference (sic).
inline std::string reference_parameter_name(const std::string& name,
                                            Architecture arch = Architecture::hopnet) {
  static const std::regex enc(R"(^modules\.(encoder|decoder)_(\d)\.(.*)$)"),
      proc(R"(^modules\.layer(\d+)_([0-9a-z]+)\.(.*)$)");
  const std::string cls = reference_class(arch);
  const std::string layer = arch == Architecture::hopnet ? "HOPNet_Layer"
                                                         : (arch == Architecture::no_object_cells
                                                                ? "HOPNet_NoObjcetCells_Layer"
                                                                : "HOPNet_NoSequential_Layer");
  std::smatch m;
  if (std::regex_match(name, m, enc))
    return "_" + cls + "__mlp_" + m[1].str() + "_" + m[2].str() + "." + m[3].str();
  if (std::regex_match(name, m, proc))
    return "_" + cls + "__layers." + m[1].str() + "._" + layer + "__mlp_processor_" + m[2].str() +
           "." + m[3].str();
  throw std::invalid_argument("no reference name for parameter '" + name + "'");
}

/// The architecture of a reference (authors') state dict, read off its class prefix; none when
/// no tensor carries a known prefix.
inline std::optional<Architecture> reference_architecture(
    const std::map<std::string, torch::Tensor>& dict) {
  for (const auto a :
       {Architecture::no_object_cells, Architecture::no_sequential, Architecture::hopnet}) {
    const std::string prefix = "_" + reference_class(a) + "__";
    if (std::any_of(dict.begin(), dict.end(),
                    [&](const auto& kv) { return kv.first.rfind(prefix, 0) == 0; }))
      return a;
  }
  return std::nullopt;
}

/// True when a tensor dict is a reference (authors') HOPNet state dict, of any variant.
inline bool is_reference_checkpoint(const std::map<std::string, torch::Tensor>& dict) {
  return reference_architecture(dict).has_value();
}

/// The configuration a checkpoint was saved with: topos checkpoints carry it (entry
/// "topos.config", JSON bytes); for reference ones it is read off the class prefix and the
/// tensor shapes: hidden width, x0 width (16/8, or 21/13 without object cells), layers, Linear
/// layers per MLP. The activation and collision radius cannot be, so they come from `fallback`.
inline HopnetOptions checkpoint_options(const std::map<std::string, torch::Tensor>& dict,
                                        const std::string& source, HopnetOptions fallback = {}) {
  auto cfg = dict.find("topos.config");
  if (cfg != dict.end()) {
    const auto t = cfg->second.to(torch::kUInt8).contiguous();
    const std::string text(reinterpret_cast<const char*>(t.data_ptr<std::uint8_t>()),
                           static_cast<std::size_t>(t.numel()));
    try {
      return HopnetOptions::from_json(nlohmann::json::parse(text));
    } catch (const std::exception& e) {
      throw std::runtime_error(source + ": unreadable topos.config: " + e.what());
    }
  }
  const auto arch = reference_architecture(dict);
  if (!arch)
    throw std::runtime_error(source +
                             ": neither a topos nor a reference HOPNet checkpoint (no "
                             "'topos.config', and no tensor of a known reference class: "
                             "'_HOPNet__', '_HOPNet_NoObjectCells__', '_HOPNet_NoSequential__')");
  const std::string cls = "_" + reference_class(*arch) + "__";
  auto e0 = dict.find(cls + "mlp_encoder_0.0.weight");
  if (e0 == dict.end() || e0->second.dim() != 2)
    throw std::runtime_error(source + ": missing tensor '" + cls + "mlp_encoder_0.0.weight'");
  HopnetOptions o = fallback;
  o.architecture(*arch).hidden(e0->second.size(0));
  const std::int64_t x0 = e0->second.size(1),
                     extra = *arch == Architecture::no_object_cells ? 5 : 0;
  if (x0 == 16 + extra)
    o.center_mass_distance(true);
  else if (x0 == 8 + extra)
    o.center_mass_distance(false);
  else
    throw std::runtime_error(source + ": tensor '" + cls + "mlp_encoder_0.0.weight' reads " +
                             std::to_string(x0) + " node features, which no " +
                             reference_class(*arch) + " configuration does (" +
                             std::to_string(16 + extra) + " or " + std::to_string(8 + extra) + ")");
  const std::string layer_class = reference_parameter_name(
      "modules.layer0_2.0.weight", *arch);  // "..layers.0.<Layer>__mlp_processor_2.0.weight"
  const auto at_layer = [&](int l) {
    std::string k = layer_class;
    k.replace(k.find("layers.0."), 9, "layers." + std::to_string(l) + ".");
    return k;
  };
  int layers = 0, mlp = 1;
  while (dict.count(at_layer(layers))) ++layers;
  while (dict.count(cls + "mlp_decoder_0." + std::to_string(2 * mlp) + ".weight")) ++mlp;
  o.num_layers(std::max(layers, 1)).mlp_layers(mlp);
  return o;
}

}  // namespace topos::models::hopnet
