// topos/nn/kernels.hpp
// The CPU kernels under message passing: a row loop over a CSR matrix (spmm's product), a
// register-blocked dense product for narrow maps (n × K by K × N, N up to 64) and the fused
// backward of act(x Wᵀ + b), each with an activation (relu, elu) applied before the row is
// stored, so that an activated product is one pass over its output and its backward needs the
// output alone. Written with GCC's vector extension and compiled per instruction set: AVX2 and
// the baseline as target clones on 32-byte vectors, AVX-512 on 64-byte ones (dispatched at run
// time); linear_act is the autograd node over the dense ones, spmm (sparse.hpp) the one over the
// CSR ones.
#pragma once

#include <ATen/Parallel.h>
#include <torch/torch.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <stdexcept>
#include <string>
#include <type_traits>

namespace topos::nn {

namespace detail {

// The row kernels are compiled for x86-64-v3 (AVX2 + FMA) and the baseline as target clones, on
// 32-byte vectors, and once more for x86-64-v4 (AVX-512) on 64-byte vectors (the `_v4` entry
// points, taken when the CPU has AVX-512: on Zen 5, whose FMA units are 512 bits wide, the dense
// kernel runs 1.9x faster on zmm registers than on ymm). The levels are dispatched by
// instruction set; an "arch=haswell" clone is dispatched by CPU model and never ran on this EPYC.
#if defined(__GNUC__) && !defined(__clang__) && defined(__x86_64__) && __GNUC__ >= 12
#define TOPOS_SIMD_CLONES __attribute__((target_clones("arch=x86-64-v3", "default")))
#define TOPOS_V4 __attribute__((target("arch=x86-64-v4")))
#define TOPOS_HAVE_V4 1
#elif defined(__GNUC__) && !defined(__clang__) && defined(__x86_64__)
#define TOPOS_SIMD_CLONES __attribute__((target_clones("avx2", "default")))
#else
#define TOPOS_SIMD_CLONES
#endif
// The kernels below are inlined into each clone so that they are compiled for its instruction set.
#if defined(__GNUC__)
#define TOPOS_INLINE_KERNEL inline __attribute__((always_inline))
#else
#define TOPOS_INLINE_KERNEL inline
#endif

#if defined(TOPOS_HAVE_V4)
inline bool cpu_has_v4() {
  static const bool v4 = __builtin_cpu_supports("avx512f") && __builtin_cpu_supports("avx512bw") &&
                         __builtin_cpu_supports("avx512dq") && __builtin_cpu_supports("avx512vl") &&
                         __builtin_cpu_supports("avx512cd");
  return v4;
}
#endif

// The activation applied to a product's rows before they are stored (a fused epilogue), so an
// activated product is one pass over its output, and its backward needs the output only.
enum class Epilogue { none, relu, elu };

template <class T>
static TOPOS_INLINE_KERNEL T epilogue_scalar(T x, Epilogue e) {
  if (e == Epilogue::relu) return x > T(0) ? x : T(0);
  if (e == Epilogue::elu) return x > T(0) ? x : std::expm1(x);
  return x;
}

#if defined(__GNUC__)
// elu on a vector of floats (any width): x where x > 0, else expm1(x) = 2^n (1 + p(r)) - 1 with
// r = x - n ln2 (two-part ln2), |r| <= ln2/2 and p(r) = r + r²(1/2 + ... + r⁵/7!) (truncation
// < 1e-8), written as (2^n - 1) + 2^n p(r) so that nothing cancels near 0: within 1e-7 of expm1,
// relative, everywhere. torch 1.13's elu calls libm's scalar expf (19 % of CWN's forward); this is
// a few vector FMAs. In place: no vector type in a function's ABI.
template <class V>
static TOPOS_INLINE_KERNEL void elu_vec(V& x) {
  typedef std::int32_t ivec __attribute__((vector_size(sizeof(V))));
  const V c = x < -87.0f ? V{} - 87.0f : x;                            // 2^n stays a normal float
  const V k = (c * 1.44269504088896341f + 12582912.0f) - 12582912.0f;  // round(c / ln2)
  V r = c - k * 0.693359375f;
  r = r - k * -2.12194440e-4f;
  const V p =
      r + r * r *
              (0.5f + r * (1.66666672e-1f +
                           r * (4.16666679e-2f +
                                r * (8.33333377e-3f + r * (1.38888892e-3f + r * 1.98412701e-4f)))));
  const ivec bits = (__builtin_convertvector(k, ivec) + 127) << 23;
  V s;
  std::memcpy(&s, &bits, sizeof s);
  const V e = (s - 1.0f) + s * p;
  x = x > 0.0f ? x : e;
}

template <class T, Epilogue E, class V>
static TOPOS_INLINE_KERNEL void epilogue_vec(V& v) {
  if constexpr (E == Epilogue::relu) {
    v = v > T(0) ? v : V{};
  } else if constexpr (E == Epilogue::elu) {
    if constexpr (std::is_same_v<T, float>) {
      elu_vec(v);
    } else {
      for (int l = 0; l < static_cast<int>(sizeof(V) / sizeof(T)); ++l)
        v[l] = epilogue_scalar<T>(v[l], E);
    }
  }
}
#endif

// Y[i] = act(Σ_k v[perm k] X[col k]) over the entries k of rows [begin, end); C channels,
// contiguous rows. For a compile-time width the row's sums stay in registers as 32-byte vectors
// (GCC's vector extension, so each clone compiles them for its instruction set; plain arrays let
// -O3 spill them): 2.8x faster than the loop below at 32 channels.
#if defined(__GNUC__)
template <class T, int C, Epilogue E, int VB>
static TOPOS_INLINE_KERNEL void csr_rows_fixed(const std::int64_t* crow, const std::int64_t* col,
                                               const T* val, const std::int64_t* perm, const T* X,
                                               T* Y, std::int64_t begin, std::int64_t end) {
  // A width narrower than the vector (8 floats on 64 bytes) takes vectors of its own size.
  constexpr int VBe = C * static_cast<int>(sizeof(T)) < VB ? C * static_cast<int>(sizeof(T)) : VB;
  typedef T vec __attribute__((vector_size(VBe)));
  constexpr int L = static_cast<int>(VBe / sizeof(T)), V = C / L;
  static_assert(C % L == 0, "the width must be a whole number of vectors");
  for (std::int64_t i = begin; i < end; ++i) {
    vec acc[V] = {};
    for (std::int64_t k = crow[i]; k < crow[i + 1]; ++k) {
      const T v = val[perm ? perm[k] : k];
      const T* x = X + col[k] * C;
      for (int j = 0; j < V; ++j) {
        vec xv;
        std::memcpy(&xv, x + j * L, sizeof(vec));
        acc[j] += v * xv;
      }
    }
    for (int j = 0; j < V; ++j) {
      epilogue_vec<T, E>(acc[j]);
      std::memcpy(Y + i * C + j * L, &acc[j], sizeof(vec));
    }
  }
}

template <class T, Epilogue E, int VB>
static TOPOS_INLINE_KERNEL bool csr_rows_width(const std::int64_t* crow, const std::int64_t* col,
                                               const T* val, const std::int64_t* perm, const T* X,
                                               T* Y, std::int64_t begin, std::int64_t end,
                                               std::int64_t C) {
  switch (C) {
    case 8:
      return csr_rows_fixed<T, 8, E, VB>(crow, col, val, perm, X, Y, begin, end), true;
    case 16:
      return csr_rows_fixed<T, 16, E, VB>(crow, col, val, perm, X, Y, begin, end), true;
    case 32:
      return csr_rows_fixed<T, 32, E, VB>(crow, col, val, perm, X, Y, begin, end), true;
    case 64:
      return csr_rows_fixed<T, 64, E, VB>(crow, col, val, perm, X, Y, begin, end), true;
    default:
      return false;
  }
}
#endif

template <class T, int VB = 32>
static TOPOS_INLINE_KERNEL void csr_rows(const std::int64_t* crow, const std::int64_t* col,
                                         const T* val, const std::int64_t* perm, const T* X, T* Y,
                                         std::int64_t begin, std::int64_t end, std::int64_t C,
                                         Epilogue e) {
#if defined(__GNUC__)
  if (e == Epilogue::none
          ? csr_rows_width<T, Epilogue::none, VB>(crow, col, val, perm, X, Y, begin, end, C)
      : e == Epilogue::relu
          ? csr_rows_width<T, Epilogue::relu, VB>(crow, col, val, perm, X, Y, begin, end, C)
          : csr_rows_width<T, Epilogue::elu, VB>(crow, col, val, perm, X, Y, begin, end, C))
    return;
#endif
  for (std::int64_t i = begin; i < end; ++i) {
    T* __restrict y = Y + i * C;
    std::fill(y, y + C, T(0));
    for (std::int64_t k = crow[i]; k < crow[i + 1]; ++k) {
      const T v = val[perm ? perm[k] : k];
      const T* __restrict x = X + col[k] * C;
      for (std::int64_t c = 0; c < C; ++c) y[c] += v * x[c];
    }
    if (e != Epilogue::none)
      for (std::int64_t c = 0; c < C; ++c) y[c] = epilogue_scalar(y[c], e);
  }
}
[[maybe_unused]] TOPOS_SIMD_CLONES static void csr_rows_float(
    const std::int64_t* crow, const std::int64_t* col, const float* val, const std::int64_t* perm,
    const float* X, float* Y, std::int64_t begin, std::int64_t end, std::int64_t C, Epilogue e) {
  csr_rows<float>(crow, col, val, perm, X, Y, begin, end, C, e);
}
#if defined(TOPOS_HAVE_V4)
[[maybe_unused]] TOPOS_V4 static void csr_rows_float_v4(
    const std::int64_t* crow, const std::int64_t* col, const float* val, const std::int64_t* perm,
    const float* X, float* Y, std::int64_t begin, std::int64_t end, std::int64_t C, Epilogue e) {
  csr_rows<float, 64>(crow, col, val, perm, X, Y, begin, end, C, e);
}
#endif
[[maybe_unused]] TOPOS_SIMD_CLONES static void csr_rows_double(
    const std::int64_t* crow, const std::int64_t* col, const double* val, const std::int64_t* perm,
    const double* X, double* Y, std::int64_t begin, std::int64_t end, std::int64_t C, Epilogue e) {
  csr_rows<double>(crow, col, val, perm, X, Y, begin, end, C, e);
}
#if defined(TOPOS_HAVE_V4)
[[maybe_unused]] TOPOS_V4 static void csr_rows_double_v4(
    const std::int64_t* crow, const std::int64_t* col, const double* val, const std::int64_t* perm,
    const double* X, double* Y, std::int64_t begin, std::int64_t end, std::int64_t C, Epilogue e) {
  csr_rows<double, 64>(crow, col, val, perm, X, Y, begin, end, C, e);
}
#endif

// The epilogue on its own, in place (after a dense product), and its backward from the output:
// g ⊙ act'(y), where relu' = [y > 0] and elu' = 1 for y > 0, y + 1 below (as torch's elu_backward
// with is_result).
template <class T, int VB = 32>
static TOPOS_INLINE_KERNEL void epilogue_rows(T* y, const T* g, T* out, std::int64_t n,
                                              Epilogue e) {
  std::int64_t i = 0;
#if defined(__GNUC__)
  typedef T vec __attribute__((vector_size(VB)));
  constexpr int L = static_cast<int>(VB / sizeof(T));
  for (; i + L <= n; i += L) {
    vec v;
    std::memcpy(&v, y + i, sizeof v);
    if (!g) {
      if (e == Epilogue::relu) epilogue_vec<T, Epilogue::relu>(v);
      if (e == Epilogue::elu) epilogue_vec<T, Epilogue::elu>(v);
      std::memcpy(y + i, &v, sizeof v);
    } else {
      vec gv;
      std::memcpy(&gv, g + i, sizeof gv);
      const vec r = v > T(0) ? gv : e == Epilogue::relu ? vec{} : gv * (v + T(1));
      std::memcpy(out + i, &r, sizeof r);
    }
  }
#endif
  for (; i < n; ++i) {
    if (!g)
      y[i] = epilogue_scalar(y[i], e);
    else
      out[i] = y[i] > T(0) ? g[i] : e == Epilogue::relu ? T(0) : g[i] * (y[i] + T(1));
  }
}
[[maybe_unused]] TOPOS_SIMD_CLONES static void epilogue_rows_float(float* y, const float* g,
                                                                   float* out, std::int64_t n,
                                                                   Epilogue e) {
  epilogue_rows<float>(y, g, out, n, e);
}
#if defined(TOPOS_HAVE_V4)
[[maybe_unused]] TOPOS_V4 static void epilogue_rows_float_v4(float* y, const float* g, float* out,
                                                             std::int64_t n, Epilogue e) {
  epilogue_rows<float, 64>(y, g, out, n, e);
}
#endif
[[maybe_unused]] TOPOS_SIMD_CLONES static void epilogue_rows_double(double* y, const double* g,
                                                                    double* out, std::int64_t n,
                                                                    Epilogue e) {
  epilogue_rows<double>(y, g, out, n, e);
}
#if defined(TOPOS_HAVE_V4)
[[maybe_unused]] TOPOS_V4 static void epilogue_rows_double_v4(double* y, const double* g,
                                                              double* out, std::int64_t n,
                                                              Epilogue e) {
  epilogue_rows<double, 64>(y, g, out, n, e);
}
#endif

// Y[i] = act(b + X[i] · M) for rows [begin, end): X n × K, M K × N (both contiguous), N a
// compile-time width. Four rows at a time keep 4·N/8 accumulators in registers and read each row
// of M once per four rows; M (K·N·4 bytes, 4 KB at 32 × 32) stays in L1. For the narrow products
// of message passing (n large, K and N at most 64) this beats OpenBLAS, which packs X and
// zeroes Y before its kernel, and it applies the bias and the activation before the store.
#if defined(__GNUC__)
template <class T, int N, Epilogue E, int VB>
static TOPOS_INLINE_KERNEL void dense_rows_fixed(const T* X, const T* M, const T* b, T* Y,
                                                 std::int64_t begin, std::int64_t end,
                                                 std::int64_t K) {
  // A width narrower than the vector (8 floats on 64 bytes) takes vectors of its own size.
  constexpr int VBe = N * static_cast<int>(sizeof(T)) < VB ? N * static_cast<int>(sizeof(T)) : VB;
  typedef T vec __attribute__((vector_size(VBe)));
  // Rows per block: as many accumulators as registers allow (16 ymm or 32 zmm).
  constexpr int L = static_cast<int>(VBe / sizeof(T)), V = N / L,
                R = V > 4                ? 2
                    : V == 4 || VBe < 64 ? 4
                                         : 8;
  static_assert(N % L == 0, "the width must be a whole number of vectors");
  vec bias[V] = {};
  if (b)
    for (int j = 0; j < V; ++j) std::memcpy(&bias[j], b + j * L, sizeof(vec));
  std::int64_t i = begin;
  for (; i + R <= end; i += R) {
    vec acc[R][V];
    for (int r = 0; r < R; ++r)
      for (int j = 0; j < V; ++j) acc[r][j] = bias[j];
    for (std::int64_t k = 0; k < K; ++k) {
      vec w[V];
      for (int j = 0; j < V; ++j) std::memcpy(&w[j], M + k * N + j * L, sizeof(vec));
      for (int r = 0; r < R; ++r) {
        const T x = X[(i + r) * K + k];
        for (int j = 0; j < V; ++j) acc[r][j] += x * w[j];
      }
    }
    for (int r = 0; r < R; ++r)
      for (int j = 0; j < V; ++j) {
        epilogue_vec<T, E>(acc[r][j]);
        std::memcpy(Y + (i + r) * N + j * L, &acc[r][j], sizeof(vec));
      }
  }
  for (; i < end; ++i) {
    vec acc[V];
    for (int j = 0; j < V; ++j) acc[j] = bias[j];
    for (std::int64_t k = 0; k < K; ++k) {
      const T x = X[i * K + k];
      for (int j = 0; j < V; ++j) {
        vec w;
        std::memcpy(&w, M + k * N + j * L, sizeof(vec));
        acc[j] += x * w;
      }
    }
    for (int j = 0; j < V; ++j) {
      epilogue_vec<T, E>(acc[j]);
      std::memcpy(Y + i * N + j * L, &acc[j], sizeof(vec));
    }
  }
}

template <class T, Epilogue E, int VB>
static TOPOS_INLINE_KERNEL void dense_rows_width(const T* X, const T* M, const T* b, T* Y,
                                                 std::int64_t begin, std::int64_t end,
                                                 std::int64_t K, std::int64_t N) {
  switch (N) {
    case 8:
      return dense_rows_fixed<T, 8, E, VB>(X, M, b, Y, begin, end, K);
    case 16:
      return dense_rows_fixed<T, 16, E, VB>(X, M, b, Y, begin, end, K);
    case 32:
      return dense_rows_fixed<T, 32, E, VB>(X, M, b, Y, begin, end, K);
    case 64:
      return dense_rows_fixed<T, 64, E, VB>(X, M, b, Y, begin, end, K);
    default:
      break;
  }
}

template <class T, int VB = 32>
static TOPOS_INLINE_KERNEL void dense_rows(const T* X, const T* M, const T* b, T* Y,
                                           std::int64_t begin, std::int64_t end, std::int64_t K,
                                           std::int64_t N, Epilogue e) {
  if (e == Epilogue::none)
    dense_rows_width<T, Epilogue::none, VB>(X, M, b, Y, begin, end, K, N);
  else if (e == Epilogue::relu)
    dense_rows_width<T, Epilogue::relu, VB>(X, M, b, Y, begin, end, K, N);
  else
    dense_rows_width<T, Epilogue::elu, VB>(X, M, b, Y, begin, end, K, N);
}
[[maybe_unused]] TOPOS_SIMD_CLONES static void dense_rows_float(const float* X, const float* M,
                                                                const float* b, float* Y,
                                                                std::int64_t begin,
                                                                std::int64_t end, std::int64_t K,
                                                                std::int64_t N, Epilogue e) {
  dense_rows<float>(X, M, b, Y, begin, end, K, N, e);
}
#if defined(TOPOS_HAVE_V4)
[[maybe_unused]] TOPOS_V4 static void dense_rows_float_v4(const float* X, const float* M,
                                                          const float* b, float* Y,
                                                          std::int64_t begin, std::int64_t end,
                                                          std::int64_t K, std::int64_t N,
                                                          Epilogue e) {
  dense_rows<float, 64>(X, M, b, Y, begin, end, K, N, e);
}
#endif
[[maybe_unused]] TOPOS_SIMD_CLONES static void dense_rows_double(const double* X, const double* M,
                                                                 const double* b, double* Y,
                                                                 std::int64_t begin,
                                                                 std::int64_t end, std::int64_t K,
                                                                 std::int64_t N, Epilogue e) {
  dense_rows<double>(X, M, b, Y, begin, end, K, N, e);
}
#if defined(TOPOS_HAVE_V4)
[[maybe_unused]] TOPOS_V4 static void dense_rows_double_v4(const double* X, const double* M,
                                                           const double* b, double* Y,
                                                           std::int64_t begin, std::int64_t end,
                                                           std::int64_t K, std::int64_t N,
                                                           Epilogue e) {
  dense_rows<double, 64>(X, M, b, Y, begin, end, K, N, e);
}
#endif

#endif

template <class T>
void csr_mm(const std::int64_t* crow, const std::int64_t* col, const T* val,
            const std::int64_t* perm, const T* X, T* Y, std::int64_t rows, std::int64_t C,
            Epilogue e = Epilogue::none) {
  at::parallel_for(0, rows, 256, [&](std::int64_t begin, std::int64_t end) {
#if defined(TOPOS_HAVE_V4)
    if constexpr (std::is_same_v<T, float>)
      if (cpu_has_v4()) return csr_rows_float_v4(crow, col, val, perm, X, Y, begin, end, C, e);
    if constexpr (std::is_same_v<T, double>)
      if (cpu_has_v4()) return csr_rows_double_v4(crow, col, val, perm, X, Y, begin, end, C, e);
#endif
    if constexpr (std::is_same_v<T, float>)
      csr_rows_float(crow, col, val, perm, X, Y, begin, end, C, e);
    else if constexpr (std::is_same_v<T, double>)
      csr_rows_double(crow, col, val, perm, X, Y, begin, end, C, e);
    else
      csr_rows<T>(crow, col, val, perm, X, Y, begin, end, C, e);
  });
}

template <class T>
void epilogue_range(T* y, const T* g, T* out, std::int64_t n, Epilogue e) {
  at::parallel_for(0, n, 1 << 15, [&](std::int64_t begin, std::int64_t end) {
    T* o = out + begin;
    const T* gb = g ? g + begin : nullptr;
#if defined(TOPOS_HAVE_V4)
    if constexpr (std::is_same_v<T, float>)
      if (cpu_has_v4()) return epilogue_rows_float_v4(y + begin, gb, o, end - begin, e);
    if constexpr (std::is_same_v<T, double>)
      if (cpu_has_v4()) return epilogue_rows_double_v4(y + begin, gb, o, end - begin, e);
#endif
    if constexpr (std::is_same_v<T, float>)
      epilogue_rows_float(y + begin, gb, o, end - begin, e);
    else if constexpr (std::is_same_v<T, double>)
      epilogue_rows_double(y + begin, gb, o, end - begin, e);
    else
      epilogue_rows<T>(y + begin, gb, o, end - begin, e);
  });
}

/// y = act(y) in place (g undefined), or the gradient g ⊙ act'(y) from the output y.
inline torch::Tensor apply_epilogue(const torch::Tensor& y, const torch::Tensor& g, Epilogue e) {
  if (e == Epilogue::none) return g.defined() ? g : y;
  TORCH_CHECK(y.is_contiguous(), "apply_epilogue: the output must be contiguous");
  const auto gc = g.defined() ? g.contiguous() : g;
  auto out = g.defined() ? torch::empty_like(y) : y;
  AT_DISPATCH_FLOATING_TYPES(y.scalar_type(), "topos_epilogue", [&] {
    epilogue_range<scalar_t>(y.data_ptr<scalar_t>(),
                             gc.defined() ? gc.data_ptr<scalar_t>() : nullptr,
                             out.data_ptr<scalar_t>(), y.numel(), e);
  });
  return out;
}

// dW[n] += Σ_i dZ[i][n] x[i] over rows [begin, end) (dW N × K, x n × K with K a compile-time
// width, dZ with leading dimension N): four rows of x stay in registers while every row of dW
// takes their four contributions, one load and one store of dW per four rows.
#if defined(__GNUC__)
template <class T, int K, int VB>
static TOPOS_INLINE_KERNEL void outer_rows_fixed(const T* dZ, const T* x, T* dW, std::int64_t begin,
                                                 std::int64_t end, std::int64_t N) {
  // A width narrower than the vector (8 floats on 64 bytes) takes vectors of its own size.
  constexpr int VBe = K * static_cast<int>(sizeof(T)) < VB ? K * static_cast<int>(sizeof(T)) : VB;
  typedef T vec __attribute__((vector_size(VBe)));
  constexpr int L = static_cast<int>(VBe / sizeof(T)), V = K / L,
                R = V > 4                ? 2
                    : V == 4 || VBe < 64 ? 4
                                         : 8;
  std::int64_t i = begin;
  for (; i + R <= end; i += R) {
    vec xr[R][V];
    for (int r = 0; r < R; ++r)
      for (int j = 0; j < V; ++j) std::memcpy(&xr[r][j], x + (i + r) * K + j * L, sizeof(vec));
    for (std::int64_t n = 0; n < N; ++n) {
      vec acc[V];
      for (int j = 0; j < V; ++j) std::memcpy(&acc[j], dW + n * K + j * L, sizeof(vec));
      for (int r = 0; r < R; ++r) {
        const T z = dZ[(i + r) * N + n];
        for (int j = 0; j < V; ++j) acc[j] += z * xr[r][j];
      }
      for (int j = 0; j < V; ++j) std::memcpy(dW + n * K + j * L, &acc[j], sizeof(vec));
    }
  }
  for (; i < end; ++i)
    for (std::int64_t n = 0; n < N; ++n) {
      const T z = dZ[i * N + n];
      for (int j = 0; j < V; ++j) {
        vec acc, xv;
        std::memcpy(&acc, dW + n * K + j * L, sizeof(vec));
        std::memcpy(&xv, x + i * K + j * L, sizeof(vec));
        acc += z * xv;
        std::memcpy(dW + n * K + j * L, &acc, sizeof(vec));
      }
    }
}

// The backward of act(x Wᵀ + b) (x n × K, W N × K) over rows [begin, end), a block of rows at a
// time so that dZ = g ⊙ act'(y) never leaves L1: dx = dZ W, and dW, db accumulate into the
// caller's buffers. Each of the three is skipped where its pointer is null.
template <class T, Epilogue E, int VB>
static TOPOS_INLINE_KERNEL void linear_backward_rows(const T* x, const T* W, const T* y, const T* g,
                                                     T* dx, T* dW, T* db, std::int64_t begin,
                                                     std::int64_t end, std::int64_t K,
                                                     std::int64_t N) {
  constexpr std::int64_t B = 32;
  alignas(64) T dZ[B * 256];
  for (std::int64_t i0 = begin; i0 < end; i0 += B) {
    const std::int64_t rows = std::min(B, end - i0);
    const T* z = g + i0 * N;
    if (E != Epilogue::none) {
      epilogue_rows<T, VB>(const_cast<T*>(y + i0 * N), g + i0 * N, dZ, rows * N, E);
      z = dZ;
    }
    if (dx) {
      switch (K) {
        case 8:
          dense_rows_fixed<T, 8, Epilogue::none, VB>(z, W, nullptr, dx + i0 * K, 0, rows, N);
          break;
        case 16:
          dense_rows_fixed<T, 16, Epilogue::none, VB>(z, W, nullptr, dx + i0 * K, 0, rows, N);
          break;
        case 32:
          dense_rows_fixed<T, 32, Epilogue::none, VB>(z, W, nullptr, dx + i0 * K, 0, rows, N);
          break;
        default:
          dense_rows_fixed<T, 64, Epilogue::none, VB>(z, W, nullptr, dx + i0 * K, 0, rows, N);
          break;
      }
    }
    if (dW) {
      switch (K) {
        case 8:
          outer_rows_fixed<T, 8, VB>(z, x + i0 * K, dW, 0, rows, N);
          break;
        case 16:
          outer_rows_fixed<T, 16, VB>(z, x + i0 * K, dW, 0, rows, N);
          break;
        case 32:
          outer_rows_fixed<T, 32, VB>(z, x + i0 * K, dW, 0, rows, N);
          break;
        default:
          outer_rows_fixed<T, 64, VB>(z, x + i0 * K, dW, 0, rows, N);
          break;
      }
    }
    if (db)
      for (std::int64_t r = 0; r < rows; ++r)
        for (std::int64_t n = 0; n < N; ++n) db[n] += z[r * N + n];
  }
}
template <class T, int VB = 32>
static TOPOS_INLINE_KERNEL void linear_backward_any(const T* x, const T* W, const T* y, const T* g,
                                                    T* dx, T* dW, T* db, std::int64_t begin,
                                                    std::int64_t end, std::int64_t K,
                                                    std::int64_t N, Epilogue e) {
  if (e == Epilogue::none)
    linear_backward_rows<T, Epilogue::none, VB>(x, W, y, g, dx, dW, db, begin, end, K, N);
  else if (e == Epilogue::relu)
    linear_backward_rows<T, Epilogue::relu, VB>(x, W, y, g, dx, dW, db, begin, end, K, N);
  else
    linear_backward_rows<T, Epilogue::elu, VB>(x, W, y, g, dx, dW, db, begin, end, K, N);
}
[[maybe_unused]] TOPOS_SIMD_CLONES static void linear_backward_float(
    const float* x, const float* W, const float* y, const float* g, float* dx, float* dW, float* db,
    std::int64_t begin, std::int64_t end, std::int64_t K, std::int64_t N, Epilogue e) {
  linear_backward_any<float>(x, W, y, g, dx, dW, db, begin, end, K, N, e);
}
#if defined(TOPOS_HAVE_V4)
[[maybe_unused]] TOPOS_V4 static void linear_backward_float_v4(
    const float* x, const float* W, const float* y, const float* g, float* dx, float* dW, float* db,
    std::int64_t begin, std::int64_t end, std::int64_t K, std::int64_t N, Epilogue e) {
  linear_backward_any<float, 64>(x, W, y, g, dx, dW, db, begin, end, K, N, e);
}
#endif
[[maybe_unused]] TOPOS_SIMD_CLONES static void linear_backward_double(
    const double* x, const double* W, const double* y, const double* g, double* dx, double* dW,
    double* db, std::int64_t begin, std::int64_t end, std::int64_t K, std::int64_t N, Epilogue e) {
  linear_backward_any<double>(x, W, y, g, dx, dW, db, begin, end, K, N, e);
}
#if defined(TOPOS_HAVE_V4)
[[maybe_unused]] TOPOS_V4 static void linear_backward_double_v4(
    const double* x, const double* W, const double* y, const double* g, double* dx, double* dW,
    double* db, std::int64_t begin, std::int64_t end, std::int64_t K, std::int64_t N, Epilogue e) {
  linear_backward_any<double, 64>(x, W, y, g, dx, dW, db, begin, end, K, N, e);
}
#endif
inline void linear_backward_clone(const float* x, const float* W, const float* y, const float* g,
                                  float* dx, float* dW, float* db, std::int64_t begin,
                                  std::int64_t end, std::int64_t K, std::int64_t N, Epilogue e) {
#if defined(TOPOS_HAVE_V4)
  if (cpu_has_v4()) return linear_backward_float_v4(x, W, y, g, dx, dW, db, begin, end, K, N, e);
#endif
  linear_backward_float(x, W, y, g, dx, dW, db, begin, end, K, N, e);
}
inline void linear_backward_clone(const double* x, const double* W, const double* y,
                                  const double* g, double* dx, double* dW, double* db,
                                  std::int64_t begin, std::int64_t end, std::int64_t K,
                                  std::int64_t N, Epilogue e) {
#if defined(TOPOS_HAVE_V4)
  if (cpu_has_v4()) return linear_backward_double_v4(x, W, y, g, dx, dW, db, begin, end, K, N, e);
#endif
  linear_backward_double(x, W, y, g, dx, dW, db, begin, end, K, N, e);
}
#endif

#if defined(__GNUC__)
inline void dense_rows_clone(const float* X, const float* M, const float* b, float* Y,
                             std::int64_t begin, std::int64_t end, std::int64_t K, std::int64_t N,
                             Epilogue e) {
#if defined(TOPOS_HAVE_V4)
  if (cpu_has_v4()) return dense_rows_float_v4(X, M, b, Y, begin, end, K, N, e);
#endif
  dense_rows_float(X, M, b, Y, begin, end, K, N, e);
}
inline void dense_rows_clone(const double* X, const double* M, const double* b, double* Y,
                             std::int64_t begin, std::int64_t end, std::int64_t K, std::int64_t N,
                             Epilogue e) {
#if defined(TOPOS_HAVE_V4)
  if (cpu_has_v4()) return dense_rows_double_v4(X, M, b, Y, begin, end, K, N, e);
#endif
  dense_rows_double(X, M, b, Y, begin, end, K, N, e);
}
#endif

/// The widths dense_product's kernel takes (the rest goes to torch's BLAS).
inline bool dense_kernel_fits(std::int64_t K, std::int64_t N) {
#if defined(__GNUC__)
  return K <= 256 && (N == 8 || N == 16 || N == 32 || N == 64);
#else
  return K < 0 && N < 0;
#endif
}

/// act(b + X · M) for contiguous float or double X (n × K) and M (K × N) on the CPU, N in
/// {8, 16, 32, 64}; b may be undefined.
inline torch::Tensor dense_product(const torch::Tensor& X, const torch::Tensor& M,
                                   const torch::Tensor& b, Epilogue e) {
  const auto x = X.contiguous(), m = M.contiguous();
  const auto bc = b.defined() ? b.contiguous() : b;
  const auto n = x.size(0), K = x.size(1), N = m.size(1);
  auto y = torch::empty({n, N}, x.options());
#if defined(__GNUC__)
  AT_DISPATCH_FLOATING_TYPES(x.scalar_type(), "topos_dense_product", [&] {
    const auto* xp = x.data_ptr<scalar_t>();
    const auto* mp = m.data_ptr<scalar_t>();
    const auto* bp = bc.defined() ? bc.data_ptr<scalar_t>() : nullptr;
    auto* yp = y.data_ptr<scalar_t>();
    at::parallel_for(0, n, 512, [&](std::int64_t begin, std::int64_t end) {
      dense_rows_clone(xp, mp, bp, yp, begin, end, K, N, e);
    });
  });
#else
  throw std::logic_error("dense_product: needs GCC's vector extension");
#endif
  return y;
}

// g[k] = <dY[row k], X[col k]>.
template <class T>
void csr_value_grad(const std::int64_t* row, const std::int64_t* col, const T* dY, const T* X, T* g,
                    std::int64_t nnz, std::int64_t C) {
  at::parallel_for(0, nnz, 2048, [&](std::int64_t begin, std::int64_t end) {
    for (std::int64_t k = begin; k < end; ++k) {
      const T* __restrict a = dY + row[k] * C;
      const T* __restrict b = X + col[k] * C;
      T s = 0;
      for (std::int64_t c = 0; c < C; ++c) s += a[c] * b[c];
      g[k] = s;
    }
  });
}

// act(x Wᵀ + b) as one node keeping x, W and its output: the activation runs in place on the
// product (one pass, vectorised) and the backward starts from dY ⊙ act'(Y).
struct LinearFunction : public torch::autograd::Function<LinearFunction> {
  static torch::Tensor forward(torch::autograd::AutogradContext* ctx, const torch::Tensor& x,
                               const torch::Tensor& W, const torch::Tensor& bias,
                               std::int64_t act) {
    const auto e = static_cast<Epilogue>(act);
    const auto b = bias.numel() > 0 ? bias : torch::Tensor();  // empty: no bias
    torch::Tensor y;
    if (dense_kernel_fits(W.size(1), W.size(0))) {
      y = dense_product(x, W.t().contiguous(), b, e);
    } else {
      y = b.defined() ? torch::addmm(b, x, W.t()) : x.mm(W.t());
      apply_epilogue(y, torch::Tensor(), e);
    }
    ctx->save_for_backward({x, W, e == Epilogue::none ? torch::Tensor() : y});
    ctx->saved_data["act"] = act;
    ctx->saved_data["bias"] = b.defined();
    return y;
  }
  static torch::autograd::tensor_list backward(torch::autograd::AutogradContext* ctx,
                                               torch::autograd::tensor_list grads) {
    const auto saved = ctx->get_saved_variables();
    const auto &x = saved[0], &W = saved[1], &Y = saved[2];
    const auto e = static_cast<Epilogue>(ctx->saved_data["act"].toInt());
    const bool bias = ctx->saved_data["bias"].toBool();
    torch::Tensor dx, dW, db;
    if (dense_kernel_fits(W.size(0), W.size(1)))
      return fused_backward(x.contiguous(), W.contiguous(), Y, grads[0].contiguous(), e,
                            ctx->needs_input_grad(0), ctx->needs_input_grad(1),
                            bias && ctx->needs_input_grad(2));
    const auto dZ = apply_epilogue(Y, grads[0].contiguous(), e);
    if (ctx->needs_input_grad(0))
      dx = dense_kernel_fits(W.size(0), W.size(1)) ? dense_product(dZ, W, {}, Epilogue::none)
                                                   : dZ.mm(W);
    if (ctx->needs_input_grad(1)) dW = dZ.t().mm(x);
    if (bias && ctx->needs_input_grad(2)) db = dZ.sum(0);
    return {dx, dW, db, {}};
  }
  // dx, dW and db in one pass over the rows (linear_backward_rows), each thread summing its own
  // share of dW and db.
  static torch::autograd::tensor_list fused_backward(const torch::Tensor& x, const torch::Tensor& W,
                                                     const torch::Tensor& Y, const torch::Tensor& g,
                                                     Epilogue e, bool want_dx, bool want_dW,
                                                     bool want_db) {
    const auto n = x.size(0), K = W.size(1), N = W.size(0);
    const auto chunks =
        std::max<std::int64_t>(1, std::min<std::int64_t>(at::get_num_threads(), n / 4096));
    torch::Tensor dx = want_dx ? torch::empty_like(x) : torch::Tensor();
    torch::Tensor dW = want_dW ? torch::zeros({chunks, N, K}, x.options()) : torch::Tensor();
    torch::Tensor db = want_db ? torch::zeros({chunks, N}, x.options()) : torch::Tensor();
#if defined(__GNUC__)
    AT_DISPATCH_FLOATING_TYPES(x.scalar_type(), "topos_linear_backward", [&] {
      at::parallel_for(0, chunks, 1, [&](std::int64_t c0, std::int64_t c1) {
        for (std::int64_t c = c0; c < c1; ++c)
          linear_backward_clone(x.data_ptr<scalar_t>(), W.data_ptr<scalar_t>(),
                                Y.defined() ? Y.data_ptr<scalar_t>() : nullptr,
                                g.data_ptr<scalar_t>(), want_dx ? dx.data_ptr<scalar_t>() : nullptr,
                                want_dW ? dW.data_ptr<scalar_t>() + c * N * K : nullptr,
                                want_db ? db.data_ptr<scalar_t>() + c * N : nullptr, c * n / chunks,
                                (c + 1) * n / chunks, K, N, e);
      });
    });
#endif
    return {dx, want_dW ? dW.sum(0) : dW, want_db ? db.sum(0) : db, {}};
  }
};

}  // namespace detail

using detail::Epilogue;

/// act(x Wᵀ + b) (torch::nn::functional::linear, then relu or elu) as one autograd node on the
/// CPU: for up to 64 outputs a register-blocked kernel with the bias and the activation applied
/// before the store, otherwise BLAS then one vectorised pass; the backward needs no exponential.
/// Any other device, dtype or shape takes torch's ops.
inline torch::Tensor linear_act(const torch::Tensor& x, const torch::Tensor& W,
                                const torch::Tensor& b, Epilogue act = Epilogue::none) {
  const bool fused = x.device().is_cpu() && x.dim() == 2 && W.dim() == 2 &&
                     (x.scalar_type() == torch::kFloat || x.scalar_type() == torch::kDouble) &&
                     W.scalar_type() == x.scalar_type() &&
                     (!b.defined() || (b.dim() == 1 && b.scalar_type() == x.scalar_type()));
  if (!fused || (act == Epilogue::none && !detail::dense_kernel_fits(W.size(1), W.size(0)))) {
    const auto y = torch::linear(x, W, b);
    return act == Epilogue::relu ? torch::relu(y) : act == Epilogue::elu ? torch::elu(y) : y;
  }
  if (x.size(1) != W.size(1) || (b.defined() && b.numel() != W.size(0)))
    throw std::invalid_argument("linear_act: " + std::to_string(x.size(1)) +
                                " input channels for a weight of " + std::to_string(W.size(0)) +
                                " x " + std::to_string(W.size(1)) +
                                (b.defined() ? " and a bias of " + std::to_string(b.numel()) : ""));
  // torch 1.13's Function::apply cannot take an undefined input: no bias is an empty one.
  return detail::LinearFunction::apply(x, W, b.defined() ? b : torch::empty({0}, x.options()),
                                       static_cast<std::int64_t>(act));
}

}  // namespace topos::nn
