// topos/nn/kernels/dense_bf16.hpp
// act(x Wᵀ + b) and its backward with bfloat16 products and float32 accumulation, on the CPU's
// AVX-512 BF16 dot products (vdpbf16ps: 32 multiply-adds of bfloat16 pairs into 16 float32 sums,
// twice the FMA's rate on a Zen 5 core): what MatmulPrecision::medium means for the products
// topos runs itself. Inputs are rounded to bfloat16 (to nearest, ties to even) as they are read;
// sums, outputs, gradients, the bias and the activation stay float32. Operands are packed in
// pairs along the summed dimension, the layout the instruction reads: a weight once per call,
// rows of x (or of dY) a block at a time in L1.
#pragma once

#include "topos/nn/kernels/epilogue.hpp"

#include <algorithm>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <stdexcept>
#include <string>
#include <vector>

#if defined(TOPOS_HAVE_V4)
#include <immintrin.h>
#define TOPOS_BF16 __attribute__((target("arch=x86-64-v4,avx512bf16")))
#define TOPOS_BF16_INLINE inline __attribute__((always_inline, target("arch=x86-64-v4,avx512bf16")))
#define TOPOS_HAVE_BF16 1
#endif

#include "topos/nn/kernels/dense_amx.hpp"  // the same products on AMX tiles

