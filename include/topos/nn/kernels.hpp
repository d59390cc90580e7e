// topos/nn/kernels.hpp
// The fused CPU kernels under message passing, each applying its activation (relu, elu, sigmoid)
// before a row is stored, so that an activated product is one pass over its output and its backward
// needs the output alone. Written with GCC's vector extension and compiled per instruction set:
// AVX2 and the baseline as target clones on 32-byte vectors, AVX-512 on 64-byte ones (dispatched at
// run time). This header holds linear_act, act(x Wᵀ + b) as one autograd node over the dense
// kernels; the kernels are in kernels/: the activations and the dispatch (epilogue.hpp), the row
// loop over a CSR matrix under spmm (csr.hpp; sparse_operator.hpp), and the register-blocked dense
// product for narrow maps (n × K by K × N, N up to 64) with its backward (dense.hpp), and oneDNN's
// sgemm for wide float32 maps when chosen (gemm.hpp, CpuGemm), and LayerNorm with its backward
// (layer_norm.hpp); at MatmulPrecision::medium, bfloat16 products with float32 sums
// (dense_bf16.hpp).
#pragma once

#include "topos/nn/kernels/csr.hpp"
#include "topos/nn/kernels/dense.hpp"
#include "topos/nn/kernels/dense_bf16.hpp"
#include "topos/nn/kernels/epilogue.hpp"
#include "topos/nn/kernels/gemm.hpp"
#include "topos/nn/kernels/layer_norm.hpp"
#include "topos/nn/kernels/packed_weights.hpp"
#include "topos/nn/kernels/precision.hpp"

#include <ATen/Parallel.h>
#include <torch/torch.h>

#include <algorithm>
#include <cstdint>
#include <memory>
#include <stdexcept>
#include <utility>
#include <string>
#include <vector>

