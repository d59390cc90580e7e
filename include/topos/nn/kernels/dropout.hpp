// topos/nn/kernels/dropout.hpp
// Dropout from a counter-based stream. torch 1.13's CPU bernoulli_ draws every element from the
// mt19937 generator one at a time: 8.8 ms for a 4000 × 128 mask on one core, five times the
// 128 × 128 product it follows, and a fifth of an EDGNN epoch on NCI109. Here draw i is
// splitmix64(seed + i·γ), so every element is computable alone and the loop vectorises, and one
// draw serves several elements: each takes the fewest bits (8, 16 or 32) at which its drop rate
// p is exact (p·2^bits an integer: 0.25 and 0.5 take 8 bits, 8 elements a draw; other rates
// keep 32 bits' resolution, 2 a draw). The seed is one draw from torch's generator, which keeps
// torch::manual_seed's runs repeatable. The mask is never stored: the backward draws it again.
#pragma once

#include "topos/nn/kernels/epilogue.hpp"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <type_traits>

namespace topos::nn::detail {

TOPOS_INLINE_KERNEL std::uint64_t splitmix64(std::uint64_t z) {
  z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
  z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
  return z ^ (z >> 31);
}

/// A drop rate as dropout's kernels take it: element k of a stream is kept when its `bits`-bit
/// lane is at least `threshold` (= p·2^bits, rounded where p is not exact at 32 bits).
struct DropoutRate {
  int bits = 32;
  std::uint32_t threshold = 0;