namespace topos::nn::detail {

/// Whether this CPU multiplies bfloat16 pairs (AVX-512 BF16) and this build has the kernels.
/// TOPOS_DISABLE_BF16=1 in the environment (read once) says no: a CPU without them, its paths
/// (oneDNN's bfloat16 products, or float32) tested and timed on one that has them.
inline bool cpu_has_bf16() {
#if defined(TOPOS_HAVE_BF16)
  static const bool bf16 = [] {
    return !env_flag("TOPOS_DISABLE_BF16") && cpu_has_v4() && __builtin_cpu_supports("avx512bf16");
  }();
  return bf16;
#else
  return false;
#endif
}

/// The shapes the bfloat16 kernels take: K inputs and N outputs, each a multiple of 16 (whole
/// vectors both ways, the backward's dx has K outputs) up to 1024.
inline bool bf16_kernel_fits(std::int64_t K, std::int64_t N) {
  return K > 0 && N > 0 && K % 16 == 0 && N % 16 == 0 && K <= 1024 && N <= 1024;
}

/// The bfloat16 bits of a float, rounded to nearest with ties to even, as vcvtne2ps2bf16 rounds
/// a normal number (NaN stays NaN).
inline std::uint16_t bf16_bits(float f) {
  std::uint32_t u;
  std::memcpy(&u, &f, 4);
  if ((u & 0x7f800000u) == 0x7f800000u && (u & 0x007fffffu))
    return static_cast<std::uint16_t>((u >> 16) | 0x40);  // a quiet NaN
  return static_cast<std::uint16_t>((u + 0x7fffu + ((u >> 16) & 1u)) >> 16);
}

/// P[r][c] = (M[2r][c], M[2r+1][c]) as bfloat16 pairs, the even row in the low half, for the
/// R × C matrix M with strides rs (rows) and cs (columns); an odd R pairs its last row with 0.
/// Element by element: the reference for pack_bf16_pairs.
inline std::vector<std::uint32_t> pack_bf16_pairs_scalar(const float* M, std::int64_t R,
                                                         std::int64_t C, std::int64_t rs,
                                                         std::int64_t cs) {
  std::vector<std::uint32_t> P(static_cast<std::size_t>((R + 1) / 2 * C));
  for (std::int64_t r = 0; r < R; r += 2)
    for (std::int64_t c = 0; c < C; ++c) {
      const std::uint32_t lo = bf16_bits(M[r * rs + c * cs]);
      const std::uint32_t hi = r + 1 < R ? bf16_bits(M[(r + 1) * rs + c * cs]) : 0;
      P[static_cast<std::size_t>(r / 2 * C + c)] = lo | hi << 16;
    }
  return P;
}

#if defined(TOPOS_HAVE_BF16)
// A row of n floats (n a multiple of 16) as n/2 bfloat16 pairs of neighbours: (x0, x1), (x2, x3)...
TOPOS_BF16_INLINE void bf16_row(const float* x, std::int64_t n, std::uint32_t* out) {
  std::int64_t k = 0;
  for (; k + 32 <= n; k += 32) {
    const __m512bh v = _mm512_cvtne2ps_pbh(_mm512_loadu_ps(x + k + 16), _mm512_loadu_ps(x + k));
    _mm512_storeu_si512(out + k / 2, reinterpret_cast<const __m512i&>(v));
  }
  if (k < n) {  // 16 left
    const __m256bh v = _mm512_cvtneps_pbh(_mm512_loadu_ps(x + k));
    _mm256_storeu_si256(reinterpret_cast<__m256i*>(out + k / 2),
                        reinterpret_cast<const __m256i&>(v));
  }
}
// Two rows a and b (b null: zeros) of n floats (a multiple of 16) as n pairs (a[c], b[c]).
TOPOS_BF16_INLINE void bf16_interleave(const float* a, const float* b, std::int64_t n,
                                       std::uint32_t* out) {
  alignas(64) static constexpr std::uint16_t kOrder[32] = {
      0, 16, 1, 17, 2,  18, 3,  19, 4,  20, 5,  21, 6,  22, 7,  23,
      8, 24, 9, 25, 10, 26, 11, 27, 12, 28, 13, 29, 14, 30, 15, 31};
  const __m512i order = _mm512_load_si512(kOrder);
  for (std::int64_t c = 0; c < n; c += 16) {
    const __m512 hi = b ? _mm512_loadu_ps(b + c) : _mm512_setzero_ps();
    const __m512bh v = _mm512_cvtne2ps_pbh(hi, _mm512_loadu_ps(a + c));
    _mm512_storeu_si512(out + c,
                        _mm512_permutexvar_epi16(order, reinterpret_cast<const __m512i&>(v)));
  }
}

// pack_bf16_pairs_scalar's pairs, a vector at a time where M's rows (cs 1) or columns (rs 1)
// are contiguous and R and C are multiples of 16 (the shapes the kernels take): a weight is
// packed on every call, so its cost counts beside small products.
TOPOS_BF16 inline void pack_bf16_pairs_into(const float* M, std::int64_t R, std::int64_t C,
                                            std::int64_t rs, std::int64_t cs, std::uint32_t* P) {
  if (cs == 1) {  // pairs of contiguous rows, interleaved
    for (std::int64_t r = 0; r < R; r += 2)
      bf16_interleave(M + r * rs, M + (r + 1) * rs, C, P + r / 2 * C);
  } else {  // rs == 1: each column contiguous, its neighbours paired; 16 columns at a time are
            // spread over P's rows as 16 neighbouring pairs (one cache line, not 16)
    alignas(64) std::uint32_t cols[16 * 512];
    for (std::int64_t c0 = 0; c0 < C; c0 += 16) {
      for (std::int64_t j = 0; j < 16; ++j) bf16_row(M + (c0 + j) * cs, R, cols + j * 512);
      for (std::int64_t p = 0; p < R / 2; ++p)
        for (std::int64_t j = 0; j < 16; ++j) P[p * C + c0 + j] = cols[j * 512 + p];
    }
  }
}
#endif

/// P[r][c] = (M[2r][c], M[2r+1][c]) as bfloat16 pairs (pack_bf16_pairs_scalar), vectorised for
/// the kernels' shapes (R, C multiples of 16 up to 1024, rows or columns contiguous).
inline std::vector<std::uint32_t> pack_bf16_pairs(const float* M, std::int64_t R, std::int64_t C,
                                                  std::int64_t rs, std::int64_t cs) {
#if defined(TOPOS_HAVE_BF16)
  if (cpu_has_bf16() && R % 16 == 0 && C % 16 == 0 && R <= 1024 && (cs == 1 || rs == 1)) {
    std::vector<std::uint32_t> P(static_cast<std::size_t>(R / 2 * C));
    pack_bf16_pairs_into(M, R, C, rs, cs, P.data());
    return P;
  }
#endif
  return pack_bf16_pairs_scalar(M, R, C, rs, cs);
}

#if defined(TOPOS_HAVE_BF16)
// Y[r][0, 16V) = act(b + Σ_k A[r][k] P[k]) for R rows: A's rows (lda pairs apart) of Kp pairs,
// P Kp × ldp pairs. accumulate: start from Y (plus b where given).
template <int R, int V, Epilogue E>
TOPOS_BF16_INLINE void bf16_tile(const std::uint32_t* A, std::int64_t lda, std::int64_t Kp,
                                 const std::uint32_t* P, std::int64_t ldp, const float* b, float* Y,
                                 std::int64_t ldy, bool accumulate) {
  __m512 acc[R][V];
  for (int r = 0; r < R; ++r)
    for (int j = 0; j < V; ++j)
      acc[r][j] = accumulate && b ? _mm512_add_ps(_mm512_loadu_ps(Y + r * ldy + 16 * j),
                                                  _mm512_loadu_ps(b + 16 * j))
                  : accumulate    ? _mm512_loadu_ps(Y + r * ldy + 16 * j)
                  : b             ? _mm512_loadu_ps(b + 16 * j)
                                  : _mm512_setzero_ps();
  for (std::int64_t k = 0; k < Kp; ++k) {
    __m512i w[V];
    for (int j = 0; j < V; ++j) w[j] = _mm512_loadu_si512(P + k * ldp + 16 * j);
    for (int r = 0; r < R; ++r) {
      const __m512i a = _mm512_set1_epi32(static_cast<int>(A[r * lda + k]));
      for (int j = 0; j < V; ++j)
        acc[r][j] = _mm512_dpbf16_ps(acc[r][j], reinterpret_cast<const __m512bh&>(a),
                                     reinterpret_cast<const __m512bh&>(w[j]));
    }
  }
  for (int r = 0; r < R; ++r)
    for (int j = 0; j < V; ++j) {
      epilogue_vec<float, E>(acc[r][j]);
      _mm512_storeu_ps(Y + r * ldy + 16 * j, acc[r][j]);
    }
}

// Y[0, rows) = act(b + A P) over all N columns (panels of 64), A rows × Kp pairs (lda apart), P
// Kp × N pairs (ldp apart); accumulate: act(Y + b + A P).
template <Epilogue E>
TOPOS_BF16_INLINE void bf16_rows(const std::uint32_t* A, std::int64_t lda, std::int64_t rows,
                                 std::int64_t Kp, const std::uint32_t* P, std::int64_t ldp,
                                 std::int64_t N, const float* b, float* Y, std::int64_t ldy,
                                 bool accumulate) {
#if defined(TOPOS_HAVE_AMX)
  if (rows >= 16 && Kp % 16 == 0 && N % 16 == 0 && use_amx()) {
    const std::int64_t tiled = rows / 16 * 16;  // the rest, fewer than 16, below
    amx_rows(A, lda, tiled, Kp, P, ldp, N, Y, ldy, accumulate);
    if (E != Epilogue::none || b)
      for (std::int64_t r = 0; r < tiled; ++r)
        for (std::int64_t c = 0; c < N; c += 16) {
          __m512 v = _mm512_loadu_ps(Y + r * ldy + c);
          if (b) v = _mm512_add_ps(v, _mm512_loadu_ps(b + c));
          epilogue_vec<float, E>(v);
          _mm512_storeu_ps(Y + r * ldy + c, v);
        }
    A += tiled * lda, Y += tiled * ldy, rows -= tiled;
  }
#endif
  for (std::int64_t c = 0; c < N; c += 64) {
    const std::int64_t V = std::min<std::int64_t>(4, (N - c) / 16);
    const float* bc = b ? b + c : nullptr;
    std::int64_t r = 0;
#define TOPOS_BF16_TILE(RR, VV) \
  bf16_tile<RR, VV, E>(A + r * lda, lda, Kp, P + c, ldp, bc, Y + r * ldy + c, ldy, accumulate)
#define TOPOS_BF16_ROWS(RR)   \
  switch (V) {                \
    case 4:                   \
      TOPOS_BF16_TILE(RR, 4); \
      break;                  \
    case 3:                   \
      TOPOS_BF16_TILE(RR, 3); \
      break;                  \
    case 2:                   \
      TOPOS_BF16_TILE(RR, 2); \
      break;                  \
    default:                  \
      TOPOS_BF16_TILE(RR, 1); \
  }
    for (; r + 6 <= rows; r += 6) TOPOS_BF16_ROWS(6)
    for (; r < rows; ++r) TOPOS_BF16_ROWS(1)
#undef TOPOS_BF16_ROWS
#undef TOPOS_BF16_TILE
  }
}

// Rows of A (at most this many pairs) converted at a time: 48 KB, in L1 beside a panel of P.
constexpr std::int64_t kBf16Block = 12288;
// Rows converted at a time for Kp pairs a row: up to 48; whole tiles of 16 on AMX.
inline std::int64_t bf16_block_rows(std::int64_t Kp) {
  const std::int64_t block = std::max<std::int64_t>(1, std::min<std::int64_t>(48, kBf16Block / Kp));
  return block >= 16 && use_amx() ? block / 16 * 16 : block;
}

template <Epilogue E>
TOPOS_BF16 void dense_rows_bf16_e(const float* X, const std::uint32_t* P, const float* b, float* Y,
                                  std::int64_t begin, std::int64_t end, std::int64_t K,
                                  std::int64_t N) {
  alignas(64) std::uint32_t A[kBf16Block];
  const std::int64_t Kp = K / 2;
  const std::int64_t block = bf16_block_rows(Kp);
  for (std::int64_t i0 = begin; i0 < end; i0 += block) {
    const std::int64_t rows = std::min(block, end - i0);
    for (std::int64_t r = 0; r < rows; ++r) bf16_row(X + (i0 + r) * K, K, A + r * Kp);
    bf16_rows<E>(A, Kp, rows, Kp, P, N, N, b, Y + i0 * N, N, false);
  }
}

/// act(b + X Wᵀ) for rows [begin, end) of X (n × K), P = pack_bf16_pairs of Wᵀ (K/2 × N pairs).
TOPOS_BF16 inline void dense_rows_bf16(const float* X, const std::uint32_t* P, const float* b,
                                       float* Y, std::int64_t begin, std::int64_t end,
                                       std::int64_t K, std::int64_t N, Epilogue e) {
  switch (e) {
    case Epilogue::none:
      return dense_rows_bf16_e<Epilogue::none>(X, P, b, Y, begin, end, K, N);
    case Epilogue::relu:
      return dense_rows_bf16_e<Epilogue::relu>(X, P, b, Y, begin, end, K, N);
    case Epilogue::elu:
      return dense_rows_bf16_e<Epilogue::elu>(X, P, b, Y, begin, end, K, N);
    default:
      return dense_rows_bf16_e<Epilogue::sigmoid>(X, P, b, Y, begin, end, K, N);
  }
}

// dW[n][k0, k0 + 16V) += Σ_p Z[p][n] Xq[p][k0...] for NT outputs n0..: Z (N pairs a row) and Xq
// (ldx pairs a row) pairs of rows; dW's rows ldw apart.
template <int NT, int V>
TOPOS_BF16_INLINE void bf16_outer_tile(const std::uint32_t* Z, std::int64_t N, std::int64_t pairs,
                                       const std::uint32_t* Xq, std::int64_t ldx, float* dW,
                                       std::int64_t ldw, std::int64_t n0, std::int64_t k0) {
  __m512 acc[NT][V];
  for (int t = 0; t < NT; ++t)
    for (int j = 0; j < V; ++j) acc[t][j] = _mm512_loadu_ps(dW + (n0 + t) * ldw + k0 + 16 * j);
  for (std::int64_t p = 0; p < pairs; ++p) {
    __m512i x[V];
    for (int j = 0; j < V; ++j) x[j] = _mm512_loadu_si512(Xq + p * ldx + k0 + 16 * j);
    for (int t = 0; t < NT; ++t) {
      const __m512i z = _mm512_set1_epi32(static_cast<int>(Z[p * N + n0 + t]));
      for (int j = 0; j < V; ++j)
        acc[t][j] = _mm512_dpbf16_ps(acc[t][j], reinterpret_cast<const __m512bh&>(z),
                                     reinterpret_cast<const __m512bh&>(x[j]));
    }
  }
  for (int t = 0; t < NT; ++t)
    for (int j = 0; j < V; ++j) _mm512_storeu_ps(dW + (n0 + t) * ldw + k0 + 16 * j, acc[t][j]);
}
// dW += Zᵀ Xq over all N outputs and the K columns of Xq, panels of 64 columns.
TOPOS_BF16_INLINE void bf16_outer(const std::uint32_t* Z, std::int64_t N, std::int64_t pairs,
                                  const std::uint32_t* Xq, std::int64_t K, float* dW,
                                  std::int64_t ldw) {
  if (pairs == 0) return;
  for (std::int64_t k0 = 0; k0 < K; k0 += 64) {
    const std::int64_t V = std::min<std::int64_t>(4, (K - k0) / 16);
    std::int64_t n = 0;
#define TOPOS_BF16_OUTER(TT, VV) bf16_outer_tile<TT, VV>(Z, N, pairs, Xq, K, dW, ldw, n, k0)
#define TOPOS_BF16_PANEL(VV, TT)                         \
  for (; n + TT <= N; n += TT) TOPOS_BF16_OUTER(TT, VV); \
  for (; n + 2 <= N; n += 2) TOPOS_BF16_OUTER(2, VV);    \
  for (; n < N; ++n) TOPOS_BF16_OUTER(1, VV);
    if (V == 4) {
      TOPOS_BF16_PANEL(4, 6)
    } else if (V == 3) {
      TOPOS_BF16_PANEL(3, 8)
    } else if (V == 2) {
      TOPOS_BF16_PANEL(2, 8)
    } else {
      TOPOS_BF16_PANEL(1, 8)
    }
#undef TOPOS_BF16_PANEL
#undef TOPOS_BF16_OUTER
  }
}

// dZ = g ⊙ act'(y) for n floats (a multiple of 16): the backward kernels' first pass over a block.
template <Epilogue E>
TOPOS_BF16_INLINE void bf16_output_gradient(const float* g, const float* y, std::int64_t n,
                                            float* dZ) {
  for (std::int64_t r = 0; r < n; r += 16) {
    __m512 gv = _mm512_loadu_ps(g + r);
    const __m512 yv = _mm512_loadu_ps(y + r);
    epilogue_grad<float>(yv, gv, E);
    _mm512_storeu_ps(dZ + r, gv);
  }
}

// db[0, N) += the column sums of z's `rows` rows (N a multiple of 16): the bias gradient.
TOPOS_BF16_INLINE void bf16_column_sums(const float* z, std::int64_t rows, std::int64_t N,
                                        float* db) {
  for (std::int64_t r = 0; r < rows; ++r)
    for (std::int64_t n = 0; n < N; n += 16)
      _mm512_storeu_ps(db + n,
                       _mm512_add_ps(_mm512_loadu_ps(db + n), _mm512_loadu_ps(z + r * N + n)));
}

// What the two bfloat16 backwards share: blocks of `rows_per_block` rows (a multiple of 6, the
// row tile of dx's product, up to 36; fewer above 170 outputs; on AMX whole tiles, 16 or 32) so
// that dZ and its pairs stay in L1, the blocks' buffers, and each block's output gradient; and
// the weight gradient's pairs of rows (of dZ and of x, K columns; none without a dW), gathered
// over several blocks (up to `dw_pairs`, about 192 KB in L2) before they are multiplied into dW:
// its sums then leave their registers (or tiles) once per gathering, not once per block.
struct Bf16BackwardScratch {
  static constexpr std::int64_t capacity = 6 * 1024;  // 6 rows of the widest N
  // N outputs, K inputs (0: no dW), `rows` rows in all (no more pairs gathered than they make).
  Bf16BackwardScratch(std::int64_t N, std::int64_t K, std::int64_t rows)
      : amx(use_amx()),
        rows_per_block(block_rows(N, K, amx)),
        dw_pairs(gathering(N, K, rows, rows_per_block / 2)),
        ldt((dw_pairs + 15) / 16 * 16),
        Zq(static_cast<std::size_t>(K > 0 ? ldt * N : 0)),
        Xq(static_cast<std::size_t>(ldt * K)) {}
  static std::int64_t block_rows(std::int64_t N, std::int64_t K, bool amx) {
    if (N < 16 || N > 1024 || K > 1024)  // bf16_kernel_fits's shapes only
      throw std::logic_error("bfloat16 backward: " + std::to_string(N) + " outputs and " +
                             std::to_string(K) + " inputs, not the kernels' 16 to 1024");
    const std::int64_t tiles = std::min<std::int64_t>(32, capacity / N) / 16 * 16;
    return amx && tiles > 0 ? tiles : std::min<std::int64_t>(36, capacity / N) / 6 * 6;
  }
  static std::int64_t gathering(std::int64_t N, std::int64_t K, std::int64_t rows,
                                std::int64_t block_pairs) {
    const std::int64_t most = std::max<std::int64_t>(1, 49152 / (N + K) / block_pairs);
    const std::int64_t needed = ((rows + 1) / 2 + block_pairs - 1) / block_pairs;
    return std::min(most, std::max<std::int64_t>(1, needed)) * block_pairs;
  }
  // dZ of the `rows` rows from i0: g ⊙ act'(y) in dZ, or g itself without an activation.
  template <Epilogue E>
  TOPOS_BF16_INLINE const float* output_gradient(const float* g, const float* y, std::int64_t i0,
                                                 std::int64_t rows, std::int64_t N) {
    if (E == Epilogue::none) return g + i0 * N;
    bf16_output_gradient<E>(g + i0 * N, y + i0 * N, rows * N, dZ);
    return dZ;
  }
  // A block's `rows` rows of dZ (N wide) as the weight gradient's pairs from `gathered` on: along
  // the outputs for bf16_outer (a pair a row of Zq), along the rows for AMX (ZT, ldt pairs a row).
  TOPOS_BF16_INLINE void gather_output_gradient(const float* z, std::int64_t rows, std::int64_t N) {
#if defined(TOPOS_HAVE_AMX)
    if (amx) return amx_transpose_rows(z, rows, N, Zq.data(), ldt, gathered);
#endif
    for (std::int64_t p = 0; 2 * p < rows; ++p)
      bf16_interleave(z + 2 * p * N, 2 * p + 1 < rows ? z + (2 * p + 1) * N : nullptr, N,
                      Zq.data() + (gathered + p) * N);
  }
  // dW (N × K) += the gathered pairs' products; none gathered after.
  TOPOS_BF16_INLINE void multiply_gathered(std::int64_t N, std::int64_t K, float* dW) {
#if defined(TOPOS_HAVE_AMX)
    if (amx) {  // whole tiles of 16 pairs: the missing ones zero on both sides
      const std::int64_t tiled = (gathered + 15) / 16 * 16, pad = tiled - gathered;
      if (pad > 0) {
        for (std::int64_t n = 0; n < N; ++n)
          std::memset(Zq.data() + n * ldt + gathered, 0, static_cast<std::size_t>(pad) * 4);
        std::memset(Xq.data() + gathered * K, 0, static_cast<std::size_t>(pad * K) * 4);
      }
      amx_rows(Zq.data(), ldt, N, tiled, Xq.data(), K, K, dW, K, true);
      gathered = 0;
      return;
    }
#endif
    bf16_outer(Zq.data(), N, gathered, Xq.data(), K, dW, K);
    gathered = 0;
  }
  const bool amx;
  const std::int64_t rows_per_block, dw_pairs, ldt;
  std::int64_t gathered = 0;  // pairs in Zq and Xq not yet in dW
  alignas(64) float dZ[capacity];
  alignas(64) std::uint32_t Zr[capacity / 2];  // dZ's rows as pairs along the outputs (dx)
  std::vector<std::uint32_t> Zq, Xq;           // dZ's and x's pairs for dW
};

// Where a bfloat16 backward takes each block's dZ from: g ⊙ act'(y) from the output y (g itself
// without an activation). Another source (a LayerNorm's backward) offers the same call.
template <Epilogue E>
struct ActivationGradient {
  const float* g;
  const float* y;
  TOPOS_BF16_INLINE const float* operator()(Bf16BackwardScratch& s, std::int64_t i0,
                                            std::int64_t rows, std::int64_t N) const {
    return s.output_gradient<E>(g, y, i0, rows, N);
  }
};

// The backward of a product Z = x Wᵀ + b over rows [begin, end) with bfloat16 products, a block
// of rows at a time: dZ of the block from `dz` (float32), dx = dZ W (PT = pack_bf16_pairs of W,
// N/2 × K pairs), dW += dZᵀ x and db += Σ dZ into the caller's buffers; null pointers skip their
// part.
template <class DZ>
TOPOS_BF16_INLINE void linear_backward_bf16_blocks(const float* x, const std::uint32_t* PT,
                                                   const DZ& dz, float* dx, float* dW, float* db,
                                                   std::int64_t begin, std::int64_t end,
                                                   std::int64_t K, std::int64_t N) {
  Bf16BackwardScratch scratch(N, dW ? K : 0, end - begin);
  std::uint32_t *Zr = scratch.Zr, *Xq = scratch.Xq.data();
  const std::int64_t B = scratch.rows_per_block;
  for (std::int64_t i0 = begin; i0 < end; i0 += B) {
    const std::int64_t rows = std::min(B, end - i0), pairs = (rows + 1) / 2;
    const float* z = dz(scratch, i0, rows, N);
    if (dx) {  // dx = dZ W: dZ's rows as pairs along the outputs
      for (std::int64_t r = 0; r < rows; ++r) bf16_row(z + r * N, N, Zr + r * (N / 2));
      bf16_rows<Epilogue::none>(Zr, N / 2, rows, N / 2, PT, K, K, nullptr, dx + i0 * K, K, false);
    }
    if (dW) {  // dW += dZᵀ x: pairs of rows, an odd last row with zeros
      const std::int64_t q = scratch.gathered;
      scratch.gather_output_gradient(z, rows, N);
      for (std::int64_t p = 0; p < pairs; ++p) {
        const bool two = 2 * p + 1 < rows;
        bf16_interleave(x + (i0 + 2 * p) * K, two ? x + (i0 + 2 * p + 1) * K : nullptr, K,
                        Xq + (q + p) * K);
      }
      scratch.gathered += pairs;
      if (scratch.gathered == scratch.dw_pairs || i0 + B >= end)
        scratch.multiply_gathered(N, K, dW);
    }
    if (db) bf16_column_sums(z, rows, N, db);
  }
}

// The backward of act(x Wᵀ + b) over rows [begin, end) (linear_backward_bf16_blocks, dZ = g ⊙
// act'(y)).
template <Epilogue E>
TOPOS_BF16 void linear_backward_bf16_e(const float* x, const std::uint32_t* PT, const float* y,
                                       const float* g, float* dx, float* dW, float* db,
                                       std::int64_t begin, std::int64_t end, std::int64_t K,
                                       std::int64_t N) {
  linear_backward_bf16_blocks(x, PT, ActivationGradient<E>{g, y}, dx, dW, db, begin, end, K, N);
}

/// The backward of act(x Wᵀ + b) with bfloat16 products (linear_backward_bf16_e).
TOPOS_BF16 inline void linear_backward_bf16(const float* x, const std::uint32_t* PT, const float* y,
                                            const float* g, float* dx, float* dW, float* db,
                                            std::int64_t begin, std::int64_t end, std::int64_t K,
                                            std::int64_t N, Epilogue e) {
  switch (e) {
    case Epilogue::none:
      return linear_backward_bf16_e<Epilogue::none>(x, PT, y, g, dx, dW, db, begin, end, K, N);
    case Epilogue::relu:
      return linear_backward_bf16_e<Epilogue::relu>(x, PT, y, g, dx, dW, db, begin, end, K, N);
    case Epilogue::elu:
      return linear_backward_bf16_e<Epilogue::elu>(x, PT, y, g, dx, dW, db, begin, end, K, N);
    default:
      return linear_backward_bf16_e<Epilogue::sigmoid>(x, PT, y, g, dx, dW, db, begin, end, K, N);
  }
}
// act(base + b + [X_0 | X_1 | ...] Wᵀ) for rows [begin, end): S blocks X_s (n × K_s, each K_s a
// multiple of 16, ΣK_s up to 1024) converted side by side into one row of pairs, so the
// concatenation exists only in L1; P = pack_bf16_pairs of Wᵀ (ΣK_s/2 × N pairs); Y holds the
// base where `accumulate`; b (N) may be null.
template <Epilogue E>
TOPOS_BF16 void dense_blocks_bf16_e(const float* const* X, const std::int64_t* K, std::int64_t S,
                                    const std::uint32_t* P, const float* b, float* Y,
                                    std::int64_t begin, std::int64_t end, std::int64_t N,
                                    bool accumulate) {
  alignas(64) std::uint32_t A[kBf16Block];
  std::int64_t Kp = 0;
  for (std::int64_t s = 0; s < S; ++s) Kp += K[s] / 2;
  const std::int64_t block = bf16_block_rows(Kp);
  for (std::int64_t i0 = begin; i0 < end; i0 += block) {
    const std::int64_t rows = std::min(block, end - i0);
    for (std::int64_t r = 0; r < rows; ++r)
      for (std::int64_t s = 0, off = 0; s < S; off += K[s] / 2, ++s)
        bf16_row(X[s] + (i0 + r) * K[s], K[s], A + r * Kp + off);
    bf16_rows<E>(A, Kp, rows, Kp, P, N, N, b, Y + i0 * N, N, accumulate);
  }
}
TOPOS_BF16 inline void dense_blocks_bf16(const float* const* X, const std::int64_t* K,
                                         std::int64_t S, const std::uint32_t* P, const float* b,
                                         float* Y, std::int64_t begin, std::int64_t end,
                                         std::int64_t N, bool accumulate, Epilogue e) {
  switch (e) {
    case Epilogue::none:
      return dense_blocks_bf16_e<Epilogue::none>(X, K, S, P, b, Y, begin, end, N, accumulate);
    case Epilogue::relu:
      return dense_blocks_bf16_e<Epilogue::relu>(X, K, S, P, b, Y, begin, end, N, accumulate);
    case Epilogue::elu:
      return dense_blocks_bf16_e<Epilogue::elu>(X, K, S, P, b, Y, begin, end, N, accumulate);
    default:
      return dense_blocks_bf16_e<Epilogue::sigmoid>(X, K, S, P, b, Y, begin, end, N, accumulate);
  }
}

// The backward of dense_blocks_bf16 over rows [begin, end): dZ = g ⊙ act'(y); dX_s = dZ W_s
// (PT = pack_bf16_pairs of W, N/2 × ΣK_s pairs; W_s its columns of block s), dW += dZᵀ [X_s]
// (dW N × ΣK_s), dbase = dZ, db += Σ dZ; null pointers skip their part.
template <Epilogue E>
TOPOS_BF16 void linear_blocks_backward_bf16_e(const float* const* X, const std::int64_t* K,
                                              std::int64_t S, const std::uint32_t* PT,
                                              const float* y, const float* g, float* const* dX,
                                              float* dW, float* dbase, float* db,
                                              std::int64_t begin, std::int64_t end,
                                              std::int64_t N) {
  std::int64_t Ktot = 0;
  for (std::int64_t s = 0; s < S; ++s) Ktot += K[s];
  Bf16BackwardScratch scratch(N, dW ? Ktot : 0, end - begin);
  std::uint32_t *Zr = scratch.Zr, *Xq = scratch.Xq.data();
  const std::int64_t B = scratch.rows_per_block;
  bool any_dx = false;
  for (std::int64_t s = 0; s < S; ++s) any_dx = any_dx || dX[s] != nullptr;
  for (std::int64_t i0 = begin; i0 < end; i0 += B) {
    const std::int64_t rows = std::min(B, end - i0), pairs = (rows + 1) / 2;
    const float* z = scratch.output_gradient<E>(g, y, i0, rows, N);
    if (dbase) std::memcpy(dbase + i0 * N, z, static_cast<std::size_t>(rows * N) * sizeof(float));
    if (db) bf16_column_sums(z, rows, N, db);
    if (any_dx) {
      for (std::int64_t r = 0; r < rows; ++r) bf16_row(z + r * N, N, Zr + r * (N / 2));
      for (std::int64_t s = 0, off = 0; s < S; off += K[s], ++s)
        if (dX[s])
          bf16_rows<Epilogue::none>(Zr, N / 2, rows, N / 2, PT + off, Ktot, K[s], nullptr,
                                    dX[s] + i0 * K[s], K[s], false);
    }
    if (dW) {  // the blocks' pairs side by side in one row of Ktot pairs, as the forward's
      const std::int64_t q = scratch.gathered;
      scratch.gather_output_gradient(z, rows, N);
      for (std::int64_t p = 0; p < pairs; ++p) {
        const bool two = 2 * p + 1 < rows;
        for (std::int64_t s = 0, off = 0; s < S; off += K[s], ++s) {
          const float* xs = X[s] + (i0 + 2 * p) * K[s];
          bf16_interleave(xs, two ? xs + K[s] : nullptr, K[s], Xq + (q + p) * Ktot + off);
        }
      }
      scratch.gathered += pairs;
      if (scratch.gathered == scratch.dw_pairs || i0 + B >= end)
        scratch.multiply_gathered(N, Ktot, dW);
    }
  }
}
TOPOS_BF16 inline void linear_blocks_backward_bf16(const float* const* X, const std::int64_t* K,
                                                   std::int64_t S, const std::uint32_t* PT,
                                                   const float* y, const float* g, float* const* dX,
                                                   float* dW, float* dbase, float* db,
                                                   std::int64_t begin, std::int64_t end,
                                                   std::int64_t N, Epilogue e) {
  switch (e) {
    case Epilogue::none:
      return linear_blocks_backward_bf16_e<Epilogue::none>(X, K, S, PT, y, g, dX, dW, dbase, db,
                                                           begin, end, N);
    case Epilogue::relu:
      return linear_blocks_backward_bf16_e<Epilogue::relu>(X, K, S, PT, y, g, dX, dW, dbase, db,
                                                           begin, end, N);
    case Epilogue::elu:
      return linear_blocks_backward_bf16_e<Epilogue::elu>(X, K, S, PT, y, g, dX, dW, dbase, db,
                                                          begin, end, N);
    default:
      return linear_blocks_backward_bf16_e<Epilogue::sigmoid>(X, K, S, PT, y, g, dX, dW, dbase, db,
                                                              begin, end, N);
  }
}
#endif

}  // namespace topos::nn::detail

namespace topos::nn {
/// The kernels that multiply MatmulPrecision::medium's CPU products in this process, as the
/// programs report them: "amx" (AMX tiles), "avx512-bf16" (AVX-512 BF16 dot products) or
/// "onednn" (oneDNN's bfloat16, emulated on a CPU without either; TOPOS_DISABLE_BF16=1 and
/// TOPOS_DISABLE_AMX=1 step down the list).
inline const char* bfloat16_kernels() {
  if (!detail::cpu_has_bf16()) return "onednn";
  return detail::use_amx() ? "amx" : "avx512-bf16";
}
}  // namespace topos::nn
