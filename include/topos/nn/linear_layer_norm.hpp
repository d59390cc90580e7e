// topos/nn/linear_layer_norm.hpp
// LayerNorm(act(x Wᵀ + b)) as one autograd node on topos's bfloat16 kernels: each block of rows is
// normalised as soon as its product is stored, while it sits in L1, and the backward forms each
// block's product gradient from the norm's backward in the same buffer the product's backward
// reads. Unfused, the product's output made a round trip through memory between the two in both
// directions (the MLPs of HOPNet and TopoBench's models end this way: their last Linear layer,
// its activation, then LayerNorm). The node under nn::linear_layer_norm (mlp.hpp, by nn::linear).
#pragma once

#include "topos/nn/kernels.hpp"
#include "topos/nn/kernels/layer_norm.hpp"

#include <ATen/Parallel.h>
#include <torch/torch.h>

#include <algorithm>
#include <cstdint>
#include <stdexcept>
#include <string>
#include <vector>

namespace topos::nn {

namespace detail {

#if defined(TOPOS_HAVE_BF16)
// Rows [begin, end) of Y = LayerNorm(act(X Wᵀ + b)) · γ + β (P = pack_bf16_pairs of Wᵀ, K/2 × N
// pairs), a block of rows at a time: the activated product into Z (or, without Z, into a block
// buffer of the caller's `scratch`, rows × N), then the norm of those rows, with each row's mean
// and rstd where `mean` is given.
TOPOS_BF16 inline void linear_layer_norm_rows_bf16(
    const float* X, const std::uint32_t* P, const float* b, Epilogue act, float* Z, float* scratch,
    const float* gamma, const float* beta, float* Y, float* mean, float* rstd, std::int64_t begin,
    std::int64_t end, std::int64_t K, std::int64_t N, float eps) {
  const std::int64_t block = bf16_block_rows(K / 2);  // the product's own block: one pass of it
  for (std::int64_t i0 = begin; i0 < end; i0 += block) {
    const std::int64_t rows = std::min(block, end - i0);
    float* z = Z ? Z + i0 * N : scratch;
    dense_rows_bf16(X + i0 * K, P, b, z, 0, rows, K, N, act);
    layer_norm_float_v4(z, nullptr, 0, nullptr, gamma, beta, Y + i0 * N, mean ? mean + i0 : nullptr,
                        rstd ? rstd + i0 : nullptr, rows, N, eps, Epilogue::none);
  }
}

// A block's dZ from the norm's backward (linear_backward_bf16_blocks's source): dY's rows through
// LayerNorm's backward from its input A = act(Z) and the rows' statistics, into the scratch's
// dZ, then times act'(A) in place; γ's and β's gradients summed into dgamma and dbeta.
template <Epilogue E>
struct LayerNormGradient {
  const float *dy, *a, *gamma, *mean, *rstd;
  float *dgamma, *dbeta;
  TOPOS_BF16_INLINE const float* operator()(Bf16BackwardScratch& s, std::int64_t i0,
                                            std::int64_t rows, std::int64_t N) const {
    layer_norm_float_v4_backward(dy + i0 * N, nullptr, a + i0 * N, gamma, mean + i0, rstd + i0,
                                 s.dZ, dgamma, dbeta, nullptr, rows, N, Epilogue::none);
    if (E != Epilogue::none) bf16_output_gradient<E>(s.dZ, a + i0 * N, rows * N, s.dZ);
    return s.dZ;
  }
};
// The backward's pointers, as LayerNormGradient takes them.
struct LayerNormSaved {
  const float *dy, *a, *gamma, *mean, *rstd;
  float *dgamma, *dbeta;
};
template <Epilogue E>
TOPOS_BF16 void linear_layer_norm_backward_bf16_e(const float* x, const std::uint32_t* PT,
                                                  const LayerNormSaved& n, float* dx, float* dW,
                                                  float* db, std::int64_t begin, std::int64_t end,
                                                  std::int64_t K, std::int64_t N) {
  const LayerNormGradient<E> dz{n.dy, n.a, n.gamma, n.mean, n.rstd, n.dgamma, n.dbeta};
  linear_backward_bf16_blocks(x, PT, dz, dx, dW, db, begin, end, K, N);
}
TOPOS_BF16 inline void linear_layer_norm_backward_bf16(const float* x, const std::uint32_t* PT,
                                                       const LayerNormSaved& n, Epilogue act,
                                                       float* dx, float* dW, float* db,
                                                       std::int64_t begin, std::int64_t end,
                                                       std::int64_t K, std::int64_t N) {
  switch (act) {
    case Epilogue::none:
      return linear_layer_norm_backward_bf16_e<Epilogue::none>(x, PT, n, dx, dW, db, begin, end, K,
                                                               N);
    case Epilogue::relu:
      return linear_layer_norm_backward_bf16_e<Epilogue::relu>(x, PT, n, dx, dW, db, begin, end, K,
                                                               N);
    case Epilogue::elu:
      return linear_layer_norm_backward_bf16_e<Epilogue::elu>(x, PT, n, dx, dW, db, begin, end, K,
                                                              N);
    default:
      return linear_layer_norm_backward_bf16_e<Epilogue::sigmoid>(x, PT, n, dx, dW, db, begin, end,
                                                                  K, N);
  }
}
#endif

// LayerNorm(act(x Wᵀ + b)) · γ + β as one node keeping x, W, the norm's input A = act(x Wᵀ + b),
// γ and each row's mean and rstd. An empty b: no bias.
struct LinearLayerNormFunction : public torch::autograd::Function<LinearLayerNormFunction> {
  // {Y, A, mean, rstd}; A and the statistics only when `keep`.
  static std::vector<torch::Tensor> compute(const torch::Tensor& input, const torch::Tensor& W,
                                            const torch::Tensor& bias, Epilogue act,
                                            const torch::Tensor& gamma, const torch::Tensor& beta,
                                            double eps, bool keep) {
#if defined(TOPOS_HAVE_BF16)
    const auto x = input.contiguous();
    const auto b = bias.numel() > 0 ? bias.contiguous() : torch::Tensor();
    const auto g = gamma.contiguous(), be = beta.contiguous();
    const auto n = x.size(0), K = W.size(1), N = W.size(0);
    auto y = torch::empty({n, N}, x.options());
    torch::Tensor a, mean, rstd;
    if (keep)
      a = torch::empty({n, N}, x.options()), mean = torch::empty({n}, x.options()),
      rstd = torch::empty({n}, x.options());
    const auto P = packed_pairs(W.t(), K, N, W.stride(1), W.stride(0));
    const float* bp = b.defined() ? b.data_ptr<float>() : nullptr;
    at::parallel_for(0, n, grain_rows(n, n * K * N / 2), [&](std::int64_t lo, std::int64_t hi) {
      std::vector<float> scratch(keep ? 0 : static_cast<std::size_t>(bf16_block_rows(K / 2) * N));
      linear_layer_norm_rows_bf16(
          x.data_ptr<float>(), P->data(), bp, act, keep ? a.data_ptr<float>() : nullptr,
          scratch.data(), g.data_ptr<float>(), be.data_ptr<float>(), y.data_ptr<float>(),
          keep ? mean.data_ptr<float>() : nullptr, keep ? rstd.data_ptr<float>() : nullptr, lo, hi,
          K, N, static_cast<float>(eps));
    });
    return {y, a, mean, rstd};
#else
    (void)input, (void)W, (void)bias, (void)act, (void)gamma, (void)beta, (void)eps, (void)keep;
    throw std::logic_error("linear_layer_norm: this build has no bfloat16 kernels");
#endif
  }
  static torch::Tensor forward(torch::autograd::AutogradContext* ctx, const torch::Tensor& x,
                               const torch::Tensor& W, const torch::Tensor& bias,
                               const torch::Tensor& gamma, const torch::Tensor& beta, double eps,
                               std::int64_t act) {
    auto out = compute(x, W, bias, static_cast<Epilogue>(act), gamma, beta, eps, true);
    ctx->save_for_backward({x, W, out[1], gamma, out[2], out[3]});
    ctx->saved_data["bias"] = bias.numel() > 0;
    ctx->saved_data["act"] = act;
    return out[0];
  }
  static torch::autograd::tensor_list backward(torch::autograd::AutogradContext* ctx,
                                               torch::autograd::tensor_list grads) {
    torch::Tensor dx, dW, db, dgamma, dbeta;
#if defined(TOPOS_HAVE_BF16)
    const auto saved = ctx->get_saved_variables();
    const auto x = saved[0].contiguous(), W = saved[1], a = saved[2], gamma = saved[3].contiguous();
    const auto &mean = saved[4], &rstd = saved[5];
    const auto act = static_cast<Epilogue>(ctx->saved_data["act"].toInt());
    const auto dy = grads[0].contiguous();
    const auto n = x.size(0), K = W.size(1), N = W.size(0);
    const auto chunks = backward_chunks(n);
    const auto partial = [&](std::vector<std::int64_t> shape) {  // one per chunk, summed after
      if (chunks > 1) shape.insert(shape.begin(), chunks);
      return torch::zeros(shape, x.options());
    };
    const bool want_db = ctx->saved_data["bias"].toBool() && ctx->needs_input_grad(2);
    if (ctx->needs_input_grad(0)) dx = torch::empty_like(x);
    if (ctx->needs_input_grad(1)) dW = partial({N, K});
    if (want_db) db = partial({N});
    // The norm's own gradients: its backward sums them whatever is asked.
    dgamma = partial({N}), dbeta = partial({N});
    const auto PT = packed_pairs(W, N, K, W.stride(0), W.stride(1));
    const auto ptr = [](torch::Tensor& t, std::int64_t off) {
      return t.defined() ? t.data_ptr<float>() + off : nullptr;
    };
    at::parallel_for(0, chunks, 1, [&](std::int64_t c0, std::int64_t c1) {
      for (std::int64_t c = c0; c < c1; ++c) {
        const LayerNormSaved norm{dy.data_ptr<float>(),    a.data_ptr<float>(),
                                  gamma.data_ptr<float>(), mean.data_ptr<float>(),
                                  rstd.data_ptr<float>(),  ptr(dgamma, c * N),
                                  ptr(dbeta, c * N)};
        linear_layer_norm_backward_bf16(x.data_ptr<float>(), PT->data(), norm, act, ptr(dx, 0),
                                        ptr(dW, c * N * K), ptr(db, c * N), c * n / chunks,
                                        (c + 1) * n / chunks, K, N);
      }
    });
    const auto total = [&](const torch::Tensor& t) {
      return t.defined() && chunks > 1 ? t.sum(0) : t;
    };
    dW = total(dW), db = total(db), dgamma = total(dgamma), dbeta = total(dbeta);
#else
    (void)grads;
#endif
    return {dx,
            dW,
            db,
            ctx->needs_input_grad(3) ? dgamma : torch::Tensor(),
            ctx->needs_input_grad(4) ? dbeta : torch::Tensor(),
            torch::Tensor(),
            torch::Tensor()};
  }
};

// Whether linear_layer_norm runs as one node at `precision`: x a float32 CPU matrix whose product
// by W (N × K) the bfloat16 kernels take, γ and β float32 rows of N on the CPU, b N or undefined.
inline bool linear_layer_norm_takes(const torch::Tensor& x, const torch::Tensor& W,
                                    const torch::Tensor& b, const torch::Tensor& gamma,
                                    const torch::Tensor& beta, MatmulPrecision precision) {
  const auto row = [&](const torch::Tensor& t) {
    return t.defined() && t.dim() == 1 && t.device().is_cpu() && t.scalar_type() == torch::kFloat &&
           t.size(0) == W.size(0);
  };
  return W.dim() == 2 && W.device().is_cpu() && W.scalar_type() == torch::kFloat && x.dim() == 2 &&
         x.size(1) == W.size(1) && (!b.defined() || row(b)) && row(gamma) && row(beta) &&
         bf16_takes(x, W.size(1), W.size(0), precision);
}

}  // namespace detail

}  // namespace topos::nn
