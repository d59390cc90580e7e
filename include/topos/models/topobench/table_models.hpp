// topos/models/topobench/table_models.hpp
// The backbones of TopoBench's table by name, as TopoBenchModel's backbones (topobench/model.hpp):
// GCN, AllSetTransformer, EDGNN, UniGNN2 = UniGCNII, CWN, CCCN, CCXN, SCN = SCN2, SCCN,
// SCCNN = TopoBench's SCCNNCustom, and TopoTune's GCCN, each an operator schedule of the zoo with
// its rank layout from model_specs() (protocol.hpp). This header includes the eleven models; a
// file that trains its own backbone includes model.hpp and trainer.hpp alone.
//   TopoBenchModel m(TopoBenchModelOptions(table_backbone("CWN"), {7, 4, 4}, 32, 2));
// Adding a backbone to the table: its ModelSpec row in protocol.hpp and its entry in
// table_backbones() below.
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
#include "topos/models/topobench/protocol.hpp"  // model_spec

#include <string>
#include <vector>

namespace topos::models::topobench {

/// A table backbone: its network at the hidden width (inputs and outputs x_r) and, where its
/// wrapper hands it operators under other names, the renaming.
struct TableBackbone {
  const char* name;  ///< a ModelSpec's name
  nn::OperatorNetwork (*network)(const BackboneContext&);
  NamedOperators (*operators)(const NamedOperators&, const BackboneContext&) = nullptr;
};

inline const std::vector<TableBackbone>& table_backbones() {
  using C = const BackboneContext&;
  using Ops = const NamedOperators&;
  static const std::vector<TableBackbone> all = {
      {"GCN",
       [](C c) {
         return nn::OperatorNetwork(
             gcn_schedule(GCNOptions(c.hidden, c.hidden).num_layers(c.n_layers)));
       }},
      {"AllSetTransformer",
       [](C c) {
         return nn::OperatorNetwork(
             allset_transformer_schedule(AllSetTransformerOptions(c.hidden, c.hidden)
                                             .n_layers(c.n_layers)
                                             .heads(4)
                                             .dropout(0)
                                             .mlp_num_layers(1)
                                             .mlp_dropout(0)));
       }},
      {"EDGNN",
       [](C c) {
         nn::OperatorNetwork net(edgnn_schedule(EDGNNOptions(c.hidden).n_layers(c.n_layers)));
         reset_edgnn_parameters(*net, c.hidden);
         return net;
       }},
      {"UniGNN2",
       [](C c) {
         return nn::OperatorNetwork(
             unigcnii_schedule(UniGCNIIOptions(c.hidden, c.hidden)
                                   .n_layers(c.n_layers)
                                   .input_drop(0)
                                   .layer_drop(0)
                                   .topomodelx_compatible(c.topobench_compatible)));
       }},
      {"CWN",
       [](C c) {
         return nn::OperatorNetwork(
             cwn_schedule(CWNOptions(c.hidden, c.hidden, c.hidden, c.hidden, c.n_layers)));
       }},
      {"CCCN",
       [](C c) {
         return nn::OperatorNetwork(cccn_schedule(CCCNOptions(c.hidden).n_layers(c.n_layers)));
       }},
      {"CCXN",
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
      {"SCN",
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
      {"SCCN",
       [](C c) {
         return nn::OperatorNetwork(sccn_schedule(
             SCCNOptions(c.hidden, 2).n_layers(c.n_layers).update_func(nn::Update::sigmoid)));
       },
       // ... and SCCN the plain Hodge Laplacians as its same-rank operators.
       [](Ops batch, C) {
         auto ops = batch;
         for (int r = 0; r < 3; ++r)
           ops["adjacency_" + std::to_string(r)] = ops.at("hodge_laplacian_" + std::to_string(r));
         return ops;
       }},
      {"SCCNN",
       [](C c) {
         return nn::OperatorNetwork(
             sccnn_custom_schedule(SCCNNCustomOptions(c.hidden)
                                       .n_layers(c.n_layers)
                                       .topobench_compatible(c.topobench_compatible)));
       }},
      {"GCCN", [](C c) {
         return nn::OperatorNetwork(gccn_schedule(
             GCCNOptions(c.hidden, topotune_cell_neighborhoods()).n_layers(c.n_layers)));
       }}};
  return all;
}

/// The table's backbone `name` (a name of model_specs(); anything else is an error listing them).
inline Backbone table_backbone(const std::string& name) {
  const ModelSpec& spec = model_spec(name);
  const TableBackbone& t = find_name(table_backbones(), name, "TopoBench model");
  Backbone b = Backbone::network(spec.name, rank_layout(spec), t.network);
  if (t.operators) b.operators(t.operators);
  return b;
}

}  // namespace topos::models::topobench
