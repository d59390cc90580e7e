// topos/nn/kernels/layer_norm.hpp
// LayerNorm over the channels of a (rows × channels) CPU tensor as one autograd node: each row's
// mean and variance in two passes over the row while it sits in L1, the normalised row scaled and
// shifted before the store, and a hand-written backward. torch 1.13's CPU layer_norm costs 5-10x
// this on HOPNet's and TopoBench's rows of 64-128 channels (bench_hopnet's BM_layer_norm); in a
// HOPNet rollout step, after the products, it was the largest single operation.
#pragma once

#include "topos/nn/kernels/epilogue.hpp"

#include <ATen/Parallel.h>
#include <torch/torch.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <vector>

namespace topos::nn {

namespace detail {

#if defined(__GNUC__)
// The sum of a row's L-wide vector partial sums and its scalar tail, as a tree (log2 L dependent
// adds, not L: a row of 128 floats is only 8 vectors).
template <class T, class V>
static TOPOS_INLINE_KERNEL T lane_sum(const V& v, T tail) {
  constexpr int L = static_cast<int>(sizeof(V) / sizeof(T));
  T a[L];
  std::memcpy(a, &v, sizeof v);
  for (int w = L / 2; w >= 1; w /= 2)
    for (int l = 0; l < w; ++l) a[l] += a[l + w];
  return a[0] + tail;
}
#endif

// Rows [0, n) of x: y = act((x - mean) · rstd · w + b) (w, b may be null; act relu or elu
// applied before the store), each row's mean and 1 / sqrt(var + eps) stored for the backward
// (unless mean is null). The variance is the mean of squared deviations (biased, as torch's).
template <class T, int VB = 32, Epilogue E = Epilogue::none>
static TOPOS_INLINE_KERNEL void layer_norm_rows(const T* x, const T* w, const T* b, T* y, T* mean,
                                                T* rstd, std::int64_t n, std::int64_t C, T eps) {
#if defined(__GNUC__)
  typedef T vec __attribute__((vector_size(VB)));
  constexpr int L = static_cast<int>(VB / sizeof(T));
#else
  constexpr int L = 1;
#endif
  const std::int64_t Cv = C / L * L;
  for (std::int64_t i = 0; i < n; ++i) {
    const T* xr = x + i * C;
    T* yr = y + i * C;
    T s = 0, q = 0;
    std::int64_t c = 0;
#if defined(__GNUC__)
    vec sv{};
    for (; c < Cv; c += L) {
      vec v;
      std::memcpy(&v, xr + c, sizeof v);
      sv += v;
    }
#endif
    for (; c < C; ++c) s += xr[c];
#if defined(__GNUC__)
    s = lane_sum(sv, s);
#endif
    const T m = s / static_cast<T>(C);
    c = 0;
#if defined(__GNUC__)
    vec qv{};
    for (; c < Cv; c += L) {
      vec v;
      std::memcpy(&v, xr + c, sizeof v);
      v -= m;
      qv += v * v;
    }
#endif
    for (; c < C; ++c) q += (xr[c] - m) * (xr[c] - m);
#if defined(__GNUC__)
    q = lane_sum(qv, q);
#endif
    const T r = T(1) / std::sqrt(q / static_cast<T>(C) + eps);
    c = 0;
#if defined(__GNUC__)
    for (; c < Cv; c += L) {
      vec v;
      std::memcpy(&v, xr + c, sizeof v);
      v = (v - m) * r;
      if (w) {
        vec wv;
        std::memcpy(&wv, w + c, sizeof wv);
        v *= wv;
      }
      if (b) {
        vec bv;
        std::memcpy(&bv, b + c, sizeof bv);
        v += bv;
      }
      epilogue_vec<T, E>(v);
      std::memcpy(yr + c, &v, sizeof v);
    }
#endif
    for (; c < C; ++c)
      yr[c] = epilogue_scalar<T>((xr[c] - m) * r * (w ? w[c] : T(1)) + (b ? b[c] : T(0)), E);
    if (mean) mean[i] = m, rstd[i] = r;
  }
}

// The backward of rows [0, n): with x̂ = (x - mean) · rstd and g = dy · w,
// dx = rstd · (g - mean(g) - x̂ · mean(g · x̂)); dw += Σ dy · x̂ and db += Σ dy into this block's
// partial sums (dw, db may be null). After an activation E, dy is first dy ⊙ act'(y) from the
// output y (epilogue_rows's rule).
template <class T, int VB = 32, Epilogue E = Epilogue::none>
static TOPOS_INLINE_KERNEL void layer_norm_backward_rows(const T* dy, const T* y, const T* x,
                                                         const T* w, const T* mean, const T* rstd,
                                                         T* dx, T* dw, T* db, std::int64_t n,
                                                         std::int64_t C) {
#if defined(__GNUC__)
  typedef T vec __attribute__((vector_size(VB)));
  constexpr int L = static_cast<int>(VB / sizeof(T));
#else
  constexpr int L = 1;
#endif
  const std::int64_t Cv = C / L * L;
  for (std::int64_t i = 0; i < n; ++i) {
    const T *dr = dy + i * C, *xr = x + i * C, *yr = y ? y + i * C : nullptr;
    // dy at channel c, times act'(y) after an activation.
    const auto grad = [&](std::int64_t c) {
      if constexpr (E == Epilogue::none) return dr[c];
      T d = dr[c];
      epilogue_grad<T>(yr[c], d, E);
      return d;
    };
    const T m = mean[i], r = rstd[i];
    T sg = 0, sgx = 0;
    std::int64_t c = 0;
#if defined(__GNUC__)
    vec sgv{}, sgxv{};
    for (; c < Cv; c += L) {
      vec d, v;
      std::memcpy(&d, dr + c, sizeof d);
      if constexpr (E != Epilogue::none) {
        vec yv;
        std::memcpy(&yv, yr + c, sizeof yv);
        epilogue_grad<T>(yv, d, E);
      }
      std::memcpy(&v, xr + c, sizeof v);
      const vec xh = (v - m) * r;
      if (dw) {
        vec a;
        std::memcpy(&a, dw + c, sizeof a);
        a += d * xh;
        std::memcpy(dw + c, &a, sizeof a);
      }
      if (db) {
        vec a;
        std::memcpy(&a, db + c, sizeof a);
        a += d;
        std::memcpy(db + c, &a, sizeof a);
      }
      if (w) {
        vec wv;
        std::memcpy(&wv, w + c, sizeof wv);
        d *= wv;
      }
      sgv += d;
      sgxv += d * xh;
    }
#endif
    for (; c < C; ++c) {
      const T d = grad(c), xh = (xr[c] - m) * r, g = d * (w ? w[c] : T(1));
      if (dw) dw[c] += d * xh;
      if (db) db[c] += d;
      sg += g;
      sgx += g * xh;
    }
#if defined(__GNUC__)
    sg = lane_sum(sgv, sg);
    sgx = lane_sum(sgxv, sgx);
#endif
    const T mg = sg / static_cast<T>(C), mgx = sgx / static_cast<T>(C);
    T* xo = dx + i * C;
    c = 0;
#if defined(__GNUC__)
    for (; c < Cv; c += L) {
      vec d, v;
      std::memcpy(&d, dr + c, sizeof d);
      if constexpr (E != Epilogue::none) {
        vec yv;
        std::memcpy(&yv, yr + c, sizeof yv);
        epilogue_grad<T>(yv, d, E);
      }
      std::memcpy(&v, xr + c, sizeof v);
      if (w) {
        vec wv;
        std::memcpy(&wv, w + c, sizeof wv);
        d *= wv;
      }
      const vec o = (d - mg - (v - m) * r * mgx) * r;
      std::memcpy(xo + c, &o, sizeof o);
    }
#endif
    for (; c < C; ++c) xo[c] = (grad(c) * (w ? w[c] : T(1)) - mg - (xr[c] - m) * r * mgx) * r;
  }
}

// The kernels per instruction set (epilogue.hpp): AVX-512 on 64-byte vectors when the CPU has it.
#define TOPOS_LAYER_NORM_ENTRY(T, NAME, ATTR, VB)                                                  \
  [[maybe_unused]] ATTR static void NAME(const T* x, const T* w, const T* b, T* y, T* mean,        \
                                         T* rstd, std::int64_t n, std::int64_t C, T eps,           \
                                         Epilogue e) {                                             \
    if (e == Epilogue::relu)                                                                       \
      return layer_norm_rows<T, VB, Epilogue::relu>(x, w, b, y, mean, rstd, n, C, eps);            \
    if (e == Epilogue::elu)                                                                        \
      return layer_norm_rows<T, VB, Epilogue::elu>(x, w, b, y, mean, rstd, n, C, eps);             \
    layer_norm_rows<T, VB>(x, w, b, y, mean, rstd, n, C, eps);                                     \
  }                                                                                                \
  [[maybe_unused]] ATTR static void NAME##_backward(                                               \
      const T* dy, const T* y, const T* x, const T* w, const T* mean, const T* rstd, T* dx, T* dw, \
      T* db, std::int64_t n, std::int64_t C, Epilogue e) {                                         \
    if (e == Epilogue::relu)                                                                       \
      return layer_norm_backward_rows<T, VB, Epilogue::relu>(dy, y, x, w, mean, rstd, dx, dw, db,  \
                                                             n, C);                                \
    if (e == Epilogue::elu)                                                                        \
      return layer_norm_backward_rows<T, VB, Epilogue::elu>(dy, y, x, w, mean, rstd, dx, dw, db,   \
                                                            n, C);                                 \
    layer_norm_backward_rows<T, VB>(dy, y, x, w, mean, rstd, dx, dw, db, n, C);                    \
  }
TOPOS_LAYER_NORM_ENTRY(float, layer_norm_float, TOPOS_SIMD_CLONES, 32)
TOPOS_LAYER_NORM_ENTRY(double, layer_norm_double, TOPOS_SIMD_CLONES, 32)
#if defined(TOPOS_HAVE_V4)
TOPOS_LAYER_NORM_ENTRY(float, layer_norm_float_v4, TOPOS_V4, 64)
TOPOS_LAYER_NORM_ENTRY(double, layer_norm_double_v4, TOPOS_V4, 64)
#endif
#undef TOPOS_LAYER_NORM_ENTRY

template <class T>
void layer_norm_forward_range(const T* x, const T* w, const T* b, T* y, T* mean, T* rstd,
                              std::int64_t n, std::int64_t C, T eps, Epilogue e) {
  at::parallel_for(0, n, grain_rows(n, 4 * n * C), [&](std::int64_t lo, std::int64_t hi) {
    const auto at = lo * C;
    // No statistics kept (mean null): a later range must not write at null + lo.
    T* const mean_lo = mean ? mean + lo : nullptr;
    T* const rstd_lo = rstd ? rstd + lo : nullptr;
#if defined(TOPOS_HAVE_V4)
    if (cpu_has_v4()) {
      if constexpr (std::is_same_v<T, float>)
        return layer_norm_float_v4(x + at, w, b, y + at, mean_lo, rstd_lo, hi - lo, C, eps, e);
      else
        return layer_norm_double_v4(x + at, w, b, y + at, mean_lo, rstd_lo, hi - lo, C, eps, e);
    }
#endif
    if constexpr (std::is_same_v<T, float>)
      layer_norm_float(x + at, w, b, y + at, mean_lo, rstd_lo, hi - lo, C, eps, e);
    else
      layer_norm_double(x + at, w, b, y + at, mean_lo, rstd_lo, hi - lo, C, eps, e);
  });
}

// The backward in blocks of rows, each block summing dw and db into its own partial sums (added
// in block order afterwards: the same numbers for any thread count).
template <class T>
void layer_norm_backward_range(const T* dy, const T* y, const T* x, const T* w, const T* mean,
                               const T* rstd, T* dx, T* dw, T* db, std::int64_t n, std::int64_t C,
                               Epilogue e) {
  const std::int64_t block = std::max<std::int64_t>(64, (1 << 16) / C);
  const std::int64_t blocks = (n + block - 1) / block;
  std::vector<T> partial(static_cast<std::size_t>(std::max<std::int64_t>(blocks, 1) * 2 * C), T(0));
  at::parallel_for(0, blocks, grain_rows(blocks, 8 * n * C), [&](std::int64_t k0, std::int64_t k1) {
    for (std::int64_t k = k0; k < k1; ++k) {
      const std::int64_t lo = k * block, rows = std::min(n, lo + block) - lo;
      T* pw = dw ? partial.data() + k * 2 * C : nullptr;
      T* pb = db ? partial.data() + k * 2 * C + C : nullptr;
      const auto at = lo * C;
      const T* ya = y ? y + at : nullptr;
#if defined(TOPOS_HAVE_V4)
      if (cpu_has_v4()) {
        if constexpr (std::is_same_v<T, float>)
          layer_norm_float_v4_backward(dy + at, ya, x + at, w, mean + lo, rstd + lo, dx + at, pw,
                                       pb, rows, C, e);
        else
          layer_norm_double_v4_backward(dy + at, ya, x + at, w, mean + lo, rstd + lo, dx + at, pw,
                                        pb, rows, C, e);
        continue;
      }
#endif
      if constexpr (std::is_same_v<T, float>)
        layer_norm_float_backward(dy + at, ya, x + at, w, mean + lo, rstd + lo, dx + at, pw, pb,
                                  rows, C, e);
      else
        layer_norm_double_backward(dy + at, ya, x + at, w, mean + lo, rstd + lo, dx + at, pw, pb,
                                   rows, C, e);
    }
  });
  for (std::int64_t k = 0; k < blocks; ++k)
    for (std::int64_t c = 0; c < C; ++c) {
      if (dw) dw[c] += partial[static_cast<std::size_t>(k * 2 * C + c)];
      if (db) db[c] += partial[static_cast<std::size_t>(k * 2 * C + C + c)];
    }
}

// LayerNorm (and the activation `act` after it) as one node keeping x, w, each row's mean and
// rstd, and with an activation its output. Undefined weight or bias come in empty (torch 1.13's
// Function::apply cannot take an undefined input).
struct LayerNormFunction : public torch::autograd::Function<LayerNormFunction> {
  static torch::Tensor forward(torch::autograd::AutogradContext* ctx, const torch::Tensor& input,
                               const torch::Tensor& weight, const torch::Tensor& bias, double eps,
                               std::int64_t act) {
    const auto e = static_cast<Epilogue>(act);
    const auto x = input.contiguous();
    const auto w = weight.numel() > 0 ? weight.contiguous() : torch::Tensor();
    const auto b = bias.numel() > 0 ? bias.contiguous() : torch::Tensor();
    const auto n = x.size(0), C = x.size(1);
    auto y = torch::empty_like(x);
    auto mean = torch::empty({n}, x.options()), rstd = torch::empty({n}, x.options());
    AT_DISPATCH_FLOATING_TYPES(x.scalar_type(), "topos_layer_norm", [&] {
      layer_norm_forward_range<scalar_t>(
          x.data_ptr<scalar_t>(), w.defined() ? w.data_ptr<scalar_t>() : nullptr,
          b.defined() ? b.data_ptr<scalar_t>() : nullptr, y.data_ptr<scalar_t>(),
          mean.data_ptr<scalar_t>(), rstd.data_ptr<scalar_t>(), n, C, static_cast<scalar_t>(eps),
          e);
    });
    ctx->save_for_backward({x, w, mean, rstd, e == Epilogue::none ? torch::Tensor() : y});
    ctx->saved_data["bias"] = b.defined();
    ctx->saved_data["act"] = act;
    return y;
  }
  static torch::autograd::tensor_list backward(torch::autograd::AutogradContext* ctx,
                                               torch::autograd::tensor_list grads) {
    const auto saved = ctx->get_saved_variables();
    const auto &x = saved[0], &w = saved[1], &mean = saved[2], &rstd = saved[3], &y = saved[4];
    const auto e = static_cast<Epilogue>(ctx->saved_data["act"].toInt());
    const bool has_bias = ctx->saved_data["bias"].toBool();
    const auto dy = grads[0].contiguous();
    const auto C = x.size(1);
    auto dx = torch::empty_like(x);
    torch::Tensor dw =
        w.defined() && ctx->needs_input_grad(1) ? torch::zeros({C}, x.options()) : torch::Tensor();
    torch::Tensor db =
        has_bias && ctx->needs_input_grad(2) ? torch::zeros({C}, x.options()) : torch::Tensor();
    AT_DISPATCH_FLOATING_TYPES(x.scalar_type(), "topos_layer_norm_backward", [&] {
      layer_norm_backward_range<scalar_t>(
          dy.data_ptr<scalar_t>(), y.defined() ? y.data_ptr<scalar_t>() : nullptr,
          x.data_ptr<scalar_t>(), w.defined() ? w.data_ptr<scalar_t>() : nullptr,
          mean.data_ptr<scalar_t>(), rstd.data_ptr<scalar_t>(), dx.data_ptr<scalar_t>(),
          dw.defined() ? dw.data_ptr<scalar_t>() : nullptr,
          db.defined() ? db.data_ptr<scalar_t>() : nullptr, x.size(0), C, e);
    });
    return {dx, dw, db, torch::Tensor(), torch::Tensor()};
  }
};

}  // namespace detail

