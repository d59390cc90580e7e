// topos/models/hypergraph/unisage.hpp
// UniSAGE (Huang & Yang, "UniGNN", IJCAI 2021; TopoModelX UniSAGE): input dropout, then per layer
// x_0 = Linear(x_0), x_1 = AGG_e(Bᵀ x_0), x_0 = x_0 + AGG_v(B x_1) (sum, or mean: divided by the
// incidence's row sums), optionally unit rows, dropout, relu.
// Parameters layers.<i>.linear.*.
#pragma once

#include "topos/models/hypergraph/unigin.hpp"

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

class UniSAGEImpl : public torch::nn::Module {
 public:
  explicit UniSAGEImpl(const UniSAGEOptions& o) : options(o) {
    auto list = register_module("layers", torch::nn::ModuleList());
    const auto h = o.hidden_channels();
    for (int l = 0; l < o.n_layers(); ++l) {
      auto layer = std::make_shared<torch::nn::Module>();
      linear_.push_back(
          layer->register_module("linear", torch::nn::Linear(l == 0 ? o.in_channels() : h, h)));
      v2e_.push_back(layer->register_module("vertex2edge",
                                            nn::Conv(nn::ConvOptions(h, h)
                                                         .aggr_norm(o.e_aggr() == nn::Aggr::mean)
                                                         .with_linear_transform(false))));
      e2v_.push_back(layer->register_module("edge2vertex",
                                            nn::Conv(nn::ConvOptions(h, h)
                                                         .aggr_norm(o.v_aggr() == nn::Aggr::mean)
                                                         .with_linear_transform(false))));
      list->push_back(layer);
    }
  }
  /// x_0 (nodes) and the node × hyperedge incidence; returns (x_0, x_1) of the last layer.
  std::vector<torch::Tensor> forward(torch::Tensor x0, const nn::SparseOperator& incidence_1) {
    if (x0.size(0) != incidence_1.rows)
      throw std::invalid_argument("UniSAGE: " + std::to_string(x0.size(0)) +
                                  " node features for an incidence of " +
                                  std::to_string(incidence_1.rows) + " nodes");
    const auto Bt = incidence_1.t();
    x0 = torch::dropout(x0, options.input_drop(), is_training());
    torch::Tensor x1;
    for (std::size_t l = 0; l < linear_.size(); ++l) {
      x0 = linear_[l]->forward(x0);
      x1 = v2e_[l]->forward(x0, Bt);
      x0 = x0 + e2v_[l]->forward(x1, incidence_1);
      if (options.use_norm()) x0 = unit_rows(x0);
      x0 = torch::relu(torch::dropout(x0, options.layer_drop(), is_training()));
    }
    return {x0, x1};
  }
  UniSAGEOptions options;

 private:
  std::vector<torch::nn::Linear> linear_;
  std::vector<nn::Conv> v2e_, e2v_;
};
TORCH_MODULE(UniSAGE);

}  // namespace topos::models
