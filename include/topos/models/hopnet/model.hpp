// topos/models/hopnet/model.hpp
// HOPNet (Wei & Fink) as a schedule of topos's DSL (spec section 6), its float32
// normalisation, the batching of frames, and import of the published PyTorch checkpoints.
//
// One processor layer, as a schedule (L = "layer<l>_"):
//   into 2        = L2 ([h2, Σ_B02 L0to2(h0), Σ_B12 L1to2(h1), B42 L4to2(h4)])
//   parallel {
//     into 3 plus  = L3 ([h3p, Σ_B23neg L2to3(h2), Σ_B23pos L2to3(h2)])
//     into 3 minus = L3 ([h3m, Σ_B23pos L2to3(h2), Σ_B23neg L2to3(h2)]) }
//   into 2        = L2p([h2, Σ_{B32, role +1} h3p + Σ_{B32, role −1} h3m])
//   into 4        = L4 ([h4, mean_B24 L2to4(h2)])            only where the complex has contacts
//   parallel {
//     into 0       = L0 ([h0, B40 L4to0(h4)])
//     into 4       = L4p([h4, mean_B04 L0to4(h0)]) }
// Encoders E0..E4 (the contact cells twice: "minus" from face0's side, "plus" from face1's),
// decoders D0 (nodes) and D4 (objects); static objects' outputs are forced to zero acceleration.
// Module names map one to one onto the reference's checkpoint names (reference_parameter_name).
#pragma once

#include "topos/models/hopnet/features.hpp"
#include "topos/models/hopnet/normalization.hpp"
#include "topos/nn/schedule.hpp"

#include <torch/torch.h>

#include <optional>
#include <regex>
#include <set>

namespace topos::hopnet {

struct HopnetOptions {
  nlohmann::json to_json() const {
    return {{"model", "hopnet"}, {"hidden", hidden_}, {"mlp_layers", mlp_layers_}, {"activation", nn::to_string(activation_)}, {"num_layers", num_layers_}, {"mode", to_string(mode_)}};
  }
  static HopnetOptions from_json(const nlohmann::json& j) {
    HopnetOptions o;
    try {
      if (j.value("model", "hopnet") != "hopnet") throw std::invalid_argument("not a HOPNet configuration: model '" + j.value("model", "") + "'");
      o.hidden(j.value("hidden", 128)).mlp_layers(j.value("mlp_layers", 2)).num_layers(j.value("num_layers", 1));
      o.activation(nn::activation_from_string(j.value("activation", "relu")));
      o.mode(feature_mode_from_string(j.value("mode", "reference")));
    } catch (const nlohmann::json::exception& e) {
      throw std::invalid_argument(std::string("malformed HOPNet configuration: ") + e.what());
    }
    if (o.hidden() <= 0 || o.mlp_layers() < 1 || o.num_layers() < 1) throw std::invalid_argument("HOPNet configuration: hidden, mlp_layers and num_layers must be positive");
    // Untrusted (a checkpoint's topos.config): refuse sizes whose parameters could not be allocated.
    if (o.hidden() > 65536 || o.mlp_layers() > 64 || o.num_layers() > 64) throw std::invalid_argument("HOPNet configuration: hidden above 65536, or mlp_layers or num_layers above 64");
    return o;
  }

