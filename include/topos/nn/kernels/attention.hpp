// topos/nn/kernels/attention.hpp
// The kernels under nn::multi_head_attention_from_cells: multi-head attention over a CSR pattern
// from per-cell scores, a target row at a time. The forward takes each entry's score (its
// source's plus its target's), the scores' activation, the per-row norm (softmax, row sum or
// none) and every head's weighted sum of the messages in one pass over the rows. The backward
// takes the rows (the weights' gradients, the norm's and the activation's backward, the targets'
// score gradients), then the columns through Aᵀ's CSR (the messages' and the sources' score
// gradients): each output row written by one thread, no atomics. Also the per-cell scores
// themselves (nn::head_scores: per cell and head <f_h, a_h>) and their backward.
#pragma once

#include "topos/nn/kernels/epilogue.hpp"

#include <ATen/Parallel.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <type_traits>
#include <utility>
#include <vector>

namespace topos::nn::detail {

/// The activations and norms the kernels apply to the scores (nn::Activation and
/// nn::AttentionNorm map onto them; the others run as torch's operations).
enum class ScoreActivation { none, relu, leaky_relu, elu };
enum class ScoreNorm { softmax, row_sum, none };

/// What the kernels read and write. Scores and weights are entries × heads (row-major), messages
/// and outputs cells × heads·channels, a head's channels side by side.
template <class T>
struct AttentionArgs {
  const std::int64_t *crow = nullptr, *col = nullptr;  // A's CSR, entries in row order
  const std::int64_t *t_crow = nullptr, *t_row = nullptr, *t_perm = nullptr;  // Aᵀ's
  const T* values = nullptr;                                                  // A's values
  const T *source = nullptr, *target = nullptr;  // per-cell scores (target may be null)
  const T* x = nullptr;                          // the messages
  T* weights = nullptr;  // forward: written (the normed weights, before A's values)
  std::int64_t rows = 0, cols = 0, nnz = 0, heads = 1, channels = 0;  // channels per head
  ScoreActivation act = ScoreActivation::none;
  T slope = 0;
  ScoreNorm norm = ScoreNorm::softmax;
};

// The entries' rows are gathered from arrays larger than the caches (REDDIT-BINARY's batches:
// 110 k rows of 64 floats): the row that entry k + kAhead reads is asked for ahead of time.
constexpr std::int64_t kAhead = 8;
template <class T>
static TOPOS_INLINE_KERNEL void prefetch_row(const T* base, const std::int64_t* index,
                                             std::int64_t k, std::int64_t nnz, std::int64_t width) {
#if defined(__GNUC__)
  if (k < nnz) {
    const char* p = reinterpret_cast<const char*>(base + index[k] * width);
    for (std::int64_t b = 0; b < width * static_cast<std::int64_t>(sizeof(T)); b += 64)
      __builtin_prefetch(p + b);
  }
#endif
}

// relu and leaky_relu without a branch on the score's sign, which is random: mispredicted about
// every other entry and head, it was a third of the forward. leaky_relu is max(s, 0) +
// slope·min(0, s), exactly s above 0 and slope·s below (a NaN stays NaN).
template <class T>
static TOPOS_INLINE_KERNEL T score_activation(T s, ScoreActivation a, T slope) {
  if (a == ScoreActivation::relu) return std::max(T(0), s);
  if (a == ScoreActivation::leaky_relu) return std::max(s, T(0)) + slope * std::min(T(0), s);
  if (a == ScoreActivation::elu) return s > T(0) ? s : std::expm1(s);
  return s;
}
// The derivative at the raw score, as torch's backward takes it (1 above 0; at 0 relu's is 0,
// leaky_relu's the slope, elu's 1); relu's and leaky_relu's picked by index, not by a branch.
template <class T>
static TOPOS_INLINE_KERNEL T score_activation_grad(T s, ScoreActivation a, T slope) {
  if (a == ScoreActivation::relu || a == ScoreActivation::leaky_relu) {
    const T grads[2] = {a == ScoreActivation::relu ? T(0) : slope, T(1)};
    return grads[s > T(0)];
  }
  if (a == ScoreActivation::elu) return s > T(0) ? T(1) : std::exp(s);
  return T(1);
}

template <class T>
static TOPOS_INLINE_KERNEL T raw_score(const AttentionArgs<T>& a, std::int64_t i, std::int64_t k,
                                       std::int64_t h) {
  const T s = a.source[a.col[k] * a.heads + h];
  return a.target != nullptr ? s + a.target[i * a.heads + h] : s;
}

// Σ u[c] w[c] over n values: L-wide partial sums, then lane_sum's tree and the scalar tail. A
// head's gradient in the backward is one per entry; summed one lane after another it was a chain
// of 16 dependent adds.
template <class T, int VB>
static TOPOS_INLINE_KERNEL T dot(const T* u, const T* w, std::int64_t n) {
  T t = 0;
  std::int64_t c = 0;
#if defined(__GNUC__)
  typedef T vec __attribute__((vector_size(VB)));
  constexpr std::int64_t L = VB / sizeof(T);
  vec s{};
  for (; c + L <= n; c += L) {
    vec x, y;
    std::memcpy(&x, u + c, sizeof x);
    std::memcpy(&y, w + c, sizeof y);
    s += x * y;
  }
#endif
  for (; c < n; ++c) t += u[c] * w[c];
#if defined(__GNUC__)
  t = lane_sum(s, t);
#endif
  return t;
}

// For each head h, out[h·C, (h + 1)·C) = Σ over entries j in [j0, j1), in order, of c_j,h times
// the L-wide slices of row_j[h·C, (h + 1)·C), each a multiply-add from 0 (the sums of a row kept
// in memory and added to an entry at a time, bit for bit), the partial sums held in registers
// across the entries instead of loaded and stored at each. entry(j, h) gives {c_j,h, row_j}.
template <class T, int VB, class Entry>
static TOPOS_INLINE_KERNEL void weighted_head_sums(T* __restrict out, std::int64_t H,
                                                   std::int64_t C, std::int64_t j0, std::int64_t j1,
                                                   const Entry& entry) {
  for (std::int64_t h = 0; h < H; ++h) {
    std::int64_t c0 = 0;
#if defined(__GNUC__)
    typedef T vec __attribute__((vector_size(VB)));
    constexpr std::int64_t L = VB / sizeof(T);
    for (; c0 + L <= C; c0 += L) {
      vec acc{};
      for (std::int64_t j = j0; j < j1; ++j) {
        const auto [c, row] = entry(j, h);
        vec x;
        std::memcpy(&x, row + h * C + c0, sizeof x);
        acc += c * x;
      }
      std::memcpy(out + h * C + c0, &acc, sizeof acc);
    }
#endif
    for (std::int64_t ch = h * C + c0; ch < (h + 1) * C; ++ch) {
      T acc = 0;
      for (std::int64_t j = j0; j < j1; ++j) {
        const auto [c, row] = entry(j, h);
        acc += c * row[ch];
      }
      out[ch] = acc;
    }
  }
}

// exp over n contiguous values <= 0, in place.
template <class T, int VB>
static TOPOS_INLINE_KERNEL void exp_nonpositive(T* p, std::int64_t n) {
  std::int64_t i = 0;
#if defined(__GNUC__)
  if constexpr (std::is_same_v<T, float>) {
    typedef T vec __attribute__((vector_size(VB)));
    constexpr int L = VB / static_cast<int>(sizeof(T));
    for (; i + L <= n; i += L) {
      vec v;
      std::memcpy(&v, p + i, sizeof v);
      exp_vec(v);
      std::memcpy(p + i, &v, sizeof v);
    }
  }
#endif
  for (; i < n; ++i) p[i] = std::exp(p[i]);
}

// y[i] over rows [begin, end): the weights of the rows' entries, then their weighted messages.
template <class T, int VB>
static TOPOS_INLINE_KERNEL void attention_forward_rows(const AttentionArgs<T>& a, T* y,
                                                       std::int64_t begin, std::int64_t end) {
  const std::int64_t H = a.heads, C = a.channels, HC = H * C;
  T* w = a.weights;
  for (std::int64_t i = begin; i < end; ++i) {
    const std::int64_t k0 = a.crow[i], k1 = a.crow[i + 1];
    for (std::int64_t k = k0; k < k1; ++k) {
      prefetch_row(a.source, a.col, k + kAhead, a.nnz, H);
      for (std::int64_t h = 0; h < H; ++h)
        w[k * H + h] = score_activation(raw_score(a, i, k, h), a.act, a.slope);
    }
    if (a.norm == ScoreNorm::softmax && k1 > k0)
      for (std::int64_t h = 0; h < H; ++h) {
        T m = -std::numeric_limits<T>::infinity();
        for (std::int64_t k = k0; k < k1; ++k) m = std::max(m, w[k * H + h]);
        for (std::int64_t k = k0; k < k1; ++k) w[k * H + h] -= m;
      }
  }
  // The exponentials of the whole range at once: a row's entries are often fewer than a vector.
  if (a.norm == ScoreNorm::softmax)
    exp_nonpositive<T, VB>(w + a.crow[begin] * H, (a.crow[end] - a.crow[begin]) * H);
  for (std::int64_t i = begin; i < end; ++i) {
    const std::int64_t k0 = a.crow[i], k1 = a.crow[i + 1];
    if (a.norm != ScoreNorm::none)
      for (std::int64_t h = 0; h < H; ++h) {
        T sum = 0;
        for (std::int64_t k = k0; k < k1; ++k) sum += w[k * H + h];
        for (std::int64_t k = k0; k < k1; ++k) w[k * H + h] /= sum;
      }
    for (std::int64_t k = k0; k < k1; ++k) prefetch_row(a.x, a.col, k + kAhead, a.nnz, HC);
    weighted_head_sums<T, VB>(y + i * HC, H, C, k0, k1, [&](std::int64_t k, std::int64_t h) {
      return std::pair<T, const T*>(w[k * H + h] * a.values[k], a.x + a.col[k] * HC);
    });
  }
}

// Over rows [begin, end): d[k, h] = the raw score's gradient of entry k and head h, from dY (g);
// d_target[i, h] = Σ over row i's entries of d (when wanted).
template <class T, int VB>
static TOPOS_INLINE_KERNEL void attention_backward_rows(const AttentionArgs<T>& a, const T* g, T* d,
                                                        T* d_target, std::int64_t begin,
                                                        std::int64_t end) {
  const std::int64_t H = a.heads, C = a.channels, HC = H * C;
  const T* w = a.weights;
  for (std::int64_t i = begin; i < end; ++i) {
    const std::int64_t k0 = a.crow[i], k1 = a.crow[i + 1];
    const T* __restrict gi = g + i * HC;
    for (std::int64_t k = k0; k < k1; ++k) {
      prefetch_row(a.x, a.col, k + kAhead, a.nnz, HC);
      prefetch_row(a.source, a.col, k + kAhead, a.nnz, H);
      const T* __restrict xk = a.x + a.col[k] * HC;
      for (std::int64_t h = 0; h < H; ++h)  // the gradient of the normed weight
        d[k * H + h] = dot<T, VB>(gi + h * C, xk + h * C, C) * a.values[k];
    }
    for (std::int64_t h = 0; h < H; ++h) {
      T t = 0, sum = 1;
      if (a.norm != ScoreNorm::none)
        for (std::int64_t k = k0; k < k1; ++k) t += w[k * H + h] * d[k * H + h];
      if (a.norm == ScoreNorm::row_sum) {  // w = s / Σ s: the activated scores' sum again
        sum = 0;
        for (std::int64_t k = k0; k < k1; ++k)
          sum += score_activation(raw_score(a, i, k, h), a.act, a.slope);
      }
      T total = 0;
      for (std::int64_t k = k0; k < k1; ++k) {
        const T dw = d[k * H + h];
        const T ds = a.norm == ScoreNorm::softmax   ? w[k * H + h] * (dw - t)
                     : a.norm == ScoreNorm::row_sum ? (dw - t) / sum
                                                    : dw;
        const T dr = ds * score_activation_grad(raw_score(a, i, k, h), a.act, a.slope);
        d[k * H + h] = dr;
        total += dr;
      }
      if (d_target != nullptr) d_target[i * H + h] = total;
    }
  }
}

// Over source cells [begin, end) through Aᵀ's CSR: dx[j] = Σ_k w[k] A[k] dY[row k] per head (when
// wanted) and d_source[j, h] = Σ_k d[k, h] over the entries of column j (when wanted).
template <class T, int VB>
static TOPOS_INLINE_KERNEL void attention_backward_cols(const AttentionArgs<T>& a, const T* g,
                                                        const T* d, T* dx, T* d_source,
                                                        std::int64_t begin, std::int64_t end) {
  const std::int64_t H = a.heads, C = a.channels, HC = H * C;
  const T* w = a.weights;
  for (std::int64_t j = begin; j < end; ++j) {
    const std::int64_t t0 = a.t_crow[j], t1 = a.t_crow[j + 1];
    if (d_source != nullptr) std::fill(d_source + j * H, d_source + (j + 1) * H, T(0));
    for (std::int64_t t = t0; t < t1; ++t) {
      if (dx != nullptr) prefetch_row(g, a.t_row, t + kAhead, a.nnz, HC);
      // The entries' weights and score gradients, read in Aᵀ's order: scattered over arrays of
      // nnz × heads (REDDIT-BINARY's: megabytes), each read waited on its miss.
      if (dx != nullptr) prefetch_row(w, a.t_perm, t + kAhead, a.nnz, H);
      if (d_source != nullptr) {
        prefetch_row(d, a.t_perm, t + kAhead, a.nnz, H);
        const std::int64_t k = a.t_perm[t];
        for (std::int64_t h = 0; h < H; ++h) d_source[j * H + h] += d[k * H + h];
      }
    }
    if (dx == nullptr) continue;
    weighted_head_sums<T, VB>(dx + j * HC, H, C, t0, t1, [&](std::int64_t t, std::int64_t h) {
      const std::int64_t k = a.t_perm[t];
      return std::pair<T, const T*>(w[k * H + h] * a.values[k], g + a.t_row[t] * HC);
    });
  }
}

// Each kernel compiled for the baseline and x86-64-v3 (target clones) and for x86-64-v4 on
// 64-byte vectors, as the product kernels are (epilogue.hpp).
#define TOPOS_ATTENTION_VARIANTS(T, suffix)                                                 \
  [[maybe_unused]] TOPOS_SIMD_CLONES static void attention_forward_##suffix(                \
      const AttentionArgs<T>& a, T* y, std::int64_t b, std::int64_t e) {                    \
    attention_forward_rows<T, 32>(a, y, b, e);                                              \
  }                                                                                         \
  [[maybe_unused]] TOPOS_SIMD_CLONES static void attention_backward_rows_##suffix(          \
      const AttentionArgs<T>& a, const T* g, T* d, T* dt, std::int64_t b, std::int64_t e) { \
    attention_backward_rows<T, 32>(a, g, d, dt, b, e);                                      \
  }                                                                                         \
  [[maybe_unused]] TOPOS_SIMD_CLONES static void attention_backward_cols_##suffix(          \
      const AttentionArgs<T>& a, const T* g, const T* d, T* dx, T* ds, std::int64_t b,      \
      std::int64_t e) {                                                                     \
    attention_backward_cols<T, 32>(a, g, d, dx, ds, b, e);                                  \
  }
