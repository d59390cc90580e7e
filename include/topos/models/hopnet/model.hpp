// topos/models/hopnet/model.hpp
// HOPNet (Wei & Fink), the module: HopnetImpl runs hopnet_schedule (schedule.hpp) on a
// HopnetBatch (batch.hpp) and forces static objects' outputs to zero acceleration; loading and
// saving checkpoints, topos's or the published PyTorch ones (names in checkpoint_format.hpp).
// Options are in options.hpp; the ablations' presets and config files in variants.hpp.
#pragma once

#include "topos/models/hopnet/batch.hpp"
#include "topos/models/hopnet/checkpoint_format.hpp"
#include "topos/models/hopnet/features.hpp"
#include "topos/models/hopnet/normalization.hpp"
#include "topos/models/hopnet/options.hpp"
#include "topos/models/hopnet/schedule.hpp"
#include "topos/models/namespace_aliases.hpp"
#include "topos/nn/cloneable.hpp"
#include "topos/nn/serialization.hpp"

#include <torch/torch.h>

#include <cstdint>
#include <filesystem>
#include <map>
#include <optional>
#include <regex>
#include <set>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

namespace topos::models::hopnet {

/// Normalised accelerations of nodes (a0) and objects (a4; undefined without object cells,
/// where a0 has a row per virtual node too, after the mesh nodes).
struct HopnetOutput {
  torch::Tensor a0, a4;
};

class HopnetImpl : public nn::Cloneable<HopnetImpl, nn::OperatorNetworkImpl> {
 public:
  explicit HopnetImpl(const HopnetOptions& opt = {})
      : Cloneable(hopnet_schedule(opt)), options(opt) {
    opt.validate();
    const auto params = parameters();
    if (!params.empty()) device_reference_ = params.front();
  }

  /// The device the model's parameters are on (the CPU without any). Read from one parameter
  /// found once: `to()` and loading a checkpoint change parameters in place, and walking every
  /// parameter's name at each rollout step took 7 % of a CPU rollout.
  torch::Device device() const {
    return device_reference_.defined() ? device_reference_.device() : torch::Device(torch::kCPU);
  }

  /// Runs the network; static objects (normalised type column x4[:, 8] < 0) and their nodes get
  /// the normalised zero acceleration. Without object cells the test is the node's own type
  /// column (x0[:, 16] with 21 columns), so the floor's virtual node is static too.
  HopnetOutput forward(const HopnetBatch& b, const Normalizer& norm) {
    // A batch carries x3_plus in every mode; the schedule declares it in native mode only.
    auto inputs = b.inputs;
    if (options.mode() != FeatureMode::native) inputs.erase("x3_plus");
    auto out = nn::OperatorNetworkImpl::forward(inputs, b.complex);
    if (options.architecture() == Architecture::no_object_cells) {
      const auto& x0 = b.inputs.at("x0");
      const auto node_static = x0.select(1, x0.size(1) - 5).lt(0).unsqueeze(1);
      return {torch::where(node_static,
                           norm.zero_node_acceleration().to(x0.device()).expand_as(out["a0"]),
                           out["a0"]),
              torch::Tensor()};
    }
    const auto& x4 = b.inputs.at("x4");
    const auto is_static = x4.select(1, 8).lt(0);
    const auto node_object = b.complex.neighborhood("B04").target;
    const auto node_static = is_static.index_select(0, node_object).unsqueeze(1);
    auto a0 = torch::where(
        node_static, norm.zero_node_acceleration().to(x4.device()).expand_as(out["a0"]), out["a0"]);
    auto a4 = torch::where(is_static.unsqueeze(1),
                           norm.zero_object_acceleration().to(x4.device()).expand_as(out["a4"]),
                           out["a4"]);
    return {a0, a4};
  }

  std::int64_t num_parameters() const {
    std::int64_t n = 0;
    for (const auto& p : parameters()) n += p.numel();
    return n;
  }

  HopnetOptions options;

