// topos/models/simplicial/scnn.hpp
// SCNN (Yang, Isufi & Leus, "Simplicial convolutional neural networks", 2022; TopoModelX SCNN):
// on one rank, y = Σ_k (L_down^k x) W_k + Σ_k (L_up^k x) W'_k + x W_0, a polynomial filter of the
// lower and upper Laplacians, one weight tensor per layer ("layers.<i>.weight", in × out ×
// (1 + conv_order_down + conv_order_up)). aggr_norm divides the powers k ≥ 2 by the Laplacian's
// row sums (TopoModelX skips the first power). TopoModelX gives the first layer neither aggr_norm
// nor update_func (the compatible mode does the same; the default gives them to every layer).
// Written as an operator schedule (scnn_schedule).
#pragma once

#include "topos/nn/operator_schedule.hpp"

#include <map>
#include <stdexcept>
#include <string>
#include <tuple>
#include <utility>
#include <vector>

namespace topos::models {

struct SCNNOptions {
  SCNNOptions(std::int64_t in, std::int64_t hidden, int conv_order_down, int conv_order_up)
      : in_channels_(in),
        hidden_channels_(hidden),
        conv_order_down_(conv_order_down),
        conv_order_up_(conv_order_up) {}
  TORCH_ARG(std::int64_t, in_channels);
  TORCH_ARG(std::int64_t, hidden_channels);
  TORCH_ARG(int, conv_order_down);
  TORCH_ARG(int, conv_order_up);
  TORCH_ARG(bool, aggr_norm) = false;
  TORCH_ARG(nn::Activation, update_func) = nn::Activation::none;  ///< relu, sigmoid or none
  TORCH_ARG(int, n_layers) = 2;
  TORCH_ARG(bool,
            topomodelx_compatible) = false;  ///< first layer without aggr_norm and update_func
};

/// The schedule: per layer one filter over [x, L_down x, ..., L_up x, ...] on one rank.
inline nn::OperatorSchedule scnn_schedule(const SCNNOptions& o) {
  using namespace nn::ops;
  if (o.conv_order_down() < 0 || o.conv_order_up() < 0 ||
      o.conv_order_down() + o.conv_order_up() == 0)
    throw std::invalid_argument("SCNN: conv_order_down and conv_order_up must be >= 0, not both 0");
  if (o.update_func() != nn::Activation::none && o.update_func() != nn::Activation::relu &&
      o.update_func() != nn::Activation::sigmoid)
    throw std::invalid_argument("SCNN: update_func must be relu, sigmoid or none");
  if (o.n_layers() < 1) throw std::invalid_argument("SCNN: n_layers must be >= 1");
  nn::OperatorSchedule s;
  s.input("x", 1, o.in_channels()).output("x", 1);
  // A Laplacian of order 0 is neither declared nor applied (TopoModelX takes None for it).
  std::vector<std::pair<std::string, int>> filters;
  for (const auto& [name, order] :
       {std::pair<std::string, int>{"laplacian_down", o.conv_order_down()},
        std::pair<std::string, int>{"laplacian_up", o.conv_order_up()}})
    if (order > 0) {
      s.operator_input(name, 1, 1);
      filters.emplace_back(name, order);
    }
  for (int l = 0; l < o.n_layers(); ++l) {
    // TopoModelX's first layer gets neither aggr_norm nor update_func.
    const bool plain = l == 0 && o.topomodelx_compatible();
    const bool norm = o.aggr_norm() && !plain;
    s.step(into(1)
               .filter("layers." + std::to_string(l) + ".weight", o.hidden_channels(),
                       from(1).powers(filters, norm, 2))
               .act(plain ? nn::Activation::none : o.update_func()));
  }
  return s;
}

class SCNNImpl : public nn::Cloneable<SCNNImpl, nn::OperatorNetworkImpl> {
 public:
  explicit SCNNImpl(const SCNNOptions& o) : Cloneable(scnn_schedule(o)), options(o) {}
  /// Features of one rank, its lower and upper Laplacians; a Laplacian of order 0 is not used
  /// and may be left undefined (TopoModelX's None).
  torch::Tensor forward(const torch::Tensor& x, const nn::SparseOperator& laplacian_down,
                        const nn::SparseOperator& laplacian_up) {
    std::map<std::string, nn::SparseOperator> ops;
    for (const auto& [name, order, A] :
         {std::tuple<const char*, int, const nn::SparseOperator*>{
              "laplacian_down", options.conv_order_down(), &laplacian_down},
          std::tuple<const char*, int, const nn::SparseOperator*>{
              "laplacian_up", options.conv_order_up(), &laplacian_up}}) {
      if (order == 0) continue;
      if (!A->defined())
        throw std::invalid_argument(std::string("SCNN: ") + name + " is needed (its order is " +
                                    std::to_string(order) +
                                    "); only a Laplacian of order 0 may be left out (None)");
      ops.emplace(name, *A);
    }
    return run({{"x", x}}, ops, {"x"})[0];
  }
  SCNNOptions options;
};
TORCH_MODULE(SCNN);

}  // namespace topos::models