TOPOS_ATTENTION_VARIANTS(float, float)
TOPOS_ATTENTION_VARIANTS(double, double)
#undef TOPOS_ATTENTION_VARIANTS
#if defined(TOPOS_HAVE_V4)
[[maybe_unused]] TOPOS_V4 static void attention_forward_float_v4(const AttentionArgs<float>& a,
                                                                 float* y, std::int64_t b,
                                                                 std::int64_t e) {
  attention_forward_rows<float, 64>(a, y, b, e);
}
[[maybe_unused]] TOPOS_V4 static void attention_backward_rows_float_v4(
    const AttentionArgs<float>& a, const float* g, float* d, float* dt, std::int64_t b,
    std::int64_t e) {
  attention_backward_rows<float, 64>(a, g, d, dt, b, e);
}
[[maybe_unused]] TOPOS_V4 static void attention_backward_cols_float_v4(
    const AttentionArgs<float>& a, const float* g, const float* d, float* dx, float* ds,
    std::int64_t b, std::int64_t e) {
  attention_backward_cols<float, 64>(a, g, d, dx, ds, b, e);
}
#endif

// The rows (or columns) of a thread's share: every entry costs each head its channels.
template <class T>
std::int64_t attention_grain(const AttentionArgs<T>& a, std::int64_t n) {
  return grain_rows(n, (a.nnz + n) * a.heads * std::max<std::int64_t>(a.channels, 1));
}

