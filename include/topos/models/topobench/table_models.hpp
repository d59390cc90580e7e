// topos/models/topobench/table_models.hpp
// The models of TopoBench's table by name, each registered once here with what the pipeline needs
// (its ModelSpec: config, domain, ranks, operators) and its backbone as TopoBenchModel's
// (topobench/model.hpp): GCN, AllSetTransformer, EDGNN, UniGNN2 = UniGCNII, CWN, CCCN, CCXN,
// SCN = SCN2, SCCN, SCCNN = TopoBench's SCCNNCustom, and TopoTune's GCCN, each an operator
// schedule of the zoo. This header includes the eleven models; a file that trains its own
// backbone includes model.hpp and trainer.hpp alone.
//   TopoBenchModel m(TopoBenchModelOptions(table_backbone("CWN"), {7, 4, 4}, 32, 2));
// Adding a model to the table (`tdl topobench --models NAME`): one entry in table_backbones()
// below (docs/topobench.md).
#pragma once

#include "topos/models/cell/cccn.hpp"
#include "topos/models/cell/ccxn.hpp"
#include "topos/models/cell/cwn.hpp"
#include "topos/models/combinatorial/gccn.hpp"
#include "topos/models/graph/gcn.hpp"
#include "topos/models/hypergraph/allset_transformer.hpp"
#include "topos/models/hypergraph/edgnn.hpp"
#include "topos/models/hypergraph/unigcnii.hpp"
#include "topos/models/simplicial/sccn.hpp"
#include "topos/models/simplicial/sccnn_custom.hpp"
#include "topos/models/simplicial/scn2.hpp"
#include "topos/models/topobench/model.hpp"
#include "topos/models/topobench/protocol.hpp"  // ModelSpec, find_name

#include <string>
#include <vector>

