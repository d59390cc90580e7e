// topos/models/hopnet/schedule.hpp
// HOPNet's network as a schedule of topos's DSL (the reference's models/hopnet.py): the schedule
// of HopnetOptions' architecture, its MLP modules, inputs and neighbourhood signature.
#pragma once

#include "topos/models/hopnet/lifting_options.hpp"
#include "topos/models/hopnet/options.hpp"
#include "topos/nn/mlp.hpp"
#include "topos/nn/schedule.hpp"

#include <cstdint>
#include <map>
#include <string>
#include <vector>

namespace topos::hopnet {

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

}  // namespace topos::hopnet
