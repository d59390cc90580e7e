// topos/models/hypergraph/unigin.hpp
// UniGIN (Huang & Yang, "UniGNN", IJCAI 2021; TopoModelX UniGIN): a linear map, then per layer
// x_1 = Bᵀ x_0 (sum over a hyperedge's nodes), x_0 = Linear((1 + ε) x_0 + B x_1), optionally each
// row scaled to unit norm (the norm taken as a constant), dropout, relu. ε is a parameter with
// train_eps, else a buffer. TopoModelX never applies its input dropout (topomodelx_compatible:
// neither do we; it only matters in training).
// Parameters initial_linear_layer.*, layers.<i>.eps, layers.<i>.linear.*.
// Written as an operator schedule (unigin_schedule).
#pragma once

#include "topos/nn/operator_schedule.hpp"

namespace topos::models {

struct UniGINOptions {
  UniGINOptions(std::int64_t in, std::int64_t hidden)
      : in_channels_(in), hidden_channels_(hidden) {}
  TORCH_ARG(std::int64_t, in_channels);
  TORCH_ARG(std::int64_t, hidden_channels);
  TORCH_ARG(int, n_layers) = 2;
  TORCH_ARG(double, input_drop) = 0.2;
  TORCH_ARG(double, layer_drop) = 0.2;
  TORCH_ARG(double, eps) = 0;
  TORCH_ARG(bool, train_eps) = false;
  TORCH_ARG(bool, use_norm) = false;
  TORCH_ARG(bool, topomodelx_compatible) = false;
};

/// The schedule: (input dropout and) a linear map, then per layer node → hyperedge and the nodes
/// updated from (1 + ε) times their own features plus their hyperedges'.
inline nn::OperatorSchedule unigin_schedule(const UniGINOptions& o) {
  using namespace nn::ops;
  if (o.n_layers() < 1) throw std::invalid_argument("UniGIN: n_layers must be >= 1");
  const auto h = o.hidden_channels();
  nn::OperatorSchedule s;
  s.input("x_0", 0, o.in_channels()).operator_input("incidence_1", 1, 0);
  auto initial = from(0);
  if (!o.topomodelx_compatible()) initial.dropout(o.input_drop());
  s.step(into(0).sum(std::move(initial.linear("initial_linear_layer", h))));
  for (int l = 0; l < o.n_layers(); ++l) {
    const auto p = "layers." + std::to_string(l) + ".";
    s.step(into(1).sum(from(0).via_t("incidence_1")));
    auto nodes = into(0).sum(from(0).scale(p + "eps", o.eps(), o.train_eps(), /*offset=*/1),
                             from(1).via("incidence_1"));
    nodes.linear(p + "linear", h);
    if (o.use_norm()) nodes.unit_rows();
    s.step(std::move(nodes.dropout(o.layer_drop()).act(nn::Activation::relu)));
  }
  s.output("x_0", 0).output("x_1", 1);
  return s;
}

class UniGINImpl : public nn::Cloneable<UniGINImpl, nn::OperatorNetworkImpl> {
 public:
  explicit UniGINImpl(const UniGINOptions& o) : Cloneable(unigin_schedule(o)), options(o) {}
  /// x_0 (nodes) and the node × hyperedge incidence; returns (x_0, x_1) of the last layer.
  std::vector<torch::Tensor> forward(const torch::Tensor& x0,
                                     const nn::SparseOperator& incidence_1) {
    nn::check_node_features("UniGIN", x0, incidence_1);
    return run({{"x_0", x0}}, {{"incidence_1", incidence_1}}, {"x_0", "x_1"});
  }
  UniGINOptions options;
};
TORCH_MODULE(UniGIN);

}  // namespace topos::models
