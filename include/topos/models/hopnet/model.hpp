// topos/models/hopnet/model.hpp
// HOPNet (Wei & Fink) as a schedule of topos's DSL (the reference's models/hopnet.py), its float32
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
//
// The ablations are other schedules over the same modules and interpreter (HopnetOptions::
// architecture, the reference's models/ablations.py); presets and config files are in variants.hpp.
// no_object_cells (virtual object nodes, A010 over mesh edges and spokes), one layer:
//   into 2 = L2([h2, Σ_B02 L0to2(h0), Σ_B12 L1to2(h1)]); the two contact steps and L2p as above
//   into 0 = L0 ([h0, Σ_B20 L2to0(h2)])                           only where the complex has
//     contacts
//   into 0 = L0p([h0, Σ_A010 L0to0(h0)])
// no_sequential, one layer: a single parallel group (every message reads the layer's input):
//   into 3 minus/plus = L3([h3, Σ_B03 L0to3(h0), Σ_B13 L1to3(h1), Σ_B23signed L2to3(h2)])
//   into 2 = L2([h2, Σ_B02 L0to2(h0), Σ_B12 L1to2(h1), Σ_A232 L2to2(h2), Σ_B32signed L3to2(h3p) +
//     Σ_B32signed L3to2(h3m), B42 L4to2(h4)])
//   into 0 = L0([h0, Σ_A010 L0to0(h0), Σ_B10 L1to0(h1), Σ_B20 L2to0(h2), Σ_B30 L3to0(h3p) + Σ_B30
//     L3to0(h3m), B40 L4to0(h4)])
//   into 1 = L1([h1, Σ_B01 L0to1(h0), Σ_A101 L1to1(h1), Σ_B21 L2to1(h2), Σ_B31 L3to1(h3p) + Σ_B31
//     L3to1(h3m), B41 L4to1(h4)])
//   into 4 = L4([h4, mean_B04 L0to4(h0), mean_B14 L1to4(h1), Σ_B24 L2to4(h2)])
#pragma once

#include "topos/models/hopnet/features.hpp"
#include "topos/models/hopnet/normalization.hpp"
#include "topos/nn/schedule.hpp"
#include "topos/nn/serialization.hpp"

#include <torch/torch.h>

#include <optional>
#include <regex>
#include <set>

