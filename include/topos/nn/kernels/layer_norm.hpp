// topos/nn/kernels/layer_norm.hpp
// LayerNorm over the channels of a (rows × channels) CPU tensor as one autograd node: each row's
// mean and variance in two passes over the row while it sits in L1, the normalised row scaled and
// shifted before the store, and a hand-written backward. torch 1.13's CPU layer_norm costs 5-10x
// this on HOPNet's and TopoBench's rows of 64-128 channels (bench_hopnet's BM_layer_norm); in a
// HOPNet rollout step, after the products, it was the largest single operation. It may normalise
// a sum x + r it forms itself (nn::add_layer_norm: a residual connection, or a bias row).
#pragma once

#include "topos/nn/kernels/epilogue.hpp"

#include <ATen/Parallel.h>
#include <torch/torch.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <type_traits>
#include <vector>

#if defined(TOPOS_HAVE_V4)
#include <immintrin.h>
#endif

namespace topos::nn {

namespace detail {

#if defined(__GNUC__)
// The vector parts of one row's passes, channels [0, Cv) (Cv a multiple of V's L lanes): shared
// by the row kernels and the 16-row groups, so that both do the same arithmetic in the same order.
template <class T, class V>
static TOPOS_INLINE_KERNEL void ln_add_vec(const T* x, const T* r, T* s, std::int64_t Cv) {
  constexpr int L = static_cast<int>(sizeof(V) / sizeof(T));
  for (std::int64_t c = 0; c < Cv; c += L) {
    V u, v;
    std::memcpy(&u, x + c, sizeof u);
    std::memcpy(&v, r + c, sizeof v);
    u += v;
    std::memcpy(s + c, &u, sizeof u);
  }
}
// (Vectors are passed back through references: returned by value, GCC warns of the ABI of the
// clones without AVX.)
template <class T, class V>
static TOPOS_INLINE_KERNEL void ln_sum_vec(const T* x, std::int64_t Cv, V& sv) {
  constexpr int L = static_cast<int>(sizeof(V) / sizeof(T));
  sv = V{};
  for (std::int64_t c = 0; c < Cv; c += L) {
    V v;
    std::memcpy(&v, x + c, sizeof v);
    sv += v;
  }
}
template <class T, class V>
static TOPOS_INLINE_KERNEL void ln_squared_deviations_vec(const T* x, T m, std::int64_t Cv, V& qv) {
  constexpr int L = static_cast<int>(sizeof(V) / sizeof(T));
  qv = V{};
  for (std::int64_t c = 0; c < Cv; c += L) {
    V v;
    std::memcpy(&v, x + c, sizeof v);
    v -= m;
    qv += v * v;
  }
}
template <class T, class V, Epilogue E>
static TOPOS_INLINE_KERNEL void ln_normalise_vec(const T* x, T m, T r, const T* w, const T* b, T* y,
                                                 std::int64_t Cv) {
  constexpr int L = static_cast<int>(sizeof(V) / sizeof(T));
  for (std::int64_t c = 0; c < Cv; c += L) {
    V v;
    std::memcpy(&v, x + c, sizeof v);
    v = (v - m) * r;
    if (w) {
      V wv;
      std::memcpy(&wv, w + c, sizeof wv);
      v *= wv;
    }
    if (b) {
      V bv;
      std::memcpy(&bv, b + c, sizeof bv);
      v += bv;
    }
    epilogue_vec<T, E>(v);
    std::memcpy(y + c, &v, sizeof v);
  }
}
// dy (times act'(y) after an activation) at channels [c, c + L).
template <class T, class V, Epilogue E>
static TOPOS_INLINE_KERNEL void ln_output_grad_vec(const T* dr, const T* yr, std::int64_t c, V& d) {
  std::memcpy(&d, dr + c, sizeof d);
  if constexpr (E != Epilogue::none) {
    V yv;
    std::memcpy(&yv, yr + c, sizeof yv);
    epilogue_grad<T>(yv, d, E);
  }
}
// The backward's first pass: dw += dy · x̂ and db += dy; sgv and sgxv the row's Σ g and Σ g · x̂.
template <class T, class V, Epilogue E>
static TOPOS_INLINE_KERNEL void ln_backward_sums_vec(const T* dr, const T* yr, const T* xr, T m,
                                                     T r, const T* w, T* dw, T* db, std::int64_t Cv,
                                                     V& sgv, V& sgxv) {
  constexpr int L = static_cast<int>(sizeof(V) / sizeof(T));
  sgv = V{}, sgxv = V{};
  for (std::int64_t c = 0; c < Cv; c += L) {
    V d, v;
    ln_output_grad_vec<T, V, E>(dr, yr, c, d);
    std::memcpy(&v, xr + c, sizeof v);
    const V xh = (v - m) * r;
    if (dw) add_into<T, V>(dw + c, d * xh);
    if (db) add_into<T, V>(db + c, d);
    if (w) {
      V wv;
      std::memcpy(&wv, w + c, sizeof wv);
      d *= wv;
    }
    sgv += d;
    sgxv += d * xh;
  }
}
// The backward's second pass: dx, and dres += dx.
template <class T, class V, Epilogue E>
static TOPOS_INLINE_KERNEL void ln_backward_dx_vec(const T* dr, const T* yr, const T* xr, T m, T r,
                                                   T mg, T mgx, const T* w, T* xo, T* dres,
                                                   std::int64_t Cv) {
  constexpr int L = static_cast<int>(sizeof(V) / sizeof(T));
  for (std::int64_t c = 0; c < Cv; c += L) {
    V d, v;
    ln_output_grad_vec<T, V, E>(dr, yr, c, d);
    std::memcpy(&v, xr + c, sizeof v);
    if (w) {
      V wv;
      std::memcpy(&wv, w + c, sizeof wv);
      d *= wv;
    }
    const V o = (d - mg - (v - m) * r * mgx) * r;
    std::memcpy(xo + c, &o, sizeof o);
    if (dres) add_into<T, V>(dres + c, o);
  }
}
#endif

#if defined(TOPOS_HAVE_V4)
#define TOPOS_V4_INLINE inline __attribute__((always_inline, target("arch=x86-64-v4")))
// Where row j of a group of 16 goes in lane_sums16's input, so that the output's lane j is its.
inline constexpr int kLaneSumSlot[16] = {0, 2, 1, 3, 8, 10, 9, 11, 4, 6, 5, 7, 12, 14, 13, 15};
// Sixteen rows' lane_sum at once: lane j of the result is lane_sum(v[kLaneSumSlot[j]], 0) by
// lane_sum's own tree (lanes l and l + w added for w = 8, 4, 2, 1), bit for bit. A row's
// statistics were a chain of dependent reductions, a division and a square root: on rows of
// 64-128 channels in L1 that chain, not the arithmetic, set a LayerNorm's speed.
TOPOS_V4_INLINE __m512 lane_sums16(const __m512* v) {
  // The zero-masked forms (here and for sqrt): the plain ones start from _mm512_undefined_ps,
  // which GCC 12 reports as maybe-uninitialized.
  constexpr __mmask16 kAll = 0xFFFF;
  __m512 u[8], p[4], q[2];
  for (int k = 0; k < 8; ++k)  // w = 8: halves of 256 bits
    u[k] = _mm512_add_ps(_mm512_maskz_shuffle_f32x4(kAll, v[k], v[k + 8], 0x44),
                         _mm512_maskz_shuffle_f32x4(kAll, v[k], v[k + 8], 0xEE));
  for (int k = 0; k < 4; ++k)  // w = 4: halves of 128 bits
    p[k] = _mm512_add_ps(_mm512_maskz_shuffle_f32x4(kAll, u[k], u[k + 4], 0x88),
                         _mm512_maskz_shuffle_f32x4(kAll, u[k], u[k + 4], 0xDD));
  for (int k = 0; k < 2; ++k)  // w = 2: within 128-bit lanes
    q[k] = _mm512_add_ps(_mm512_maskz_shuffle_ps(kAll, p[k], p[k + 2], 0x44),
                         _mm512_maskz_shuffle_ps(kAll, p[k], p[k + 2], 0xEE));
  return _mm512_add_ps(_mm512_maskz_shuffle_ps(kAll, q[0], q[1], 0x88),  // w = 1
                       _mm512_maskz_shuffle_ps(kAll, q[0], q[1], 0xDD));
}
// Sixteen rows' sums (lane_sum's, a scalar tail of 0 added) divided by C, lane j row j's.
TOPOS_V4_INLINE void row_means16(const __m512* slots, std::int64_t C, float* out) {
  _mm512_store_ps(out, _mm512_div_ps(_mm512_add_ps(lane_sums16(slots), _mm512_setzero_ps()),
                                     _mm512_set1_ps(static_cast<float>(C))));
}
typedef float vec16f __attribute__((vector_size(64)));

// layer_norm_rows for 16 rows of float at once (C a multiple of 16), through the same row passes:
// the same outputs and statistics bit for bit, the reductions, divisions and square roots shared
// by the 16 rows. A call of its own, not inlined: the row kernels that call it are compiled for
// every target.
template <Epilogue E>
TOPOS_V4 inline void layer_norm_rows16(const float* x, const float* res, std::int64_t r_step,
                                       float* sum, const float* w, const float* b, float* y,
                                       float* mean, float* rstd, std::int64_t C, float eps) {
  const float* xs[16];
  __m512 slots[16];
  for (int j = 0; j < 16; ++j) {
    xs[j] = x + j * C;
    if (res) {
      ln_add_vec<float, vec16f>(xs[j], res + j * r_step, sum + j * C, C);
      xs[j] = sum + j * C;
    }
    vec16f sv;
    ln_sum_vec<float, vec16f>(xs[j], C, sv);
    std::memcpy(&slots[kLaneSumSlot[j]], &sv, sizeof sv);
  }
  alignas(64) float ms[16], vs[16];
  row_means16(slots, C, ms);
  for (int j = 0; j < 16; ++j) {
    vec16f qv;
    ln_squared_deviations_vec<float, vec16f>(xs[j], ms[j], C, qv);
    std::memcpy(&slots[kLaneSumSlot[j]], &qv, sizeof qv);
  }
  row_means16(slots, C, vs);  // the variances
  alignas(64) float rs[16];
  _mm512_store_ps(
      rs, _mm512_div_ps(_mm512_set1_ps(1.0f),
                        _mm512_maskz_sqrt_ps(0xFFFF, _mm512_load_ps(vs) + _mm512_set1_ps(eps))));
  for (int j = 0; j < 16; ++j) {
    ln_normalise_vec<float, vec16f, E>(xs[j], ms[j], rs[j], w, b, y + j * C, C);
    if (mean) mean[j] = ms[j], rstd[j] = rs[j];
  }
}

// layer_norm_backward_rows for 16 rows of float at once (C a multiple of 16), through the same
// row passes, dw, db and dres summed over the rows in their order: the same bits.
template <Epilogue E>
TOPOS_V4 inline void layer_norm_backward_rows16(const float* dy, const float* y, const float* x,
                                                const float* w, const float* mean,
                                                const float* rstd, float* dx, float* dw, float* db,
                                                float* dres, std::int64_t C) {
  __m512 sgs[16], sgxs[16];
  for (int j = 0; j < 16; ++j) {
    vec16f sgv, sgxv;
    ln_backward_sums_vec<float, vec16f, E>(dy + j * C, y ? y + j * C : nullptr, x + j * C, mean[j],
                                           rstd[j], w, dw, db, C, sgv, sgxv);
    std::memcpy(&sgs[kLaneSumSlot[j]], &sgv, sizeof sgv);
    std::memcpy(&sgxs[kLaneSumSlot[j]], &sgxv, sizeof sgxv);
  }
  alignas(64) float mgs[16], mgxs[16];
  row_means16(sgs, C, mgs);
  row_means16(sgxs, C, mgxs);
  for (int j = 0; j < 16; ++j)
    ln_backward_dx_vec<float, vec16f, E>(dy + j * C, y ? y + j * C : nullptr, x + j * C, mean[j],
                                         rstd[j], mgs[j], mgxs[j], w, dx + j * C, dres, C);
}
#endif

// Rows [0, n) of x: y = act((x - mean) · rstd · w + b) (w, b may be null; act relu, elu or sigmoid
// applied before the store), each row's mean and 1 / sqrt(var + eps) stored for the backward
// (unless mean is null). The variance is the mean of squared deviations (biased, as torch's).
// With a residual r (rows `r_step` apart: C, or 0 for one row added to every row), x + r is
// normalised, and written to `sum` first (the backward's input).
template <class T, int VB = 32, Epilogue E = Epilogue::none>
static TOPOS_INLINE_KERNEL void layer_norm_rows(const T* x, const T* res, std::int64_t r_step,
                                                T* sum, const T* w, const T* b, T* y, T* mean,
                                                T* rstd, std::int64_t n, std::int64_t C, T eps) {
#if defined(__GNUC__)
  typedef T vec __attribute__((vector_size(VB)));
  const std::int64_t Cv = C / static_cast<std::int64_t>(VB / sizeof(T)) * (VB / sizeof(T));
#else
  const std::int64_t Cv = 0;  // no vector part: every channel in the scalar loops
#endif
  std::int64_t i = 0;
#if defined(TOPOS_HAVE_V4)
  if constexpr (std::is_same_v<T, float> && VB == 64) {
    if (C % 16 == 0)
      for (; i + 16 <= n; i += 16)
        layer_norm_rows16<E>(x + i * C, res ? res + i * r_step : nullptr, r_step,
                             res ? sum + i * C : nullptr, w, b, y + i * C,
                             mean ? mean + i : nullptr, rstd ? rstd + i : nullptr, C, eps);
  }
#endif
  for (; i < n; ++i) {
    const T* xr = x + i * C;
    T* yr = y + i * C;
    T s = 0, q = 0;
    if (res) {
      const T* rr = res + i * r_step;
      T* sr = sum + i * C;
#if defined(__GNUC__)
      ln_add_vec<T, vec>(xr, rr, sr, Cv);
#endif
      for (std::int64_t c = Cv; c < C; ++c) sr[c] = xr[c] + rr[c];
      xr = sr;
    }
#if defined(__GNUC__)
    vec sv;
    ln_sum_vec<T, vec>(xr, Cv, sv);
#endif
    for (std::int64_t c = Cv; c < C; ++c) s += xr[c];
#if defined(__GNUC__)
    s = lane_sum(sv, s);
#endif
    const T m = s / static_cast<T>(C);
#if defined(__GNUC__)
    vec qv;
    ln_squared_deviations_vec<T, vec>(xr, m, Cv, qv);
#endif
    for (std::int64_t c = Cv; c < C; ++c) q += (xr[c] - m) * (xr[c] - m);
#if defined(__GNUC__)
    q = lane_sum(qv, q);
#endif
    const T r = T(1) / std::sqrt(q / static_cast<T>(C) + eps);
#if defined(__GNUC__)
    ln_normalise_vec<T, vec, E>(xr, m, r, w, b, yr, Cv);
#endif
    for (std::int64_t c = Cv; c < C; ++c)
      yr[c] = epilogue_scalar<T>((xr[c] - m) * r * (w ? w[c] : T(1)) + (b ? b[c] : T(0)), E);
    if (mean) mean[i] = m, rstd[i] = r;
  }
}

// The backward of rows [0, n): with x̂ = (x - mean) · rstd and g = dy · w,
// dx = rstd · (g - mean(g) - x̂ · mean(g · x̂)); dw += Σ dy · x̂, db += Σ dy and dres += Σ dx (a
// residual row's gradient) into this block's partial sums (dw, db, dres may be null). After an
// activation E, dy is first dy ⊙ act'(y) from the output y (epilogue_rows's rule).
template <class T, int VB = 32, Epilogue E = Epilogue::none>
static TOPOS_INLINE_KERNEL void layer_norm_backward_rows(const T* dy, const T* y, const T* x,
                                                         const T* w, const T* mean, const T* rstd,
                                                         T* dx, T* dw, T* db, T* dres,
                                                         std::int64_t n, std::int64_t C) {
#if defined(__GNUC__)
  typedef T vec __attribute__((vector_size(VB)));
  const std::int64_t Cv = C / static_cast<std::int64_t>(VB / sizeof(T)) * (VB / sizeof(T));
#else
  const std::int64_t Cv = 0;  // no vector part: every channel in the scalar loops
#endif
  std::int64_t i = 0;
#if defined(TOPOS_HAVE_V4)
  if constexpr (std::is_same_v<T, float> && VB == 64) {
    if (C % 16 == 0)
      for (; i + 16 <= n; i += 16)
        layer_norm_backward_rows16<E>(dy + i * C, y ? y + i * C : nullptr, x + i * C, w, mean + i,
                                      rstd + i, dx + i * C, dw, db, dres, C);
  }
#endif
  for (; i < n; ++i) {
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
#if defined(__GNUC__)
    vec sgv, sgxv;
    ln_backward_sums_vec<T, vec, E>(dr, yr, xr, m, r, w, dw, db, Cv, sgv, sgxv);
#endif
    for (std::int64_t c = Cv; c < C; ++c) {
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
#if defined(__GNUC__)
    ln_backward_dx_vec<T, vec, E>(dr, yr, xr, m, r, mg, mgx, w, xo, dres, Cv);
#endif
    for (std::int64_t c = Cv; c < C; ++c) {
      xo[c] = (grad(c) * (w ? w[c] : T(1)) - mg - (xr[c] - m) * r * mgx) * r;
      if (dres) dres[c] += xo[c];
    }
  }
}

// The kernels per instruction set (epilogue.hpp): AVX-512 on 64-byte vectors when the CPU has it.
#define TOPOS_LAYER_NORM_ENTRY(T, NAME, ATTR, VB)                                                  \
  [[maybe_unused]] ATTR static void NAME(const T* x, const T* res, std::int64_t r_step, T* sum,    \
                                         const T* w, const T* b, T* y, T* mean, T* rstd,           \
                                         std::int64_t n, std::int64_t C, T eps, Epilogue e) {      \
    if (e == Epilogue::relu)                                                                       \
      return layer_norm_rows<T, VB, Epilogue::relu>(x, res, r_step, sum, w, b, y, mean, rstd, n,   \
                                                    C, eps);                                       \
    if (e == Epilogue::elu)                                                                        \
      return layer_norm_rows<T, VB, Epilogue::elu>(x, res, r_step, sum, w, b, y, mean, rstd, n, C, \
                                                   eps);                                           \
    if (e == Epilogue::sigmoid)                                                                    \
      return layer_norm_rows<T, VB, Epilogue::sigmoid>(x, res, r_step, sum, w, b, y, mean, rstd,   \
                                                       n, C, eps);                                 \
    layer_norm_rows<T, VB>(x, res, r_step, sum, w, b, y, mean, rstd, n, C, eps);                   \
  }                                                                                                \
  [[maybe_unused]] ATTR static void NAME##_backward(                                               \
      const T* dy, const T* y, const T* x, const T* w, const T* mean, const T* rstd, T* dx, T* dw, \
      T* db, T* dr, std::int64_t n, std::int64_t C, Epilogue e) {                                  \
    if (e == Epilogue::relu)                                                                       \
      return layer_norm_backward_rows<T, VB, Epilogue::relu>(dy, y, x, w, mean, rstd, dx, dw, db,  \
                                                             dr, n, C);                            \
    if (e == Epilogue::elu)                                                                        \
      return layer_norm_backward_rows<T, VB, Epilogue::elu>(dy, y, x, w, mean, rstd, dx, dw, db,   \
                                                            dr, n, C);                             \
    if (e == Epilogue::sigmoid)                                                                    \
      return layer_norm_backward_rows<T, VB, Epilogue::sigmoid>(dy, y, x, w, mean, rstd, dx, dw,   \
                                                                db, dr, n, C);                     \
    layer_norm_backward_rows<T, VB>(dy, y, x, w, mean, rstd, dx, dw, db, dr, n, C);                \
  }
TOPOS_LAYER_NORM_ENTRY(float, layer_norm_float, TOPOS_SIMD_CLONES, 32)
TOPOS_LAYER_NORM_ENTRY(double, layer_norm_double, TOPOS_SIMD_CLONES, 32)
#if defined(TOPOS_HAVE_V4)
TOPOS_LAYER_NORM_ENTRY(float, layer_norm_float_v4, TOPOS_V4, 64)
TOPOS_LAYER_NORM_ENTRY(double, layer_norm_double_v4, TOPOS_V4, 64)
#endif
#undef TOPOS_LAYER_NORM_ENTRY

// What a LayerNorm normalises: x, or x + r with r `r_step` apart (C: a tensor of x's shape; 0:
// one row added to every row), the sum written to `sum` (the backward's input).
template <class T>
struct LayerNormInput {
  const T* x = nullptr;
  const T* res = nullptr;
  std::int64_t r_step = 0;
  T* sum = nullptr;
};

template <class T>
void layer_norm_forward_range(const LayerNormInput<T>& in, const T* w, const T* b, T* y, T* mean,
                              T* rstd, std::int64_t n, std::int64_t C, T eps, Epilogue e) {
  at::parallel_for(0, n, grain_rows(n, 4 * n * C), [&](std::int64_t lo, std::int64_t hi) {
    const auto at = lo * C;
    // No statistics kept (mean null): a later range must not write at null + lo.
    T* const mean_lo = mean ? mean + lo : nullptr;
    T* const rstd_lo = rstd ? rstd + lo : nullptr;
    const T* const res = in.res ? in.res + lo * in.r_step : nullptr;
    T* const sum = in.res ? in.sum + at : nullptr;
#if defined(TOPOS_HAVE_V4)
    if (cpu_has_v4()) {
      if constexpr (std::is_same_v<T, float>)
        return layer_norm_float_v4(in.x + at, res, in.r_step, sum, w, b, y + at, mean_lo, rstd_lo,
                                   hi - lo, C, eps, e);
      else
        return layer_norm_double_v4(in.x + at, res, in.r_step, sum, w, b, y + at, mean_lo, rstd_lo,
                                    hi - lo, C, eps, e);
    }
#endif
    if constexpr (std::is_same_v<T, float>)
      layer_norm_float(in.x + at, res, in.r_step, sum, w, b, y + at, mean_lo, rstd_lo, hi - lo, C,
                       eps, e);
    else
      layer_norm_double(in.x + at, res, in.r_step, sum, w, b, y + at, mean_lo, rstd_lo, hi - lo, C,
                        eps, e);
  });
}

// The backward in blocks of rows, each block summing dw, db and dr (a residual row's gradient)
// into its own partial sums (added in block order afterwards: the same numbers for any thread
// count).
template <class T>
void layer_norm_backward_range(const T* dy, const T* y, const T* x, const T* w, const T* mean,
                               const T* rstd, T* dx, T* dw, T* db, T* dr, std::int64_t n,
                               std::int64_t C, Epilogue e) {
  const std::int64_t block = std::max<std::int64_t>(64, (1 << 16) / C);
  const std::int64_t blocks = (n + block - 1) / block;
  std::vector<T> partial(static_cast<std::size_t>(std::max<std::int64_t>(blocks, 1) * 3 * C), T(0));
  at::parallel_for(0, blocks, grain_rows(blocks, 8 * n * C), [&](std::int64_t k0, std::int64_t k1) {
    for (std::int64_t k = k0; k < k1; ++k) {
      const std::int64_t lo = k * block, rows = std::min(n, lo + block) - lo;
      T* pw = dw ? partial.data() + k * 3 * C : nullptr;
      T* pb = db ? partial.data() + k * 3 * C + C : nullptr;
      T* pr = dr ? partial.data() + k * 3 * C + 2 * C : nullptr;
      const auto at = lo * C;
      const T* ya = y ? y + at : nullptr;
#if defined(TOPOS_HAVE_V4)
      if (cpu_has_v4()) {
        if constexpr (std::is_same_v<T, float>)
          layer_norm_float_v4_backward(dy + at, ya, x + at, w, mean + lo, rstd + lo, dx + at, pw,
                                       pb, pr, rows, C, e);
        else
          layer_norm_double_v4_backward(dy + at, ya, x + at, w, mean + lo, rstd + lo, dx + at, pw,
                                        pb, pr, rows, C, e);
        continue;
      }
#endif
      if constexpr (std::is_same_v<T, float>)
        layer_norm_float_backward(dy + at, ya, x + at, w, mean + lo, rstd + lo, dx + at, pw, pb, pr,
                                  rows, C, e);
      else
        layer_norm_double_backward(dy + at, ya, x + at, w, mean + lo, rstd + lo, dx + at, pw, pb,
                                   pr, rows, C, e);
    }
  });
  for (std::int64_t k = 0; k < blocks; ++k)
    for (std::int64_t c = 0; c < C; ++c) {
      const auto* p = partial.data() + k * 3 * C;
      if (dw) dw[c] += p[c];
      if (db) db[c] += p[C + c];
      if (dr) dr[c] += p[2 * C + c];
    }
}

// LayerNorm of x (+ a residual) and the activation `act` after it as one node keeping what it
// normalised (x, or the sum), w, each row's mean and rstd, and with an activation its output.
// Undefined tensors come in empty (torch 1.13's Function::apply cannot take an undefined input);
// a residual of C entries is one row added to every row.
struct LayerNormFunction : public torch::autograd::Function<LayerNormFunction> {
  // y, and the sum and statistics when `keep` (else those stay undefined).
  static std::vector<torch::Tensor> compute(const torch::Tensor& input,
                                            const torch::Tensor& residual,
                                            const torch::Tensor& weight, const torch::Tensor& bias,
                                            double eps, Epilogue e, bool keep) {
    const auto x = input.contiguous();
    const auto r = residual.numel() > 0 ? residual.contiguous() : torch::Tensor();
    const auto w = weight.numel() > 0 ? weight.contiguous() : torch::Tensor();
    const auto b = bias.numel() > 0 ? bias.contiguous() : torch::Tensor();
    const auto n = x.size(0), C = x.size(1);
    auto y = torch::empty_like(x);
    // Without a backward the sum is formed in y itself (each row read and written in place).
    torch::Tensor sum = r.defined() ? (keep ? torch::empty_like(x) : y) : x, mean, rstd;
    if (keep) mean = torch::empty({n}, x.options()), rstd = torch::empty({n}, x.options());
    AT_DISPATCH_FLOATING_TYPES(x.scalar_type(), "topos_layer_norm", [&] {
      using T = scalar_t;
      LayerNormInput<T> in;
      in.x = x.data_ptr<T>();
      if (r.defined())
        in.res = r.data_ptr<T>(), in.r_step = r.dim() == 1 ? 0 : C, in.sum = sum.data_ptr<T>();
      layer_norm_forward_range<T>(
          in, w.defined() ? w.data_ptr<T>() : nullptr, b.defined() ? b.data_ptr<T>() : nullptr,
          y.data_ptr<T>(), keep ? mean.data_ptr<T>() : nullptr, keep ? rstd.data_ptr<T>() : nullptr,
          n, C, static_cast<T>(eps), e);
    });
    return {y, sum, mean, rstd, w};
  }
  static torch::Tensor forward(torch::autograd::AutogradContext* ctx, const torch::Tensor& input,
                               const torch::Tensor& residual, const torch::Tensor& weight,
                               const torch::Tensor& bias, double eps, std::int64_t act) {
    const auto e = static_cast<Epilogue>(act);
    auto out = compute(input, residual, weight, bias, eps, e, true);
    ctx->save_for_backward(
        {out[1], out[4], out[2], out[3], e == Epilogue::none ? torch::Tensor() : out[0]});
    ctx->saved_data["bias"] = bias.numel() > 0;
    ctx->saved_data["residual"] = residual.numel() == 0 ? 0 : residual.dim();
    ctx->saved_data["act"] = act;
    return out[0];
  }
  static torch::autograd::tensor_list backward(torch::autograd::AutogradContext* ctx,
                                               torch::autograd::tensor_list grads) {
    const auto saved = ctx->get_saved_variables();
    const auto &x = saved[0], &w = saved[1], &mean = saved[2], &rstd = saved[3], &y = saved[4];
    const auto e = static_cast<Epilogue>(ctx->saved_data["act"].toInt());
    const bool has_bias = ctx->saved_data["bias"].toBool();
    const auto residual = ctx->saved_data["residual"].toInt();  // 0 none, 1 a row, 2 a tensor
    const auto dy = grads[0].contiguous();
    const auto C = x.size(1);
    auto dx = torch::empty_like(x);
    torch::Tensor dw =
        w.defined() && ctx->needs_input_grad(2) ? torch::zeros({C}, x.options()) : torch::Tensor();
    torch::Tensor db =
        has_bias && ctx->needs_input_grad(3) ? torch::zeros({C}, x.options()) : torch::Tensor();
    torch::Tensor dr = residual == 1 && ctx->needs_input_grad(1) ? torch::zeros({C}, x.options())
                                                                 : torch::Tensor();
    const auto ptr = [](torch::Tensor& t, auto* type) {
      return t.defined() ? t.data_ptr<std::remove_pointer_t<decltype(type)>>() : nullptr;
    };
    AT_DISPATCH_FLOATING_TYPES(x.scalar_type(), "topos_layer_norm_backward", [&] {
      scalar_t* type = nullptr;
      layer_norm_backward_range<scalar_t>(
          dy.data_ptr<scalar_t>(), y.defined() ? y.data_ptr<scalar_t>() : nullptr,
          x.data_ptr<scalar_t>(), w.defined() ? w.data_ptr<scalar_t>() : nullptr,
          mean.data_ptr<scalar_t>(), rstd.data_ptr<scalar_t>(), dx.data_ptr<scalar_t>(),
          ptr(dw, type), ptr(db, type), ptr(dr, type), x.size(0), C, e);
    });
    if (residual == 2 && ctx->needs_input_grad(1)) dr = dx;  // d(x + r)/dr = 1
    return {ctx->needs_input_grad(0) ? dx : torch::Tensor(),
            dr,
            dw,
            db,
            torch::Tensor(),
            torch::Tensor()};
  }
};

}  // namespace detail

/// LayerNorm over the last dimension of x + residual (torch::nn::functional::layer_norm with
/// normalized_shape {channels}), then `act`: a 2-D float or double CPU tensor through the kernels
/// above as one autograd node (the same values up to float rounding: the mean and variance summed
/// in another order; no second derivative). `residual`, when defined, is a tensor of x's shape
/// (a residual connection's) or one row of channels added to every row (a bias); the sum is formed
/// in the kernel. Any other device, dtype or shape takes torch's add, layer_norm and activation.
inline torch::Tensor add_layer_norm(const torch::Tensor& x, const torch::Tensor& residual,
                                    const torch::Tensor& weight, const torch::Tensor& bias,
                                    double eps = 1e-5,
                                    detail::Epilogue act = detail::Epilogue::none) {
  const auto C = x.dim() == 2 ? x.size(1) : -1;
  const auto same = [&](const torch::Tensor& p) {
    return p.device() == x.device() && p.scalar_type() == x.scalar_type();
  };
  const auto fits = [&](const torch::Tensor& p) {
    return !p.defined() || (p.dim() == 1 && p.numel() == C && same(p));
  };
  const bool residual_fits =
      !residual.defined() || fits(residual) ||
      (residual.dim() == 2 && residual.sizes() == x.sizes() && same(residual));
  const bool fused = x.device().is_cpu() && x.dim() == 2 && C > 0 && x.size(0) > 0 &&
                     (x.scalar_type() == torch::kFloat || x.scalar_type() == torch::kDouble) &&
                     fits(weight) && fits(bias) && residual_fits;
  if (!fused) {
    const auto s = residual.defined() ? x + residual : x;
    return detail::activate(torch::layer_norm(s, {s.dim() > 0 ? s.size(-1) : 0}, weight, bias, eps),
                            act);
  }
  const auto needs = [](const torch::Tensor& t) { return t.defined() && t.requires_grad(); };
  const bool grad = torch::GradMode::is_enabled() &&
                    (needs(x) || needs(residual) || needs(weight) || needs(bias));
  if (!grad)  // a rollout's: no node, no statistics kept
    return detail::LayerNormFunction::compute(x, residual.defined() ? residual : torch::Tensor(),
                                              weight, bias, eps, act, false)[0];
  const auto empty = torch::empty({0}, x.options());
  const auto or_empty = [&](const torch::Tensor& t) { return t.defined() ? t : empty; };
  return detail::LayerNormFunction::apply(x, or_empty(residual), or_empty(weight), or_empty(bias),
                                          eps, static_cast<std::int64_t>(act));
}

/// LayerNorm over the last dimension, then `act` (add_layer_norm without a residual).
inline torch::Tensor layer_norm(const torch::Tensor& x, const torch::Tensor& weight,
                                const torch::Tensor& bias, double eps = 1e-5,
                                detail::Epilogue act = detail::Epilogue::none) {
  return add_layer_norm(x, torch::Tensor(), weight, bias, eps, act);
}

/// A torch::nn::LayerNorm module applied to x + residual (residual may be undefined) through
/// add_layer_norm above when it normalises one dimension (the add, the module's own forward,
/// then `act`, otherwise).
inline torch::Tensor add_layer_norm(const torch::Tensor& x, const torch::Tensor& residual,
                                    torch::nn::LayerNormImpl& m,
                                    detail::Epilogue act = detail::Epilogue::none) {
  if (m.options.normalized_shape().size() != 1)
    return detail::activate(m.forward(residual.defined() ? x + residual : x), act);
  return add_layer_norm(x, residual, m.weight, m.bias, m.options.eps(), act);
}

/// A torch::nn::LayerNorm module applied through layer_norm above when it normalises one
/// dimension (the module's own forward, then `act`, otherwise).
inline torch::Tensor layer_norm(const torch::Tensor& x, torch::nn::LayerNormImpl& m,
                                detail::Epilogue act = detail::Epilogue::none) {
  return add_layer_norm(x, torch::Tensor(), m, act);
}

}  // namespace topos::nn
