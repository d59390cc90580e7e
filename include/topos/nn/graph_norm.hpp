// topos/nn/graph_norm.hpp
// GraphNorm (Cai et al., 2021; PyG's torch_geometric.nn.GraphNorm): each graph of a batch
// normalised on its own, y = w ⊙ (x - α ⊙ μ_g) / sqrt(σ²_g + ε) + b, with μ_g the mean of the
// graph's rows, σ²_g the mean of (x - α ⊙ μ_g)² and learned w, b, α. No running statistics:
// training and evaluation compute the same thing. Also segment_sum, the per-graph sum pooling,
// and graph_norm_linear, GraphNorm then a Linear at the cost of the input's nonzeros.
#pragma once

#include "topos/nn/kernels.hpp"

#include <torch/torch.h>

#include <cstdint>

namespace topos::nn {

/// Rows of x summed per segment (batch[i] is row i's segment): num_segments × channels.
inline torch::Tensor segment_sum(const torch::Tensor& x, const torch::Tensor& batch,
                                 std::int64_t num_segments) {
  return torch::zeros({num_segments, x.size(1)}, x.options()).index_add(0, batch, x);
}

/// Rows per segment, at least 1 (a divisor for means), as a column of `options`' dtype.
inline torch::Tensor segment_count(const torch::Tensor& batch, std::int64_t num_segments,
                                   const torch::TensorOptions& options) {
  return torch::zeros({num_segments}, options)
      .index_add(0, batch, torch::ones({batch.size(0)}, options))
      .clamp_min(1)
      .unsqueeze(1);
}

/// Rows of x averaged per segment; empty segments give zeros.
inline torch::Tensor segment_mean(const torch::Tensor& x, const torch::Tensor& batch,
                                  std::int64_t num_segments) {
  return segment_sum(x, batch, num_segments) / segment_count(batch, num_segments, x.options());
}

class GraphNormImpl : public torch::nn::Module {
 public:
  explicit GraphNormImpl(std::int64_t channels, double eps = 1e-5) : eps_(eps) {
    weight = register_parameter("weight", torch::ones({channels}));
    bias = register_parameter("bias", torch::zeros({channels}));
    mean_scale = register_parameter("mean_scale", torch::ones({channels}));
  }
  /// x (rows × channels), batch (rows, int64: each row's graph), num_graphs.
  torch::Tensor forward(const torch::Tensor& x, const torch::Tensor& batch,
                        std::int64_t num_graphs) {
    const auto mean = segment_mean(x, batch, num_graphs).index_select(0, batch);
    const auto out = x - mean * mean_scale;
    const auto var = segment_mean(out * out, batch, num_graphs).index_select(0, batch);
    return weight * out / (var + eps_).sqrt() + bias;
  }
  double eps() const { return eps_; }
  torch::Tensor weight, bias, mean_scale;

 private:
  double eps_;
};
TORCH_MODULE(GraphNorm);

/// linear(norm(x, batch, num_graphs)) for an input that needs no gradient and is mostly zeros:
/// one-hot labels, bags of words, and their sums over cells (every TopoBench feature). Per graph
/// the pair is x (W diag s_g)ᵀ + c_g, with s_g = w / sqrt(σ²_g + ε),
/// σ²_g = E_g[x²] - (2α - α²) μ_g² and c_g = (b - α μ_g s_g) Wᵀ + bias, so the work is a weighted
/// sum of Wᵀ's rows per nonzero of x (torch::embedding_bag) plus graph × channel tensors; the
/// dense pair makes a dozen passes over every entry of x (Citeseer: 3,703 words, 1 % of them set).
/// The statistics are accumulated in double, since the expanded variance cancels. Values and
/// gradients (w, b, α, W, bias) are the two modules'; where more than a quarter of x is set, it
/// runs the two modules, the Linear and `act` as one node (nn::linear_act). `act` (relu, elu or
/// sigmoid) is applied to the result either way.
inline torch::Tensor graph_norm_linear(GraphNorm& norm, torch::nn::Linear& linear,
                                       const torch::Tensor& x, const torch::Tensor& batch,
                                       std::int64_t num_graphs, Epilogue act = Epilogue::none) {
  TORCH_CHECK(x.dim() == 2 && !x.requires_grad(),
              "graph_norm_linear: x must be a matrix that needs no gradient");
  TORCH_CHECK(batch.dim() == 1 && batch.size(0) == x.size(0),
              "graph_norm_linear: batch needs one graph per row of x");
  TORCH_CHECK(linear->weight.size(1) == x.size(1) && norm->weight.size(0) == x.size(1),
              "graph_norm_linear: x has ", x.size(1), " channels, the norm ", norm->weight.size(0),
              " and the linear ", linear->weight.size(1));
  const auto n = x.size(0), f = x.size(1);
  const auto nz = x.nonzero();  // row-major, so grouped by row as embedding_bag's bags are
  if (4 * nz.size(0) > n * f)
    return linear_act(norm->forward(x, batch, num_graphs), linear->weight, linear->bias, act);
  const auto rows = nz.select(1, 0), cols = nz.select(1, 1);
  const auto values = x.reshape(-1).index_select(0, rows * f + cols);
  const auto entry = batch.index_select(0, rows) * f + cols;  // (graph, channel), flattened
  const auto dbl = x.options().dtype(torch::kDouble);
  const auto v = values.to(torch::kDouble);
  const auto count = segment_count(batch, num_graphs, dbl);
  const auto mean =
      torch::zeros({num_graphs * f}, dbl).index_add_(0, entry, v).view({-1, f}) / count;
  const auto square =
      torch::zeros({num_graphs * f}, dbl).index_add_(0, entry, v * v).view({-1, f}) / count;
  const auto alpha = norm->mean_scale.to(torch::kDouble);
  const auto var = (square - (2 * alpha - alpha * alpha) * mean * mean).clamp_min(0);
  const auto scale = norm->weight.to(torch::kDouble) / (var + norm->eps()).sqrt();
  auto shift = torch::matmul(norm->bias.to(torch::kDouble) - alpha * mean * scale,
                             linear->weight.to(torch::kDouble).t());
  if (linear->bias.defined()) shift = shift + linear->bias.to(torch::kDouble);
  const auto weights = scale.to(x.scalar_type()).reshape(-1).index_select(0, entry) * values;
  const auto per_row = torch::bincount(rows, {}, n);
  const auto offsets = per_row.cumsum(0) - per_row;
  const auto y = std::get<0>(torch::embedding_bag(linear->weight.t().contiguous(), cols, offsets,
                                                  false, 0, false, weights));
  auto out = y + shift.to(x.scalar_type()).index_select(0, batch);
  return act == Epilogue::relu ? out.relu_() : detail::activate(out, act);  // a temporary
}

}  // namespace topos::nn
