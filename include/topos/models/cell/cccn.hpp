// topos/models/cell/cccn.hpp
// CCCN (TopoBench's cell complex convolutional network): edges only, per layer
//   x_1 <- relu(Linear(x_1) + GCNConv_up(x_1, L↑) + GCNConv_down(x_1, L↓))
// where GCNConv(x, M) = D^-1/2 M D^-1/2 (x Θ) + b with D the row sums of M and no self-loops
// (PyG's GCNConv given a weighted sparse matrix): the operators "up_laplacian_1_gcn" and
// "down_laplacian_1_gcn" (topobench/lifting.hpp). TopoBench's wrapper then sums each node's
// edges, x_0 = |B_1| x_1 ("incidence_1"). Written as an operator schedule (cccn_schedule).
#pragma once

#include "topos/nn/operator_schedule.hpp"

namespace topos::models {

struct CCCNOptions {
  explicit CCCNOptions(std::int64_t channels) : channels_(channels) {}
  TORCH_ARG(std::int64_t, channels);
  TORCH_ARG(int, n_layers) = 2;
  TORCH_ARG(double, dropout) = 0;
};

inline nn::OperatorSchedule cccn_schedule(const CCCNOptions& o) {
  using namespace nn::ops;
  const auto c = o.channels();
  nn::OperatorSchedule s;
  s.input("x_1", 1, c)
      .operator_input("up_laplacian_1_gcn", 1, 1)
      .operator_input("down_laplacian_1_gcn", 1, 1)
      .operator_input("incidence_1", 1, 0)
      .output("x_0", 0)
      .output("x_1", 1);
  for (int l = 0; l < o.n_layers(); ++l) {
    const std::string p = "layers." + std::to_string(l);
    if (o.dropout() > 0) s.step(into(1).sum(from(1).dropout(o.dropout())));
    s.step(into(1)
               .sum(from(1).linear(p + ".lin", c),
                    from(1)
                        .weight(p + ".conv_up.lin.weight", c, 1.0)
                        .via("up_laplacian_1_gcn")
                        .bias(p + ".conv_up.bias"),
                    from(1)
                        .weight(p + ".conv_down.lin.weight", c, 1.0)
                        .via("down_laplacian_1_gcn")
                        .bias(p + ".conv_down.bias"))
               .act(nn::Activation::relu));
  }
  s.step(into(0).sum(from(1).via("incidence_1")));
  return s;
}

}  // namespace topos::models
