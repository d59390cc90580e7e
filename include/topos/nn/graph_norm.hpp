// topos/nn/graph_norm.hpp
// GraphNorm (Cai et al., 2021; PyG's torch_geometric.nn.GraphNorm): each graph of a batch
// normalised on its own, y = w ⊙ (x - α ⊙ μ_g) / sqrt(σ²_g + ε) + b, with μ_g the mean of the
// graph's rows, σ²_g the mean of (x - α ⊙ μ_g)² and learned w, b, α. No running statistics:
// training and evaluation compute the same thing. Also segment_sum, the per-graph sum pooling.
#pragma once

#include <torch/torch.h>

#include <cstdint>

namespace topos::nn {

/// Rows of x summed per segment (batch[i] is row i's segment): num_segments × channels.
inline torch::Tensor segment_sum(const torch::Tensor& x, const torch::Tensor& batch,
                                 std::int64_t num_segments) {
  return torch::zeros({num_segments, x.size(1)}, x.options()).index_add(0, batch, x);
}

/// Rows of x averaged per segment; empty segments give zeros.
inline torch::Tensor segment_mean(const torch::Tensor& x, const torch::Tensor& batch,
                                  std::int64_t num_segments) {
  const auto count = torch::zeros({num_segments}, x.options())
                         .index_add(0, batch, torch::ones({x.size(0)}, x.options()));
  return segment_sum(x, batch, num_segments) / count.clamp_min(1).unsqueeze(1);
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
  torch::Tensor weight, bias, mean_scale;

 private:
  double eps_;
};
TORCH_MODULE(GraphNorm);

}  // namespace topos::nn