/// y (rows × heads·channels) and a.weights (entries × heads) from the scores and messages.
template <class T>
void attention_forward(const AttentionArgs<T>& a, T* y) {
  at::parallel_for(0, a.rows, attention_grain(a, a.rows), [&](std::int64_t b, std::int64_t e) {
#if defined(TOPOS_HAVE_V4)
    if constexpr (std::is_same_v<T, float>)
      if (cpu_has_v4()) return attention_forward_float_v4(a, y, b, e);
#endif
    if constexpr (std::is_same_v<T, float>)
      attention_forward_float(a, y, b, e);
    else
      attention_forward_double(a, y, b, e);
  });
}

/// From dY (g, rows × heads·channels): the raw scores' gradient d (entries × heads, a buffer the
/// caller owns), then the targets' and sources' score gradients and the messages' (each null when
/// not wanted).
template <class T>
void attention_backward(const AttentionArgs<T>& a, const T* g, T* d, T* d_target, T* d_source,
                        T* dx) {
  at::parallel_for(0, a.rows, attention_grain(a, a.rows), [&](std::int64_t b, std::int64_t e) {
#if defined(TOPOS_HAVE_V4)
    if constexpr (std::is_same_v<T, float>)
      if (cpu_has_v4()) return attention_backward_rows_float_v4(a, g, d, d_target, b, e);
#endif
    if constexpr (std::is_same_v<T, float>)
      attention_backward_rows_float(a, g, d, d_target, b, e);
    else
      attention_backward_rows_double(a, g, d, d_target, b, e);
  });
  if (dx == nullptr && d_source == nullptr) return;
  at::parallel_for(0, a.cols, attention_grain(a, a.cols), [&](std::int64_t b, std::int64_t e) {
#if defined(TOPOS_HAVE_V4)
    if constexpr (std::is_same_v<T, float>)
      if (cpu_has_v4()) return attention_backward_cols_float_v4(a, g, d, dx, d_source, b, e);
#endif
    if constexpr (std::is_same_v<T, float>)
      attention_backward_cols_float(a, g, d, dx, d_source, b, e);
    else
      attention_backward_cols_double(a, g, d, dx, d_source, b, e);
  });
}

