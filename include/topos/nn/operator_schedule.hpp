// topos/nn/operator_schedule.hpp
// The operator schedule: a message-passing network over named sparse operators (incidences,
// adjacencies, Laplacians with their values) written as data, the way TopoModelX's models are
// written as layers of convolutions. The zoo's models are schedules of this kind.
//
//   using namespace topos::nn;
//   using namespace topos::nn::ops;
//   OperatorSchedule s;
//   s.input("x_0", 0, 8).input("x_1", 1, 4)                  // cochains fed by name
//    .operator_input("adjacency_1", 1, 1)                     // source rank -> target rank
//    .operator_input("incidence_1", 1, 0);                    // B_1: nodes × edges, 1 -> 0
//   s.step(into(1).sum(from(1).conv("conv_1_to_1", 16).via("adjacency_1").act(Activation::elu),
//                      from(0).conv("conv_0_to_1", 16).via_t("incidence_1"))
//                 .linear("update", 16).act(Activation::relu));   // after the messages are mixed
//   s.step(into(1).filter("weight", 16,                       // Σ_k T_k W[:, :, k] over the terms
//                         from(1).powers({{"laplacian_down_1", 2}, {"laplacian_up_1", 2}})));
//   s.output("x_1", 1);
//   OperatorNetwork net(s);                                   // validated here
//   auto out = net->forward({{"x_0", x0}, {"x_1", x1}}, {{"adjacency_1", A1},
//                            {"incidence_1", B1}, {"laplacian_down_1", L_down_1},
//                            {"laplacian_up_1", L_up_1}});   // outputs by name: out["x_1"]
//
// A term starts at a cochain (rank, state) and applies its operations in order: operators
// (`via`, `via_t` for the transpose, `pattern` for the sparsity pattern alone), learned maps
// (`conv`/`weight`: x·W with W in × out, TopoModelX's Conv layout; `linear`: torch.nn.Linear;
// `head_weights`, `bias`, `scale` by a learned or buffered scalar), activations, dropout,
// attention (`attend`: GAT scores, one or several heads, keys and queries from other cochains),
// `pow`, `normalize`, and last, optionally, a polynomial filter (`powers`) that fans
// the term out into [y, A y, ..., A^K y]. A step mixes its terms (sum, mean, concatenation, or a
// filter weight over all of them), applies its own operations, and writes the target cochain.
// Steps run in sequence; a parallel group reads one snapshot (a layer that updates every rank at
// once). A buffer (a scale that is not trained) is saved at its path like a parameter.
//
// Parameters are created at the dotted paths the schedule names ("layers.0.conv_0_to_0.weight"),
// with their shapes inferred from the channels, so a TopoModelX state_dict loads by its own
// names; a path used twice is one shared parameter. Building the network checks every step:
// unknown cochains, inputs or operators, operators applied to the wrong rank, terms of mismatched
// channels or ranks, a parameter path reused with another shape; each error names the step.
//
// The language's parts: the vocabulary and the schedule (operator_schedule/builder.hpp), the
// network that checks and runs it (network.hpp), its shape inference (build-inl.hpp), its
// interpreter (interpreter-inl.hpp) and its printer (printer-inl.hpp); the `-inl` files are
// compiled into topos::nn unless TOPOS_HEADER_ONLY (topos/config.hpp).
#pragma once

#include "topos/nn/operator_schedule/builder.hpp"
#include "topos/nn/operator_schedule/network.hpp"
#include "topos/nn/cloneable.hpp"  // the models built on OperatorNetwork are Cloneable