 private:
  torch::Tensor device_reference_;
};
TORCH_MODULE(Hopnet);

/// Loads a checkpoint into `model`: a topos checkpoint by name, or a reference state dict by
/// the reference's names. Missing, extra and misshapen tensors are errors naming the tensor
/// as the file names it.
inline void load_checkpoint(HopnetImpl& model, const std::map<std::string, torch::Tensor>& dict,
                            const std::string& source) {
  if (!is_reference_checkpoint(dict)) {
    auto d = dict;
    d.erase("topos.config");
    nn::load_parameters(model, d, source);
    return;
  }
  torch::NoGradGuard guard;
  std::set<std::string> used;
  for (auto& p : model.named_parameters()) {
    const std::string ref = reference_parameter_name(p.key(), model.options.architecture());
    auto it = dict.find(ref);
    if (it == dict.end()) throw std::runtime_error(source + ": missing tensor '" + ref + "'");
    if (it->second.sizes() != p.value().sizes()) {
      std::ostringstream s;
      s << source << ": tensor '" << ref << "' has shape " << it->second.sizes() << ", expected "
        << p.value().sizes();
      throw std::runtime_error(s.str());
    }
    p.value().copy_(it->second);
    used.insert(ref);
  }
  for (const auto& [k, v] : dict)
    if (!used.count(k)) throw std::runtime_error(source + ": unexpected tensor '" + k + "'");
}

/// What a caller may set when loading a checkpoint: the feature mode the network runs in and
/// the collision radius (neither changes the parameters), and the activation, which reference
/// state dicts do not record (a topos checkpoint records it: a different one is an error).
struct CheckpointOverrides {
  std::optional<FeatureMode> mode;
  std::optional<nn::Activation> activation;
  std::optional<double> collision_radius;
};

/// The activation a reference checkpoint's file name gives by the reference's convention: the
/// first '_'-separated word of the name ("gelu_seed0_e39.pt") when it is gelu, elu or selu. A
/// reference state dict does not record its activation; other names mean ReLU, its default.
inline std::optional<nn::Activation> activation_from_reference_name(const std::string& path) {
  const std::string stem = std::filesystem::path(path).stem().string();
  const std::string word = stem.substr(0, stem.find('_'));
  for (const char* a : {"gelu", "elu", "selu"})
    if (word == a) return nn::activation_from_string(a);
  return std::nullopt;
}

/// Loads a checkpoint (topos or reference, of any architecture) from a checkpoint already read
/// (nn::read_tensor_dict); `source` names it in errors. Several models (one per thread) can be
/// built from one read.
inline Hopnet load_hopnet(const std::map<std::string, torch::Tensor>& dict,
                          const std::string& source, const CheckpointOverrides& ov) {
  HopnetOptions opt = checkpoint_options(dict, source);
  if (ov.activation) {
    if (!is_reference_checkpoint(dict) && opt.activation() != *ov.activation)
      throw std::invalid_argument(source + ": the checkpoint was trained with activation " +
                                  nn::activation_name(opt.activation()) + ", not " +
                                  nn::activation_name(*ov.activation));
    opt.activation(*ov.activation);
  }
  if (ov.mode) opt.mode(*ov.mode);
  if (ov.collision_radius) opt.collision_radius(*ov.collision_radius);
  Hopnet model(opt);
  load_checkpoint(*model, dict, source);
  return model;
}

/// `mode`, when given, overrides the feature mode the network runs in.
inline Hopnet load_hopnet(const std::map<std::string, torch::Tensor>& dict,
                          const std::string& source,
                          std::optional<FeatureMode> mode = std::nullopt) {
  CheckpointOverrides ov;
  ov.mode = mode;
  return load_hopnet(dict, source, ov);
}

inline Hopnet load_hopnet(const std::string& path, std::optional<FeatureMode> mode = std::nullopt) {
  return load_hopnet(nn::read_tensor_dict(path), path, mode);
}

/// Saves a topos checkpoint: parameters by name plus "topos.config" (the options as JSON
/// bytes), a dict of tensors that Python's torch.load opens. Atomic.
inline void save_hopnet(const HopnetImpl& model, const std::string& path) {
  c10::Dict<std::string, torch::Tensor> dict;
  for (const auto& p : model.named_parameters()) dict.insert(p.key(), p.value().detach().cpu());
  const std::string cfg = model.options.to_json().dump();
  dict.insert("topos.config",
              torch::tensor(std::vector<std::uint8_t>(cfg.begin(), cfg.end()), torch::kUInt8));
  nn::write_tensor_dict(dict, path);
}

}  // namespace topos::models::hopnet
