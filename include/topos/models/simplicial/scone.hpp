// topos/models/simplicial/scone.hpp
// SCoNe (Roddenberry, Glaze & Segarra, "Principled simplicial neural networks for trajectory
// prediction", 2021; TopoModelX SCoNe): on the edges,
// x <- tanh(B_2 B_2ᵀ x W_2 + x W_1 + B_1ᵀ B_1 x W_0), the upper and lower Laplacians applied as
// products of the incidences (never formed). Parameters layers.<i>.weight_0/1/2 (in × out).
// TopoModelX's layer always uses tanh (its update_func is not reachable from SCoNe); so does
// this one unless update_func is set.
// Written as an operator schedule (scone_schedule).
#pragma once

#include "topos/nn/operator_schedule.hpp"

namespace topos::models {

struct SCoNeOptions {
  SCoNeOptions(std::int64_t in, std::int64_t hidden, int n_layers)
      : in_channels_(in), hidden_channels_(hidden), n_layers_(n_layers) {}
  TORCH_ARG(std::int64_t, in_channels);
  TORCH_ARG(std::int64_t, hidden_channels);
  TORCH_ARG(int, n_layers);
  TORCH_ARG(nn::Activation, update_func) = nn::Activation::tanh;
};

/// The schedule: per layer one step on the edges summing the three terms.
inline nn::OperatorSchedule scone_schedule(const SCoNeOptions& o) {
  using namespace nn::ops;
  if (o.n_layers() < 1) throw std::invalid_argument("SCoNe: n_layers must be >= 1");
  const auto h = o.hidden_channels();
  nn::OperatorSchedule s;
  s.input("x", 1, o.in_channels())
      .operator_input("incidence_1", 1, 0)
      .operator_input("incidence_2", 2, 1)
      .output("x", 1);
  for (int l = 0; l < o.n_layers(); ++l) {
    const auto p = "layers." + std::to_string(l) + ".weight_";
    s.step(into(1)
               .sum(from(1).via_t("incidence_2").via("incidence_2").weight(p + "2", h, 1.0),
                    from(1).weight(p + "1", h, 1.0),
                    from(1).via("incidence_1").via_t("incidence_1").weight(p + "0", h, 1.0))
               .act(o.update_func()));
  }
  return s;
}

class SCoNeImpl : public nn::Cloneable<SCoNeImpl, nn::OperatorNetworkImpl> {
 public:
  explicit SCoNeImpl(const SCoNeOptions& o) : Cloneable(scone_schedule(o)), options(o) {}
  /// Edge features, the node × edge incidence B_1 and the edge × triangle incidence B_2.
  torch::Tensor forward(const torch::Tensor& x, const nn::SparseOperator& incidence_1,
                        const nn::SparseOperator& incidence_2) {
    return run({{"x", x}}, {{"incidence_1", incidence_1}, {"incidence_2", incidence_2}}, {"x"})[0];
  }
  SCoNeOptions options;
};
TORCH_MODULE(SCoNe);

}  // namespace topos::models
