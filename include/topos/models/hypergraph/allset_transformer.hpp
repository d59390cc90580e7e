// topos/models/hypergraph/allset_transformer.hpp
// AllSetTransformer (Chien et al., "You are AllSet", ICLR 2022; TopoModelX AllSetTransformer):
// AllSet's set functions as multi-head attention with one learned query per head (PMA):
// per target, softmax over its sources of leaky_relu_0.2(<x_j K_h, q_h>), the weighted sum of
// x_j V_h, plus q_h; heads concatenated, LayerNorm, then LayerNorm(y + relu(MLP(y))). Nodes ->
// hyperedges, relu, then hyperedges -> nodes, relu. Only the incidence's pattern is used.
// Parameters layers.<i>.{vertex2edge,edge2vertex}.{multihead_att.{K,Q,V}_weight, mlp.<k>.weight,
// ln0, ln1}, as in TopoModelX. Written as an operator schedule (allset_transformer_schedule).
#pragma once

#include "topos/models/hypergraph/allset.hpp"  // MlpNorm
#include "topos/nn/operator_schedule.hpp"

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
  TORCH_ARG(std::optional<nn::Activation>, mlp_activation) = nn::Activation::relu;
  TORCH_ARG(double, mlp_dropout) = 0.2;
  TORCH_ARG(MlpNorm, mlp_norm) = MlpNorm::none;
};

/// The schedule: per layer two set functions (TopoModelX AllSetTransformerBlock), nodes ->
/// hyperedges over Bᵀ, then hyperedges -> nodes over B. Each: the attention (source-only scores
/// of the keys x K_h against the query q_h, folded as x (K_h q_h): the keys are never formed;
/// messages x V_h) plus q_h and ln0 into the target, then ln1(y + relu(MLP(y))), relu, dropout.
inline nn::OperatorSchedule allset_transformer_schedule(const AllSetTransformerOptions& o) {
  using namespace nn::ops;
  using nn::Activation;
  if (o.heads() <= 0)
    throw std::invalid_argument("AllSetTransformer: heads (" + std::to_string(o.heads()) +
                                ") must be positive");
  if (o.hidden_channels() % o.heads() != 0)
    throw std::invalid_argument("AllSetTransformer: hidden_channels (" +
                                std::to_string(o.hidden_channels()) +
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
  if (o.n_layers() < 1) throw std::invalid_argument("AllSetTransformer: n_layers must be >= 1");
  const int layers = o.mlp_num_layers();
  if (layers < 1)
    throw std::invalid_argument("MLP: mlp_num_layers (" + std::to_string(layers) +
                                ") must be positive");
  // The block's MLP is built as TopoModelX-compatible (allset.hpp's TopoMLP).
  if (layers > 1 && !o.mlp_activation())
    throw std::invalid_argument("MLP: mlp_activation None with " + std::to_string(layers) +
                                " MLP layers fails in TopoModelX (name an activation)");
  const std::int64_t h = o.hidden_channels(), H = o.heads(), c = h / H;
  nn::OperatorSchedule s;
  s.input("x_0", 0, o.in_channels()).operator_input("incidence_1", 1, 0);  // B's pattern
  auto block = [&](const std::string& p, int src, int dst) {
    const auto q = p + "multihead_att.Q_weight";
    s.step(into(dst)
               .sum(from(src)
                        .head_weights(p + "multihead_att.V_weight", H, c)
                        .attend("incidence_1",
                                nn::AttendOptions(q)
                                    .shape({H, 1, c})
                                    .keys(nn::CochainKey{src, ""})
                                    .key_weights(nn::KeyWeights(p + "multihead_att.K_weight", c))
                                    .source_only(true)
                                    .activation(Activation::leaky_relu)
                                    .negative_slope(0.2)
                                    .norm(nn::AttentionNorm::softmax)
                                    .heads(H)
                                    .transposed(dst == 1)))
               .bias(q, {H, 1, c})  // PMA's skip connection: the query
               .layer_norm(p + "ln0"));
    // TopoModelX's MLP: [Linear, norm?, act, Dropout] but the last, Linear, then Dropout;
    // numbered like its torch.nn.Sequential.
    auto mlp = from(dst);
    for (int l = 0, idx = 0; l < layers; ++l) {
      mlp.linear(p + "mlp." + std::to_string(idx++), h, false);
      if (l + 1 == layers) break;
      if (o.mlp_norm() == MlpNorm::layer_norm) mlp.layer_norm(p + "mlp." + std::to_string(idx++));
      mlp.act(o.mlp_activation().value_or(Activation::none)).dropout(o.mlp_dropout());
      idx += 2;  // the activation and Dropout modules
    }
    mlp.dropout(o.mlp_dropout()).act(Activation::relu);
    s.step(into(dst)
               .sum(from(dst), std::move(mlp))
               .layer_norm(p + "ln1")
               .act(Activation::relu)
               .dropout(o.dropout()));
  };
  for (int l = 0; l < o.n_layers(); ++l) {
    const auto p = "layers." + std::to_string(l) + ".";
    block(p + "vertex2edge.", 0, 1);
    block(p + "edge2vertex.", 1, 0);
  }
  s.output("x_0", 0).output("x_1", 1);
  return s;
}

class AllSetTransformerImpl : public nn::Cloneable<AllSetTransformerImpl, nn::OperatorNetworkImpl> {
 public:
  explicit AllSetTransformerImpl(const AllSetTransformerOptions& o)
      : Cloneable(allset_transformer_schedule(o)), options(o) {}
  /// x_0 (nodes) and the node × hyperedge incidence; returns (x_0, x_1) of the last layer.
  std::vector<torch::Tensor> forward(const torch::Tensor& x0,
                                     const nn::SparseOperator& incidence_1) {
    nn::check_node_features("AllSetTransformer", x0, incidence_1);
    return run({{"x_0", x0}}, {{"incidence_1", incidence_1.pattern()}}, {"x_0", "x_1"});
  }
  AllSetTransformerOptions options;
};
TORCH_MODULE(AllSetTransformer);

}  // namespace topos::models