  TORCH_ARG(std::int64_t, hidden) = 128;          ///< width of every cochain and MLP
  TORCH_ARG(int, mlp_layers) = 2;                 ///< Linear layers per MLP (the reference's L)
  TORCH_ARG(nn::Activation, activation) = nn::Activation::relu;
  TORCH_ARG(int, num_layers) = 1;                 ///< processor layers
  /// reference: the plus view of a contact negates the *normalised* direction (the published
  /// weights expect it); native: it is built from raw features, then normalised (input "x3_plus").
  TORCH_ARG(FeatureMode, mode) = FeatureMode::reference;
};

/// The schedule of spec 6.3 for `opt`.
inline nn::Schedule hopnet_schedule(const HopnetOptions& opt) {
  using namespace nn::dsl;
  using nn::Reduce;
  nn::Schedule s;
  s.encode(0, "", "x0", "encoder_0").encode(1, "", "x1", "encoder_1").encode(2, "", "x2", "encoder_2").encode(4, "", "x4", "encoder_4");
  s.encode(3, "minus", "x3", "encoder_3");
  if (opt.mode() == FeatureMode::reference) {
    std::vector<std::int64_t> cols;  // [y0:4, y16:28, y4:16]: the faces' blocks swapped
    for (int c = 0; c < 4; ++c) cols.push_back(c);
    for (int c = 16; c < 28; ++c) cols.push_back(c);
    for (int c = 4; c < 16; ++c) cols.push_back(c);
    s.encode(3, "plus", "x3", "encoder_3", cols, {0, 1, 2});
  } else {
    s.encode(3, "plus", "x3_plus", "encoder_3");
  }
  for (int l = 0; l < opt.num_layers(); ++l) {
    const std::string L = "layer" + std::to_string(l) + "_";
    s.step(into(2).msg(from(0).via("B02").map(L + "0to2")).msg(from(1).via("B12").map(L + "1to2")).msg(from(4).via("B42").map(L + "4to2")).update_with(L + "2").named(L + "faces"));
    s.parallel({into(3, "plus").msg(from(2).via("B23neg").map(L + "2to3").weighted()).msg(from(2).via("B23pos").map(L + "2to3").weighted()).update_with(L + "3").named(L + "contacts_plus"),
                into(3, "minus").msg(from(2).via("B23pos").map(L + "2to3").weighted()).msg(from(2).via("B23neg").map(L + "2to3").weighted()).update_with(L + "3").named(L + "contacts_minus")});
    s.step(into(2).msg(from(3, "plus").via("B32").only(1)).add(from(3, "minus").via("B32").only(-1)).update_with(L + "2p").named(L + "faces_from_contacts"));
    s.step(into(4).msg(from(2).via("B24").map(L + "2to4").reduce(Reduce::mean)).update_with(L + "4").when_nonempty(3).named(L + "objects_from_faces"));
    s.parallel({into(0).msg(from(4).via("B40").map(L + "4to0")).update_with(L + "0").named(L + "nodes_from_objects"),
                into(4).msg(from(0).via("B04").map(L + "0to4").reduce(Reduce::mean)).update_with(L + "4p").named(L + "objects_from_nodes")});
  }
  s.decode(0, "", "decoder_0", "a0").decode(4, "", "decoder_4", "a4");
  return s;
}

inline std::map<std::string, nn::MlpOptions> hopnet_modules(const HopnetOptions& opt) {
  const std::int64_t D = opt.hidden();
  std::map<std::string, nn::MlpOptions> m;
  const auto mlp = [&](std::int64_t in, std::int64_t out) { return nn::MlpOptions(in, D, out).layers(opt.mlp_layers()).activation(opt.activation()); };
  for (int r = 0; r < 5; ++r) m.emplace("encoder_" + std::to_string(r), mlp(kFeatureWidth[static_cast<std::size_t>(r)], D));
  for (int l = 0; l < opt.num_layers(); ++l) {
    const std::string L = "layer" + std::to_string(l) + "_";
    for (const char* x : {"0to2", "1to2", "4to2", "2to3", "2to4", "0to4", "4to0"}) m.emplace(L + x, mlp(D, D));
    m.emplace(L + "2", mlp(4 * D, D));
    m.emplace(L + "3", mlp(3 * D, D));
    for (const char* x : {"2p", "4", "0", "4p"}) m.emplace(L + x, mlp(2 * D, D));
  }
  for (int r : {0, 4}) m.emplace("decoder_" + std::to_string(r), mlp(D, 3).final_activation(false).layer_norm(false));
  return m;
}

inline nn::ScheduleSignature hopnet_signature(const HopnetOptions& opt) {
  nn::ScheduleSignature sig;
  sig.neighborhoods = {{"B02", {0, 2}}, {"B12", {1, 2}}, {"B42", {4, 2}}, {"B23neg", {2, 3}}, {"B23pos", {2, 3}},
                       {"B32", {3, 2}}, {"B24", {2, 4}}, {"B04", {0, 4}}, {"B40", {4, 0}}};
  for (int r = 0; r < 5; ++r) sig.inputs["x" + std::to_string(r)] = kFeatureWidth[static_cast<std::size_t>(r)];
  if (opt.mode() == FeatureMode::native) sig.inputs["x3_plus"] = 28;
  return sig;
}

/// Statistics as float32 tensors, applied as the reference does: (x − mean) / std in float32.
class Normalizer {
 public:
  Normalizer() = default;
  explicit Normalizer(const NormalizationStats& s) : stats_(s) {
    s.validate("normalisation statistics");
    for (const auto& [k, n] : NormalizationStats::layout()) {
      mean_[k] = torch::tensor(s.mean.at(k), torch::kDouble).to(torch::kFloat);
      std_[k] = torch::tensor(s.std.at(k), torch::kDouble).to(torch::kFloat);
    }
    z0_ = -mean_["t0"] / std_["t0"];
    z4_ = -mean_["t4"] / std_["t4"];
  }
  /// Raw double features (cast to float32 first, as the reference stores them) -> normalised.
  torch::Tensor normalize(const std::string& key, const RowMatrix& x) const { return normalize(key, to_tensor(x)); }
  torch::Tensor normalize(const std::string& key, const torch::Tensor& x) const {
    const std::string k = key == "x3_plus" ? "x3" : key;
    return (x.to(torch::kFloat) - mean_.at(k).to(x.device())) / std_.at(k).to(x.device());
  }
  torch::Tensor denormalize(const std::string& key, const torch::Tensor& y) const { return y * std_.at(key).to(y.device()) + mean_.at(key).to(y.device()); }
  const torch::Tensor& zero_node_acceleration() const { return z0_; }
  const torch::Tensor& zero_object_acceleration() const { return z4_; }
  const NormalizationStats& stats() const { return stats_; }

