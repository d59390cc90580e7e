// topos/nn/kernels/dropout.hpp
// Dropout's mask from a counter-based stream. torch 1.13's CPU bernoulli_ draws every element
// from the mt19937 generator one at a time: 8.8 ms for a 4000 × 128 mask on one core, five times
// the 128 × 128 product it follows, and a fifth of an EDGNN epoch on NCI109. Here element pair
// i takes the two 32-bit halves of splitmix64(seed + i·γ), so every element is computable alone
// and the loop vectorises; the seed is one draw from torch's generator, which keeps
// torch::manual_seed's runs repeatable.
#pragma once

#include "topos/nn/kernels/epilogue.hpp"

#include <cstdint>
#include <type_traits>

namespace topos::nn::detail {

TOPOS_INLINE_KERNEL std::uint64_t splitmix64(std::uint64_t z) {
  z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
  z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
  return z ^ (z >> 31);
}

// m[k] = scale where draw k of stream `seed` is at least `threshold`, else 0, for k in
// [2·first, 2·first + n): the pairs from `first` on, so a parallel chunk draws its own.
template <class T>
TOPOS_INLINE_KERNEL void dropout_mask_pairs(T* m, std::int64_t first, std::int64_t n,
                                            std::uint64_t seed, std::uint32_t threshold, T scale) {
  for (std::int64_t i = 0; i < n; ++i) {
    const std::uint64_t z =
        splitmix64(seed + static_cast<std::uint64_t>(first + i) * 0x9E3779B97F4A7C15ull);
    m[2 * i] = static_cast<std::uint32_t>(z) >= threshold ? scale : T(0);
    m[2 * i + 1] = static_cast<std::uint32_t>(z >> 32) >= threshold ? scale : T(0);
  }
}
[[maybe_unused]] TOPOS_SIMD_CLONES static void dropout_mask_float(float* m, std::int64_t first,
                                                                  std::int64_t n,
                                                                  std::uint64_t seed,
                                                                  std::uint32_t threshold,
                                                                  float scale) {
  dropout_mask_pairs<float>(m, first, n, seed, threshold, scale);
}
#if defined(TOPOS_HAVE_V4)
[[maybe_unused]] TOPOS_V4 static void dropout_mask_float_v4(float* m, std::int64_t first,
                                                            std::int64_t n, std::uint64_t seed,
                                                            std::uint32_t threshold, float scale) {
  dropout_mask_pairs<float>(m, first, n, seed, threshold, scale);
}
#endif

/// The mask of `count` elements (0 or scale), keeping each with probability 1 - threshold / 2³².
template <class T>
void dropout_mask(T* m, std::int64_t count, std::uint64_t seed, std::uint32_t threshold, T scale) {
  const std::int64_t pairs = count / 2;
  at::parallel_for(0, pairs, 1 << 14, [&](std::int64_t begin, std::int64_t end) {
    T* out = m + 2 * begin;
#if defined(TOPOS_HAVE_V4)
    if constexpr (std::is_same_v<T, float>)
      if (cpu_has_v4())
        return dropout_mask_float_v4(out, begin, end - begin, seed, threshold, scale);
#endif
    if constexpr (std::is_same_v<T, float>)
      dropout_mask_float(out, begin, end - begin, seed, threshold, scale);
    else
      dropout_mask_pairs<T>(out, begin, end - begin, seed, threshold, scale);
  });
  if (count % 2) {  // the last element: the low half of the next pair's draw
    T pair[2];
    dropout_mask_pairs<T>(pair, pairs, 1, seed, threshold, scale);
    m[count - 1] = pair[0];
  }
}

}  // namespace topos::nn::detail
