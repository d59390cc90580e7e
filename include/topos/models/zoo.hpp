// topos/models/zoo.hpp
// The model zoo by TopoModelX class name: builds a model from its TopoModelX constructor
// arguments (a JSON object, as in a golden case's "config"; an unknown or mistyped argument is
// an error naming it) and runs it on TopoModelX's positional forward arguments (tensors,
// operators, tuples/lists of them, None). Used by `tdl forward` / `tdl grad` and the parity tests.
// The registry is here; its pieces are in zoo/: config.hpp (reading a config), arguments.hpp
// (forward arguments, ZooModel), hypergraph.hpp and simplicial_and_cell.hpp (per-domain makers),
// all in topos::models::zoo.
#pragma once

#include "topos/models/cell/cwn.hpp"
#include "topos/models/combinatorial/hmc.hpp"
#include "topos/models/hypergraph/unigcnii.hpp"
#include "topos/models/simplicial/san.hpp"
#include "topos/models/simplicial/sccnn.hpp"
#include "topos/models/simplicial/scn2.hpp"
#include "topos/models/zoo/arguments.hpp"
#include "topos/models/zoo/config.hpp"
#include "topos/models/zoo/hypergraph.hpp"
#include "topos/models/zoo/simplicial_and_cell.hpp"

#include <nlohmann/json.hpp>

#include <map>
#include <stdexcept>
#include <string>
#include <vector>

namespace topos::models {

namespace zoo::detail {

inline const std::map<std::string, Maker>& makers() {
  static const std::map<std::string, Maker> m = [] {
    std::map<std::string, Maker> m = {
        {"SCN2",
         [](Config& c, bool) {
           SCN2 net(SCN2Options(c.need<std::int64_t>("in_channels_0"),
                                c.need<std::int64_t>("in_channels_1"),
                                c.need<std::int64_t>("in_channels_2"))
                        .n_layers(c.get("n_layers", 2)));
           return wrap<SCN2>(
               "SCN2", net,
               [](SCN2& n, const Args& a) {
                 return n->forward({a.tensor(0), a.tensor(1), a.tensor(2)},
                                   {a.op(3), a.op(4), a.op(5)});
               },
               6, 6);
         }},
        {"SCCNN",
         [](Config& c, bool) {
           SCCNN net(SCCNNOptions(c.need<std::vector<std::int64_t>>("in_channels_all"),
                                  c.need<std::vector<std::int64_t>>("hidden_channels_all"),
                                  c.need<int>("conv_order"), c.need<int>("sc_order"))
                         .aggr_norm(c.get("aggr_norm", false))
                         .update_func(c.update("update_func", nn::Activation::none))
                         .n_layers(c.get("n_layers", 2)));
           return wrap<SCCNN>(
               "SCCNN", net,
               [](SCCNN& n, const Args& a) { return n->forward(a.tensors(0), a.ops(1), a.ops(2)); },
               3, 3);
         }},
        {"SAN",
         [](Config& c, bool) {
           SAN net(SANOptions(c.need<std::int64_t>("in_channels"),
                              c.need<std::int64_t>("hidden_channels"))
                       .out_channels(c.get<std::int64_t>("out_channels", 0))
                       .n_filters(c.get("n_filters", 2))
                       .order_harmonic(c.get("order_harmonic", 5))
                       .epsilon_harmonic(c.get("epsilon_harmonic", 0.1))
                       .n_layers(c.get("n_layers", 2)));
           return wrap<SAN>(
               "SAN", net,
               [](SAN& n, const Args& a) {
                 return std::vector<torch::Tensor>{n->forward(a.tensor(0), a.op(1), a.op(2))};
               },
               3, 3);
         }},
        {"CWN",
         [](Config& c, bool) {
           CWN net(CWNOptions(c.need<std::int64_t>("in_channels_0"),
                              c.need<std::int64_t>("in_channels_1"),
                              c.need<std::int64_t>("in_channels_2"),
                              c.need<std::int64_t>("hid_channels"), c.need<int>("n_layers")));
           return wrap<CWN>(
               "CWN", net,
               [](CWN& n, const Args& a) {
                 return n->forward({a.tensor(0), a.tensor(1), a.tensor(2)}, a.op(3), a.op(4),
                                   a.op(5));
               },
               6, 6);
         }},
        {"UniGCNII",
         [](Config& c, bool compatible) {
           UniGCNII net(UniGCNIIOptions(c.need<std::int64_t>("in_channels"),
                                        c.need<std::int64_t>("hidden_channels"))
                            .n_layers(c.get("n_layers", 2))
                            .alpha(c.get("alpha", 0.5))
                            .beta(c.get("beta", 0.5))
                            .input_drop(c.get("input_drop", 0.2))
                            .layer_drop(c.get("layer_drop", 0.2))
                            .use_norm(c.get("use_norm", false))
                            .topomodelx_compatible(compatible));
           return wrap<UniGCNII>(
               "UniGCNII", net,
               [](UniGCNII& n, const Args& a) { return n->forward(a.tensor(0), a.op(1)); }, 2, 2);
         }},
        {"HMC",
         [](Config& c, bool compatible) {
           HMC net(
               HMCOptions(c.need<HMCChannels>("channels_per_layer"))
                   .negative_slope(c.get("negative_slope", 0.2))
                   .update_func_attention(c.update("update_func_attention", nn::Activation::relu))
                   .update_func_aggregation(
                       c.update("update_func_aggregation", nn::Activation::relu))
                   .topomodelx_compatible(compatible));
           return wrap<HMC>(
               "HMC", net,
               [](HMC& n, const Args& a) {
                 return n->forward({a.tensor(0), a.tensor(1), a.tensor(2)}, a.op(3), a.op(4),
                                   a.op(5), a.op(6), a.op(7));
               },
               8, 8);
         }},
    };
    m.merge(hypergraph_makers());
    m.merge(more_simplicial_and_cell_makers());
    return m;
  }();
  return m;
}

}  // namespace zoo::detail

/// TopoModelX class names the zoo builds.
inline std::vector<std::string> zoo_model_names() {
  std::vector<std::string> out;
  for (const auto& [k, v] : zoo::detail::makers()) out.push_back(k);
  return out;
}

/// Builds `model` (a TopoModelX class name) from its constructor arguments. With
/// `topomodelx_compatible`, the model reproduces TopoModelX's numbers where they differ from the
/// paper's definition (docs/models.md lists where).
inline zoo::ZooModel make_zoo_model(const std::string& model, const nlohmann::json& config,
                                    bool topomodelx_compatible = true) {
  const auto& m = zoo::detail::makers();
  auto it = m.find(model);
  if (it == m.end()) {
    std::string known;
    for (const auto& [k, v] : m) known += (known.empty() ? "" : ", ") + k;
    throw zoo::ZooError("unknown model '" + model + "' (known: " + known + ")");
  }
  zoo::detail::Config c(config, model);
  zoo::ZooModel z;
  try {
    z = it->second(c, topomodelx_compatible);
  } catch (const zoo::ZooError&) {
    throw;
  } catch (const std::exception& e) {
    throw zoo::ZooError(model + ": " + e.what());
  }
  c.finish();
  return z;
}

}  // namespace topos::models
