// topos/models/hypergraph/unisage.hpp
// UniSAGE (Huang & Yang, "UniGNN", IJCAI 2021; TopoModelX UniSAGE): input dropout, then per layer
// x_0 = Linear(x_0), x_1 = AGG_e(Bᵀ x_0), x_0 = x_0 + AGG_v(B x_1) (sum, or mean: divided by the
// incidence's row sums), optionally unit rows, dropout, relu.
// Parameters layers.<i>.linear.*.
// Written as an operator schedule (unisage_schedule).
#pragma once

#include "topos/nn/operator_schedule.hpp"

namespace topos::models {

struct UniSAGEOptions {
  UniSAGEOptions(std::int64_t in, std::int64_t hidden)
      : in_channels_(in), hidden_channels_(hidden) {}
  TORCH_ARG(std::int64_t, in_channels);
  TORCH_ARG(std::int64_t, hidden_channels);
  TORCH_ARG(int, n_layers) = 2;
  TORCH_ARG(double, input_drop) = 0.2;
  TORCH_ARG(double, layer_drop) = 0.2;
  TORCH_ARG(nn::Aggr, e_aggr) = nn::Aggr::sum;
  TORCH_ARG(nn::Aggr, v_aggr) = nn::Aggr::mean;
  TORCH_ARG(bool, use_norm) = false;
};

/// The schedule: input dropout, then per layer a linear map, node → hyperedge, and the nodes
/// updated by their own features plus their hyperedges'.
inline nn::OperatorSchedule unisage_schedule(const UniSAGEOptions& o) {
  using namespace nn::ops;
  if (o.n_layers() < 1) throw std::invalid_argument("UniSAGE: n_layers must be >= 1");
  const auto h = o.hidden_channels();
  nn::OperatorSchedule s;
  s.input("x_0", 0, o.in_channels()).operator_input("incidence_1", 1, 0);
  s.step(into(0).sum(from(0).dropout(o.input_drop())));
  for (int l = 0; l < o.n_layers(); ++l) {
    const auto p = "layers." + std::to_string(l) + ".";
    s.step(into(0).sum(from(0).linear(p + "linear", h)));
    s.step(into(1).sum(from(0).via_t("incidence_1", o.e_aggr() == nn::Aggr::mean)));
    auto nodes = into(0).sum(from(0), from(1).via("incidence_1", o.v_aggr() == nn::Aggr::mean));
    if (o.use_norm()) nodes.unit_rows();
    s.step(std::move(nodes.dropout(o.layer_drop()).act(nn::Activation::relu)));
  }
  s.output("x_0", 0).output("x_1", 1);
  return s;
}

class UniSAGEImpl : public nn::Cloneable<UniSAGEImpl, nn::OperatorNetworkImpl> {
 public:
  explicit UniSAGEImpl(const UniSAGEOptions& o) : Cloneable(unisage_schedule(o)), options(o) {}
  /// x_0 (nodes) and the node × hyperedge incidence; returns (x_0, x_1) of the last layer.
  std::vector<torch::Tensor> forward(const torch::Tensor& x0,
                                     const nn::SparseOperator& incidence_1) {
    nn::check_node_features("UniSAGE", x0, incidence_1);
    return run({{"x_0", x0}}, {{"incidence_1", incidence_1}}, {"x_0", "x_1"});
  }
  UniSAGEOptions options;
};
TORCH_MODULE(UniSAGE);

}  // namespace topos::models