namespace topos::hopnet {

struct HopnetOptions {
  nlohmann::json to_json() const {
    return {{"model", "hopnet"},
            {"architecture", to_string(architecture_)},
            {"center_mass_distance", center_mass_distance_},
            {"hidden", hidden_},
            {"mlp_layers", mlp_layers_},
            {"activation", nn::to_string(activation_)},
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
    if (!(collision_radius() > 0) || !std::isfinite(collision_radius()))
      throw std::invalid_argument(
          "HOPNet configuration: the collision radius must be a positive number");
  }
  LiftingOptions lifting() const {
    LiftingOptions l;
    l.mode = mode_;
    l.architecture = architecture_;
    l.center_mass_distance = center_mass_distance_;
    return l;
  }

  TORCH_ARG(std::int64_t, hidden) = 128;  ///< width of every cochain and MLP
  TORCH_ARG(int, mlp_layers) = 2;         ///< Linear layers per MLP (the reference's L)
  TORCH_ARG(nn::Activation, activation) = nn::Activation::relu;
  TORCH_ARG(int, num_layers) = 1;  ///< processor layers
  /// reference: the plus view of a contact negates the *normalised* direction (the published
  /// weights expect it); native: it is built from raw features, then normalised (input "x3_plus").
  TORCH_ARG(FeatureMode, mode) = FeatureMode::reference;
  TORCH_ARG(Architecture, architecture) = Architecture::hopnet;  ///< the member of the family
  TORCH_ARG(bool, center_mass_distance) = true;  ///< x0 keeps r0, rt (false: 8 columns)
  TORCH_ARG(double, collision_radius) = 0.1;     ///< d_c of contact detection (training, rollout)
};

/// The schedule of the reference's HOPNet.forward (or of an ablation's) for `opt`.
inline nn::Schedule hopnet_schedule(const HopnetOptions& opt) {
  using namespace nn::dsl;
  using nn::Reduce;
  const Architecture arch = opt.architecture();
  nn::Schedule s;
  s.encode(0, "", "x0", "encoder_0")
      .encode(1, "", "x1", "encoder_1")
      .encode(2, "", "x2", "encoder_2");
  if (arch != Architecture::no_object_cells) s.encode(4, "", "x4", "encoder_4");
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
    if (arch == Architecture::no_sequential) {
      const auto contact = [&](const char* view) {
        return into(3, view)
            .msg(from(0).via("B03").map(L + "0to3"))
            .msg(from(1).via("B13").map(L + "1to3"))
            .msg(from(2).via("B23signed").map(L + "2to3").weighted())
            .update_with(L + "3")
            .named(L + "contacts_" + view);
      };
      s.parallel({contact("minus"), contact("plus"),
                  into(2)
                      .msg(from(0).via("B02").map(L + "0to2"))
                      .msg(from(1).via("B12").map(L + "1to2"))
                      .msg(from(2).via("A232").map(L + "2to2"))
                      .msg(from(3, "plus").via("B32signed").map(L + "3to2").weighted())
                      .add(from(3, "minus").via("B32signed").map(L + "3to2").weighted())
                      .msg(from(4).via("B42").map(L + "4to2"))
                      .update_with(L + "2")
                      .named(L + "faces"),
                  into(0)
                      .msg(from(0).via("A010").map(L + "0to0"))
                      .msg(from(1).via("B10").map(L + "1to0"))
                      .msg(from(2).via("B20").map(L + "2to0"))
                      .msg(from(3, "plus").via("B30").map(L + "3to0"))
                      .add(from(3, "minus").via("B30").map(L + "3to0"))
                      .msg(from(4).via("B40").map(L + "4to0"))
                      .update_with(L + "0")
                      .named(L + "nodes"),
                  into(1)
                      .msg(from(0).via("B01").map(L + "0to1"))
                      .msg(from(1).via("A101").map(L + "1to1"))
                      .msg(from(2).via("B21").map(L + "2to1"))
                      .msg(from(3, "plus").via("B31").map(L + "3to1"))
                      .add(from(3, "minus").via("B31").map(L + "3to1"))
                      .msg(from(4).via("B41").map(L + "4to1"))
                      .update_with(L + "1")
                      .named(L + "edges"),
                  into(4)
                      .msg(from(0).via("B04").map(L + "0to4").reduce(Reduce::mean))
                      .msg(from(1).via("B14").map(L + "1to4").reduce(Reduce::mean))
                      .msg(from(2).via("B24").map(L + "2to4"))
                      .update_with(L + "4")
                      .named(L + "objects")});
      continue;
    }
    const bool objects = arch == Architecture::hopnet;
    auto faces =
        into(2).msg(from(0).via("B02").map(L + "0to2")).msg(from(1).via("B12").map(L + "1to2"));
    if (objects) faces.msg(from(4).via("B42").map(L + "4to2"));
    s.step(faces.update_with(L + "2").named(L + "faces"));
    s.parallel({into(3, "plus")
                    .msg(from(2).via("B23neg").map(L + "2to3").weighted())
                    .msg(from(2).via("B23pos").map(L + "2to3").weighted())
                    .update_with(L + "3")
                    .named(L + "contacts_plus"),
                into(3, "minus")
                    .msg(from(2).via("B23pos").map(L + "2to3").weighted())
                    .msg(from(2).via("B23neg").map(L + "2to3").weighted())
                    .update_with(L + "3")
                    .named(L + "contacts_minus")});
    s.step(into(2)
               .msg(from(3, "plus").via("B32").only(1))
               .add(from(3, "minus").via("B32").only(-1))
               .update_with(L + "2p")
               .named(L + "faces_from_contacts"));
    if (!objects) {
      s.step(into(0)
                 .msg(from(2).via("B20").map(L + "2to0"))
                 .update_with(L + "0")
                 .when_nonempty(3)
                 .named(L + "nodes_from_faces"));
      s.step(into(0)
                 .msg(from(0).via("A010").map(L + "0to0"))
                 .update_with(L + "0p")
                 .named(L + "nodes_from_nodes"));
      continue;
    }
    s.step(into(4)
               .msg(from(2).via("B24").map(L + "2to4").reduce(Reduce::mean))
               .update_with(L + "4")
               .when_nonempty(3)
               .named(L + "objects_from_faces"));
    s.parallel({into(0)
                    .msg(from(4).via("B40").map(L + "4to0"))
                    .update_with(L + "0")
                    .named(L + "nodes_from_objects"),
                into(4)
                    .msg(from(0).via("B04").map(L + "0to4").reduce(Reduce::mean))
                    .update_with(L + "4p")
                    .named(L + "objects_from_nodes")});
  }
  s.decode(0, "", "decoder_0", "a0");
  if (arch != Architecture::no_object_cells) s.decode(4, "", "decoder_4", "a4");
  return s;
}

/// Input widths of an architecture: x0 (lifting), x1 8, x2 3, x3 28, x4 13 (none without object
/// cells).
inline std::map<std::string, std::int64_t> hopnet_inputs(const HopnetOptions& opt) {
  std::map<std::string, std::int64_t> in{{"x0", opt.lifting().x0_width()},
                                         {"x1", kFeatureWidth[1]},
                                         {"x2", kFeatureWidth[2]},
                                         {"x3", kFeatureWidth[3]}};
  if (opt.architecture() != Architecture::no_object_cells) in["x4"] = kFeatureWidth[4];
  if (opt.mode() == FeatureMode::native) in["x3_plus"] = kFeatureWidth[3];
  return in;
}

inline std::map<std::string, nn::MlpOptions> hopnet_modules(const HopnetOptions& opt) {
  const std::int64_t D = opt.hidden();
  std::map<std::string, nn::MlpOptions> m;
  const auto mlp = [&](std::int64_t in, std::int64_t out) {
    return nn::MlpOptions(in, D, out).layers(opt.mlp_layers()).activation(opt.activation());
  };
  const auto inputs = hopnet_inputs(opt);
  for (int r = 0; r < 5; ++r)
    if (inputs.count("x" + std::to_string(r)))
      m.emplace("encoder_" + std::to_string(r), mlp(inputs.at("x" + std::to_string(r)), D));
  for (int l = 0; l < opt.num_layers(); ++l) {
    const std::string L = "layer" + std::to_string(l) + "_";
    switch (opt.architecture()) {
      case Architecture::hopnet:
        for (const char* x : {"0to2", "1to2", "4to2", "2to3", "2to4", "0to4", "4to0"})
          m.emplace(L + x, mlp(D, D));
        m.emplace(L + "2", mlp(4 * D, D));
        m.emplace(L + "3", mlp(3 * D, D));
        for (const char* x : {"2p", "4", "0", "4p"}) m.emplace(L + x, mlp(2 * D, D));
        break;
      case Architecture::no_object_cells:
        for (const char* x : {"0to0", "0to2", "1to2", "2to3", "2to0"}) m.emplace(L + x, mlp(D, D));
        m.emplace(L + "2", mlp(3 * D, D));
        m.emplace(L + "3", mlp(3 * D, D));
        for (const char* x : {"2p", "0", "0p"}) m.emplace(L + x, mlp(2 * D, D));
        break;
      case Architecture::no_sequential:
        for (const char* x : {"0to0", "0to1", "0to2", "0to3", "0to4", "1to0", "1to1",
                              "1to2", "1to3", "1to4", "2to0", "2to1", "2to2", "2to3",
                              "2to4", "3to0", "3to1", "3to2", "4to0", "4to1", "4to2"})
          m.emplace(L + x, mlp(D, D));
        for (const char* x : {"0", "1", "2"}) m.emplace(L + x, mlp(6 * D, D));
        for (const char* x : {"3", "4"}) m.emplace(L + x, mlp(4 * D, D));
        break;
    }
  }
  for (int r : {0, 4})
    if (r == 0 || opt.architecture() != Architecture::no_object_cells)
      m.emplace("decoder_" + std::to_string(r),
                mlp(D, 3).final_activation(false).layer_norm(false));
  return m;
}

inline nn::ScheduleSignature hopnet_signature(const HopnetOptions& opt) {
  nn::ScheduleSignature sig;
  sig.neighborhoods = {{"B02", {0, 2}},    {"B12", {1, 2}},    {"B42", {4, 2}},
                       {"B23neg", {2, 3}}, {"B23pos", {2, 3}}, {"B32", {3, 2}},
                       {"B24", {2, 4}},    {"B04", {0, 4}},    {"B40", {4, 0}}};
  if (opt.architecture() != Architecture::hopnet)
    sig.neighborhoods.insert({{"A010", {0, 0}}, {"B20", {2, 0}}});
  if (opt.architecture() == Architecture::no_sequential)
    sig.neighborhoods.insert({{"B01", {0, 1}},
                              {"B10", {1, 0}},
                              {"A101", {1, 1}},
                              {"B14", {1, 4}},
                              {"B41", {4, 1}},
                              {"B21", {2, 1}},
                              {"A232", {2, 2}},
                              {"B03", {0, 3}},
                              {"B30", {3, 0}},
                              {"B13", {1, 3}},
                              {"B31", {3, 1}},
                              {"B23signed", {2, 3}},
                              {"B32signed", {3, 2}}});
  sig.inputs = hopnet_inputs(opt);
  return sig;
}

/// Statistics as float32 tensors, applied as the reference does: (x − mean) / std in float32.
class Normalizer {
 public:
  Normalizer() = default;
  explicit Normalizer(const NormalizationStats& s) : stats_(s) {
    s.validate("normalisation statistics");
    for (const auto& [k, n] : s.keys()) {
      mean_[k] = torch::tensor(s.mean.at(k), torch::kDouble).to(torch::kFloat);
      std_[k] = torch::tensor(s.std.at(k), torch::kDouble).to(torch::kFloat);
    }
    z0_ = -mean_["t0"] / std_["t0"];
    if (s.has_objects()) z4_ = -mean_["t4"] / std_["t4"];
  }
  /// Raw double features (cast to float32 first, as the reference stores them) -> normalised.
  torch::Tensor normalize(const std::string& key, const RowMatrix& x) const {
    return normalize(key, to_tensor(x));
  }
  torch::Tensor normalize(const std::string& key, const torch::Tensor& x) const {
    const std::string k = key == "x3_plus" ? "x3" : key;
    auto it = mean_.find(k);
    if (it == mean_.end())
      throw std::invalid_argument("the normalisation statistics have no '" + k +
                                  "' entries (statistics of a model without object cells?)");
    if (x.dim() != 2 || x.size(1) != it->second.size(0))
      throw std::invalid_argument(
          "the normalisation statistics give '" + k + "' " + std::to_string(it->second.size(0)) +
          " columns, the features have " + std::to_string(x.dim() == 2 ? x.size(1) : -1) +
          ": use the statistics this model variant was trained with");
    return (x.to(torch::kFloat) - it->second.to(x.device())) / std_.at(k).to(x.device());
  }
  torch::Tensor denormalize(const std::string& key, const torch::Tensor& y) const {
    return y * std_.at(key).to(y.device()) + mean_.at(key).to(y.device());
  }
  const torch::Tensor& zero_node_acceleration() const { return z0_; }
  /// Undefined for statistics without object entries (no object cells).
  const torch::Tensor& zero_object_acceleration() const { return z4_; }
  const NormalizationStats& stats() const { return stats_; }