namespace topos::nn {

namespace detail {

// How many chunks of rows a fused dense backward splits n rows into, each summing its own partial
// dW (and db): one per thread, each of at least 4096 rows. linear_act's and linear_blocks' take
// the same, so that their weight gradients sum alike.
inline std::int64_t backward_chunks(std::int64_t n) {
  return std::max<std::int64_t>(1, std::min<std::int64_t>(at::get_num_threads(), n / 4096));
}

// Which library ran a product, so that its backward runs on the same one.
enum class ProductPath : std::int64_t { kernel = 0, onednn = 1, bf16 = 2 };

// Whether topos's bfloat16 kernels serve x's products here: a 2-D CPU tensor on a CPU with
// AVX-512 BF16 (the shape aside). Where they do, medium's maps they cannot take stay float32.
inline bool bf16_kernels_serve(const torch::Tensor& x) {
  return x.device().is_cpu() && x.dim() == 2 && cpu_has_bf16();
}

// Whether x·M (M K × N) runs on the bfloat16 kernels at `precision`: medium, float32 on a CPU
// with AVX-512 BF16, a shape bf16_kernel_fits takes.
inline bool bf16_takes(const torch::Tensor& x, std::int64_t K, std::int64_t N,
                       MatmulPrecision precision) {
  return precision == MatmulPrecision::medium && x.scalar_type() == torch::kFloat &&
         bf16_kernel_fits(K, N) && bf16_kernels_serve(x);
}

// act(b + X M) on the bfloat16 kernels (M K × N float32, any strides; b float32 or undefined).
inline torch::Tensor bf16_product(const torch::Tensor& X, const torch::Tensor& M,
                                  const torch::Tensor& b, Epilogue e) {
  const auto x = X.contiguous();
  const auto bc = b.defined() ? b.contiguous() : b;
  const auto n = x.size(0), K = M.size(0), N = M.size(1);
  auto y = torch::empty({n, N}, x.options());
#if defined(TOPOS_HAVE_BF16)
  const auto P = packed_pairs(M, K, N, M.stride(0), M.stride(1));
  const float* xp = x.data_ptr<float>();
  const float* bp = bc.defined() ? bc.data_ptr<float>() : nullptr;
  float* yp = y.data_ptr<float>();
  at::parallel_for(0, n, grain_rows(n, n * K * N / 2), [&](std::int64_t begin, std::int64_t end) {
    dense_rows_bf16(xp, P->data(), bp, yp, begin, end, K, N, e);
  });
#else
  throw std::logic_error("bf16_product: this build has no bfloat16 kernels");
#endif
  return y;
}

// act(x Wᵀ + b) as one node keeping x, W and its output: the activation runs in place on the
// product (one pass, vectorised) and the backward starts from dY ⊙ act'(Y).
struct LinearFunction : public torch::autograd::Function<LinearFunction> {
  /// act(x Wᵀ + b) (b undefined: none), and the library that ran it (the backward follows).
  static std::pair<torch::Tensor, ProductPath> product(
      const torch::Tensor& x, const torch::Tensor& W, const torch::Tensor& b, Epilogue e,
      MatmulPrecision precision = get_float32_matmul_precision()) {
    return product_right(x, W.t(), b, e, precision);
  }
  /// act(x M + b) for M = Wᵀ (in × out, a schedule's weight as it is stored), as `product`.
  static std::pair<torch::Tensor, ProductPath> product_right(
      const torch::Tensor& x, const torch::Tensor& M, const torch::Tensor& b, Epilogue e,
      MatmulPrecision precision = get_float32_matmul_precision()) {
    if (M.scalar_type() == torch::kFloat && M.device().is_cpu() &&
        bf16_takes(x, M.size(0), M.size(1), precision))
      return {bf16_product(x, M, b, e), ProductPath::bf16};
    // oneDNN takes the wide products when chosen (CpuGemm): on a 128-wide map the dense kernel
    // runs at half BLAS's speed and oneDNN 1.3x BLAS's (AVX-512 EPYC).
    const bool onednn = M.size(1) > 64 && use_onednn(x);
    torch::Tensor y;
    if (onednn) {
      y = onednn_mm(x, M);
      bias_epilogue(y, b, e);
    } else if (dense_kernel_fits(M.size(0), M.size(1))) {
      y = dense_product(x, M, b, e,
                        weight_operand(M, packs_panels(x, x.size(0), M.size(0), M.size(1))));
    } else {
      y = b.defined() ? torch::addmm(b, x, M) : x.mm(M);
      apply_epilogue(y, torch::Tensor(), e);
    }
    return {y, onednn ? ProductPath::onednn : ProductPath::kernel};
  }
  // how: the activation in two bits, 4 at medium precision.
  static torch::Tensor forward(torch::autograd::AutogradContext* ctx, const torch::Tensor& x,
                               const torch::Tensor& W, const torch::Tensor& bias,
                               std::int64_t how) {
    const auto e = static_cast<Epilogue>(how & epilogue_mask);
    const auto precision = (how & 4) != 0 ? MatmulPrecision::medium : MatmulPrecision::highest;
    const auto b = bias.numel() > 0 ? bias : torch::Tensor();  // empty: no bias
    const auto [y, path] = product(x, W, b, e, precision);
    ctx->save_for_backward({x, W, e == Epilogue::none ? torch::Tensor() : y});
    ctx->saved_data["how"] = (how & epilogue_mask) | static_cast<std::int64_t>(path) << 2;
    ctx->saved_data["bias"] = b.defined();
    return y;
  }
  static torch::autograd::tensor_list backward(torch::autograd::AutogradContext* ctx,
                                               torch::autograd::tensor_list grads) {
    const auto saved = ctx->get_saved_variables();
    const auto how = ctx->saved_data["how"].toInt();
    const bool bias = ctx->saved_data["bias"].toBool();
    return gradients(saved[0], saved[1], saved[2], grads[0],
                     static_cast<Epilogue>(how & epilogue_mask), static_cast<ProductPath>(how >> 2),
                     ctx->needs_input_grad(0), ctx->needs_input_grad(1),
                     bias && ctx->needs_input_grad(2));
  }
  /// dx, dW and db of Y = act(x Wᵀ + b) from dY = g (Y undefined without an activation), as
  /// `product` ran it (`path`); what is not wanted stays undefined.
  static torch::autograd::tensor_list gradients(const torch::Tensor& x, const torch::Tensor& W,
                                                const torch::Tensor& Y, const torch::Tensor& g,
                                                Epilogue e, ProductPath path, bool want_dx,
                                                bool want_dW, bool want_db) {
    torch::Tensor dx, dW, db;
    if (path == ProductPath::onednn) {
      const auto dZ = apply_epilogue(Y, g.contiguous(), e);
      if (want_dx) dx = onednn_mm(dZ, W);
      if (want_dW) dW = onednn_mm(dZ.t(), x);
      if (want_db) db = dZ.sum(0);
      return {dx, dW, db, {}};
    }
    if (path == ProductPath::bf16 || dense_kernel_fits(W.size(0), W.size(1)))
      return fused_backward(x.contiguous(), W, Y, g.contiguous(), e, path, want_dx, want_dW,
                            want_db);
    const auto dZ = apply_epilogue(Y, g.contiguous(), e);
    if (want_dx) dx = dZ.mm(W);
    if (want_dW) dW = dZ.t().mm(x);
    if (want_db) db = dZ.sum(0);
    return {dx, dW, db, {}};
  }
  // dx, dW and db in one pass over the rows (linear_backward_rows), each thread summing its own
  // share of dW and db.
  // On the bfloat16 kernels (path bf16) W is read through its strides.
  static torch::autograd::tensor_list fused_backward(const torch::Tensor& x, const torch::Tensor& W,
                                                     const torch::Tensor& Y, const torch::Tensor& g,
                                                     Epilogue e, ProductPath path, bool want_dx,
                                                     bool want_dW, bool want_db) {
    const auto n = x.size(0), K = W.size(1), N = W.size(0);
    const auto chunks = backward_chunks(n);
    torch::Tensor dx = want_dx ? torch::empty_like(x) : torch::Tensor();
    // One chunk (one thread, or under 8192 rows) sums straight into the result: no reduction.
    const auto shape = [&](std::vector<std::int64_t> s) {
      if (chunks > 1) s.insert(s.begin(), chunks);
      return s;
    };
    torch::Tensor dW = want_dW ? torch::zeros(shape({N, K}), x.options()) : torch::Tensor();
    torch::Tensor db = want_db ? torch::zeros(shape({N}), x.options()) : torch::Tensor();
#if defined(TOPOS_HAVE_BF16)
    if (path == ProductPath::bf16) {
      const auto PT = packed_pairs(W, N, K, W.stride(0), W.stride(1));
      at::parallel_for(0, chunks, 1, [&](std::int64_t c0, std::int64_t c1) {
        for (std::int64_t c = c0; c < c1; ++c)
          linear_backward_bf16(x.data_ptr<float>(), PT->data(),
                               Y.defined() ? Y.data_ptr<float>() : nullptr, g.data_ptr<float>(),
                               want_dx ? dx.data_ptr<float>() : nullptr,
                               want_dW ? dW.data_ptr<float>() + c * N * K : nullptr,
                               want_db ? db.data_ptr<float>() + c * N : nullptr, c * n / chunks,
                               (c + 1) * n / chunks, K, N, e);
      });
      if (chunks > 1) dW = want_dW ? dW.sum(0) : dW, db = want_db ? db.sum(0) : db;
      return {dx, dW, db, {}};
    }
#endif
#if defined(__GNUC__)
    const auto Wc = W.contiguous();
    // dx = dZ W from W's panels packed where the forward's product would pack its own.
    const auto WP = want_dx && packs_panels(x, n, N, K) ? dense_operand(Wc, true) : torch::Tensor();
    AT_DISPATCH_FLOATING_TYPES(x.scalar_type(), "topos_linear_backward", [&] {
      const scalar_t* wp = WP.defined() ? WP.data_ptr<scalar_t>() : nullptr;
      at::parallel_for(0, chunks, 1, [&](std::int64_t c0, std::int64_t c1) {
        for (std::int64_t c = c0; c < c1; ++c)
          linear_backward_clone(x.data_ptr<scalar_t>(), Wc.data_ptr<scalar_t>(), wp,
                                Y.defined() ? Y.data_ptr<scalar_t>() : nullptr,
                                g.data_ptr<scalar_t>(), want_dx ? dx.data_ptr<scalar_t>() : nullptr,
                                want_dW ? dW.data_ptr<scalar_t>() + c * N * K : nullptr,
                                want_db ? db.data_ptr<scalar_t>() + c * N : nullptr, c * n / chunks,
                                (c + 1) * n / chunks, K, N, e);
      });
    });
#endif
    if (chunks > 1) dW = want_dW ? dW.sum(0) : dW, db = want_db ? db.sum(0) : db;
    return {dx, dW, db, {}};
  }
};

// [X_0 | X_1 | ...] Wᵀ without the concatenation (dense_blocks_rows): the blocks' gradients come
// back as blocks of their own, contiguous, where a concatenation's would be strided slices that
// each reader copies.
struct LinearBlocksFunction : public torch::autograd::Function<LinearBlocksFunction> {
  /// Whether the kernels take these blocks and W (N × ΣK): CPU, one floating type, rows alike,
  /// each block's width as dense_kernel_fits takes it both ways, and ΣK as linear_act's kernel
  /// takes it (else linear_act over the concatenation goes to BLAS, and so does this).
  /// Whether the blocks and W (N × ΣK) are CPU matrices of one floating type, the blocks' rows
  /// alike and their columns W's.
  static bool alike(const std::vector<torch::Tensor>& xs, const torch::Tensor& W) {
    if (xs.empty() || W.dim() != 2 || !W.device().is_cpu() ||
        (W.scalar_type() != torch::kFloat && W.scalar_type() != torch::kDouble))
      return false;
    std::int64_t K = 0;
    for (const auto& x : xs) {
      if (x.dim() != 2 || !x.device().is_cpu() || x.scalar_type() != W.scalar_type() ||
          x.size(0) != xs[0].size(0))
        return false;
      K += x.size(1);
    }
    return K == W.size(1);
  }
  /// Whether the kernels take these blocks and W (alike): each block's width as
  /// dense_kernel_fits takes it both ways, and ΣK as linear_act's kernel takes it (else
  /// linear_act over the concatenation goes to BLAS, and so does this).
  static bool fits(const std::vector<torch::Tensor>& xs, const torch::Tensor& W) {
    if (!alike(xs, W)) return false;
    for (const auto& x : xs)
      if (!dense_kernel_fits(x.size(1), W.size(0)) || !dense_kernel_fits(W.size(0), x.size(1)))
        return false;
    return dense_kernel_fits(W.size(1), W.size(0)) && !(W.size(0) > 64 && use_onednn(xs[0]));
  }
  /// Whether the bfloat16 kernels take these blocks at `precision` (alike() holds): each block's
  /// columns, their sum and N as bf16_kernel_fits takes them.
  static bool bf16_takes(const std::vector<torch::Tensor>& xs, const torch::Tensor& W,
                         MatmulPrecision precision) {
    if (!detail::bf16_takes(xs[0], W.size(1), W.size(0), precision)) return false;
    for (const auto& x : xs)
      if (x.size(1) % 16 != 0) return false;
    return true;
  }
  /// act(base + bias + [xs] Wᵀ); base and bias may be undefined (0); a bias only where the
  /// bfloat16 kernels take the product. `path`, when given, says which kernels ran.
  static torch::Tensor product(const std::vector<torch::Tensor>& xs, const torch::Tensor& W,
                               const torch::Tensor& base = {}, Epilogue e = Epilogue::none,
                               MatmulPrecision precision = get_float32_matmul_precision(),
                               ProductPath* path = nullptr, const torch::Tensor& bias = {}) {
    const auto n = xs[0].size(0), N = W.size(0);
    const bool has_base = base.defined();
    auto y =
        has_base ? base.clone(at::MemoryFormat::Contiguous) : torch::empty({n, N}, xs[0].options());
    const bool bf16 = bf16_takes(xs, W, precision);
    if (path) *path = bf16 ? ProductPath::bf16 : ProductPath::kernel;
    if (bias.defined() && !bf16)
      throw std::logic_error("linear_blocks: a bias only on the bfloat16 kernels");
#if defined(TOPOS_HAVE_BF16)
    if (bf16) {
      const auto bc = bias.defined() ? bias.contiguous() : bias;
      const float* bp = bc.defined() ? bc.data_ptr<float>() : nullptr;
      const auto P = packed_pairs(W, W.size(1), N, W.stride(1), W.stride(0));
      std::vector<torch::Tensor> held;
      std::vector<const float*> X;
      std::vector<std::int64_t> K;
      for (const auto& x : xs) {
        held.push_back(x.contiguous());
        X.push_back(held.back().data_ptr<float>()), K.push_back(x.size(1));
      }
      const auto S = static_cast<std::int64_t>(xs.size());
      at::parallel_for(0, n, grain_rows(n, n * W.size(1) * N / 2),
                       [&](std::int64_t b, std::int64_t f) {
                         dense_blocks_bf16(X.data(), K.data(), S, P->data(), bp,
                                           y.data_ptr<float>(), b, f, N, has_base, e);
                       });
      return y;
    }
#endif
    const auto M = weight_operand(W.t(), false);
#if defined(__GNUC__)
    AT_DISPATCH_FLOATING_TYPES(W.scalar_type(), "topos_linear_blocks", [&] {
      std::vector<torch::Tensor> held;
      std::vector<const scalar_t*> X;
      std::vector<std::int64_t> K;
      for (const auto& x : xs) {
        held.push_back(x.contiguous());
        X.push_back(held.back().data_ptr<scalar_t>()), K.push_back(x.size(1));
      }
      const auto S = static_cast<std::int64_t>(xs.size());
      at::parallel_for(0, n, grain_rows(n, n * W.size(1) * N), [&](std::int64_t b, std::int64_t f) {
        dense_blocks_clone(X.data(), K.data(), S, M.data_ptr<scalar_t>(), y.data_ptr<scalar_t>(), b,
                           f, N, has_base, e);
      });
    });
#else
    throw std::logic_error("linear_blocks: needs GCC's vector extension");
#endif
    return y;
  }
  // how: the activation in two bits, 4 with a base (torch 1.13's Function::apply takes no
  // undefined input: without one, base is any tensor, unread), 8 at medium precision; the saved
  // how has 16 where the bfloat16 kernels ran. An empty bias: none.
  static torch::Tensor forward(torch::autograd::AutogradContext* ctx, at::TensorList xs,
                               const torch::Tensor& W, const torch::Tensor& base,
                               const torch::Tensor& bias, std::int64_t how) {
    const auto e = static_cast<Epilogue>(how & epilogue_mask);
    const bool has_base = (how & 4) != 0;
    ProductPath path = ProductPath::kernel;
    auto y = product(std::vector<torch::Tensor>(xs.begin(), xs.end()), W,
                     has_base ? base : torch::Tensor(), e,
                     (how & 8) != 0 ? MatmulPrecision::medium : MatmulPrecision::highest, &path,
                     bias.numel() > 0 ? bias : torch::Tensor());
    ctx->saved_data["bias"] = bias.numel() > 0;
    std::vector<torch::Tensor> saved(xs.begin(), xs.end());
    saved.push_back(W);
    saved.push_back(e == Epilogue::none ? torch::Tensor() : y);
    ctx->save_for_backward(saved);
    ctx->saved_data["how"] = (how & 7) | (path == ProductPath::bf16 ? 16 : 0);
    return y;
  }
  // The blocks' inputs (made contiguous in `saved`), the buffers of the gradients asked for (in
  // `out`; null where not asked) and the blocks' widths, as the kernels take them.
  template <typename T>
  struct BlockPointers {
    std::vector<const T*> X;
    std::vector<T*> dX;
    std::vector<std::int64_t> K;
  };
  template <typename T>
  static BlockPointers<T> block_pointers(torch::autograd::AutogradContext* ctx,
                                         torch::autograd::tensor_list& saved,
                                         torch::autograd::tensor_list& out) {
    BlockPointers<T> b;
    for (std::size_t s = 0; s < saved.size(); ++s) {
      auto& x = saved[s];
      x = x.contiguous();
      b.X.push_back(x.data_ptr<T>()), b.K.push_back(x.size(1));
      if (ctx->needs_input_grad(s)) out[s] = torch::empty_like(x);
      b.dX.push_back(out[s].defined() ? out[s].data_ptr<T>() : nullptr);
    }
    return b;
  }
  static torch::autograd::tensor_list backward(torch::autograd::AutogradContext* ctx,
                                               torch::autograd::tensor_list grads) {
    auto saved = ctx->get_saved_variables();
    const auto y = saved.back();
    saved.pop_back();
    const auto W = saved.back().contiguous();
    saved.pop_back();
    const auto how = ctx->saved_data["how"].toInt();
    const auto e = static_cast<Epilogue>(how & epilogue_mask);
    const auto S = static_cast<std::int64_t>(saved.size());
    const auto g = grads[0].contiguous();
    const auto n = g.size(0), N = W.size(0), Ktot = W.size(1);
    const bool want_dW = ctx->needs_input_grad(static_cast<std::size_t>(S));
    const bool want_dbase =
        (how & 4) != 0 && ctx->needs_input_grad(static_cast<std::size_t>(S) + 1);
    const bool want_db =
        ctx->saved_data["bias"].toBool() && ctx->needs_input_grad(static_cast<std::size_t>(S) + 2);
    torch::autograd::tensor_list out(saved.size() + 4);
    const auto chunks = backward_chunks(n);
    const auto partial = [&](std::vector<std::int64_t> shape) {  // one per chunk
      if (chunks > 1) shape.insert(shape.begin(), chunks);
      return torch::zeros(shape, W.options());
    };
    torch::Tensor dW, dbase, db;
    if (want_dW) dW = partial({N, Ktot});
    if (want_db) db = partial({N});
    if (want_dbase) dbase = torch::empty_like(g);
#if defined(TOPOS_HAVE_BF16)
    if ((how & 16) != 0) {
      const auto PT = packed_pairs(W, N, Ktot, Ktot, 1);
      const auto b = block_pointers<float>(ctx, saved, out);
      const float* yp = y.defined() ? y.data_ptr<float>() : nullptr;
      at::parallel_for(0, chunks, 1, [&](std::int64_t c0, std::int64_t c1) {
        for (std::int64_t c = c0; c < c1; ++c)
          linear_blocks_backward_bf16(b.X.data(), b.K.data(), S, PT->data(), yp,
                                      g.data_ptr<float>(), b.dX.data(),
                                      want_dW ? dW.data_ptr<float>() + c * N * Ktot : nullptr,
                                      want_dbase ? dbase.data_ptr<float>() : nullptr,
                                      want_db ? db.data_ptr<float>() + c * N : nullptr,
                                      c * n / chunks, (c + 1) * n / chunks, N, e);
      });
      out[static_cast<std::size_t>(S)] = want_dW && chunks > 1 ? dW.sum(0) : dW;
      out[static_cast<std::size_t>(S) + 1] = dbase;
      out[static_cast<std::size_t>(S) + 2] = want_db && chunks > 1 ? db.sum(0) : db;
      return out;
    }
#endif
#if defined(__GNUC__)
    AT_DISPATCH_FLOATING_TYPES(W.scalar_type(), "topos_linear_blocks_backward", [&] {
      const auto b = block_pointers<scalar_t>(ctx, saved, out);
      const scalar_t* yp = y.defined() ? y.data_ptr<scalar_t>() : nullptr;
      at::parallel_for(0, chunks, 1, [&](std::int64_t c0, std::int64_t c1) {
        for (std::int64_t c = c0; c < c1; ++c)
          linear_blocks_backward_clone(b.X.data(), b.K.data(), S, W.data_ptr<scalar_t>(), yp,
                                       g.data_ptr<scalar_t>(), b.dX.data(),
                                       want_dW ? dW.data_ptr<scalar_t>() + c * N * Ktot : nullptr,
                                       want_dbase ? dbase.data_ptr<scalar_t>() : nullptr,
                                       c * n / chunks, (c + 1) * n / chunks, N, e);
      });
    });
#endif
    out[static_cast<std::size_t>(S)] = want_dW && chunks > 1 ? dW.sum(0) : dW;
    out[static_cast<std::size_t>(S) + 1] = dbase;
    return out;
  }
};

}  // namespace detail

using detail::Epilogue;

/// act(x Wᵀ + b) (torch::nn::functional::linear, then relu, elu or sigmoid) as one autograd node
/// on the CPU: for up to 64 outputs a register-blocked kernel with the bias and the activation
/// applied before the store, otherwise BLAS (or oneDNN: set_cpu_gemm) then one vectorised pass; the
/// backward needs no exponential. At `precision` medium, float32 products of the widths
/// dense_bf16.hpp takes run on the bfloat16 kernels where the CPU has them.
/// Any other device, dtype or shape takes torch's ops.
inline torch::Tensor linear_act(const torch::Tensor& x, const torch::Tensor& W,
                                const torch::Tensor& b, Epilogue act = Epilogue::none,
                                MatmulPrecision precision = get_float32_matmul_precision()) {
  const bool fused = x.device().is_cpu() && x.dim() == 2 && W.dim() == 2 &&
                     (x.scalar_type() == torch::kFloat || x.scalar_type() == torch::kDouble) &&
                     W.scalar_type() == x.scalar_type() &&
                     (!b.defined() || (b.dim() == 1 && b.scalar_type() == x.scalar_type()));
  const bool bf16 =
      fused && W.device().is_cpu() && detail::bf16_takes(x, W.size(1), W.size(0), precision);
  if (!fused ||
      (act == Epilogue::none && !bf16 && !detail::dense_kernel_fits(W.size(1), W.size(0)) &&
       !(W.size(0) > 64 && detail::use_onednn(x)))) {
    const auto y = torch::linear(x, W, b);
    return detail::activate(y, act);
  }
  if (x.size(1) != W.size(1) || (b.defined() && b.numel() != W.size(0)))
    throw std::invalid_argument("linear_act: " + std::to_string(x.size(1)) +
                                " input channels for a weight of " + std::to_string(W.size(0)) +
                                " x " + std::to_string(W.size(1)) +
                                (b.defined() ? " and a bias of " + std::to_string(b.numel()) : ""));
  // Without a gradient to take (a rollout's NoGradGuard), no autograd node: Function::apply
  // costs a context, its saved values and the outputs' wrapping on every call.
  if (!torch::GradMode::is_enabled() ||
      !(x.requires_grad() || W.requires_grad() || (b.defined() && b.requires_grad())))
    return detail::LinearFunction::product(x, W, b, act, precision).first;
  // torch 1.13's Function::apply cannot take an undefined input: no bias is an empty one.
  return detail::LinearFunction::apply(
      x, W, b.defined() ? b : torch::empty({0}, x.options()),
      static_cast<std::int64_t>(act) | (precision == MatmulPrecision::medium ? 4 : 0));
}

/// act(base + [x_0 | x_1 | ...] Wᵀ + bias) (W N × Σ columns; base n × N and bias N, or undefined
/// for none) as one autograd node that never forms the concatenation, each block's gradient a
/// tensor of its own, the activation applied as the last block is stored, where the dense kernels
/// take the widths (CPU, float or double; each block's columns, their sum and N as linear_act
/// takes them): the same values as activate(base + linear_act(torch::cat(xs, 1), W, bias), act),
/// and the same gradients where its fused backward takes the sum too (else BLAS's, in another
/// order). Otherwise exactly that. At MatmulPrecision::medium, blocks of multiples of 16 columns
/// go to the bfloat16 kernels, whatever N up to 1,024 (their values are then those of bfloat16
/// products, not linear_act's to the bit); a bias is summed in the kernels there only.
inline torch::Tensor linear_blocks(const std::vector<torch::Tensor>& xs, const torch::Tensor& W,
                                   Epilogue act = Epilogue::none, const torch::Tensor& base = {},
                                   const torch::Tensor& bias = {}) {
  if (xs.empty()) throw std::invalid_argument("linear_blocks: no blocks");
  std::int64_t K = 0;
  for (const auto& x : xs) K += x.dim() == 2 ? x.size(1) : 0;
  if (W.dim() != 2 || K != W.size(1))
    throw std::invalid_argument(
        "linear_blocks: blocks of " + std::to_string(K) + " columns in all for a weight of " +
        (W.dim() == 2 ? std::to_string(W.size(0)) + " x " + std::to_string(W.size(1))
                      : std::to_string(W.dim()) + " dimensions"));
  if (base.defined() && (base.dim() != 2 || base.size(0) != xs[0].size(0) ||
                         base.size(1) != W.size(0) || base.scalar_type() != W.scalar_type()))
    throw std::invalid_argument("linear_blocks: a base of " + c10::str(base.sizes()) + " " +
                                c10::toString(base.scalar_type()) + " for a product of " +
                                std::to_string(xs[0].size(0)) + " x " + std::to_string(W.size(0)) +
                                " " + c10::toString(W.scalar_type()) +
                                ": give the base the product's rows, columns and dtype");
  if (bias.defined() &&
      (bias.dim() != 1 || bias.size(0) != W.size(0) || bias.scalar_type() != W.scalar_type()))
    throw std::invalid_argument("linear_blocks: a bias of " + c10::str(bias.sizes()) + " " +
                                c10::toString(bias.scalar_type()) + " for a weight of " +
                                std::to_string(W.size(0)) + " x " + std::to_string(W.size(1)) +
                                ": give the bias one entry per output, the weight's dtype");
  const auto fallback = [&] {
    const auto x = xs.size() == 1 ? xs[0] : torch::cat(xs, 1);
    if (!base.defined()) return linear_act(x, W, bias, act);
    return detail::activate(base + linear_act(x, W, bias), act);
  };
  using F = detail::LinearBlocksFunction;
  // The precision read once: the kernels chosen here are the ones the node runs.
  const auto precision = get_float32_matmul_precision();
  const bool base_ok = !base.defined() || base.device().is_cpu();
  const bool bf16 = base_ok && (!bias.defined() || bias.device().is_cpu()) && F::alike(xs, W) &&
                    F::bf16_takes(xs, W, precision);
  if ((xs.size() == 1 && !base.defined()) ||
      (!bf16 && (bias.defined() || !F::fits(xs, W) || !base_ok)))
    return fallback();
  bool grad = W.requires_grad() || (base.defined() && base.requires_grad()) ||
              (bias.defined() && bias.requires_grad());
  for (const auto& x : xs) grad = grad || x.requires_grad();
  if (!torch::GradMode::is_enabled() || !grad)
    return F::product(xs, W, base, act, precision, nullptr, bias);
  return F::apply(at::TensorList(xs), W, base.defined() ? base : torch::empty({0}, W.options()),
                  bias.defined() ? bias : torch::empty({0}, W.options()),
                  static_cast<std::int64_t>(act) | (base.defined() ? 4 : 0) |
                      (precision == MatmulPrecision::medium ? 8 : 0));
}

}  // namespace topos::nn