// Per cell and head the score <f_h, a_h> (nn::head_scores): f cells × heads·C (a head's channels
// side by side), a heads·C, out cells × heads. One pass over f; torch's broadcast product and
// sum made three, and an autograd node each.
template <class T, int VB>
static TOPOS_INLINE_KERNEL void head_scores_rows(const T* f, const T* a, T* out, std::int64_t n,
                                                 std::int64_t H, std::int64_t C) {
  for (std::int64_t i = 0; i < n * H; ++i) out[i] = dot<T, VB>(f + i * C, a + (i % H) * C, C);
}

// The backward of rows [0, n) from the scores' gradient g (cells × heads): df = g_{i,h} a_h (df
// may be null) and da += Σ_i g_{i,h} f_{i,h} into this block's partial sums (da may be null).
template <class T, int VB>
static TOPOS_INLINE_KERNEL void head_scores_backward_rows(const T* g, const T* f, const T* a, T* df,
                                                          T* da, std::int64_t n, std::int64_t H,
                                                          std::int64_t C) {
#if defined(__GNUC__)
  typedef T vec __attribute__((vector_size(VB)));
  constexpr std::int64_t L = VB / sizeof(T);
#else
  constexpr std::int64_t L = 1;
#endif
  const std::int64_t Cv = C / L * L;
  for (std::int64_t i = 0; i < n * H; ++i) {
    const T gi = g[i];
    const T *fr = f + i * C, *ar = a + (i % H) * C;
    T *dr = df ? df + i * C : nullptr, *sa = da ? da + (i % H) * C : nullptr;
    std::int64_t c = 0;
#if defined(__GNUC__)
    for (; c < Cv; c += L) {
      vec w;
      if (dr) {
        std::memcpy(&w, ar + c, sizeof w);
        w *= gi;
        std::memcpy(dr + c, &w, sizeof w);
      }
      if (sa) {
        vec u;
        std::memcpy(&u, fr + c, sizeof u);
        add_into<T, vec>(sa + c, gi * u);
      }
    }
#endif
    for (; c < C; ++c) {
      if (dr) dr[c] = gi * ar[c];
      if (sa) sa[c] += gi * fr[c];
    }
  }
}