  static torch::Tensor to_tensor(const RowMatrix& x) {
    if (x.size() == 0) return torch::zeros({x.rows(), x.cols()}, torch::kFloat);
    return torch::from_blob(const_cast<double*>(x.data()), {x.rows(), x.cols()}, torch::kDouble)
        .to(torch::kFloat);
  }

 private:
  NormalizationStats stats_;
  std::map<std::string, torch::Tensor> mean_, std_;
  torch::Tensor z0_, z4_;
};

/// Throws a clear error when `stats` cannot feed a model configured by `opt` (x0's width, the
/// object entries).
inline void check_stats_fit(const HopnetOptions& opt, const NormalizationStats& stats,
                            const std::string& source) {
  const auto want = static_cast<std::size_t>(opt.lifting().x0_width());
  if (stats.x0_width() != want)
    throw std::invalid_argument(source + ": x0 statistics have " +
                                std::to_string(stats.x0_width()) + " columns, the " +
                                to_string(opt.architecture()) +
                                (opt.center_mass_distance() ? "" : " (no centre-mass distance)") +
                                " model reads " + std::to_string(want) +
                                (opt.architecture() == Architecture::no_object_cells
                                     ? " (no object cells: e.g. normalization/movia-nox4.json)"
                                     : ""));
  if (opt.architecture() != Architecture::no_object_cells && !stats.has_objects())
    throw std::invalid_argument(
        source + ": the statistics have no object (x4, t4) entries, which this model needs");
}

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
  return {{g.num_rank0(), g.num_rank1(), f.num_faces(), f.num_contacts(), g.num_objects()},
          hopnet_neighborhoods(g, f)};
}