namespace topos::models::topobench {

/// A table model: its spec (the row's name, config, domain, ranks, operators) and its backbone's
/// network at the hidden width (inputs and outputs x_r) and, where its wrapper hands it operators
/// under other names, the renaming.
struct TableBackbone : ModelSpec {
  nn::OperatorNetwork (*network)(const BackboneContext&);
  NamedOperators (*operators)(const NamedOperators&, const BackboneContext&) = nullptr;
};

inline const std::vector<TableBackbone>& table_backbones() {
  using C = const BackboneContext&;
  using Ops = const NamedOperators&;
  static const std::vector<TableBackbone> all = {
      {{"GCN", "graph/gcn", Domain::graph, {0}, 1, {"gcn_adjacency"}},
       [](C c) {
         return nn::OperatorNetwork(
             gcn_schedule(GCNOptions(c.hidden, c.hidden).num_layers(c.n_layers)));
       }},
      {{"AllSetTransformer",
        "hypergraph/allsettransformer",
        Domain::hypergraph,
        {0},
        1,
        {"incidence_1"}},
       [](C c) {
         return nn::OperatorNetwork(
             allset_transformer_schedule(AllSetTransformerOptions(c.hidden, c.hidden)
                                             .n_layers(c.n_layers)
                                             .heads(4)
                                             .dropout(0)
                                             .mlp_num_layers(1)
                                             .mlp_dropout(0)));
       }},
      {{"EDGNN", "hypergraph/edgnn", Domain::hypergraph, {0}, 1, {"incidence_1", "node_degree"}},
       [](C c) {
         nn::OperatorNetwork net(edgnn_schedule(EDGNNOptions(c.hidden).n_layers(c.n_layers)));
         reset_edgnn_parameters(*net, c.hidden);
         return net;
       }},
      {{"UniGNN2",
        "hypergraph/unignn2",
        Domain::hypergraph,
        {0},
        1,
        {"incidence_1", "incidence_1_norm"}},
       [](C c) {
         return nn::OperatorNetwork(
             unigcnii_schedule(UniGCNIIOptions(c.hidden, c.hidden)
                                   .n_layers(c.n_layers)
                                   .input_drop(0)
                                   .layer_drop(0)
                                   .topomodelx_compatible(c.topobench_compatible)));
       }},
      {{"CWN",
        "cell/cwn",
        Domain::cell,
        {0, 1, 2},
        3,
        {"adjacency_1", "incidence_1", "incidence_2", "incidence_1_t"}},
       [](C c) {
         return nn::OperatorNetwork(
             cwn_schedule(CWNOptions(c.hidden, c.hidden, c.hidden, c.hidden, c.n_layers)));
       }},
      {{"CCCN",
        "cell/cccn",
        Domain::cell,
        {0, 1},
        2,
        {"incidence_1", "up_laplacian_1_gcn", "down_laplacian_1_gcn"}},
       [](C c) {
         return nn::OperatorNetwork(cccn_schedule(CCCNOptions(c.hidden).n_layers(c.n_layers)));
       }},
      {{"CCXN",
        "cell/ccxn",
        Domain::cell,
        {0, 1, 2},
        3,
        {"adjacency_0", "incidence_1", "incidence_2", "incidence_2_t"}},
       [](C c) {
         return nn::OperatorNetwork(
             ccxn_schedule(CCXNOptions(c.hidden, c.hidden, c.hidden)
                               .n_layers(c.n_layers)
                               .att(true)
                               .topomodelx_compatible(c.topobench_compatible)));
       },
       // TopoModelX's compatible attention scores 2-cell i with edge i of the whole batch.
       [](Ops batch, C c) {
         auto ops = batch;
         const auto& bt = ops.at("incidence_2_t");
         ops["incidence_2_t_target"] =
             c.topobench_compatible
                 ? nn::SparseOperator::selection(torch::arange(bt.rows), bt.cols, torch::kFloat)
                 : bt;
         return ops;
       }},
      {{"SCN",
        "simplicial/scn",
        Domain::simplicial,
        {0, 1, 2},
        3,
        {"incidence_1", "incidence_2", "hodge_laplacian_0_norm", "hodge_laplacian_1_norm",
         "hodge_laplacian_2_norm"}},
       [](C c) {
         return nn::OperatorNetwork(
             scn2_schedule(SCN2Options(c.hidden, c.hidden, c.hidden).n_layers(c.n_layers)));
       },
       // TopoBench's wrapper hands SCN the normalised Hodge Laplacians.
       [](Ops batch, C) {
         auto ops = batch;
         for (int r = 0; r < 3; ++r)
           ops["laplacian_" + std::to_string(r)] =
               ops.at("hodge_laplacian_" + std::to_string(r) + "_norm");
         return ops;
       }},
      {{"SCCN",
        "simplicial/sccn",
        Domain::simplicial,
        {0, 1, 2},
        3,
        {"incidence_1", "incidence_2", "hodge_laplacian_0", "hodge_laplacian_1",
         "hodge_laplacian_2"}},
       [](C c) {
         return nn::OperatorNetwork(sccn_schedule(
             SCCNOptions(c.hidden, 2).n_layers(c.n_layers).update_func(nn::Activation::sigmoid)));
       },
       // ... and SCCN the plain Hodge Laplacians as its same-rank operators.
       [](Ops batch, C) {
         auto ops = batch;
         for (int r = 0; r < 3; ++r)
           ops["adjacency_" + std::to_string(r)] = ops.at("hodge_laplacian_" + std::to_string(r));
         return ops;
       }},
      {{"SCCNN",
        "simplicial/sccnn_custom",
        Domain::simplicial,
        {0, 1, 2},
        3,
        {"incidence_1", "incidence_2", "hodge_laplacian_0", "down_laplacian_1", "up_laplacian_1",
         "down_laplacian_2", "up_laplacian_2"}},
       [](C c) {
         return nn::OperatorNetwork(
             sccnn_custom_schedule(SCCNNCustomOptions(c.hidden)
                                       .n_layers(c.n_layers)
                                       .topobench_compatible(c.topobench_compatible)));
       }},
      // GCCN (TopoTune) with topotune.yaml's cell routes; incidence_r for the readout.
      {{"GCCN",
        "cell/topotune",
        Domain::cell,
        {0, 1, 2},
        3,
        [] {
          std::set<std::string> ops(topotune_cell_neighborhoods().begin(),
                                    topotune_cell_neighborhoods().end());
          ops.insert({"incidence_1", "incidence_2"});
          return ops;
        }()},
       [](C c) {
         return nn::OperatorNetwork(gccn_schedule(
             GCCNOptions(c.hidden, topotune_cell_neighborhoods()).n_layers(c.n_layers)));
       }}};
  return all;
}

/// The table's models' specs, in the table's order.
inline const std::vector<ModelSpec>& model_specs() {
  static const std::vector<ModelSpec> specs(table_backbones().begin(), table_backbones().end());
  return specs;
}
/// The spec of the table's model `name` (anything else is an error listing the names).
inline const ModelSpec& model_spec(const std::string& name) {
  return find_name(table_backbones(), name, "TopoBench model");
}
/// The table's models' names, in the table's order (the report's rows: RunsFolder).
inline std::vector<std::string> table_model_names() {
  std::vector<std::string> names;
  for (const auto& t : table_backbones()) names.emplace_back(t.name);
  return names;
}

/// The table's backbone `name` (a name of table_backbones(); anything else is an error listing
/// them).
inline Backbone table_backbone(const std::string& name) {
  const TableBackbone& t = find_name(table_backbones(), name, "TopoBench model");
  Backbone b = Backbone::network(t.name, rank_layout(t), t.network);
  if (t.operators) b.operators(t.operators);
  return b;
}

}  // namespace topos::models::topobench
