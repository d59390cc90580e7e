// topos/nn/mlp.hpp
// The MLP block of HOPNet (the reference's models/mlp.py): Linear(in, hid), act,
// [(Linear(hid, hid), act) × (L-2)],
// Linear(hid, out), optional act, optional LayerNorm(out). With L = 1 only Linear(in, out) and an
// optional act (never LayerNorm). Submodules are numbered like torch.nn.Sequential, so parameter
// names ("0.weight", "2.bias", "4.weight") match the reference's checkpoints.
#pragma once

#include "topos/nn/activation.hpp"
#include "topos/nn/kernels.hpp"  // linear_act, CpuGemm
#include "topos/nn/kernels/layer_norm.hpp"
#include "topos/nn/kernels/precision.hpp"
#include "topos/nn/linear_layer_norm.hpp"

#include <torch/torch.h>

#include <optional>
#include <stdexcept>
#include <string>

namespace topos::nn {

namespace detail {
/// Rows of a bfloat16 product rounded up so that its shapes repeat (at most 8 row counts per
/// octave, under 12.5 % padding). oneDNN compiles a kernel per shape and caches 1,024; HOPNet's
/// chunks give every MLP a new row count, so each step compiled hundreds of kernels, and once the
/// cache evicted under two worker threads oneDNN 2.6 failed inside brgemm_kernel_create
/// (std::bad_array_new_length, `hopnet train` on the demo's data at step 38).
inline std::int64_t padded_rows(std::int64_t m) {
  if (m <= 64) return m <= 0 ? m : 64;
  int octave = 0;
  while ((m >> (octave + 1)) != 0) ++octave;  // floor(log2 m) >= 6
  const std::int64_t step = std::int64_t{1} << (octave - 3);
  return (m + step - 1) / step * step;
}

/// Whether x·Wᵀ at `highest` goes through linear_act rather than torch::linear (set_cpu_gemm):
/// 2-D float32 on the CPU, and oneDNN chosen for a map of more than 64 outputs (narrower maps keep
/// their own kernels), or topos's kernels chosen for a shape the dense kernel takes.
inline bool linear_act_takes(const torch::Tensor& x, const torch::Tensor& weight) {
  if (x.dim() != 2 || weight.dim() != 2 || weight.scalar_type() != torch::kFloat ||
      x.scalar_type() != torch::kFloat || !x.device().is_cpu())
    return false;
  switch (get_cpu_gemm()) {
    case CpuGemm::onednn:
      return weight.size(0) > 64 && use_onednn(x);
    case CpuGemm::topos:
      return dense_kernel_fits(weight.size(1), weight.size(0));
    case CpuGemm::blas:
      break;
  }
  return false;
}

/// Whether x·Wᵀ at `precision` goes through linear_act: at highest as linear_act_takes says, at
/// medium where topos's bfloat16 kernels take the shape (detail::bf16_takes), and, on a CPU
/// that has them, the shapes they do not take as at highest: those maps are narrow (an
/// encoder's first layer of 3-28 inputs), where bfloat16 through oneDNN paid two casts, a row
/// padding and an unfused activation, four autograd nodes, for a product that costs less than
/// they do. They stay float32 (torch's set_float32_matmul_precision allows bfloat16, it does
/// not require it).
inline bool linear_act_takes(const torch::Tensor& x, const torch::Tensor& weight,
                             MatmulPrecision precision) {
  if (precision == MatmulPrecision::highest) return linear_act_takes(x, weight);
  if (weight.dim() != 2 || weight.scalar_type() != torch::kFloat) return false;
  return bf16_takes(x, weight.size(1), weight.size(0), precision) ||
         (cpu_has_bf16() && linear_act_takes(x, weight));
}

}  // namespace detail

/// x·Wᵀ + b (b may be undefined) at `precision`: float32 in and out either way, so everything
/// around the product (activations, LayerNorm, gathers, the loss) stays float32. At `highest`,
/// a 2-D product goes to oneDNN (more than 64 outputs) or topos's dense kernel when set_cpu_gemm
/// chose it; at `medium`, to topos's bfloat16 kernels where they take it, 2-D CPU shapes they do
/// not take as at `highest` (a CPU with the kernels), anything else to oneDNN's bfloat16 (a GPU,
/// or a CPU without the kernels).
inline torch::Tensor linear(const torch::Tensor& x, const torch::Tensor& weight,
                            const torch::Tensor& bias = {},
                            MatmulPrecision precision = get_float32_matmul_precision()) {
  if (detail::linear_act_takes(x, weight, precision))
    return linear_act(x, weight, bias, Epilogue::none, precision);
  if (weight.scalar_type() != torch::kFloat || precision == MatmulPrecision::highest ||
      detail::bf16_kernels_serve(x))
    return torch::linear(x, weight, bias);
  auto xb = x.to(torch::kBFloat16);
  const std::int64_t m = x.dim() == 2 ? x.size(0) : 0, rows = detail::padded_rows(m);
  if (rows != m) xb = torch::constant_pad_nd(xb, {0, 0, 0, rows - m});
  auto y = torch::linear(xb, weight.to(torch::kBFloat16),
                         bias.defined() ? bias.to(torch::kBFloat16) : bias);
  if (rows != m) y = y.narrow(0, 0, m);
  return y.to(torch::kFloat);
}

/// LayerNorm(act(x Wᵀ + b)) over the product's channels, scaled by γ and shifted by β (eps as
/// torch::nn::LayerNorm's; act relu, elu, sigmoid or none): at MatmulPrecision::medium on topos's
/// bfloat16 kernels one autograd node that normalises each block of rows as its product is
/// stored (the product's values those of nn::linear_act's bfloat16 products, the norm's those of
/// nn::layer_norm up to float rounding); otherwise exactly
/// nn::layer_norm(linear_act(x, W, b, act), γ, β, eps) (nn::linear's route without act).
inline torch::Tensor linear_layer_norm(const torch::Tensor& x, const torch::Tensor& W,
                                       const torch::Tensor& b, const torch::Tensor& gamma,
                                       const torch::Tensor& beta, double eps = 1e-5,
                                       Epilogue act = Epilogue::none,
                                       MatmulPrecision precision = get_float32_matmul_precision()) {
  if (!detail::linear_layer_norm_takes(x, W, b, gamma, beta, precision))
    return layer_norm(
        act == Epilogue::none ? linear(x, W, b, precision) : linear_act(x, W, b, act, precision),
        gamma, beta, eps);
  const auto needs = [](const torch::Tensor& t) { return t.defined() && t.requires_grad(); };
  const bool grad = torch::GradMode::is_enabled() &&
                    (needs(x) || needs(W) || needs(b) || needs(gamma) || needs(beta));
  if (!grad)  // a rollout's: no node, no product or statistics kept
    return detail::LinearLayerNormFunction::compute(x, W, b.defined() ? b : torch::Tensor(), act,
                                                    gamma, beta, eps, false)[0];
  return detail::LinearLayerNormFunction::apply(x, W,
                                                b.defined() ? b : torch::empty({0}, x.options()),
                                                gamma, beta, eps, static_cast<std::int64_t>(act));
}

struct MlpOptions {
  MlpOptions(std::int64_t in, std::int64_t hidden, std::int64_t out)
      : in_(in), hidden_(hidden), out_(out) {}
  TORCH_ARG(std::int64_t, in);
  TORCH_ARG(std::int64_t, hidden);
  TORCH_ARG(std::int64_t, out);
  TORCH_ARG(int, layers) = 2;
  TORCH_ARG(Activation, activation) = Activation::relu;  ///< none: no activation module
  TORCH_ARG(bool, final_activation) = true;
  TORCH_ARG(bool, layer_norm) = true;
};

class MlpImpl : public torch::nn::Module {
 public:
  explicit MlpImpl(const MlpOptions& o) : options(o) {
    if (o.in() <= 0 || o.out() <= 0 || o.hidden() <= 0 || o.layers() < 1)
      throw std::invalid_argument("Mlp: sizes must be positive and layers >= 1");
    int idx = 0;
    auto add = [&](auto module) {
      register_module(std::to_string(idx++), module.ptr());
      layers_.emplace_back(module);
    };
    auto add_linear = [&](std::int64_t i, std::int64_t out) { add(torch::nn::Linear(i, out)); };
    auto add_act = [&] {
      switch (o.activation()) {
        case Activation::none:
          break;
        case Activation::relu:
          add(torch::nn::ReLU(torch::nn::ReLUOptions().inplace(true)));
          break;
        case Activation::gelu:
          add(torch::nn::GELU());
          break;
        case Activation::elu:
          add(torch::nn::ELU());
          break;
        case Activation::selu:
          add(torch::nn::SELU());
          break;
        case Activation::sigmoid:
          add(torch::nn::Sigmoid());
          break;
        case Activation::tanh:
          add(torch::nn::Tanh());
          break;
        case Activation::leaky_relu:
          add(torch::nn::LeakyReLU());
          break;
      }
    };
    if (o.layers() == 1) {
      add_linear(o.in(), o.out());
      if (o.final_activation()) add_act();
    } else {
      add_linear(o.in(), o.hidden());
      add_act();
      for (int l = 0; l < o.layers() - 2; ++l) {
        add_linear(o.hidden(), o.hidden());
        add_act();
      }
      add_linear(o.hidden(), o.out());
      if (o.final_activation()) add_act();
      if (o.layer_norm())
        add(torch::nn::LayerNorm(torch::nn::LayerNormOptions({o.out()}).eps(1e-5)));
    }
  }
  torch::Tensor forward(torch::Tensor x) { return forward_from(0, std::move(x)); }
  /// The first Linear layer, and the rest of the MLP applied to its output. A caller that knows
  /// its input is a concatenation can apply the weight's column blocks separately.
  torch::nn::Linear first_linear() const { return layers_.front().get<torch::nn::Linear>(); }
  torch::Tensor forward_after_first(torch::Tensor z) { return forward_from(1, std::move(z)); }
  /// The activation right after the first Linear layer (nullopt: none there), and the rest of
  /// the MLP applied to its output: a caller may apply it in the first layer's product.
  std::optional<Activation> first_activation() const {
    if (layers_.size() < 2 || options.activation() == Activation::none) return std::nullopt;
    return options.activation();
  }
  torch::Tensor forward_after_first_activation(torch::Tensor a) {
    if (!first_activation())
      throw std::logic_error("Mlp: no activation after the first Linear layer to continue from");
    return forward_from(2, std::move(a));
  }
  MlpOptions options;

