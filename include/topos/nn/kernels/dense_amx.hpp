// topos/nn/kernels/dense_amx.hpp
// The bfloat16 products of dense_bf16.hpp on Intel's AMX tiles, where the CPU has them (Sapphire
// Rapids and later): one tdpbf16ps multiplies a 16 × 32 bfloat16 tile by a 32 × 16 one into 16 ×
// 16 float32 sums, 8 times the multiply-adds of a vdpbf16ps. The operands are the pairs the
// AVX-512 BF16 kernels already pack (a row of A: 16 pairs along the summed dimension; a row of
// B: 16 columns of one pair), so a tile loads them as they are. The sums stay float32 in the
// tiles; bias, activation and accumulation are the callers' (dense_bf16.hpp). Linux grants the
// tiles' 8 KB of state per process on request (arch_prctl), once, before the first use.
#pragma once

#include <algorithm>
#include <atomic>
#include <cstdint>
#include <cstdlib>
#include <string>

#if defined(TOPOS_HAVE_BF16) && defined(__GNUC__) && !defined(__clang__) && __GNUC__ >= 11 && \
    defined(__linux__)
#include <cpuid.h>
#include <immintrin.h>
#include <sys/syscall.h>
#include <unistd.h>
#define TOPOS_HAVE_AMX 1
#define TOPOS_AMX __attribute__((target("arch=x86-64-v4,avx512bf16,amx-tile,amx-bf16")))
#endif

