// topos/models/hypergraph/unigcn.hpp
// UniGCN (Huang & Yang, "UniGNN", IJCAI 2021; TopoModelX UniGCN) as TopoModelX computes it: per
// layer x_1 = Bᵀ x_0 W_1 (optionally BatchNorm), x_0 = B x_1 W_2, both optionally averaged
// (aggr_norm: divided by the incidence's row sums); no activation. TopoModelX drops a layer's
// first linear map when in_channels == hidden_channels (topomodelx_compatible: so do we, and
// that layer has no conv_level1_0_to_1.weight); the default keeps it.
// Parameters layers.<i>.conv_level1_0_to_1.weight, layers.<i>.conv_level2_1_to_0.weight,
// layers.<i>.bn.*.
// Written as an operator schedule (unigcn_schedule).
#pragma once

#include "topos/nn/operator_schedule.hpp"

namespace topos::models {

struct UniGCNOptions {
  UniGCNOptions(std::int64_t in, std::int64_t hidden)
      : in_channels_(in), hidden_channels_(hidden) {}
  TORCH_ARG(std::int64_t, in_channels);
  TORCH_ARG(std::int64_t, hidden_channels);
  TORCH_ARG(int, n_layers) = 2;
  TORCH_ARG(bool, aggr_norm) = false;
  TORCH_ARG(bool, use_bn) = false;
  TORCH_ARG(bool, topomodelx_compatible) = false;
};

/// The schedule: per layer node → hyperedge (optionally batch-normalised) → node.
inline nn::OperatorSchedule unigcn_schedule(const UniGCNOptions& o) {
  using namespace nn::ops;
  if (o.n_layers() < 1) throw std::invalid_argument("UniGCN: n_layers must be >= 1");
  const auto h = o.hidden_channels();
  const bool norm = o.aggr_norm();
  nn::OperatorSchedule s;
  s.input("x_0", 0, o.in_channels()).operator_input("incidence_1", 1, 0);
  for (int l = 0; l < o.n_layers(); ++l) {
    const auto p = "layers." + std::to_string(l) + ".";
    const auto in = l == 0 ? o.in_channels() : h;
    auto to_edges = from(0);
    // TopoModelX's layer has no first linear map when in_channels == hidden_channels.
    if (!o.topomodelx_compatible() || in != h) to_edges.conv(p + "conv_level1_0_to_1", h);
    auto edges = into(1).sum(std::move(to_edges.via_t("incidence_1", norm)));
    if (o.use_bn()) edges.batch_norm(p + "bn");
    s.step(std::move(edges));
    s.step(into(0).sum(from(1).conv(p + "conv_level2_1_to_0", h).via("incidence_1", norm)));
  }
  s.output("x_0", 0).output("x_1", 1);
  return s;
}

class UniGCNImpl : public nn::Cloneable<UniGCNImpl, nn::OperatorNetworkImpl> {
 public:
  explicit UniGCNImpl(const UniGCNOptions& o) : Cloneable(unigcn_schedule(o)), options(o) {}
  /// x_0 (nodes) and the node × hyperedge incidence; returns (x_0, x_1) of the last layer.
  std::vector<torch::Tensor> forward(const torch::Tensor& x0,
                                     const nn::SparseOperator& incidence_1) {
    nn::check_node_features("UniGCN", x0, incidence_1);
    return run({{"x_0", x0}}, {{"incidence_1", incidence_1}}, {"x_0", "x_1"});
  }
  UniGCNOptions options;
};
TORCH_MODULE(UniGCN);

}  // namespace topos::models