/// Collates frames (of one scene or several) into one batch.
inline HopnetBatch make_batch(
    const std::vector<std::pair<const HopnetGeometry*, const HopnetFrame*>>& frames,
    const Normalizer& norm) {
  std::vector<nn::ComplexView> views;
  std::map<std::string, std::vector<torch::Tensor>> parts;
  for (const auto& [g, f] : frames) {
    views.push_back(hopnet_view(*g, *f));
    parts["x0"].push_back(norm.normalize("x0", f->x0));
    parts["x1"].push_back(norm.normalize("x1", f->x1));
    parts["x2"].push_back(norm.normalize("x2", f->x2));
    parts["x3"].push_back(norm.normalize("x3", f->x3));
    parts["x3_plus"].push_back(norm.normalize("x3", f->x3_plus));
    if (g->lifting.object_cells()) parts["x4"].push_back(norm.normalize("x4", f->x4));
  }
  HopnetBatch b;
  for (auto& [k, v] : parts) b.inputs[k] = v.size() == 1 ? v[0] : torch::cat(v, 0);
  b.complex = nn::ComplexBatch::collate(views, 4);
  return b;
}

/// Normalised accelerations of nodes (a0) and objects (a4; undefined without object cells,
/// where a0 has a row per virtual node too, after the mesh nodes).
struct HopnetOutput {
  torch::Tensor a0, a4;
};

