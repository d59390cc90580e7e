// topos/models/hypergraph/hmpnn.hpp
// HMPNN (Heydari & Livi, "Message passing neural networks for hypergraphs", 2022; TopoModelX
// HMPNN): linear maps of node and hyperedge features, then per layer node messages
// m_v = σ(Linear(x_v)), their sum (or mean) per hyperedge M_e, hyperedge messages
// m_e = σ(Linear([x_e || M_e])), their sum (or mean) per node M_v, and the updates
// x_v = σ(BN(x_v) + M_v), x_e = σ(BN(x_e) + M_e), with dropout of the incidence's entries and of
// the features in training. TopoModelX aggregates over the incidence's indices, so its adjacency
// dropout has no effect, and its feature dropout keeps an entry with probability p and rescales
// rows by (2n - kept in the row) / n; topomodelx_compatible reproduces both, the default drops
// incidence entries and uses standard dropout. BatchNorm in eval mode uses the loaded running
// statistics. Parameters as TopoModelX's (linear_node, linear_edge, layers.<i>.*).
#pragma once

#include "topos/nn/conv.hpp"

namespace topos::models {

struct HMPNNOptions {
  HMPNNOptions(std::int64_t in, std::int64_t hidden) : in_channels_(in), hidden_channels_(hidden) {}
  TORCH_ARG(std::int64_t, in_channels);
  TORCH_ARG(std::int64_t, hidden_channels);
  TORCH_ARG(int, n_layers) = 2;
  TORCH_ARG(double, adjacency_dropout_rate) = 0.7;
  TORCH_ARG(double, regular_dropout_rate) = 0.5;
  TORCH_ARG(nn::Aggr, aggr_func) = nn::Aggr::sum;
  TORCH_ARG(bool, topomodelx_compatible) = false;
};

class HMPNNImpl : public torch::nn::Module {
 public:
  explicit HMPNNImpl(const HMPNNOptions& o) : options(o) {
    const auto h = o.hidden_channels();
    linear_node = register_module("linear_node", torch::nn::Linear(o.in_channels(), h));
    linear_edge = register_module("linear_edge", torch::nn::Linear(o.in_channels(), h));
    auto list = register_module("layers", torch::nn::ModuleList());
    for (int l = 0; l < o.n_layers(); ++l) {
      auto layer = std::make_shared<torch::nn::Module>();
      Layer L;
      auto n2e = nn::submodule_group(*layer, "node_to_hyperedge_messenger");
      auto seq = n2e->register_module(
          "messaging_func", torch::nn::Sequential(torch::nn::Linear(h, h), torch::nn::Sigmoid()));
      L.node_message = torch::nn::Linear(seq->ptr<torch::nn::LinearImpl>(0));
      auto e2n = nn::submodule_group(*layer, "hyperedge_to_node_messenger");
      L.edge_message = nn::submodule_group(*e2n, "messaging_func")
                           ->register_module("linear", torch::nn::Linear(2 * h, h));
      L.node_bn = layer->register_module("node_batchnorm", torch::nn::BatchNorm1d(h));
      L.edge_bn = layer->register_module("hyperedge_batchnorm", torch::nn::BatchNorm1d(h));
      list->push_back(layer);
      layers_.push_back(L);
    }
  }
  /// x_0 (nodes), x_1 (hyperedges) and the node × hyperedge incidence (its pattern); returns (x_0,
  /// x_1).
  std::vector<torch::Tensor> forward(torch::Tensor x0, torch::Tensor x1,
                                     const nn::SparseOperator& incidence_1) {
    if (x0.size(0) != incidence_1.rows || x1.size(0) != incidence_1.cols)
      throw std::invalid_argument(
          "HMPNN: " + std::to_string(x0.size(0)) + " node and " + std::to_string(x1.size(0)) +
          " hyperedge features for an incidence of " + std::to_string(incidence_1.rows) + " x " +
          std::to_string(incidence_1.cols));
    x0 = linear_node->forward(x0);
    x1 = linear_edge->forward(x1);
    for (auto& L : layers_) {
      const auto B = incidence_dropout(incidence_1), Bt = B.t();
      const auto m0 = torch::sigmoid(L.node_message->forward(x0));
      const auto M1 = nn::pattern_aggregate(Bt, m0, options.aggr_func());  // per hyperedge
      const auto m1 = torch::sigmoid(L.edge_message->forward(torch::cat({x1, M1}, 1)));
      const auto M0 = nn::pattern_aggregate(B, m1, options.aggr_func());  // per node
      x0 = torch::sigmoid(feature_dropout(L.node_bn->forward(x0)) + M0);
      x1 = torch::sigmoid(feature_dropout(L.edge_bn->forward(x1)) + M1);
    }
    return {x0, x1};
  }
  HMPNNOptions options;
  torch::nn::Linear linear_node{nullptr}, linear_edge{nullptr};

 private:
  nn::SparseOperator incidence_dropout(const nn::SparseOperator& B) const {
    if (!is_training() || options.topomodelx_compatible() || options.adjacency_dropout_rate() <= 0)
      return B;
    const auto keep =
        (torch::rand({B.nnz()}) >= options.adjacency_dropout_rate()).nonzero().squeeze(1);
    return nn::SparseOperator::from_sorted(
        B.rows, B.cols, nn::index_vector(B.row.index_select(0, keep)),
        nn::index_vector(B.col.index_select(0, keep)), B.values.index_select(0, keep));
  }
  torch::Tensor feature_dropout(const torch::Tensor& x) const {
    if (!is_training()) return x;
    if (!options.topomodelx_compatible())
      return torch::dropout(x, options.regular_dropout_rate(), true);
    const auto mask = torch::bernoulli(torch::full_like(x, options.regular_dropout_rate()));
    const double n = static_cast<double>(x.size(0));
    return x * mask * ((2 * n - mask.sum(1, true)) / n);
  }
  struct Layer {
    torch::nn::Linear node_message{nullptr}, edge_message{nullptr};
    torch::nn::BatchNorm1d node_bn{nullptr}, edge_bn{nullptr};
  };
  std::vector<Layer> layers_;
};
TORCH_MODULE(HMPNN);

}  // namespace topos::models
