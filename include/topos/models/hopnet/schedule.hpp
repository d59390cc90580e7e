// topos/models/hopnet/schedule.hpp
// HOPNet's network as an operator schedule (the reference's models/hopnet.py): the schedule of
// HopnetOptions' architecture, with its MLPs at the reference's names ("modules.<name>"), over a
// ComplexBatch's neighbourhoods; and the one operation of its own, the plus view of a contact.
#pragma once

#include "topos/models/hopnet/lifting_options.hpp"
#include "topos/models/hopnet/options.hpp"
#include "topos/models/namespace_aliases.hpp"
#include "topos/nn/operator_schedule.hpp"

#include <array>
#include <cstdint>
#include <map>
#include <string>
#include <vector>

namespace topos::models::hopnet {

// One processor layer, as a schedule (L = "layer<l>_"):
//   into 2        = L2 ([h2, Σ_B02 L0to2(h0), Σ_B12 L1to2(h1), B42 L4to2(h4)])
//   parallel {
//     into 3 plus  = L3 ([h3p, Σ_B23neg L2to3(h2), Σ_B23pos L2to3(h2)])
//     into 3 minus = L3 ([h3m, Σ_B23pos L2to3(h2), Σ_B23neg L2to3(h2)]) }
//   into 2 contacts = Σ_{B32, role +1} h3p + Σ_{B32, role −1} h3m
//   into 2        = L2p([h2, contacts])
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
// no_sequential, one layer: every message reads the layer's input (the sums over both contact
// views first, into scratch states, then one parallel group):
//   into 3 minus/plus = L3([h3, Σ_B03 L0to3(h0), Σ_B13 L1to3(h1), Σ_B23signed L2to3(h2)])
//   into 2 = L2([h2, Σ_B02 L0to2(h0), Σ_B12 L1to2(h1), Σ_A232 L2to2(h2), Σ_B32signed L3to2(h3p) +
//     Σ_B32signed L3to2(h3m), B42 L4to2(h4)])
//   into 0 = L0([h0, Σ_A010 L0to0(h0), Σ_B10 L1to0(h1), Σ_B20 L2to0(h2), Σ_B30 L3to0(h3p) + Σ_B30
//     L3to0(h3m), B40 L4to0(h4)])
//   into 1 = L1([h1, Σ_B01 L0to1(h0), Σ_A101 L1to1(h1), Σ_B21 L2to1(h2), Σ_B31 L3to1(h3p) + Σ_B31
//     L3to1(h3m), B41 L4to1(h4)])
//   into 4 = L4([h4, mean_B04 L0to4(h0), mean_B14 L1to4(h1), Σ_B24 L2to4(h2)])

/// The reference's plus view of a contact cell's features (reference mode): the other face's
/// blocks first ([y0:4, y16:28, y4:16]) and the direction (columns 0..2) negated, after the
/// normalisation, as the published weights expect. HOPNet's own operation, written through the
/// operator schedule's extension point (nn::Operation).
struct ContactPlusView : nn::Operation {
  std::string str(const std::string& x) const override { return "plus_view(" + x + ")"; }
  nn::TermShape infer(nn::BuildContext& ctx, nn::TermShape x) const override {
    if (x.channels != kFeatureWidth[3])
      ctx.fail("the plus view takes the " + std::to_string(kFeatureWidth[3]) +
               " contact features, not " + std::to_string(x.channels));
    return x;
  }
  torch::Tensor forward(nn::RunContext&, const torch::Tensor& x) const override {
    std::vector<std::int64_t> cols;  // [y0:4, y16:28, y4:16]: the faces' blocks swapped
    for (int c = 0; c < 4; ++c) cols.push_back(c);
    for (int c = 16; c < 28; ++c) cols.push_back(c);
    for (int c = 4; c < 16; ++c) cols.push_back(c);
    auto sign = torch::ones({x.size(1)}, x.options());
    for (int c = 0; c < 3; ++c) sign[c] = -1;
    return (x * sign).index_select(1, torch::tensor(cols, torch::kLong).to(x.device()));
  }
  nn::OperationTraits traits() const override {  // a column permutation, row by row
    nn::OperationTraits t;
    t.row_wise = true;
    t.identity = "plus_view";
    return t;
  }
};

/// Input widths of an architecture: x0 (lifting), x1 8, x2 3, x3 28, x4 13 (none without object
/// cells); x3_plus in native mode.
inline std::map<std::string, std::int64_t> hopnet_inputs(const HopnetOptions& opt) {
  std::map<std::string, std::int64_t> in{{"x0", opt.lifting().x0_width()},
                                         {"x1", kFeatureWidth[1]},
                                         {"x2", kFeatureWidth[2]},
                                         {"x3", kFeatureWidth[3]}};
  if (opt.architecture() != Architecture::no_object_cells) in["x4"] = kFeatureWidth[4];
  if (opt.mode() == FeatureMode::native) in["x3_plus"] = kFeatureWidth[3];
  return in;
}

/// The schedule of the reference's HOPNet.forward (or of an ablation's) for `opt`: inputs x0..x4
/// (and x3_plus), the ComplexBatch's neighbourhoods (hopnet_neighborhoods), outputs a0 and a4.
inline nn::OperatorSchedule hopnet_schedule(const HopnetOptions& opt) {
  using namespace nn::ops;
  using nn::Aggr;
  using nn::OperatorStep;
  const Architecture arch = opt.architecture();
  const std::int64_t D = opt.hidden();
  const auto options = [&](std::int64_t in, std::int64_t out) {
    return nn::MlpOptions(in, D, out).layers(opt.mlp_layers()).activation(opt.activation());
  };
  // The reference's module `name` (state_dict "modules.<name>...") from `in` channels to D.
  const auto M = [](const std::string& name) { return "modules." + name; };
  const auto message = [&](int rank, const std::string& state, const std::string& name) {
    return from(rank, state).mlp(M(name), options(D, D));
  };
  const auto self_and = [&](int rank, const std::string& state, std::vector<Term> terms) {
    std::vector<Term> all{from(rank, state)};
    all.insert(all.end(), terms.begin(), terms.end());
    return into(rank, state).concat(std::move(all));
  };
  const auto update = [&](OperatorStep step, const std::string& name) {
    const auto in = static_cast<std::int64_t>(step.terms.size()) * D;
    return step.mlp(M(name), options(in, D));
  };

  nn::OperatorSchedule s;
  const auto inputs = hopnet_inputs(opt);
  for (const auto& [name, width] : inputs)
    s.input(name, name == "x3_plus" ? 3 : name[1] - '0', width, name);
  for (const auto& [name, rank] : std::map<std::string, std::pair<int, int>>{
           {"B02", {0, 2}},    {"B12", {1, 2}},  {"B42", {4, 2}},       {"B23neg", {2, 3}},
           {"B23pos", {2, 3}}, {"B32", {3, 2}},  {"B24", {2, 4}},       {"B04", {0, 4}},
           {"B40", {4, 0}},    {"A010", {0, 0}}, {"B20", {2, 0}},       {"B01", {0, 1}},
           {"B10", {1, 0}},    {"A101", {1, 1}}, {"B14", {1, 4}},       {"B41", {4, 1}},
           {"B21", {2, 1}},    {"A232", {2, 2}}, {"B03", {0, 3}},       {"B30", {3, 0}},
           {"B13", {1, 3}},    {"B31", {3, 1}},  {"B23signed", {2, 3}}, {"B32signed", {3, 2}}})
    s.operator_input(name, rank.first, rank.second);

  std::vector<OperatorStep> encoders;
  for (int r : {0, 1, 2, 4}) {
    const auto x = "x" + std::to_string(r);
    if (!inputs.count(x)) continue;
    encoders.push_back(
        into(r)
            .sum(from(r, x).mlp(M("encoder_" + std::to_string(r)), options(inputs.at(x), D)))
            .named("encoder_" + std::to_string(r)));
  }
  const auto enc3 = [&] { return options(kFeatureWidth[3], D); };
  encoders.push_back(
      into(3, "minus").sum(from(3, "x3").mlp(M("encoder_3"), enc3())).named("encoder_3_minus"));
  encoders.push_back(
      into(3, "plus")
          .sum(opt.mode() == FeatureMode::reference
                   ? from(3, "x3").apply(ContactPlusView()).mlp(M("encoder_3"), enc3())
                   : from(3, "x3_plus").mlp(M("encoder_3"), enc3()))
          .named("encoder_3_plus"));
  s.parallel(encoders);

  for (int l = 0; l < opt.num_layers(); ++l) {
    const std::string L = "layer" + std::to_string(l) + "_";
    s.layer("layer" + std::to_string(l));
    if (arch == Architecture::no_sequential) {
      // The messages from both contact views, summed, into scratch states (read below).
      // (B32signed weighted by its signs, B30 and B31 plain sums.)
      const auto both_views = [&](int rank, const std::string& op, bool weighted) {
        const auto module = L + "3to" + std::to_string(rank);
        auto plus = message(3, "plus", module), minus = message(3, "minus", module);
        if (weighted)
          plus.via(op), minus.via(op);
        else
          plus.pattern(op), minus.pattern(op);
        return into(rank, "from_contacts")
            .sum(plus, minus)
            .named(L + "contacts_to_" + std::to_string(rank));
      };
      s.parallel({both_views(2, "B32signed", true), both_views(0, "B30", false),
                  both_views(1, "B31", false)});
      const auto contact = [&](const char* view) {
        return update(self_and(3, view,
                               {message(0, "", L + "0to3").pattern("B03"),
                                message(1, "", L + "1to3").pattern("B13"),
                                message(2, "", L + "2to3").via("B23signed")}),
                      L + "3")
            .named(L + "contacts_" + view);
      };
      // Rank r's update from ranks 0, 1 and 2 over ops[0..2] and, below the objects, the contacts'
      // sum and the objects over ops[3]: the reference's concatenation order.
      const auto from_all = [&](int r, const std::array<const char*, 4>& ops, const char* name) {
        const auto R = std::to_string(r);
        std::vector<Term> terms;
        for (int q : {0, 1, 2})
          terms.push_back(message(q, "", L + std::to_string(q) + "to" + R)
                              .pattern(ops[static_cast<std::size_t>(q)],
                                       r == 4 && q < 2 ? Aggr::mean : Aggr::sum));
        if (r != 4) {
          terms.push_back(from(r, "from_contacts"));
          terms.push_back(message(4, "", L + "4to" + R).pattern(ops[3]));
        }
        return update(self_and(r, "", std::move(terms)), L + R).named(L + name);
      };
      s.parallel({contact("minus"), contact("plus"),
                  from_all(2, {"B02", "B12", "A232", "B42"}, "faces"),
                  from_all(0, {"A010", "B10", "B20", "B40"}, "nodes"),
                  from_all(1, {"B01", "A101", "B21", "B41"}, "edges"),
                  from_all(4, {"B04", "B14", "B24", ""}, "objects")});
      continue;
    }
    const bool objects = arch == Architecture::hopnet;
    std::vector<Term> to_faces{message(0, "", L + "0to2").pattern("B02"),
                               message(1, "", L + "1to2").pattern("B12")};
    if (objects) to_faces.push_back(message(4, "", L + "4to2").pattern("B42"));
    s.step(update(self_and(2, "", to_faces), L + "2").named(L + "faces"));
    s.parallel({update(self_and(3, "plus",
                                {message(2, "", L + "2to3").via("B23neg"),
                                 message(2, "", L + "2to3").via("B23pos")}),
                       L + "3")
                    .named(L + "contacts_plus"),
                update(self_and(3, "minus",
                                {message(2, "", L + "2to3").via("B23pos"),
                                 message(2, "", L + "2to3").via("B23neg")}),
                       L + "3")
                    .named(L + "contacts_minus")});
    // Each face sums the contact cells it takes part in, from its own side.
    s.step(
        into(2, "from_contacts")
            .sum(from(3, "plus").pattern("B32").only(1), from(3, "minus").pattern("B32").only(-1))
            .named(L + "contacts_to_faces"));
    s.step(update(self_and(2, "", {from(2, "from_contacts")}), L + "2p")
               .named(L + "faces_from_contacts"));
    if (!objects) {
      s.step(update(self_and(0, "", {message(2, "", L + "2to0").pattern("B20")}), L + "0")
                 .when_nonempty(3)
                 .named(L + "nodes_from_faces"));
      s.step(update(self_and(0, "", {message(0, "", L + "0to0").pattern("A010")}), L + "0p")
                 .named(L + "nodes_from_nodes"));
      continue;
    }
    s.step(update(self_and(4, "", {message(2, "", L + "2to4").pattern("B24", Aggr::mean)}), L + "4")
               .when_nonempty(3)
               .named(L + "objects_from_faces"));
    s.parallel(
        {update(self_and(0, "", {message(4, "", L + "4to0").pattern("B40")}), L + "0")
             .named(L + "nodes_from_objects"),
         update(self_and(4, "", {message(0, "", L + "0to4").pattern("B04", Aggr::mean)}), L + "4p")
             .named(L + "objects_from_nodes")});
  }
  const auto decoder = options(D, 3).final_activation(false).layer_norm(false);
  s.step(into(0, "a0").sum(from(0).mlp(M("decoder_0"), decoder)).named("decoder_0"));
  s.output("a0", 0, "a0");
  if (arch != Architecture::no_object_cells) {
    s.step(into(4, "a4").sum(from(4).mlp(M("decoder_4"), decoder)).named("decoder_4"));
    s.output("a4", 4, "a4");
  }
  return s;
}

}  // namespace topos::models::hopnet
