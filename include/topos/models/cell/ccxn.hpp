// topos/models/cell/ccxn.hpp
// CCXN (Hajij, Istvan & Zamzmi, "Cell complex neural networks", 2020; TopoModelX CCXN): per
// layer x_0 <- relu(A_0 relu(x_0) W_0) and x_2 <- relu(B_2ᵀ relu(x_1) W_1), x_1 <- relu(x_1);
// optional elu attention on each neighbourhood (Conv's att). Parameters
// layers.<i>.conv_0_to_0.* (in_channels_0 × in_channels_0), layers.<i>.conv_1_to_2.*
// (in_channels_1 × in_channels_2). x_2 is recomputed from x_1 in every layer, so only the
// last layer's rank-2 output survives (as in TopoModelX).
// With attention, TopoModelX scores a 2-cell's incoming edges with the features of the edge
// whose index is the 2-cell's (x_target = None): the compatible mode. The default scores them
// with the sum of the 2-cell's boundary edges' features (|B_2|ᵀ x_1, the same width).
// Written as an operator schedule (ccxn_schedule).
#pragma once

#include "topos/nn/operator_schedule.hpp"

namespace topos::models {

struct CCXNOptions {
  CCXNOptions(std::int64_t c0, std::int64_t c1, std::int64_t c2)
      : in_channels_0_(c0), in_channels_1_(c1), in_channels_2_(c2) {}
  TORCH_ARG(std::int64_t, in_channels_0);
  TORCH_ARG(std::int64_t, in_channels_1);
  TORCH_ARG(std::int64_t, in_channels_2);
  TORCH_ARG(int, n_layers) = 2;
  TORCH_ARG(bool, att) = false;
  TORCH_ARG(bool, topomodelx_compatible) =
      false;  ///< attention targets as TopoModelX indexes them (above)
};

/// The schedule: per layer relu(x_0), its message over the adjacency, relu(x_1), and x_2 from
/// x_1 over B_2ᵀ. With attention, a step first writes the features the 2-cells are scored with
/// into x_2 ("incidence_2_t_target": |B_2ᵀ|, or in the compatible mode the selection of the edges
/// whose indices are the 2-cells'), and each Conv's attention takes its keys from the relu'd
/// features while its messages are x W (Conv's A (x W)).
inline nn::OperatorSchedule ccxn_schedule(const CCXNOptions& o) {
  using namespace nn::ops;
  using nn::Activation;
  if (o.n_layers() < 1) throw std::invalid_argument("CCXN: n_layers must be >= 1");
  nn::OperatorSchedule s;
  s.input("x_0", 0, o.in_channels_0())
      .input("x_1", 1, o.in_channels_1())
      .operator_input("adjacency_0", 0, 0)
      .operator_input("incidence_2_t", 1, 2);
  if (o.att()) s.operator_input("incidence_2_t_target", 1, 2);
  // Conv(att=True): weights from the source cochain `keys` and the step's target (both before
  // the step), applied to x W.
  auto conv = [&](Term t, const std::string& path, std::int64_t out, const std::string& op,
                  int keys) -> Term {
    t.conv(path, out);
    if (o.att())
      t.attend(op, nn::AttendOptions(path + ".att_weight").keys(nn::CochainKey{keys, ""}));
    else
      t.via(op);
    return t;
  };
  for (int l = 0; l < o.n_layers(); ++l) {
    const auto p = "layers." + std::to_string(l) + ".";
    s.step(into(0).sum(from(0)).act(Activation::relu));
    s.step(into(0)
               .sum(conv(from(0), p + "conv_0_to_0", o.in_channels_0(), "adjacency_0", 0))
               .act(Activation::relu));
    s.step(into(1).sum(from(1)).act(Activation::relu));
    if (o.att()) s.step(into(2).sum(from(1).via("incidence_2_t_target")));
    s.step(into(2)
               .sum(conv(from(1), p + "conv_1_to_2", o.in_channels_2(), "incidence_2_t", 1))
               .act(Activation::relu));
  }
  s.output("x_0", 0).output("x_1", 1).output("x_2", 2);
  return s;
}

class CCXNImpl : public nn::Cloneable<CCXNImpl, nn::OperatorNetworkImpl> {
 public:
  explicit CCXNImpl(const CCXNOptions& o) : Cloneable(ccxn_schedule(o)), options(o) {}
  /// Node and edge features, the node adjacency and B_2ᵀ (2-cells × edges). Returns (x_0, x_1,
  /// x_2).
  std::vector<torch::Tensor> forward(const torch::Tensor& x_0, const torch::Tensor& x_1,
                                     const nn::SparseOperator& adjacency_0,
                                     const nn::SparseOperator& incidence_2_t) {
    std::map<std::string, nn::SparseOperator> ops{{"adjacency_0", adjacency_0},
                                                  {"incidence_2_t", incidence_2_t}};
    if (options.att()) {
      if (!options.topomodelx_compatible()) {
        ops["incidence_2_t_target"] = incidence_2_t.abs();
      } else {
        if (incidence_2_t.rows > x_1.size(0))
          throw std::invalid_argument(
              "CCXN: TopoModelX-compatible attention needs no more 2-cells than edges");
        ops["incidence_2_t_target"] = nn::SparseOperator::selection(
            torch::arange(incidence_2_t.rows), x_1.size(0), incidence_2_t.values.scalar_type());
      }
    }
    return run({{"x_0", x_0}, {"x_1", x_1}}, ops, {"x_0", "x_1", "x_2"});
  }
  CCXNOptions options;
};
TORCH_MODULE(CCXN);

}  // namespace topos::models