  static DropoutRate of(double p) {
    for (int bits : {8, 16}) {
      const double t = p * static_cast<double>(1u << bits);
      if (t == static_cast<double>(static_cast<std::uint32_t>(t))) return {bits, std::uint32_t(t)};
    }
    return {32, static_cast<std::uint32_t>(
                    std::min<long long>(std::llround(p * 4294967296.0), 4294967295LL))};
  }
};

// Elements go by blocks of 64 draws: element j·64 + i of a block takes lane j of the block's
// draw i, so each lane is a contiguous run of 64 elements and every loop below vectorises.
constexpr std::int64_t kDropoutBlockDraws = 64;

// y = x·scale where the element's lane is at least `threshold`, else 0, for blocks [first,
// first + n) (x and y at the first block's first element).
template <int Bits, class T>
TOPOS_INLINE_KERNEL void dropout_blocks(const T* x, T* y, std::int64_t first, std::int64_t n,
                                        std::uint64_t seed, std::uint32_t threshold, T scale) {
  constexpr int per = 64 / Bits;
  constexpr std::int64_t B = kDropoutBlockDraws;
  constexpr std::uint64_t lane = Bits == 32 ? 0xFFFFFFFFull : (1ull << Bits) - 1;
  for (std::int64_t b = 0; b < n; ++b) {
    std::uint64_t z[B];
    const auto d0 = static_cast<std::uint64_t>((first + b) * B);
    for (std::int64_t i = 0; i < B; ++i)
      z[i] = splitmix64(seed + (d0 + static_cast<std::uint64_t>(i)) * 0x9E3779B97F4A7C15ull);
    for (int j = 0; j < per; ++j) {
      const T* xs = x + (b * per + j) * B;
      T* ys = y + (b * per + j) * B;
      for (std::int64_t i = 0; i < B; ++i)
        ys[i] = ((z[i] >> (Bits * j)) & lane) >= threshold ? xs[i] * scale : T(0);
    }
  }
}

#define TOPOS_DROPOUT_VARIANT(NAME, ATTR, BITS)                                        \
  [[maybe_unused]] ATTR static void NAME(const float* x, float* y, std::int64_t first, \
                                         std::int64_t n, std::uint64_t seed,           \
                                         std::uint32_t threshold, float scale) {       \
    dropout_blocks<BITS, float>(x, y, first, n, seed, threshold, scale);               \
  }
TOPOS_DROPOUT_VARIANT(dropout_float_8, TOPOS_SIMD_CLONES, 8)
TOPOS_DROPOUT_VARIANT(dropout_float_16, TOPOS_SIMD_CLONES, 16)
TOPOS_DROPOUT_VARIANT(dropout_float_32, TOPOS_SIMD_CLONES, 32)
#if defined(TOPOS_HAVE_V4)
TOPOS_DROPOUT_VARIANT(dropout_float_8_v4, TOPOS_V4, 8)
TOPOS_DROPOUT_VARIANT(dropout_float_16_v4, TOPOS_V4, 16)
TOPOS_DROPOUT_VARIANT(dropout_float_32_v4, TOPOS_V4, 32)
#endif
#undef TOPOS_DROPOUT_VARIANT

template <int Bits, class T>
void dropout_block_range(const T* x, T* y, std::int64_t first, std::int64_t n, std::uint64_t seed,
                         std::uint32_t threshold, T scale) {
  if constexpr (std::is_same_v<T, float>) {
#if defined(TOPOS_HAVE_V4)
    if (cpu_has_v4()) {
      if constexpr (Bits == 8) return dropout_float_8_v4(x, y, first, n, seed, threshold, scale);
      if constexpr (Bits == 16) return dropout_float_16_v4(x, y, first, n, seed, threshold, scale);
      if constexpr (Bits == 32) return dropout_float_32_v4(x, y, first, n, seed, threshold, scale);
    }
#endif
    if constexpr (Bits == 8) return dropout_float_8(x, y, first, n, seed, threshold, scale);
    if constexpr (Bits == 16) return dropout_float_16(x, y, first, n, seed, threshold, scale);
    if constexpr (Bits == 32) return dropout_float_32(x, y, first, n, seed, threshold, scale);
  } else {
    dropout_blocks<Bits, T>(x, y, first, n, seed, threshold, scale);
  }
}

template <int Bits, class T>
void dropout_elements(const T* x, T* y, std::int64_t count, std::uint64_t seed,
                      std::uint32_t threshold, T scale) {
  constexpr std::int64_t B = kDropoutBlockDraws, block = B * (64 / Bits);
  constexpr std::uint64_t lane = Bits == 32 ? 0xFFFFFFFFull : (1ull << Bits) - 1;
  const std::int64_t blocks = count / block;
  at::parallel_for(0, blocks, grain_rows(blocks, 4 * blocks * block),
                   [&](std::int64_t begin, std::int64_t end) {
                     dropout_block_range<Bits, T>(x + block * begin, y + block * begin, begin,
                                                  end - begin, seed, threshold, scale);
                   });
  // The last, partial block: element o takes lane o / B of the block's draw o % B, as in a whole
  // one.
  const auto d0 = static_cast<std::uint64_t>(blocks * B);
  for (std::int64_t o = 0; o < count - blocks * block; ++o) {
    const std::uint64_t z =
        splitmix64(seed + (d0 + static_cast<std::uint64_t>(o % B)) * 0x9E3779B97F4A7C15ull);
    const auto k = blocks * block + o;
    y[k] = ((z >> (Bits * (o / B))) & lane) >= threshold ? x[k] * scale : T(0);
  }
}

/// y = x·scale, each of the `count` elements kept unless its lane of stream `seed` is below
/// `rate.threshold`, else 0.
template <class T>
void dropout_apply(const T* x, T* y, std::int64_t count, std::uint64_t seed, DropoutRate rate,
                   T scale) {
  switch (rate.bits) {
    case 8:
      return dropout_elements<8, T>(x, y, count, seed, rate.threshold, scale);
    case 16:
      return dropout_elements<16, T>(x, y, count, seed, rate.threshold, scale);
    default:
      return dropout_elements<32, T>(x, y, count, seed, rate.threshold, scale);
  }
}

}  // namespace topos::nn::detail
