// topos/models/hypergraph/allset_transformer.hpp
// AllSetTransformer (Chien et al., "You are AllSet", ICLR 2022; TopoModelX AllSetTransformer):
// AllSet's set functions as multi-head attention with one learned query per head (PMA):
// per target, softmax over its sources of leaky_relu_0.2(<x_j K_h, q_h>), the weighted sum of
// x_j V_h, plus q_h; heads concatenated, LayerNorm, then LayerNorm(y + relu(MLP(y))). Nodes ->
// hyperedges, relu, then hyperedges -> nodes, relu. Only the incidence's pattern is used.
// Parameters layers.<i>.{vertex2edge,edge2vertex}.{multihead_att.{K,Q,V}_weight, mlp.<k>.weight,
// ln0, ln1}, as in TopoModelX.
#pragma once

#include "topos/models/hypergraph/allset.hpp"

namespace topos::models {

struct AllSetTransformerOptions {
  AllSetTransformerOptions(std::int64_t in, std::int64_t hidden)
      : in_channels_(in), hidden_channels_(hidden) {}
  TORCH_ARG(std::int64_t, in_channels);
  TORCH_ARG(std::int64_t, hidden_channels);
  TORCH_ARG(int, n_layers) = 1;
  TORCH_ARG(int, heads) = 4;
  TORCH_ARG(int, number_queries) = 1;
  TORCH_ARG(double, dropout) = 0.2;
  TORCH_ARG(int, mlp_num_layers) = 2;
  TORCH_ARG(std::optional<nn::Update>, mlp_activation) = nn::Update::relu;
  TORCH_ARG(double, mlp_dropout) = 0.2;
  TORCH_ARG(MlpNorm, mlp_norm) = MlpNorm::none;
};

/// Multi-head attention of targets over their sources with learned queries (TopoModelX
/// MultiHeadAttention): returns targets × heads·(hidden/heads), head-major, queries added.
class SetAttentionImpl : public torch::nn::Module {
 public:
  SetAttentionImpl(std::int64_t in, std::int64_t per_head, int heads) {
    K_weight = register_parameter("K_weight", torch::empty({heads, in, per_head}));
    Q_weight = register_parameter("Q_weight", torch::empty({heads, 1, per_head}));
    V_weight = register_parameter("V_weight", torch::empty({heads, in, per_head}));
    for (auto* w : {&K_weight, &Q_weight, &V_weight}) nn::xavier_uniform(*w);
  }
  torch::Tensor forward(const torch::Tensor& x_source, const nn::SparseOperator& A) {
    const auto xK = torch::matmul(x_source, K_weight);  // heads × sources × c
    const auto xV = torch::matmul(x_source, V_weight);
    const auto score = torch::leaky_relu((xK * Q_weight).sum(-1), 0.2);  // heads × sources
    std::vector<torch::Tensor> out;
    for (std::int64_t h = 0; h < K_weight.size(0); ++h) {
      const auto w = nn::row_softmax(A, score[h].index_select(0, A.col.to(score.device())));
      out.push_back(nn::spmm(A.with_values(w), xV[h]) + Q_weight[h]);  // skip connection: the query
    }
    return torch::cat(out, 1);
  }
  torch::Tensor K_weight, Q_weight, V_weight;
};
TORCH_MODULE(SetAttention);

/// One set function (TopoModelX AllSetTransformerBlock): Y = LN0(MH + Q), LN1(Y + relu(MLP(Y))).
class AllSetTransformerBlockImpl : public torch::nn::Module {
 public:
  AllSetTransformerBlockImpl(std::int64_t in, const AllSetTransformerOptions& o) {
    const auto h = o.hidden_channels();
    multihead_att = register_module("multihead_att", SetAttention(in, h / o.heads(), o.heads()));
    mlp = register_module("mlp", TopoMLP(h, h, o.mlp_num_layers(), o.mlp_activation(), o.mlp_norm(),
                                         o.mlp_dropout(), true));
    ln0 = register_module("ln0", torch::nn::LayerNorm(torch::nn::LayerNormOptions({h})));
    ln1 = register_module("ln1", torch::nn::LayerNorm(torch::nn::LayerNormOptions({h})));
  }
  torch::Tensor forward(const torch::Tensor& x_source, const nn::SparseOperator& A) {
    const auto y = ln0->forward(multihead_att->forward(x_source, A));
    return ln1->forward(y + torch::relu(mlp->forward(y)));
  }
  SetAttention multihead_att{nullptr};
  TopoMLP mlp{nullptr};
  torch::nn::LayerNorm ln0{nullptr}, ln1{nullptr};
};
TORCH_MODULE(AllSetTransformerBlock);

class AllSetTransformerImpl : public torch::nn::Module {
 public:
  explicit AllSetTransformerImpl(const AllSetTransformerOptions& o) : options(o) {
    if (o.heads() <= 0)
      throw std::invalid_argument("AllSetTransformer: heads (" + std::to_string(o.heads()) +
                                  ") must be positive");
    if (o.hidden_channels() % o.heads() != 0)
      throw std::invalid_argument(
          "AllSetTransformer: hidden_channels (" + std::to_string(o.hidden_channels()) +
          ") must be divisible by heads (" + std::to_string(o.heads()) + ")");
    // TopoModelX broadcasts the keys against the queries, which only works for one query.
    if (o.number_queries() != 1)
      throw std::invalid_argument(
          "AllSetTransformer: number_queries must be 1 (TopoModelX's attention supports one query "
          "per head)");
    if (o.mlp_norm() == MlpNorm::batch_norm)
      throw std::invalid_argument(
          "AllSetTransformer: mlp_norm BatchNorm1d is not supported (the MLP sees targets x "
          "queries x channels)");
    auto list = register_module("layers", torch::nn::ModuleList());
    for (int l = 0; l < o.n_layers(); ++l) {
      auto layer = std::make_shared<torch::nn::Module>();
      v2e_.push_back(layer->register_module(
          "vertex2edge",
          AllSetTransformerBlock(l == 0 ? o.in_channels() : o.hidden_channels(), o)));
      e2v_.push_back(
          layer->register_module("edge2vertex", AllSetTransformerBlock(o.hidden_channels(), o)));
      list->push_back(layer);
    }
  }
  /// x_0 (nodes) and the node × hyperedge incidence; returns (x_0, x_1) of the last layer.
  std::vector<torch::Tensor> forward(torch::Tensor x0, const nn::SparseOperator& incidence_1) {
    nn::check_node_features("AllSetTransformer", x0, incidence_1);
    const auto B = incidence_1.pattern(), Bt = B.t();
    torch::Tensor x1;
    for (std::size_t l = 0; l < v2e_.size(); ++l) {
      x1 = torch::dropout(torch::relu(v2e_[l]->forward(x0, Bt)), options.dropout(), is_training());
      x0 = torch::dropout(torch::relu(e2v_[l]->forward(x1, B)), options.dropout(), is_training());
    }
    return {x0, x1};
  }
  AllSetTransformerOptions options;

 private:
  std::vector<AllSetTransformerBlock> v2e_, e2v_;
};
TORCH_MODULE(AllSetTransformer);

}  // namespace topos::models