#define TOPOS_HEAD_SCORES_ENTRY(T, NAME, ATTR, VB)                                             \
  [[maybe_unused]] ATTR static void NAME(const T* f, const T* a, T* out, std::int64_t n,       \
                                         std::int64_t H, std::int64_t C) {                     \
    head_scores_rows<T, VB>(f, a, out, n, H, C);                                               \
  }                                                                                            \
  [[maybe_unused]] ATTR static void NAME##_backward(const T* g, const T* f, const T* a, T* df, \
                                                    T* da, std::int64_t n, std::int64_t H,     \
                                                    std::int64_t C) {                          \
    head_scores_backward_rows<T, VB>(g, f, a, df, da, n, H, C);                                \
  }
TOPOS_HEAD_SCORES_ENTRY(float, head_scores_float, TOPOS_SIMD_CLONES, 32)
TOPOS_HEAD_SCORES_ENTRY(double, head_scores_double, TOPOS_SIMD_CLONES, 32)
#if defined(TOPOS_HAVE_V4)
TOPOS_HEAD_SCORES_ENTRY(float, head_scores_float_v4, TOPOS_V4, 64)
TOPOS_HEAD_SCORES_ENTRY(double, head_scores_double_v4, TOPOS_V4, 64)
#endif
#undef TOPOS_HEAD_SCORES_ENTRY