/// LayerNorm over the last dimension (torch::nn::functional::layer_norm with normalized_shape
/// {channels}), then `act`: a 2-D float or double CPU tensor through the kernels above as one
/// autograd node (the same values up to float rounding: the mean and variance summed in another
/// order; no second derivative); any other device, dtype or shape takes torch's layer_norm and
/// activation.
inline torch::Tensor layer_norm(const torch::Tensor& x, const torch::Tensor& weight,
                                const torch::Tensor& bias, double eps = 1e-5,
                                detail::Epilogue act = detail::Epilogue::none) {
  const auto C = x.dim() == 2 ? x.size(1) : -1;
  const auto fits = [&](const torch::Tensor& p) {
    return !p.defined() || (p.dim() == 1 && p.numel() == C && p.device() == x.device() &&
                            p.scalar_type() == x.scalar_type());
  };
  const bool fused = x.device().is_cpu() && x.dim() == 2 && C > 0 && x.size(0) > 0 &&
                     (x.scalar_type() == torch::kFloat || x.scalar_type() == torch::kDouble) &&
                     fits(weight) && fits(bias);
  if (!fused)
    return detail::activate(torch::layer_norm(x, {x.dim() > 0 ? x.size(-1) : 0}, weight, bias, eps),
                            act);
  const bool grad = torch::GradMode::is_enabled() &&
                    (x.requires_grad() || (weight.defined() && weight.requires_grad()) ||
                     (bias.defined() && bias.requires_grad()));
  if (!grad) {  // a rollout's: no node, no statistics kept
    const auto xc = x.contiguous();
    const auto w = weight.defined() ? weight.contiguous() : weight;
    const auto b = bias.defined() ? bias.contiguous() : bias;
    auto y = torch::empty_like(xc);
    AT_DISPATCH_FLOATING_TYPES(x.scalar_type(), "topos_layer_norm", [&] {
      detail::layer_norm_forward_range<scalar_t>(
          xc.data_ptr<scalar_t>(), w.defined() ? w.data_ptr<scalar_t>() : nullptr,
          b.defined() ? b.data_ptr<scalar_t>() : nullptr, y.data_ptr<scalar_t>(), nullptr, nullptr,
          xc.size(0), C, static_cast<scalar_t>(eps), act);
    });
    return y;
  }
  const auto empty = torch::empty({0}, x.options());
  return detail::LayerNormFunction::apply(x, weight.defined() ? weight : empty,
                                          bias.defined() ? bias : empty, eps,
                                          static_cast<std::int64_t>(act));
}

/// A torch::nn::LayerNorm module applied through layer_norm above when it normalises one
/// dimension (the module's own forward, then `act`, otherwise).
inline torch::Tensor layer_norm(const torch::Tensor& x, torch::nn::LayerNormImpl& m,
                                detail::Epilogue act = detail::Epilogue::none) {
  if (m.options.normalized_shape().size() != 1) return detail::activate(m.forward(x), act);
  return layer_norm(x, m.weight, m.bias, m.options.eps(), act);
}

}  // namespace topos::nn
