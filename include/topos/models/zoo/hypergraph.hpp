// topos/models/zoo/hypergraph.hpp
// The zoo's hypergraph models (AllSet, AllSetTransformer, HNHN, HyperGAT, HyperSAGE, UniGCN,
// UniGIN, UniSAGE, HMPNN): how each is built from its config and called.
#pragma once

#include "topos/models/hypergraph/allset.hpp"
#include "topos/models/hypergraph/allset_transformer.hpp"
#include "topos/models/hypergraph/hmpnn.hpp"
#include "topos/models/hypergraph/hnhn.hpp"
#include "topos/models/hypergraph/hypergat.hpp"
#include "topos/models/hypergraph/hypersage.hpp"
#include "topos/models/hypergraph/unigcn.hpp"
#include "topos/models/hypergraph/unigin.hpp"
#include "topos/models/hypergraph/unisage.hpp"
#include "topos/models/zoo/arguments.hpp"
#include "topos/models/zoo/config.hpp"

#include <map>
#include <optional>
#include <string>

namespace topos::models::zoo::detail {

/// The hypergraph models: forward(x_0, incidence_1) (HMPNN: x_0, x_1, incidence_1).
inline std::map<std::string, Maker> hypergraph_makers() {
  using nn::Activation;
  return {
      {"AllSet",
       [](Config& c, bool compatible) {
         AllSet net(AllSetOptions(c.need<std::int64_t>("in_channels"),
                                  c.need<std::int64_t>("hidden_channels"))
                        .n_layers(c.get("n_layers", 2))
                        .layer_dropout(c.get("layer_dropout", 0.2))
                        .mlp_num_layers(c.get("mlp_num_layers", 2))
                        .mlp_activation(torch_activation(c, "mlp_activation", std::nullopt))
                        .mlp_dropout(c.get("mlp_dropout", 0.0))
                        .mlp_norm(torch_norm(c, "mlp_norm"))
                        .topomodelx_compatible(compatible));
         return wrap<AllSet>(
             "AllSet", net,
             [](AllSet& n, const Args& a) { return n->forward(a.tensor(0), a.op(1)); }, 2, 2);
       }},
      {"AllSetTransformer",
       [](Config& c, bool) {
         AllSetTransformer net(
             AllSetTransformerOptions(c.need<std::int64_t>("in_channels"),
                                      c.need<std::int64_t>("hidden_channels"))
                 .n_layers(c.get("n_layers", 1))
                 .heads(c.get("heads", 4))
                 .number_queries(c.get("number_queries", 1))
                 .dropout(c.get("dropout", 0.2))
                 .mlp_num_layers(c.get("mlp_num_layers", 2))
                 .mlp_activation(torch_activation(c, "mlp_activation", Activation::relu))
                 .mlp_dropout(c.get("mlp_dropout", 0.2))
                 .mlp_norm(torch_norm(c, "mlp_norm")));
         return wrap<AllSetTransformer>(
             "AllSetTransformer", net,
             [](AllSetTransformer& n, const Args& a) { return n->forward(a.tensor(0), a.op(1)); },
             2, 2);
       }},
      {"HNHN",
       [](Config& c, bool) {
         if (c.has("incidence_1"))
           throw ZooError(
               "HNHN: config 'incidence_1' must be null (pass the incidence to forward)");
         c.get<std::string>("incidence_1", "");  // null: read
         initialization_of(c, "bias_init", "xavier_uniform", {"xavier_uniform", "xavier_normal"});
         HNHN net(HNHNOptions(c.need<std::int64_t>("in_channels"),
                              c.need<std::int64_t>("hidden_channels"))
                      .n_layers(c.get("n_layers", 2))
                      .layer_drop(c.get("layer_drop", 0.2))
                      .use_bias(c.get("use_bias", true))
                      .use_normalized_incidence(c.get("use_normalized_incidence", true))
                      .alpha(c.get("alpha", -1.5))
                      .beta(c.get("beta", -0.5))
                      .bias_gain(c.get("bias_gain", 1.414)));
         return wrap<HNHN>(
             "HNHN", net, [](HNHN& n, const Args& a) { return n->forward(a.tensor(0), a.op(1)); },
             2, 2);
       }},
      {"HyperGAT",
       [](Config& c, bool compatible) {
         initialization_of(c, "initialization", "xavier_uniform",
                           {"xavier_uniform", "xavier_normal"});
         HyperGAT net(HyperGATOptions(c.need<std::int64_t>("in_channels"),
                                      c.need<std::int64_t>("hidden_channels"))
                          .n_layers(c.get("n_layers", 2))
                          .layer_drop(c.get("layer_drop", 0.2))
                          .update_func(c.update("update_func", Activation::relu))
                          .initialization_gain(c.get("initialization_gain", 1.414))
                          .topomodelx_compatible(compatible));
         return wrap<HyperGAT>(
             "HyperGAT", net,
             [](HyperGAT& n, const Args& a) { return n->forward(a.tensor(0), a.op(1)); }, 2, 2);
       }},
      {"HyperSAGE",
       [](Config& c, bool compatible) {
         const auto init = initialization_of(c, "initialization", "uniform",
                                             {"uniform", "xavier_uniform", "xavier_normal"});
         if (c.get<std::string>("device", "cpu") != "cpu")
           throw ZooError("HyperSAGE: config 'device' must be \"cpu\"");
         HyperSAGE net(HyperSAGEOptions(c.need<std::int64_t>("in_channels"),
                                        c.need<std::int64_t>("hidden_channels"))
                           .n_layers(c.get("n_layers", 2))
                           .alpha(c.get("alpha", -1))
                           .update_func(c.update("update_func", Activation::relu))
                           .uniform_initialization(init == "uniform")
                           .topomodelx_compatible(compatible));
         return wrap<HyperSAGE>(
             "HyperSAGE", net,
             [](HyperSAGE& n, const Args& a) { return n->forward(a.tensor(0), a.op(1)); }, 2, 2);
       }},
      {"UniGCN",
       [](Config& c, bool compatible) {
         UniGCN net(UniGCNOptions(c.need<std::int64_t>("in_channels"),
                                  c.need<std::int64_t>("hidden_channels"))
                        .n_layers(c.get("n_layers", 2))
                        .aggr_norm(c.get("aggr_norm", false))
                        .use_bn(c.get("use_bn", false))
                        .topomodelx_compatible(compatible));
         return wrap<UniGCN>(
             "UniGCN", net,
             [](UniGCN& n, const Args& a) { return n->forward(a.tensor(0), a.op(1)); }, 2, 2);
       }},
      {"UniGIN",
       [](Config& c, bool compatible) {
         UniGIN net(UniGINOptions(c.need<std::int64_t>("in_channels"),
                                  c.need<std::int64_t>("hidden_channels"))
                        .n_layers(c.get("n_layers", 2))
                        .input_drop(c.get("input_drop", 0.2))
                        .layer_drop(c.get("layer_drop", 0.2))
                        .eps(c.get("eps", 0.0))
                        .train_eps(c.get("train_eps", false))
                        .use_norm(c.get("use_norm", false))
                        .topomodelx_compatible(compatible));
         return wrap<UniGIN>(
             "UniGIN", net,
             [](UniGIN& n, const Args& a) { return n->forward(a.tensor(0), a.op(1)); }, 2, 2);
       }},
      {"UniSAGE",
       [](Config& c, bool) {
         UniSAGE net(UniSAGEOptions(c.need<std::int64_t>("in_channels"),
                                    c.need<std::int64_t>("hidden_channels"))
                         .n_layers(c.get("n_layers", 2))
                         .input_drop(c.get("input_drop", 0.2))
                         .layer_drop(c.get("layer_drop", 0.2))
                         .e_aggr(aggr_of(c, "e_aggr", "sum"))
                         .v_aggr(aggr_of(c, "v_aggr", "mean"))
                         .use_norm(c.get("use_norm", false)));
         return wrap<UniSAGE>(
             "UniSAGE", net,
             [](UniSAGE& n, const Args& a) { return n->forward(a.tensor(0), a.op(1)); }, 2, 2);
       }},
      {"HMPNN",
       [](Config& c, bool compatible) {
         HMPNN net(HMPNNOptions(c.need<std::int64_t>("in_channels"),
                                c.need<std::int64_t>("hidden_channels"))
                       .n_layers(c.get("n_layers", 2))
                       .adjacency_dropout_rate(c.get("adjacency_dropout_rate", 0.7))
                       .regular_dropout_rate(c.get("regular_dropout_rate", 0.5))
                       .aggr_func(aggr_of(c, "aggr_func", "sum"))
                       .topomodelx_compatible(compatible));
         return wrap<HMPNN>(
             "HMPNN", net,
             [](HMPNN& n, const Args& a) { return n->forward(a.tensor(0), a.tensor(1), a.op(2)); },
             3, 3);
       }},
  };
}

}  // namespace topos::models::zoo::detail
