// topos/models/zoo/simplicial_and_cell.hpp
// Most of the zoo's simplicial models (SCNN, HSN, SCConv, SCoNe, SCCN, Dist2Cycle, SCA-CMPS) and
// its cell models CAN and CCXN: how each is built from its config and called.
#pragma once

#include "topos/models/cell/can.hpp"
#include "topos/models/cell/ccxn.hpp"
#include "topos/models/simplicial/dist2cycle.hpp"
#include "topos/models/simplicial/hsn.hpp"
#include "topos/models/simplicial/sca_cmps.hpp"
#include "topos/models/simplicial/sccn.hpp"
#include "topos/models/simplicial/scconv.hpp"
#include "topos/models/simplicial/scnn.hpp"
#include "topos/models/simplicial/scone.hpp"
#include "topos/models/zoo/arguments.hpp"
#include "topos/models/zoo/config.hpp"

#include <map>
#include <optional>
#include <string>
#include <vector>

namespace topos::models::zoo::detail {

/// SCNN, HSN, SCConv, SCoNe, SCCN, Dist2Cycle, SCA-CMPS (simplicial); CAN, CCXN (cell).
inline std::map<std::string, Maker> more_simplicial_and_cell_makers() {
  using nn::Activation;
  return {
      {"SCNN",
       [](Config& c, bool compatible) {
         SCNN net(SCNNOptions(c.need<std::int64_t>("in_channels"),
                              c.need<std::int64_t>("hidden_channels"),
                              c.need<int>("conv_order_down"), c.need<int>("conv_order_up"))
                      .aggr_norm(c.get("aggr_norm", false))
                      .update_func(c.update("update_func", Activation::none))
                      .n_layers(c.get("n_layers", 2))
                      .topomodelx_compatible(compatible));
         return wrap<SCNN>(
             "SCNN", net,
             [](SCNN& n, const Args& a) {
               // A Laplacian of order 0 may be None (TopoModelX's SCNN ignores it).
               return std::vector<torch::Tensor>{
                   n->forward(a.tensor(0), a.op_or_none(1), a.op_or_none(2))};
             },
             3, 3);
       }},
      {"HSN",
       [](Config& c, bool) {
         HSN net(HSNOptions(c.need<std::int64_t>("channels")).n_layers(c.get("n_layers", 2)));
         return wrap<HSN>(
             "HSN", net,
             [](HSN& n, const Args& a) {
               return std::vector<torch::Tensor>{n->forward(a.tensor(0), a.op(1), a.op(2))};
             },
             3, 3);
       }},
      {"SCConv",
       [](Config& c, bool) {
         SCConv net(SCConvOptions(c.need<std::int64_t>("node_channels"))
                        .edge_channels(c.get<std::int64_t>("edge_channels", 0))
                        .face_channels(c.get<std::int64_t>("face_channels", 0))
                        .n_layers(c.get("n_layers", 2)));
         return wrap<SCConv>(
             "SCConv", net,
             [](SCConv& n, const Args& a) {
               return n->forward({a.tensor(0), a.tensor(1), a.tensor(2)},
                                 SCConvOperators{a.op(3), a.op(4), a.op(5), a.op(6), a.op(7),
                                                 a.op(8), a.op(9), a.op(10)});
             },
             11, 11);
       }},
      {"SCoNe",
       [](Config& c, bool) {
         SCoNe net(SCoNeOptions(c.need<std::int64_t>("in_channels"),
                                c.need<std::int64_t>("hidden_channels"), c.need<int>("n_layers")));
         return wrap<SCoNe>(
             "SCoNe", net,
             [](SCoNe& n, const Args& a) {
               return std::vector<torch::Tensor>{n->forward(a.tensor(0), a.op(1), a.op(2))};
             },
             3, 3);
       }},
      {"SCCN",
       [](Config& c, bool) {
         const auto update = c.is_null("update_func")
                                 ? Activation::none
                                 : c.update("update_func", Activation::sigmoid);
         c.get<std::string>("update_func", "");  // read (null)
         SCCN net(SCCNOptions(c.need<std::int64_t>("channels"), c.need<int>("max_rank"))
                      .n_layers(c.get("n_layers", 2))
                      .update_func(update));
         const int R = net->options.max_rank();
         return wrap<SCCN>(
             "SCCN", net,
             [R](SCCN& n, const Args& a) {
               return n->forward(a.tensors(0, "rank_", 0, R), a.ops(1, "rank_", 1, R),
                                 a.ops(2, "rank_", 0, R));
             },
             3, 3);
       }},
      {"Dist2Cycle",
       [](Config& c, bool compatible) {
         Dist2Cycle net(Dist2CycleOptions(c.need<std::int64_t>("channels"))
                            .n_layers(c.get("n_layers", 2))
                            .topomodelx_compatible(compatible));
         return wrap<Dist2Cycle>(
             "Dist2Cycle", net,
             [](Dist2Cycle& n, const Args& a) {
               return std::vector<torch::Tensor>{n->forward(a.tensor(0), a.op(1), a.op(2))};
             },
             3, 3);
       }},
      {"SCACMPS",
       [](Config& c, bool compatible) {
         SCACMPS net(SCACMPSOptions(c.need<std::vector<std::int64_t>>("in_channels_all"),
                                    c.need<int>("complex_dim"))
                         .n_layers(c.get("n_layers", 2))
                         .att(c.get("att", false))
                         .topomodelx_compatible(compatible));
         return wrap<SCACMPS>(
             "SCACMPS", net,
             [](SCACMPS& n, const Args& a) { return n->forward(a.tensors(0), a.ops(1), a.ops(2)); },
             3, 3);
       }},
      {"CAN",
       [](Config& c, bool compatible) {
         const auto act =
             torch_activation(c, "att_activation",
                              std::nullopt);  // None: LeakyReLU(0.2); a named class: its defaults
         CAN net(CANOptions(c.need<std::int64_t>("in_channels_0"),
                            c.need<std::int64_t>("in_channels_1"),
                            c.need<std::int64_t>("out_channels"))
                     .dropout(c.get("dropout", 0.5))
                     .heads(c.get<std::int64_t>("heads", 2))
                     .concat(c.get("concat", true))
                     .skip_connection(c.get("skip_connection", true))
                     .att_activation(act.value_or(Activation::leaky_relu))
                     .att_negative_slope(act ? 0.01 : 0.2)
                     .n_layers(c.get("n_layers", 2))
                     .att_lift(c.get("att_lift", true))
                     .version(c.get<std::string>("version", "v1"))
                     .share_weights(c.get("share_weights", false))
                     .add_self_loops(c.get("add_self_loops", true))
                     .pooling(c.get("pooling", false))
                     .k_pool(c.get("k_pool", 0.5))
                     .topomodelx_compatible(compatible));
         return wrap<CAN>(
             "CAN", net,
             [](CAN& n, const Args& a) {
               return std::vector<torch::Tensor>{
                   n->forward(a.tensor(0), a.tensor(1), a.op(2), a.op(3), a.op(4))};
             },
             5, 5);
       }},
      {"CCXN",
       [](Config& c, bool compatible) {
         CCXN net(CCXNOptions(c.need<std::int64_t>("in_channels_0"),
                              c.need<std::int64_t>("in_channels_1"),
                              c.need<std::int64_t>("in_channels_2"))
                      .n_layers(c.get("n_layers", 2))
                      .att(c.get("att", false))
                      .topomodelx_compatible(compatible));
         return wrap<CCXN>(
             "CCXN", net,
             [](CCXN& n, const Args& a) {
               return n->forward(a.tensor(0), a.tensor(1), a.op(2), a.op(3));
             },
             4, 4);
       }},
  };
}

}  // namespace topos::models::zoo::detail