  static torch::Tensor to_tensor(const RowMatrix& x) {
    if (x.size() == 0) return torch::zeros({x.rows(), x.cols()}, torch::kFloat);
    return torch::from_blob(const_cast<double*>(x.data()), {x.rows(), x.cols()}, torch::kDouble).to(torch::kFloat);
  }

 private:
  NormalizationStats stats_;
  std::map<std::string, torch::Tensor> mean_, std_;
  torch::Tensor z0_, z4_;
};

/// Frames ready for the network: normalised inputs and their batched complex.
struct HopnetBatch {
  std::map<std::string, torch::Tensor> inputs;
  nn::ComplexBatch complex;
  HopnetBatch to(const torch::Device& d) const {
    HopnetBatch b{{}, complex.to(d)};
    for (const auto& [k, v] : inputs) b.inputs[k] = v.to(d);
    return b;
  }
};

inline nn::ComplexView hopnet_view(const HopnetGeometry& g, const HopnetFrame& f) {
  return {{g.num_nodes(), g.num_edges(), f.num_faces(), f.num_contacts(), g.num_objects()}, hopnet_neighborhoods(g, f)};
}

/// Collates frames (of one scene or several) into one batch.
inline HopnetBatch make_batch(const std::vector<std::pair<const HopnetGeometry*, const HopnetFrame*>>& frames, const Normalizer& norm) {
  std::vector<nn::ComplexView> views;
  std::map<std::string, std::vector<torch::Tensor>> parts;
  for (const auto& [g, f] : frames) {
    views.push_back(hopnet_view(*g, *f));
    parts["x0"].push_back(norm.normalize("x0", f->x0));
    parts["x1"].push_back(norm.normalize("x1", f->x1));
    parts["x2"].push_back(norm.normalize("x2", f->x2));
    parts["x3"].push_back(norm.normalize("x3", f->x3));
    parts["x3_plus"].push_back(norm.normalize("x3", f->x3_plus));
    parts["x4"].push_back(norm.normalize("x4", f->x4));
  }
  HopnetBatch b;
  for (auto& [k, v] : parts) b.inputs[k] = v.size() == 1 ? v[0] : torch::cat(v, 0);
  b.complex = nn::ComplexBatch::collate(views, 4);
  return b;
}

/// Normalised accelerations of nodes (a0) and objects (a4).
struct HopnetOutput {
  torch::Tensor a0, a4;
};

class HopnetImpl : public nn::ScheduleNetworkImpl {
 public:
  explicit HopnetImpl(const HopnetOptions& opt = {}) : nn::ScheduleNetworkImpl(hopnet_schedule(opt), hopnet_modules(opt), hopnet_signature(opt)), options(opt) {}

