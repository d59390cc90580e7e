// topos/models/graph/gcn.hpp
// GCN (Kipf & Welling, 2017; PyG's torch_geometric.nn.models.GCN, TopoBench's graph baseline):
// per layer x <- Â (x Θ) + b with Â = D̂^-1/2 (A + I) D̂^-1/2, relu between layers (none after
// the last). Â is the operator "gcn_adjacency" (topobench/lifting.hpp builds it). Parameters
// convs.<i>.lin.weight (stored in × out here, Glorot) and convs.<i>.bias, as PyG names them.
// Written as an operator schedule (gcn_schedule).
#pragma once

#include "topos/nn/operator_schedule.hpp"

namespace topos::models {

struct GCNOptions {
  GCNOptions(std::int64_t in, std::int64_t hidden) : in_channels_(in), hidden_channels_(hidden) {}
  TORCH_ARG(std::int64_t, in_channels);
  TORCH_ARG(std::int64_t, hidden_channels);
  TORCH_ARG(int, num_layers) = 2;
  TORCH_ARG(double, dropout) = 0;  ///< before every layer but the first (PyG's BasicGNN)
};

inline nn::OperatorSchedule gcn_schedule(const GCNOptions& o) {
  using namespace nn::ops;
  nn::OperatorSchedule s;
  s.input("x_0", 0, o.in_channels()).operator_input("gcn_adjacency", 0, 0).output("x_0", 0);
  for (int l = 0; l < o.num_layers(); ++l) {
    const std::string p = "convs." + std::to_string(l);
    auto term = from(0);
    if (l > 0 && o.dropout() > 0) term.dropout(o.dropout());
    auto step =
        into(0).sum(term.weight(p + ".lin.weight", o.hidden_channels(), 1.0).via("gcn_adjacency"));
    step.bias(p + ".bias");
    if (l + 1 < o.num_layers()) step.act(nn::Activation::relu);
    s.step(std::move(step));
  }
  return s;
}

}  // namespace topos::models
