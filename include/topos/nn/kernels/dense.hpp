// topos/nn/kernels/dense.hpp
// The register-blocked dense kernels under linear_act (kernels.hpp): act(b + X M) for maps of
// 4 to 64 outputs, and of any multiple of 64 in panels of 64 where the CPU has AVX-512
// (dense_product), and the backward of act(x Wᵀ + b) in one pass over the rows.
#pragma once

#include "topos/nn/kernels/epilogue.hpp"

#include <ATen/Parallel.h>
#include <torch/torch.h>

#include <algorithm>
#include <cstdint>
#include <cstring>
#include <stdexcept>
#include <type_traits>

namespace topos::nn {

namespace detail {

// Y[i] = act(b + X[i] · M) for rows [begin, end): X n × K (contiguous), M K × N and Y n × N with
// row strides ldm and ldy (N for whole matrices, more for a panel of columns), N a compile-time
// width. Four rows at a time keep 4·N/8 accumulators in registers and read each row
// of M once per four rows; M (K·N·4 bytes, 4 KB at 32 × 32) stays in L1. For the narrow products
// of message passing (n large, K and N at most 64) this beats OpenBLAS, which packs X and
// zeroes Y before its kernel, and it applies the bias and the activation before the store.
// RB, when set, is the rows per block (otherwise as many as the registers allow). `accumulate`
// starts from Y's rows instead of the bias: a product over several blocks of K, each summed in
// turn onto the last (dense_blocks_rows, dense_rows_packed), adds in the order one product over
// all of K would. X's rows are `ldx` apart (0: K; more for a block of X's columns).
#if defined(__GNUC__)
template <class T, int N, Epilogue E, int VB, int RB = 0>
static TOPOS_INLINE_KERNEL void dense_rows_fixed(const T* X, const T* M, const T* b, T* Y,
                                                 std::int64_t begin, std::int64_t end,
                                                 std::int64_t K, std::int64_t ldm = N,
                                                 std::int64_t ldy = N, bool accumulate = false,
                                                 std::int64_t ldx = 0) {
  if (ldx == 0) ldx = K;
  // A width narrower than the vector (8 floats on 64 bytes) takes vectors of its own size.
  constexpr int VBe = N * static_cast<int>(sizeof(T)) < VB ? N * static_cast<int>(sizeof(T)) : VB;
  typedef T vec __attribute__((vector_size(VBe)));
  // Rows per block: as many accumulators as registers allow (16 ymm or 32 zmm).
  constexpr int L = static_cast<int>(VBe / sizeof(T)), V = N / L,
                R = RB > 0               ? RB
                    : V > 4              ? 2
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
      for (int j = 0; j < V; ++j)
        if (accumulate)
          std::memcpy(&acc[r][j], Y + (i + r) * ldy + j * L, sizeof(vec));
        else
          acc[r][j] = bias[j];
    for (std::int64_t k = 0; k < K; ++k) {
      vec w[V];
      for (int j = 0; j < V; ++j) std::memcpy(&w[j], M + k * ldm + j * L, sizeof(vec));
      for (int r = 0; r < R; ++r) {
        const T x = X[(i + r) * ldx + k];
        for (int j = 0; j < V; ++j) acc[r][j] += x * w[j];
      }
    }
    for (int r = 0; r < R; ++r)
      for (int j = 0; j < V; ++j) {
        epilogue_vec<T, E>(acc[r][j]);
        std::memcpy(Y + (i + r) * ldy + j * L, &acc[r][j], sizeof(vec));
      }
  }
  for (; i < end; ++i) {
    vec acc[V];
    for (int j = 0; j < V; ++j)
      if (accumulate)
        std::memcpy(&acc[j], Y + i * ldy + j * L, sizeof(vec));
      else
        acc[j] = bias[j];
    for (std::int64_t k = 0; k < K; ++k) {
      const T x = X[i * ldx + k];
      for (int j = 0; j < V; ++j) {
        vec w;
        std::memcpy(&w, M + k * ldm + j * L, sizeof(vec));
        acc[j] += x * w;
      }
    }
    for (int j = 0; j < V; ++j) {
      epilogue_vec<T, E>(acc[j]);
      std::memcpy(Y + i * ldy + j * L, &acc[j], sizeof(vec));
    }
  }
}

// Widths that are multiples of 64, as panels of 64 columns: a block of 48 rows of X (24 KB at
// K = 128) stays in L1 while it meets every panel of M. A panel of M may come from L2 (128 × 64
// floats fill 32 KB), so six rows share each load of it, not four: on a Zen 5 core 128 × 128
// products run at 240 GFLOP/s that way and at 185 with four (OpenBLAS's AVX2 kernels: 118).
template <class T, int VB>
constexpr int panel_rows = VB == 64 && sizeof(T) == 4 ? 6 : 0;  // 0: dense_rows_fixed's own
template <class T, Epilogue E, int VB>
static TOPOS_INLINE_KERNEL void dense_rows_panels(const T* X, const T* M, const T* b, T* Y,
                                                  std::int64_t begin, std::int64_t end,
                                                  std::int64_t K, std::int64_t N, std::int64_t ldm,
                                                  bool accumulate) {
  constexpr std::int64_t rows = 48;
  for (std::int64_t i0 = begin; i0 < end; i0 += rows) {
    const std::int64_t i1 = std::min(end, i0 + rows);
    for (std::int64_t c = 0; c < N; c += 64)
      dense_rows_fixed<T, 64, E, VB, panel_rows<T, VB>>(X, M + c, b ? b + c : nullptr, Y + c, i0,
                                                        i1, K, ldm, N, accumulate);
  }
}

// dense_rows_panels from M packed by dense_operand (N / 64 panels, each K × 64 contiguous), in
// blocks of 128 of K, each summed onto the last: the same sums in the same order. In M itself a
// panel's rows are N floats apart, so at N = 128 every row of a panel falls in the same eighth of
// L1's sets, more lines than their 12 ways hold, and the panel comes from L2 at every block of
// rows; packed, a panel's block of K (32 KB) fills the sets evenly. On an Intel Xeon VM (AVX-512,
// 48 KB L1) 16,384 × 128 · 128 products ran at 81-86 GFLOP/s unpacked and 122-130 packed, and
// with 256 or 512 inputs at 96-107 and 117-120 (docs/benchmarks.md).
template <class T, Epilogue E, int VB>
static TOPOS_INLINE_KERNEL void dense_rows_packed(const T* X, const T* P, const T* b, T* Y,
                                                  std::int64_t begin, std::int64_t end,
                                                  std::int64_t K, std::int64_t N) {
  constexpr std::int64_t rows = 48, depth = 128;
  constexpr int R = panel_rows<T, VB>;
  for (std::int64_t i0 = begin; i0 < end; i0 += rows) {
    const std::int64_t i1 = std::min(end, i0 + rows);
    for (std::int64_t c = 0; c < N; c += 64)
      for (std::int64_t k0 = 0; k0 < K; k0 += depth) {
        const std::int64_t kb = std::min(depth, K - k0);
        const T* panel = P + c * K + k0 * 64;
        const T* bias = k0 == 0 && b ? b + c : nullptr;
        if (k0 + kb < K)
          dense_rows_fixed<T, 64, Epilogue::none, VB, R>(X + k0, panel, bias, Y + c, i0, i1, kb, 64,
                                                         N, k0 > 0, K);
        else
          dense_rows_fixed<T, 64, E, VB, R>(X + k0, panel, bias, Y + c, i0, i1, kb, 64, N, k0 > 0,
                                            K);
      }
  }
}

// Any width dense_kernel_fits takes; M's rows `ldm` apart (N for a whole matrix, more for a
// block of M's columns).
template <class T, Epilogue E, int VB>
static TOPOS_INLINE_KERNEL void dense_rows_width(const T* X, const T* M, const T* b, T* Y,
                                                 std::int64_t begin, std::int64_t end,
                                                 std::int64_t K, std::int64_t N,
                                                 std::int64_t ldm = 0, bool accumulate = false) {
  if (ldm == 0) ldm = N;
  switch (N) {
    case 4:
      return dense_rows_fixed<T, 4, E, VB>(X, M, b, Y, begin, end, K, ldm, N, accumulate);
    case 8:
      return dense_rows_fixed<T, 8, E, VB>(X, M, b, Y, begin, end, K, ldm, N, accumulate);
    case 16:
      return dense_rows_fixed<T, 16, E, VB>(X, M, b, Y, begin, end, K, ldm, N, accumulate);
    case 32:
      return dense_rows_fixed<T, 32, E, VB>(X, M, b, Y, begin, end, K, ldm, N, accumulate);
    case 64:
      return dense_rows_fixed<T, 64, E, VB>(X, M, b, Y, begin, end, K, ldm, N, accumulate);
    default:
      return dense_rows_panels<T, E, VB>(X, M, b, Y, begin, end, K, N, ldm, accumulate);
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
  else if (e == Epilogue::elu)
    dense_rows_width<T, Epilogue::elu, VB>(X, M, b, Y, begin, end, K, N);
  else
    dense_rows_width<T, Epilogue::sigmoid, VB>(X, M, b, Y, begin, end, K, N);
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
#if defined(TOPOS_HAVE_V4)
[[maybe_unused]] TOPOS_V4 static void dense_rows_packed_float_v4(const float* X, const float* P,
                                                                 const float* b, float* Y,
                                                                 std::int64_t begin,
                                                                 std::int64_t end, std::int64_t K,
                                                                 std::int64_t N, Epilogue e) {
  if (e == Epilogue::none)
    dense_rows_packed<float, Epilogue::none, 64>(X, P, b, Y, begin, end, K, N);
  else if (e == Epilogue::relu)
    dense_rows_packed<float, Epilogue::relu, 64>(X, P, b, Y, begin, end, K, N);
  else if (e == Epilogue::elu)
    dense_rows_packed<float, Epilogue::elu, 64>(X, P, b, Y, begin, end, K, N);
  else
    dense_rows_packed<float, Epilogue::sigmoid, 64>(X, P, b, Y, begin, end, K, N);
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

/// The widths dense_product's kernel takes (the rest goes to torch's BLAS). With AVX-512: up to
/// 1024 inputs, and 4, 8, 16, 32 or 64 outputs or a multiple of 64 up to 1024 (a filter's taps
/// side by side: SCCNN's are 5 × 64 wide). Without: up to 256 inputs and 4 to 64 outputs (the
/// wide shapes were measured with AVX-512 only; elsewhere OpenBLAS keeps them). Four outputs are
/// attention's folded keys, one score per head (AllSetTransformer's x (K_h q_h)), where OpenBLAS
/// copied all of x before its kernel. linear_act's fused backward takes the same widths with
/// inputs and outputs swapped.
inline bool dense_kernel_fits(std::int64_t K, std::int64_t N) {
#if defined(__GNUC__)
  if (K < 0 || N <= 0) return false;
  const bool narrow = N == 4 || N == 8 || N == 16 || N == 32 || N == 64;
#if defined(TOPOS_HAVE_V4)
  if (cpu_has_v4()) return K <= 1024 && (narrow || (N % 64 == 0 && N <= 1024));
#endif
  return K <= 256 && narrow;
#else
  return K < 0 && N < 0;
#endif
}

/// Whether a float32 product of n rows by a map of K inputs and N outputs runs from M's panels
/// packed (dense_rows_packed): AVX-512, some inputs (with none, the unpacked kernel writes the
/// bias), several panels of 64 outputs, and rows enough to repay the copy (at 192 rows × 128 ·
/// 128 the copy cost more than it saved; at 512 the packed product was 1.3-1.5x faster).
inline bool packs_panels(const torch::Tensor& x, std::int64_t n, std::int64_t K, std::int64_t N) {
#if defined(TOPOS_HAVE_V4) && defined(__GNUC__)
  return x.scalar_type() == torch::kFloat && K > 0 && N % 64 == 0 && N > 64 && n >= 256 &&
         cpu_has_v4();
#else
  return x.scalar_type() != x.scalar_type() && n < 0 && K < 0 && N < 0;
#endif
}

// dst[r · ld + c] = src[r · rs + c · cs] for an R × C block, in tiles of 16 × 16 so that a
// transposed read (rs 1: a weight's transpose) stays in L1. LibTorch's copy of a transposed
// weight went element by element: a fifth of a HOPNet rollout step on these kernels.
template <class T>
inline void copy_2d(const T* src, std::int64_t R, std::int64_t C, std::int64_t rs, std::int64_t cs,
                    T* dst, std::int64_t ld) {
  if (cs == 1) {
    for (std::int64_t r = 0; r < R; ++r) std::memcpy(dst + r * ld, src + r * rs, C * sizeof(T));
    return;
  }
  constexpr std::int64_t tile = 16;
  for (std::int64_t r0 = 0; r0 < R; r0 += tile) {
    const auto r1 = std::min(R, r0 + tile);
    for (std::int64_t c0 = 0; c0 < C; c0 += tile) {
      const auto c1 = std::min(C, c0 + tile);
      for (std::int64_t c = c0; c < c1; ++c)
        for (std::int64_t r = r0; r < r1; ++r) dst[r * ld + c] = src[r * rs + c * cs];
    }
  }
}

/// M (K × N, any strides) as dense_product's kernels read it: N / 64 panels of K × 64
/// contiguous values (`panels`, dense_rows_packed's operand; N a multiple of 64), or K × N
/// contiguous (M itself where it is). One copy.
inline torch::Tensor dense_operand(const torch::Tensor& M, bool panels) {
  const auto K = M.size(0), N = M.size(1);
  if (!panels && M.is_contiguous()) return M;
  auto out =
      panels ? torch::empty({N / 64, K, 64}, M.options()) : torch::empty({K, N}, M.options());
  AT_DISPATCH_FLOATING_TYPES(M.scalar_type(), "topos_dense_operand", [&] {
    const auto* src = M.data_ptr<scalar_t>();
    auto* dst = out.data_ptr<scalar_t>();
    if (!panels) return copy_2d(src, K, N, M.stride(0), M.stride(1), dst, N);
    for (std::int64_t p = 0; p < N / 64; ++p)
      copy_2d(src + p * 64 * M.stride(1), K, 64, M.stride(0), M.stride(1), dst + p * K * 64, 64);
  });
  return out;
}

#if defined(__GNUC__)
// dense_product's rows [begin, end): from M's packed panels (float32 with AVX-512, `packed`) or
// from M contiguous.
template <class T>
inline void dense_product_rows(const T* X, const T* M, const T* b, T* Y, std::int64_t begin,
                               std::int64_t end, std::int64_t K, std::int64_t N, Epilogue e,
                               bool packed) {
#if defined(TOPOS_HAVE_V4)
  if constexpr (std::is_same_v<T, float>)
    if (packed) return dense_rows_packed_float_v4(X, M, b, Y, begin, end, K, N, e);
#endif
  dense_rows_clone(X, M, b, Y, begin, end, K, N, e);
}
#endif

/// act(b + X · M) for contiguous float or double X (n × K) and M (K × N) on the CPU, K and N as
/// dense_kernel_fits takes them; b may be undefined. M may be strided (a weight's transpose):
/// it is copied once, contiguous or in packed panels, unless `operand` holds that copy already
/// (dense_operand(M, packs_panels(X, n, K, N)), e.g. kept across a rollout's steps).
inline torch::Tensor dense_product(const torch::Tensor& X, const torch::Tensor& M,
                                   const torch::Tensor& b, Epilogue e,
                                   const torch::Tensor& operand = {}) {
  const auto x = X.contiguous();
  const auto bc = b.defined() ? b.contiguous() : b;
  const auto n = x.size(0), K = x.size(1), N = M.size(1);
  auto y = torch::empty({n, N}, x.options());
#if defined(__GNUC__)
  const bool packed = packs_panels(x, n, K, N);
  const auto m = operand.defined() ? operand : dense_operand(M, packed);
  TORCH_CHECK(m.dim() == (packed ? 3 : 2) && m.numel() == K * N && m.is_contiguous(),
              "dense_product: the operand is not dense_operand(M, ", packed, ")");
  AT_DISPATCH_FLOATING_TYPES(x.scalar_type(), "topos_dense_product", [&] {
    const auto* xp = x.data_ptr<scalar_t>();
    const auto* mp = m.data_ptr<scalar_t>();
    const auto* bp = bc.defined() ? bc.data_ptr<scalar_t>() : nullptr;
    auto* yp = y.data_ptr<scalar_t>();
    at::parallel_for(0, n, grain_rows(n, n * K * N), [&](std::int64_t begin, std::int64_t end) {
      dense_product_rows(xp, mp, bp, yp, begin, end, K, N, e, packed);
    });
  });
#else
  throw std::logic_error("dense_product: needs GCC's vector extension");
#endif
  return y;
}

#if defined(__GNUC__)
// dW[n] += Σ_i dZ[i][n] x[i] over a block of `rows` rows of dZ (leading dimension N) and x (row
// stride ldx), for one panel of KP columns of x and dW (row stride ldw): NT outputs'
// accumulators stay in registers over all the block's rows, so each entry of dW is loaded and
// stored once per block. (Loaded and stored every four rows, a 128 × 128 dW streamed from L2 and
// its FMAs were a third of CWN's MUTAG epoch.) Every entry sums its rows in ascending order, one
// FMA each, as that loop did: the same numbers.
template <class T, int KP, int NT, int VB>
static TOPOS_INLINE_KERNEL void outer_tile_fixed(const T* dZ, const T* x, T* dW, std::int64_t rows,
                                                 std::int64_t n0, std::int64_t N, std::int64_t ldx,
                                                 std::int64_t ldw) {
  constexpr int VBe = KP * static_cast<int>(sizeof(T)) < VB ? KP * static_cast<int>(sizeof(T)) : VB;
  typedef T vec __attribute__((vector_size(VBe)));
  constexpr int L = static_cast<int>(VBe / sizeof(T)), V = KP / L;
  vec acc[NT][V];
  for (int t = 0; t < NT; ++t)
    for (int j = 0; j < V; ++j) std::memcpy(&acc[t][j], dW + (n0 + t) * ldw + j * L, sizeof(vec));
  for (std::int64_t i = 0; i < rows; ++i) {
    vec xv[V];
    for (int j = 0; j < V; ++j) std::memcpy(&xv[j], x + i * ldx + j * L, sizeof(vec));
    for (int t = 0; t < NT; ++t) {
      const T z = dZ[i * N + n0 + t];
      for (int j = 0; j < V; ++j) acc[t][j] += z * xv[j];
    }
  }
  for (int t = 0; t < NT; ++t)
    for (int j = 0; j < V; ++j) std::memcpy(dW + (n0 + t) * ldw + j * L, &acc[t][j], sizeof(vec));
}
// dW[n] += Σ_i dZ[i][n] x[i] over a block of rows for a panel of KP columns, all N outputs: tiles
// of as many outputs as the registers hold (24 accumulators of 32 zmm, 12 of 16 ymm), then
// smaller ones.
template <class T, int KP, int VB>
static TOPOS_INLINE_KERNEL void outer_block_fixed(const T* dZ, const T* x, T* dW, std::int64_t rows,
                                                  std::int64_t N, std::int64_t ldx = KP,
                                                  std::int64_t ldw = KP) {
  constexpr int VBe = KP * static_cast<int>(sizeof(T)) < VB ? KP * static_cast<int>(sizeof(T)) : VB;
  constexpr int V = KP / static_cast<int>(VBe / sizeof(T));
  constexpr int budget = VB == 64 ? 24 : 12;
  constexpr int NT = budget / V > 8 ? 8 : budget / V < 1 ? 1 : budget / V;
  std::int64_t n = 0;
  for (; n + NT <= N; n += NT) outer_tile_fixed<T, KP, NT, VB>(dZ, x, dW, rows, n, N, ldx, ldw);
  // The rest in tiles of 4 and 2 (64 outputs in tiles of 6 leave 4: one load of x per 4, not 1).
  if constexpr (NT > 4)
    for (; n + 4 <= N; n += 4) outer_tile_fixed<T, KP, 4, VB>(dZ, x, dW, rows, n, N, ldx, ldw);
  if constexpr (NT > 2)
    for (; n + 2 <= N; n += 2) outer_tile_fixed<T, KP, 2, VB>(dZ, x, dW, rows, n, N, ldx, ldw);
  for (; n < N; ++n) outer_tile_fixed<T, KP, 1, VB>(dZ, x, dW, rows, n, N, ldx, ldw);
}

// outer_block_fixed for any width dense_kernel_fits takes (x's rows K apart, dW's ldw).
template <class T, int VB>
static TOPOS_INLINE_KERNEL void outer_block_any(const T* z, const T* x, T* dW, std::int64_t rows,
                                                std::int64_t N, std::int64_t K, std::int64_t ldw) {
  switch (K) {
    case 4:
      return outer_block_fixed<T, 4, VB>(z, x, dW, rows, N, K, ldw);
    case 8:
      return outer_block_fixed<T, 8, VB>(z, x, dW, rows, N, K, ldw);
    case 16:
      return outer_block_fixed<T, 16, VB>(z, x, dW, rows, N, K, ldw);
    case 32:
      return outer_block_fixed<T, 32, VB>(z, x, dW, rows, N, K, ldw);
    case 64:
      return outer_block_fixed<T, 64, VB>(z, x, dW, rows, N, K, ldw);
    default:  // a multiple of 64: panels of dW's columns
      for (std::int64_t c = 0; c < K; c += 64)
        outer_block_fixed<T, 64, VB>(z, x + c, dW + c, rows, N, K, ldw);
  }
}

// The backward of act(x Wᵀ + b) (x n × K, W N × K) over rows [begin, end), a block of rows at a
// time so that dZ = g ⊙ act'(y) never leaves L1: dx = dZ W, and dW, db accumulate into the
// caller's buffers. Each of the three is skipped where its pointer is null. WP, when given, is W
// in packed panels (dense_operand, K a multiple of 64): dx is then dense_rows_packed's product.
template <class T, Epilogue E, int VB>
static TOPOS_INLINE_KERNEL void linear_backward_rows(const T* x, const T* W, const T* WP,
                                                     const T* y, const T* g, T* dx, T* dW, T* db,
                                                     std::int64_t begin, std::int64_t end,
                                                     std::int64_t K, std::int64_t N) {
  // Blocks of up to 30 rows, fewer above 256 outputs so that dZ keeps its 32 KB (float) on the
  // stack: a multiple of the 6 rows the product kernels take at a time (32 left 2 rows to the
  // one-row loop in every block). Each entry of dW and db still sums its rows in order.
  constexpr std::int64_t capacity = 32 * 256;
  std::int64_t B = std::max<std::int64_t>(
      1, std::min<std::int64_t>(30, capacity / std::max<std::int64_t>(N, 1)));
  if (B >= 6) B -= B % 6;
  alignas(64) T dZ[capacity];
  for (std::int64_t i0 = begin; i0 < end; i0 += B) {
    const std::int64_t rows = std::min(B, end - i0);
    const T* z = g + i0 * N;
    if (E != Epilogue::none) {
      epilogue_rows<T, VB>(const_cast<T*>(y + i0 * N), g + i0 * N, dZ, rows * N, E);
      z = dZ;
    }
    if (dx && WP)  // dx = dZ W: the forward's product with W's K columns as outputs
      dense_rows_packed<T, Epilogue::none, VB>(z, WP, nullptr, dx + i0 * K, 0, rows, N, K);
    else if (dx)
      dense_rows_width<T, Epilogue::none, VB>(z, W, nullptr, dx + i0 * K, 0, rows, N, K);
    if (dW) outer_block_any<T, VB>(z, x + i0 * K, dW, rows, N, K, K);
    if (db)
      for (std::int64_t r = 0; r < rows; ++r)
        for (std::int64_t n = 0; n < N; ++n) db[n] += z[r * N + n];
  }
}
template <class T, int VB = 32>
static TOPOS_INLINE_KERNEL void linear_backward_any(const T* x, const T* W, const T* WP, const T* y,
                                                    const T* g, T* dx, T* dW, T* db,
                                                    std::int64_t begin, std::int64_t end,
                                                    std::int64_t K, std::int64_t N, Epilogue e) {
  if (e == Epilogue::none)
    linear_backward_rows<T, Epilogue::none, VB>(x, W, WP, y, g, dx, dW, db, begin, end, K, N);
  else if (e == Epilogue::relu)
    linear_backward_rows<T, Epilogue::relu, VB>(x, W, WP, y, g, dx, dW, db, begin, end, K, N);
  else if (e == Epilogue::elu)
    linear_backward_rows<T, Epilogue::elu, VB>(x, W, WP, y, g, dx, dW, db, begin, end, K, N);
  else
    linear_backward_rows<T, Epilogue::sigmoid, VB>(x, W, WP, y, g, dx, dW, db, begin, end, K, N);
}
[[maybe_unused]] TOPOS_SIMD_CLONES static void linear_backward_float(
    const float* x, const float* W, const float* WP, const float* y, const float* g, float* dx,
    float* dW, float* db, std::int64_t begin, std::int64_t end, std::int64_t K, std::int64_t N,
    Epilogue e) {
  linear_backward_any<float>(x, W, WP, y, g, dx, dW, db, begin, end, K, N, e);
}
#if defined(TOPOS_HAVE_V4)
[[maybe_unused]] TOPOS_V4 static void linear_backward_float_v4(const float* x, const float* W,
                                                               const float* WP, const float* y,
                                                               const float* g, float* dx, float* dW,
                                                               float* db, std::int64_t begin,
                                                               std::int64_t end, std::int64_t K,
                                                               std::int64_t N, Epilogue e) {
  linear_backward_any<float, 64>(x, W, WP, y, g, dx, dW, db, begin, end, K, N, e);
}
#endif
[[maybe_unused]] TOPOS_SIMD_CLONES static void linear_backward_double(
    const double* x, const double* W, const double* WP, const double* y, const double* g,
    double* dx, double* dW, double* db, std::int64_t begin, std::int64_t end, std::int64_t K,
    std::int64_t N, Epilogue e) {
  linear_backward_any<double>(x, W, WP, y, g, dx, dW, db, begin, end, K, N, e);
}
#if defined(TOPOS_HAVE_V4)
[[maybe_unused]] TOPOS_V4 static void linear_backward_double_v4(
    const double* x, const double* W, const double* WP, const double* y, const double* g,
    double* dx, double* dW, double* db, std::int64_t begin, std::int64_t end, std::int64_t K,
    std::int64_t N, Epilogue e) {
  linear_backward_any<double, 64>(x, W, WP, y, g, dx, dW, db, begin, end, K, N, e);
}
#endif
inline void linear_backward_clone(const float* x, const float* W, const float* WP, const float* y,
                                  const float* g, float* dx, float* dW, float* db,
                                  std::int64_t begin, std::int64_t end, std::int64_t K,
                                  std::int64_t N, Epilogue e) {
#if defined(TOPOS_HAVE_V4)
  if (cpu_has_v4())
    return linear_backward_float_v4(x, W, WP, y, g, dx, dW, db, begin, end, K, N, e);
#endif
  linear_backward_float(x, W, WP, y, g, dx, dW, db, begin, end, K, N, e);
}
inline void linear_backward_clone(const double* x, const double* W, const double* WP,
                                  const double* y, const double* g, double* dx, double* dW,
                                  double* db, std::int64_t begin, std::int64_t end, std::int64_t K,
                                  std::int64_t N, Epilogue e) {
#if defined(TOPOS_HAVE_V4)
  if (cpu_has_v4())
    return linear_backward_double_v4(x, W, WP, y, g, dx, dW, db, begin, end, K, N, e);
#endif
  linear_backward_double(x, W, WP, y, g, dx, dW, db, begin, end, K, N, e);
}
#endif

// Blocks of columns side by side without their concatenation: X = [X_0 | X_1 | ...], X_s
// n × K[s] (contiguous, S of them), M (ΣK) × N. Y = act(Y0 + X M) over rows [begin, end), each
// block of 48 rows summing the blocks of K in turn while its Y stays in L1: the sums of one
// product over the concatenation, in its order, without writing the concatenation (a filter's
// taps: combine_terms). `base`: Y already holds Y0 (a filter's other part), else Y0 = 0; the
// activation is applied as the last block is stored.
#if defined(__GNUC__)
template <class T, Epilogue E, int VB>
static TOPOS_INLINE_KERNEL void dense_blocks_rows(const T* const* X, const std::int64_t* K,
                                                  std::int64_t S, const T* M, T* Y,
                                                  std::int64_t begin, std::int64_t end,
                                                  std::int64_t N, bool base) {
  constexpr std::int64_t rows = 48;
  for (std::int64_t i0 = begin; i0 < end; i0 += rows) {
    const std::int64_t i1 = std::min(end, i0 + rows);
    const T* m = M;
    for (std::int64_t s = 0; s < S; m += K[s] * N, ++s)
      if (s + 1 < S)
        dense_rows_width<T, Epilogue::none, VB>(X[s], m, nullptr, Y, i0, i1, K[s], N, N,
                                                base || s > 0);
      else
        dense_rows_width<T, E, VB>(X[s], m, nullptr, Y, i0, i1, K[s], N, N, base || s > 0);
  }
}
// Its backward from dY = g (n × N) and the output y: dZ = g ⊙ act'(y) a block of rows at a time
// (into dbase where not null: Y0's gradient; else on the stack), dX_s = dZ W_s (W = Mᵀ, N × ΣK,
// W_s its K[s] columns) into dX[s] where not null, and dW += dZᵀ X (dW N × ΣK) where not null,
// over rows [begin, end).
template <class T, Epilogue E, int VB>
static TOPOS_INLINE_KERNEL void linear_blocks_backward_rows(
    const T* const* X, const std::int64_t* K, std::int64_t S, const T* W, const T* y, const T* g,
    T* const* dX, T* dW, T* dbase, std::int64_t begin, std::int64_t end, std::int64_t N) {
  std::int64_t ldw = 0;
  for (std::int64_t s = 0; s < S; ++s) ldw += K[s];
  constexpr std::int64_t capacity = 32 * 256;
  const std::int64_t B = std::max<std::int64_t>(1, std::min<std::int64_t>(32, capacity / N));
  alignas(64) T dZ[E == Epilogue::none ? 1 : capacity];
  for (std::int64_t i0 = begin; i0 < end; i0 += B) {
    const std::int64_t rows = std::min(B, end - i0);
    const T* z = g + i0 * N;
    if (E != Epilogue::none) {
      T* out = dbase ? dbase + i0 * N : dZ;
      epilogue_rows<T, VB>(const_cast<T*>(y + i0 * N), g + i0 * N, out, rows * N, E);
      z = out;
    } else if (dbase) {
      std::memcpy(dbase + i0 * N, z, static_cast<std::size_t>(rows * N) * sizeof(T));
    }
    std::int64_t off = 0;
    for (std::int64_t s = 0; s < S; off += K[s], ++s) {
      if (dX[s])
        dense_rows_width<T, Epilogue::none, VB>(z, W + off, nullptr, dX[s] + i0 * K[s], 0, rows, N,
                                                K[s], ldw);
      if (dW) outer_block_any<T, VB>(z, X[s] + i0 * K[s], dW + off, rows, N, K[s], ldw);
    }
  }
}
// An epilogue known at run time as the kernel's template argument.
#define TOPOS_BLOCKS_DISPATCH(F, ...)                  \
  switch (e) {                                         \
    case Epilogue::none:                               \
      return F<T, Epilogue::none, VB>(__VA_ARGS__);    \
    case Epilogue::relu:                               \
      return F<T, Epilogue::relu, VB>(__VA_ARGS__);    \
    case Epilogue::elu:                                \
      return F<T, Epilogue::elu, VB>(__VA_ARGS__);     \
    case Epilogue::sigmoid:                            \
      return F<T, Epilogue::sigmoid, VB>(__VA_ARGS__); \
  }
template <class T, int VB>
static TOPOS_INLINE_KERNEL void dense_blocks_any(const T* const* X, const std::int64_t* K,
                                                 std::int64_t S, const T* M, T* Y,
                                                 std::int64_t begin, std::int64_t end,
                                                 std::int64_t N, bool base, Epilogue e) {
  TOPOS_BLOCKS_DISPATCH(dense_blocks_rows, X, K, S, M, Y, begin, end, N, base);
}
template <class T, int VB>
static TOPOS_INLINE_KERNEL void linear_blocks_backward_any(const T* const* X, const std::int64_t* K,
                                                           std::int64_t S, const T* W, const T* y,
                                                           const T* g, T* const* dX, T* dW,
                                                           T* dbase, std::int64_t begin,
                                                           std::int64_t end, std::int64_t N,
                                                           Epilogue e) {
  TOPOS_BLOCKS_DISPATCH(linear_blocks_backward_rows, X, K, S, W, y, g, dX, dW, dbase, begin, end,
                        N);
}
#undef TOPOS_BLOCKS_DISPATCH
#define TOPOS_BLOCKS_KERNELS(T, NAME, ATTR, VB)                                           \
  [[maybe_unused]] ATTR static void dense_blocks_##NAME(                                  \
      const T* const* X, const std::int64_t* K, std::int64_t S, const T* M, T* Y,         \
      std::int64_t begin, std::int64_t end, std::int64_t N, bool base, Epilogue e) {      \
    dense_blocks_any<T, VB>(X, K, S, M, Y, begin, end, N, base, e);                       \
  }                                                                                       \
  [[maybe_unused]] ATTR static void linear_blocks_backward_##NAME(                        \
      const T* const* X, const std::int64_t* K, std::int64_t S, const T* W, const T* y,   \
      const T* g, T* const* dX, T* dW, T* dbase, std::int64_t begin, std::int64_t end,    \
      std::int64_t N, Epilogue e) {                                                       \
    linear_blocks_backward_any<T, VB>(X, K, S, W, y, g, dX, dW, dbase, begin, end, N, e); \
  }
TOPOS_BLOCKS_KERNELS(float, float, TOPOS_SIMD_CLONES, 32)
TOPOS_BLOCKS_KERNELS(double, double, TOPOS_SIMD_CLONES, 32)
#if defined(TOPOS_HAVE_V4)
TOPOS_BLOCKS_KERNELS(float, float_v4, TOPOS_V4, 64)
TOPOS_BLOCKS_KERNELS(double, double_v4, TOPOS_V4, 64)
#endif
#undef TOPOS_BLOCKS_KERNELS
#define TOPOS_BLOCKS_CLONE(T, NAME)                                                               \
  inline void dense_blocks_clone(const T* const* X, const std::int64_t* K, std::int64_t S,        \
                                 const T* M, T* Y, std::int64_t begin, std::int64_t end,          \
                                 std::int64_t N, bool base, Epilogue e) {                         \
    TOPOS_IF_V4(return dense_blocks_##NAME##_v4(X, K, S, M, Y, begin, end, N, base, e));          \
    dense_blocks_##NAME(X, K, S, M, Y, begin, end, N, base, e);                                   \
  }                                                                                               \
  inline void linear_blocks_backward_clone(const T* const* X, const std::int64_t* K,              \
                                           std::int64_t S, const T* W, const T* y, const T* g,    \
                                           T* const* dX, T* dW, T* dbase, std::int64_t begin,     \
                                           std::int64_t end, std::int64_t N, Epilogue e) {        \
    TOPOS_IF_V4(return linear_blocks_backward_##NAME##_v4(X, K, S, W, y, g, dX, dW, dbase, begin, \
                                                          end, N, e));                            \
    linear_blocks_backward_##NAME(X, K, S, W, y, g, dX, dW, dbase, begin, end, N, e);             \
  }
#if defined(TOPOS_HAVE_V4)
#define TOPOS_IF_V4(call) \
  if (cpu_has_v4()) call
#else
#define TOPOS_IF_V4(call)
#endif
TOPOS_BLOCKS_CLONE(float, float) TOPOS_BLOCKS_CLONE(double, double)
#undef TOPOS_IF_V4
#undef TOPOS_BLOCKS_CLONE
#endif

}  // namespace detail

}  // namespace topos::nn