  /// Runs the network; static objects (normalised type column x4[:, 8] < 0) and their nodes get
  /// the normalised zero acceleration.
  HopnetOutput forward(const HopnetBatch& b, const Normalizer& norm) {
    auto out = nn::ScheduleNetworkImpl::forward(b.inputs, b.complex);
    const auto& x4 = b.inputs.at("x4");
    const auto is_static = x4.select(1, 8).lt(0);
    const auto node_object = b.complex.neighborhood("B04").target;
    const auto node_static = is_static.index_select(0, node_object).unsqueeze(1);
    auto a0 = torch::where(node_static, norm.zero_node_acceleration().to(x4.device()).expand_as(out["a0"]), out["a0"]);
    auto a4 = torch::where(is_static.unsqueeze(1), norm.zero_object_acceleration().to(x4.device()).expand_as(out["a4"]), out["a4"]);
    return {a0, a4};
  }

  std::int64_t num_parameters() const {
    std::int64_t n = 0;
    for (const auto& p : parameters()) n += p.numel();
    return n;
  }

  HopnetOptions options;
};
TORCH_MODULE(Hopnet);

/// The reference checkpoint's name of a topos parameter ("modules.layer0_2to3.0.weight" ->
/// "_HOPNet__layers.0._HOPNet_Layer__mlp_processor_2to3.0.weight").
inline std::string reference_parameter_name(const std::string& name) {
  static const std::regex enc(R"(^modules\.(encoder|decoder)_(\d)\.(.*)$)"), proc(R"(^modules\.layer(\d+)_([0-9a-z]+)\.(.*)$)");
  std::smatch m;
  if (std::regex_match(name, m, enc)) return "_HOPNet__mlp_" + m[1].str() + "_" + m[2].str() + "." + m[3].str();
  if (std::regex_match(name, m, proc)) return "_HOPNet__layers." + m[1].str() + "._HOPNet_Layer__mlp_processor_" + m[2].str() + "." + m[3].str();
  throw std::invalid_argument("no reference name for parameter '" + name + "'");
}

/// True when a tensor dict is a reference (authors') HOPNet state dict.
inline bool is_reference_checkpoint(const std::map<std::string, torch::Tensor>& dict) {
  return std::any_of(dict.begin(), dict.end(), [](const auto& kv) { return kv.first.rfind("_HOPNet__", 0) == 0; });
}

/// The configuration a checkpoint was saved with: topos checkpoints carry it (entry
/// "topos.config", JSON bytes); for reference ones it is read off the tensor shapes
/// (the activation cannot be, so it comes from `fallback`).
inline HopnetOptions checkpoint_options(const std::map<std::string, torch::Tensor>& dict, const std::string& source, HopnetOptions fallback = {}) {
  auto cfg = dict.find("topos.config");
  if (cfg != dict.end()) {
    const auto t = cfg->second.to(torch::kUInt8).contiguous();
    const std::string text(reinterpret_cast<const char*>(t.data_ptr<std::uint8_t>()), static_cast<std::size_t>(t.numel()));
    try {
      return HopnetOptions::from_json(nlohmann::json::parse(text));
    } catch (const std::exception& e) {
      throw std::runtime_error(source + ": unreadable topos.config: " + e.what());
    }
  }
  if (!is_reference_checkpoint(dict)) throw std::runtime_error(source + ": neither a topos nor a reference HOPNet checkpoint (no 'topos.config', no '_HOPNet__' tensors)");
  auto e0 = dict.find("_HOPNet__mlp_encoder_0.0.weight");
  if (e0 == dict.end() || e0->second.dim() != 2) throw std::runtime_error(source + ": missing tensor '_HOPNet__mlp_encoder_0.0.weight'");
  HopnetOptions o = fallback;
  o.hidden(e0->second.size(0));
  int layers = 0, mlp = 1;
  while (dict.count("_HOPNet__layers." + std::to_string(layers) + "._HOPNet_Layer__mlp_processor_2.0.weight")) ++layers;
  while (dict.count("_HOPNet__mlp_decoder_0." + std::to_string(2 * mlp) + ".weight")) ++mlp;
  o.num_layers(std::max(layers, 1)).mlp_layers(mlp);
  return o;
}

/// Loads a checkpoint into `model`: a topos checkpoint by name, or a reference state dict by
/// the reference's names. Missing, extra and misshapen tensors are errors naming the tensor
/// as the file names it.
inline void load_checkpoint(HopnetImpl& model, const std::map<std::string, torch::Tensor>& dict, const std::string& source) {
  if (!is_reference_checkpoint(dict)) {
    auto d = dict;
    d.erase("topos.config");
    nn::load_parameters(model, d, source);
    return;
  }
  torch::NoGradGuard guard;
  std::set<std::string> used;
  for (auto& p : model.named_parameters()) {
    const std::string ref = reference_parameter_name(p.key());
    auto it = dict.find(ref);
    if (it == dict.end()) throw std::runtime_error(source + ": missing tensor '" + ref + "'");
    if (it->second.sizes() != p.value().sizes()) {
      std::ostringstream s;
      s << source << ": tensor '" << ref << "' has shape " << it->second.sizes() << ", expected " << p.value().sizes();
      throw std::runtime_error(s.str());
    }
    p.value().copy_(it->second);
    used.insert(ref);
  }
  for (const auto& [k, v] : dict)
    if (!used.count(k)) throw std::runtime_error(source + ": unexpected tensor '" + k + "'");
}

/// Loads a checkpoint (topos or reference). `mode`, when given, overrides the feature mode the
/// network runs in (the parameters do not depend on it).
/// The same from a checkpoint already read (nn::read_tensor_dict); `source` names it in errors.
/// Several models (one per thread) can be built from one read.
inline Hopnet load_hopnet(const std::map<std::string, torch::Tensor>& dict, const std::string& source, std::optional<FeatureMode> mode = std::nullopt) {
  HopnetOptions opt = checkpoint_options(dict, source);
  if (mode) opt.mode(*mode);
  Hopnet model(opt);
  load_checkpoint(*model, dict, source);
  return model;
}

inline Hopnet load_hopnet(const std::string& path, std::optional<FeatureMode> mode = std::nullopt) { return load_hopnet(nn::read_tensor_dict(path), path, mode); }

/// Saves a topos checkpoint: parameters by name plus "topos.config" (the options as JSON
/// bytes), a dict of tensors that Python's torch.load opens. Atomic.
inline void save_hopnet(const HopnetImpl& model, const std::string& path) {
  c10::Dict<std::string, torch::Tensor> dict;
  for (const auto& p : model.named_parameters()) dict.insert(p.key(), p.value().detach().cpu());
  const std::string cfg = model.options.to_json().dump();
  dict.insert("topos.config", torch::tensor(std::vector<std::uint8_t>(cfg.begin(), cfg.end()), torch::kUInt8));
  nn::write_tensor_dict(dict, path);
}

}  // namespace topos::hopnet