 private:
  torch::Tensor forward_from(std::size_t first, torch::Tensor x) {
    // At medium precision on a CPU without topos's bfloat16 kernels, the hidden activations
    // stay bfloat16 from one Linear to the next through oneDNN (the next product would round them
    // to bfloat16 anyway) and only the last Linear's output returns to float32: two casts per MLP
    // instead of two per Linear. Activations other than ReLU get float32 inputs. With the
    // kernels, each Linear is routed as nn::linear routes it: linear_act where linear_act_takes
    // (float32 out, the ReLU fused; bfloat16 products where the kernels take the shape), else
    // torch::linear in float32 (a narrow first layer on BLAS). The
    // precision is read once, so a change from another thread cannot split an MLP between the two.
    const MatmulPrecision precision = get_float32_matmul_precision();
    const bool bf16 = x.scalar_type() == torch::kFloat && precision == MatmulPrecision::medium &&
                      options.activation() == Activation::relu && !detail::bf16_kernels_serve(x);
    const std::int64_t rows = x.dim() == 2 ? x.size(0) : -1;
    const std::int64_t padded = bf16 ? detail::padded_rows(rows) : rows;
    std::size_t last_linear = 0;
    for (std::size_t i = 0; i < layers_.size(); ++i)
      if (layers_[i].ptr()->as<torch::nn::LinearImpl>()) last_linear = i;
    for (std::size_t i = first; i < layers_.size(); ++i) {
      const auto* l = layers_[i].ptr()->as<torch::nn::LinearImpl>();
      // The last Linear layer, a ReLU after it and the LayerNorm after that as one node
      // (linear_layer_norm).
      const bool relu_next =
          i + 1 < layers_.size() && layers_[i + 1].ptr()->as<torch::nn::ReLUImpl>() != nullptr;
      const std::size_t at_norm = i + (relu_next ? 2 : 1);
      auto* norm = l && at_norm < layers_.size()
                       ? layers_[at_norm].ptr()->as<torch::nn::LayerNormImpl>()
                       : nullptr;
      if (norm && !bf16 && norm->options.normalized_shape().size() == 1 &&
          detail::linear_layer_norm_takes(x, l->weight, l->bias, norm->weight, norm->bias,
                                          precision)) {
        x = linear_layer_norm(x, l->weight, l->bias, norm->weight, norm->bias, norm->options.eps(),
                              relu_next ? Epilogue::relu : Epilogue::none, precision);
        i = at_norm;
      } else if (l && !bf16 && detail::linear_act_takes(x, l->weight, precision)) {
        // oneDNN's or topos's product with the bias and a following ReLU in one pass over its
        // output (the ReLU module is skipped: the same values).
        const bool relu =
            i + 1 < layers_.size() && layers_[i + 1].ptr()->as<torch::nn::ReLUImpl>() != nullptr;
        x = linear_act(x, l->weight, l->bias, relu ? Epilogue::relu : Epilogue::none, precision);
        if (relu) ++i;
      } else if (l && bf16 && i < last_linear) {
        // Padded once to a repeating row count (detail::padded_rows); the rows go at the end.
        auto xb = x.to(torch::kBFloat16);
        if (x.dim() == 2 && x.size(0) == rows && padded != rows)
          xb = torch::constant_pad_nd(xb, {0, 0, 0, padded - rows});
        x = torch::linear(xb, l->weight.to(torch::kBFloat16), l->bias.to(torch::kBFloat16));
      } else if (l) {
        x = nn::linear(x, l->weight, l->bias, precision);
        if (x.dim() == 2 && x.size(0) != rows) x = x.narrow(0, 0, rows);
      } else if (auto* norm = layers_[i].ptr()->as<torch::nn::LayerNormImpl>()) {
        x = nn::layer_norm(x, *norm);
      } else {
        x = layers_[i].forward(x);
      }
    }
    return x;
  }
  std::vector<torch::nn::AnyModule> layers_;
};
TORCH_MODULE(Mlp);

}  // namespace topos::nn