class HopnetImpl : public nn::ScheduleNetworkImpl {
 public:
  explicit HopnetImpl(const HopnetOptions& opt = {})
      : nn::ScheduleNetworkImpl(hopnet_schedule(opt), hopnet_modules(opt), hopnet_signature(opt)),
        options(opt) {
    opt.validate();
  }

  /// Runs the network; static objects (normalised type column x4[:, 8] < 0) and their nodes get
  /// the normalised zero acceleration. Without object cells the test is the node's own type
  /// column (x0[:, 16] with 21 columns), so the floor's virtual node is static too.
  HopnetOutput forward(const HopnetBatch& b, const Normalizer& norm) {
    auto out = nn::ScheduleNetworkImpl::forward(b.inputs, b.complex);
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
};
TORCH_MODULE(Hopnet);

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

/// Loads a checkpoint (topos or reference, of any architecture) from a checkpoint already read
/// (nn::read_tensor_dict); `source` names it in errors. Several models (one per thread) can be
/// built from one read.
inline Hopnet load_hopnet(const std::map<std::string, torch::Tensor>& dict,
                          const std::string& source, const CheckpointOverrides& ov) {
  HopnetOptions opt = checkpoint_options(dict, source);
  if (ov.activation) {
    if (!is_reference_checkpoint(dict) && opt.activation() != *ov.activation)
      throw std::invalid_argument(source + ": the checkpoint was trained with activation " +
                                  nn::to_string(opt.activation()) + ", not " +
                                  nn::to_string(*ov.activation));
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

}  // namespace topos::hopnet
