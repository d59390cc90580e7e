// topos/models/simplicial/scone.hpp
// SCoNe (Roddenberry, Glaze & Segarra, "Principled simplicial neural networks for trajectory
// prediction", 2021; TopoModelX SCoNe): on the edges,
// x <- tanh(B_2 B_2ᵀ x W_2 + x W_1 + B_1ᵀ B_1 x W_0), the upper and lower Laplacians applied as
// products of the incidences (never formed). Parameters layers.<i>.weight_0/1/2 (in × out).
// TopoModelX's layer always uses tanh (its update_func is not reachable from SCoNe); so does
// this one unless update_func is set.
#pragma once

#include "topos/nn/conv.hpp"

namespace topos::models {

struct SCoNeOptions {
  SCoNeOptions(std::int64_t in, std::int64_t hidden, int n_layers)
      : in_channels_(in), hidden_channels_(hidden), n_layers_(n_layers) {}
  TORCH_ARG(std::int64_t, in_channels);
  TORCH_ARG(std::int64_t, hidden_channels);
  TORCH_ARG(int, n_layers);
  TORCH_ARG(nn::Update, update_func) = nn::Update::tanh;
};

class SCoNeImpl : public torch::nn::Module {
 public:
  explicit SCoNeImpl(const SCoNeOptions& o) : options(o) {
    if (o.n_layers() < 1) throw std::invalid_argument("SCoNe: n_layers must be >= 1");
    auto list = register_module("layers", torch::nn::ModuleList());
    for (int l = 0; l < o.n_layers(); ++l) {
      auto m = std::make_shared<torch::nn::Module>();
      const auto in = l == 0 ? o.in_channels() : o.hidden_channels();
      std::array<torch::Tensor, 3> w;
      for (std::size_t k = 0; k < 3; ++k) {
        w[k] = m->register_parameter("weight_" + std::to_string(k),
                                     torch::empty({in, o.hidden_channels()}));
        nn::xavier_uniform(w[k], 1.0);
      }
      weights_.push_back(w);
      list->push_back(m);
    }
  }
  /// Edge features, the node × edge incidence B_1 and the edge × triangle incidence B_2.
  torch::Tensor forward(torch::Tensor x, const nn::SparseOperator& incidence_1,
                        const nn::SparseOperator& incidence_2) {
    const auto b1t = incidence_1.t(), b2t = incidence_2.t();
    for (auto& w : weights_) {
      const auto z1 = nn::spmm(incidence_2, nn::spmm(b2t, x)).matmul(w[2]);
      const auto z2 = x.matmul(w[1]);
      const auto z3 = nn::spmm(b1t, nn::spmm(incidence_1, x)).matmul(w[0]);
      x = nn::aggregate_messages({z1, z2, z3}, nn::Aggr::sum, options.update_func());
    }
    return x;
  }
  SCoNeOptions options;

 private:
  std::vector<std::array<torch::Tensor, 3>> weights_;
};
TORCH_MODULE(SCoNe);

}  // namespace topos::models