namespace topos::nn::detail {

/// Whether the environment sets `name` to anything but empty or "0": the TOPOS_DISABLE_* switches.
inline bool env_flag(const char* name) {
  const char* v = std::getenv(name);
  return v != nullptr && *v != '\0' && std::string(v) != "0";
}

/// Whether this CPU has AMX with bfloat16 and the kernel granted this process its tiles.
/// TOPOS_DISABLE_AMX=1 in the environment (read once) says no.
inline bool cpu_has_amx() {
#if defined(TOPOS_HAVE_AMX)
  static const bool amx = [] {
    if (env_flag("TOPOS_DISABLE_AMX")) return false;
    unsigned a = 0, b = 0, c = 0, d = 0;
    if (__get_cpuid_count(7, 0, &a, &b, &c, &d) == 0) return false;
    const bool tile = (d >> 24) & 1u, bf16 = (d >> 22) & 1u;
    if (!tile || !bf16) return false;
    unsigned lo = 0, hi = 0;  // the OS saves the tiles' configuration and data (XCR0 bits 17, 18)
    __asm__ volatile("xgetbv" : "=a"(lo), "=d"(hi) : "c"(0));
    if ((lo & 0x60000u) != 0x60000u) return false;
    constexpr long kReqXcompPerm = 0x1023, kXfeatureXtiledata = 18;
    return syscall(SYS_arch_prctl, kReqXcompPerm, kXfeatureXtiledata) == 0;
  }();
  return amx;
#else
  return false;
#endif
}

inline std::atomic<bool>& amx_allowed() {
  static std::atomic<bool> allowed{true};
  return allowed;
}
/// Whether the bfloat16 kernels take AMX's tiles: on a CPU that has them, unless turned off
/// (set_amx_enabled(false): the AVX-512 BF16 kernels, for side-by-side tests and timings).
inline bool use_amx() {
  return cpu_has_amx() && amx_allowed().load(std::memory_order_relaxed);
}
inline void set_amx_enabled(bool on) {
  amx_allowed().store(on);
}

#if defined(TOPOS_HAVE_AMX)
// Eight tiles of 16 rows × 64 bytes: sums C00 C01 C10 C11 (tmm0-3), A0 A1 (tmm4-5), B0 B1 (tmm6-7).
struct alignas(64) AmxTileConfig {
  std::uint8_t palette = 1, start_row = 0;
  std::uint8_t reserved[14] = {};
  std::uint16_t colsb[16] = {64, 64, 64, 64, 64, 64, 64, 64};
  std::uint8_t rows[16] = {16, 16, 16, 16, 16, 16, 16, 16};
};

// C (RT × CT tiles of 16 × 16 float32 at Y, ldy floats a row) = (accumulate ? C : 0) +
// A (RT × 16 rows of Kp pairs, lda apart) · P (Kp rows of pairs, 16·CT columns, ldp apart).
template <int RT, int CT>
TOPOS_AMX inline void amx_block(const std::uint32_t* A, std::int64_t lda, std::int64_t Kp,
                                const std::uint32_t* P, std::int64_t ldp, float* Y,
                                std::int64_t ldy, bool accumulate) {
  const long sa = static_cast<long>(lda * 4), sp = static_cast<long>(ldp * 4),
             sy = static_cast<long>(ldy * 4);
  if (accumulate) {
    _tile_loadd(0, Y, sy);
    if constexpr (CT == 2) _tile_loadd(1, Y + 16, sy);
    if constexpr (RT == 2) _tile_loadd(2, Y + 16 * ldy, sy);
    if constexpr (RT == 2 && CT == 2) _tile_loadd(3, Y + 16 * ldy + 16, sy);
  } else {
    _tile_zero(0);
    if constexpr (CT == 2) _tile_zero(1);
    if constexpr (RT == 2) _tile_zero(2);
    if constexpr (RT == 2 && CT == 2) _tile_zero(3);
  }
  for (std::int64_t k = 0; k < Kp; k += 16) {
    _tile_loadd(4, A + k, sa);
    _tile_loadd(6, P + k * ldp, sp);
    _tile_dpbf16ps(0, 4, 6);
    if constexpr (CT == 2) {
      _tile_loadd(7, P + k * ldp + 16, sp);
      _tile_dpbf16ps(1, 4, 7);
    }
    if constexpr (RT == 2) {
      _tile_loadd(5, A + 16 * lda + k, sa);
      _tile_dpbf16ps(2, 5, 6);
      if constexpr (CT == 2) _tile_dpbf16ps(3, 5, 7);
    }
  }
  _tile_stored(0, Y, sy);
  if constexpr (CT == 2) _tile_stored(1, Y + 16, sy);
  if constexpr (RT == 2) _tile_stored(2, Y + 16 * ldy, sy);
  if constexpr (RT == 2 && CT == 2) _tile_stored(3, Y + 16 * ldy + 16, sy);
}

/// Y[r][0, N) = (accumulate ? Y[r] : 0) + Σ_k A[r][k] P[k][0, N) for `rows` rows, all multiples
/// of 16 (rows, Kp pairs, N columns): A's rows lda pairs apart, P's ldp pairs, Y's ldy floats.
/// A product's forward and input gradient, and (A the output gradient's pairs along the rows,
/// amx_transpose_rows; P x's) its weight gradient into dW.
TOPOS_AMX __attribute__((noinline)) inline void amx_rows(const std::uint32_t* A, std::int64_t lda,
                                                         std::int64_t rows, std::int64_t Kp,
                                                         const std::uint32_t* P, std::int64_t ldp,
                                                         std::int64_t N, float* Y, std::int64_t ldy,
                                                         bool accumulate) {
  static const AmxTileConfig config;
  _tile_loadconfig(&config);
  for (std::int64_t c = 0; c < N; c += 32) {
    const bool two_cols = c + 32 <= N;
    for (std::int64_t r = 0; r < rows; r += 32) {
      const std::uint32_t* a = A + r * lda;
      float* y = Y + r * ldy + c;
      if (r + 32 <= rows) {
        if (two_cols)
          amx_block<2, 2>(a, lda, Kp, P + c, ldp, y, ldy, accumulate);
        else
          amx_block<2, 1>(a, lda, Kp, P + c, ldp, y, ldy, accumulate);
      } else {
        if (two_cols)
          amx_block<1, 2>(a, lda, Kp, P + c, ldp, y, ldy, accumulate);
        else
          amx_block<1, 1>(a, lda, Kp, P + c, ldp, y, ldy, accumulate);
      }
    }
  }
  _tile_release();
}

// 16 × 16 floats transposed in place: unpacks by 32 and 64 bits, then two rounds of 128-bit lanes
// (the maskz forms: GCC 12 warns that the plain ones read an undefined vector).
TOPOS_BF16_INLINE void transpose16x16(__m512* r) {
  constexpr __mmask16 all = 0xFFFF;
  __m512 t[16], u[16];
  for (int i = 0; i < 16; i += 2) {
    t[i] = _mm512_maskz_unpacklo_ps(all, r[i], r[i + 1]);
    t[i + 1] = _mm512_maskz_unpackhi_ps(all, r[i], r[i + 1]);
  }
  for (int i = 0; i < 16; i += 4) {
    u[i] = _mm512_maskz_shuffle_ps(all, t[i], t[i + 2], 0x44);
    u[i + 1] = _mm512_maskz_shuffle_ps(all, t[i], t[i + 2], 0xEE);
    u[i + 2] = _mm512_maskz_shuffle_ps(all, t[i + 1], t[i + 3], 0x44);
    u[i + 3] = _mm512_maskz_shuffle_ps(all, t[i + 1], t[i + 3], 0xEE);
  }
  for (int i = 0; i < 16; i += 8)
    for (int j = 0; j < 4; ++j) {
      t[i + j] = _mm512_maskz_shuffle_f32x4(all, u[i + j], u[i + j + 4], 0x88);
      t[i + j + 4] = _mm512_maskz_shuffle_f32x4(all, u[i + j], u[i + j + 4], 0xDD);
    }
  for (int j = 0; j < 8; ++j) {
    r[j] = _mm512_maskz_shuffle_f32x4(all, t[j], t[j + 8], 0x88);
    r[j + 8] = _mm512_maskz_shuffle_f32x4(all, t[j], t[j + 8], 0xDD);
  }
}

// Sixteen columns of `rows` (up to 32; the missing ones read as zeros) float rows of z (ldz
// apart) transposed into 16 rows of ZT (ldt pairs apart) of (rows + 1) / 2 pairs each: ZT[n][p]
// = (z[2p][n], z[2p+1][n]) in bfloat16, A's layout for a sum over z's rows.
TOPOS_BF16_INLINE void amx_transpose16(const float* z, std::int64_t ldz, std::int64_t rows,
                                       std::uint32_t* ZT, std::int64_t ldt) {
  __m512 lo[16], hi[16];
  for (int i = 0; i < 16; ++i) {
    lo[i] = i < rows ? _mm512_loadu_ps(z + i * ldz) : _mm512_setzero_ps();
    hi[i] = i + 16 < rows ? _mm512_loadu_ps(z + (i + 16) * ldz) : _mm512_setzero_ps();
  }
  transpose16x16(lo);
  transpose16x16(hi);
  const __mmask16 keep = static_cast<__mmask16>((1u << ((rows + 1) / 2)) - 1u);
  for (int n = 0; n < 16; ++n) {
    const __m512bh v = _mm512_cvtne2ps_pbh(hi[n], lo[n]);
    _mm512_mask_storeu_epi32(ZT + n * ldt, keep, reinterpret_cast<const __m512i&>(v));
  }
}

/// ZT[n][q, q + (rows + 1) / 2) for n < N (a multiple of 16): the pairs of `rows` rows of z (N
/// floats each) along the rows, 32 rows at a time (amx_transpose16).
TOPOS_BF16_INLINE void amx_transpose_rows(const float* z, std::int64_t rows, std::int64_t N,
                                          std::uint32_t* ZT, std::int64_t ldt, std::int64_t q) {
  for (std::int64_t r = 0; r < rows; r += 32)
    for (std::int64_t n = 0; n < N; n += 16)
      amx_transpose16(z + r * N + n, N, std::min<std::int64_t>(32, rows - r),
                      ZT + n * ldt + q + r / 2, ldt);
}

#endif

}  // namespace topos::nn::detail