/// out (n × H) = per row and head <f_h, a_h>, rows split among the threads.
template <class T>
void head_scores_forward(const T* f, const T* a, T* out, std::int64_t n, std::int64_t H,
                         std::int64_t C) {
  at::parallel_for(0, n, grain_rows(n, 2 * n * H * C), [&](std::int64_t lo, std::int64_t hi) {
    const T* fl = f + lo * H * C;
    T* ol = out + lo * H;
#if defined(TOPOS_HAVE_V4)
    if (cpu_has_v4()) {
      if constexpr (std::is_same_v<T, float>)
        return head_scores_float_v4(fl, a, ol, hi - lo, H, C);
      else
        return head_scores_double_v4(fl, a, ol, hi - lo, H, C);
    }
#endif
    if constexpr (std::is_same_v<T, float>)
      head_scores_float(fl, a, ol, hi - lo, H, C);
    else
      head_scores_double(fl, a, ol, hi - lo, H, C);
  });
}

/// df and da (either may be null; da summed into, H·C) from the scores' gradient g: blocks of
/// rows each sum da into partial sums of their own, added in block order (the same numbers for
/// any thread count).
template <class T>
void head_scores_backward(const T* g, const T* f, const T* a, T* df, T* da, std::int64_t n,
                          std::int64_t H, std::int64_t C) {
  const std::int64_t HC = H * C, block = std::max<std::int64_t>(64, (1 << 16) / HC);
  const std::int64_t blocks = (n + block - 1) / block;
  std::vector<T> partial(da ? static_cast<std::size_t>(blocks * HC) : 0, T(0));
  at::parallel_for(
      0, blocks, grain_rows(blocks, 4 * n * HC), [&](std::int64_t k0, std::int64_t k1) {
        for (std::int64_t k = k0; k < k1; ++k) {
          const std::int64_t lo = k * block, rows = std::min(n, lo + block) - lo;
          T* pa = da ? partial.data() + k * HC : nullptr;
          T* dl = df ? df + lo * HC : nullptr;
#if defined(TOPOS_HAVE_V4)
          if (cpu_has_v4()) {
            if constexpr (std::is_same_v<T, float>)
              head_scores_float_v4_backward(g + lo * H, f + lo * HC, a, dl, pa, rows, H, C);
            else
              head_scores_double_v4_backward(g + lo * H, f + lo * HC, a, dl, pa, rows, H, C);
            continue;
          }
#endif
          if constexpr (std::is_same_v<T, float>)
            head_scores_float_backward(g + lo * H, f + lo * HC, a, dl, pa, rows, H, C);
          else
            head_scores_double_backward(g + lo * H, f + lo * HC, a, dl, pa, rows, H, C);
        }
      });
  if (da)
    for (std::int64_t k = 0; k < blocks; ++k)
      for (std::int64_t c = 0; c < HC; ++c) da[c] += partial[static_cast<std::size_t>(k * HC + c)];
}

}  // namespace topos::nn::detail
