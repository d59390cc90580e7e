// topos/models/simplicial/san.hpp
// SAN (Giusti et al., "Simplicial attention neural networks", 2022; TopoModelX SAN) on edge
// features: per layer, attention-weighted filters over the lower and upper Laplacians' patterns
// (Σ_p A^p x W_p with A the per-target softmax of elu(a·[x W_j || x W_i])) plus a harmonic filter
// (I - εL)^k x W with L = L_up + L_down. Everything is sparse products: TopoModelX forms the
// attention matrix densely and the harmonic projection as a dense n × n matrix power.
#pragma once

#include "topos/nn/conv.hpp"

namespace topos::models {

struct SANOptions {
  SANOptions(std::int64_t in, std::int64_t hidden) : in_channels_(in), hidden_channels_(hidden) {}
  TORCH_ARG(std::int64_t, in_channels);
  TORCH_ARG(std::int64_t, hidden_channels);
  TORCH_ARG(std::int64_t, out_channels) = 0;  ///< 0: hidden_channels
  TORCH_ARG(int, n_filters) = 2;
  TORCH_ARG(int, order_harmonic) = 5;
  TORCH_ARG(double, epsilon_harmonic) = 0.1;
  TORCH_ARG(int, n_layers) = 2;
};

/// One attention filter bank: parameters "weight" (filters × in × out), "att_weight"
/// (2·out·filters).
class SANConvImpl : public torch::nn::Module {
 public:
  SANConvImpl(std::int64_t in, std::int64_t out, int filters) : out_(out), filters_(filters) {
    weight = register_parameter("weight", torch::empty({filters, in, out}));
    att_weight = register_parameter("att_weight", torch::empty({2 * out * filters}));
    nn::xavier_uniform(weight);
    nn::xavier_uniform(att_weight);
  }
  torch::Tensor forward(const torch::Tensor& x, const nn::SparseOperator& L) {
    // TopoModelX scores the filters' outputs side by side, [x W_0 || x W_1 || ...] · a; the same
    // sum is taken filter by filter, without the concatenated copy.
    std::vector<torch::Tensor> m;
    const auto a = att_weight.view({2, filters_, out_});
    torch::Tensor s_col, s_row;
    for (int p = 0; p < filters_; ++p) {
      m.push_back(x.mm(weight[p]));
      const auto sc = m[p].mv(a[0][p]), sr = m[p].mv(a[1][p]);
      s_col = s_col.defined() ? s_col + sc : sc;
      s_row = s_row.defined() ? s_row + sr : sr;
    }
    const auto A = L.with_values(nn::attention_weights(
        L, nn::entry_scores(L, s_col, s_row), nn::Update::elu, 0, nn::AttentionNorm::softmax));
    torch::Tensor y;
    for (int p = 0; p < filters_; ++p) {  // A^(p+1) m_p
      auto z = m[static_cast<std::size_t>(p)];
      for (int q = 0; q <= p; ++q) z = nn::spmm(A, z);
      y = y.defined() ? y + z : z;
    }
    return y;
  }
  torch::Tensor weight, att_weight;

 private:
  std::int64_t out_;
  int filters_;
};
TORCH_MODULE(SANConv);

class SANImpl : public torch::nn::Module {
 public:
  explicit SANImpl(const SANOptions& o) : options(o) {
    const auto out = o.out_channels() > 0 ? o.out_channels() : o.hidden_channels();
    auto list = register_module("layers", torch::nn::ModuleList());
    for (int l = 0; l < o.n_layers(); ++l) {
      const auto in = l == 0 ? o.in_channels() : o.hidden_channels();
      const auto c = l + 1 == o.n_layers() ? out : o.hidden_channels();
      auto layer = std::make_shared<torch::nn::Module>();
      Layer L{layer->register_module("conv_down", SANConv(in, c, o.n_filters())),
              layer->register_module("conv_up", SANConv(in, c, o.n_filters())),
              layer->register_module("conv_harmonic", nn::Conv(nn::ConvOptions(in, c)))};
      list->push_back(layer);
      layers_.push_back(L);
    }
  }
  torch::Tensor forward(torch::Tensor x, const nn::SparseOperator& laplacian_up,
                        const nn::SparseOperator& laplacian_down) {
    for (auto& l : layers_) {
      const auto harmonic =  // (I - ε(L↑ + L↓))^k x W, the Laplacian never summed
          nn::apply_affine_power({laplacian_up, laplacian_down}, x.matmul(l.harmonic->weight),
                                 options.order_harmonic(), 1.0, -options.epsilon_harmonic());
      x = l.down->forward(x, laplacian_down) + l.up->forward(x, laplacian_up) + harmonic;
    }
    return x;
  }
  SANOptions options;

 private:
  struct Layer {
    SANConv down, up;
    nn::Conv harmonic;
  };
  std::vector<Layer> layers_;
};
TORCH_MODULE(SAN);

}  // namespace topos::models
