// topos/data/numpy_random.hpp
// NumPy's legacy RandomState(seed) replayed in C++ (std::mt19937 emits the same 32-bit stream):
// random_sample/uniform from 53-bit doubles of two draws, and the legacy masked-rejection
// randint (hi exclusive), on which choice() rests. Enough to replay Kubric's MOVi scene
// sampling draw for draw. std only.
#pragma once

#include <cstdint>
#include <random>
#include <stdexcept>

namespace topos::data {

class NumpyRandomState {
 public:
  explicit NumpyRandomState(std::uint32_t seed) : mt_(seed) {}

  std::uint32_t next32() { return static_cast<std::uint32_t>(mt_()); }
  /// random_sample(): ((a >> 5) · 2^26 + (b >> 6)) / 2^53.
  double random() {
    const std::uint32_t a = next32() >> 5, b = next32() >> 6;
    return (static_cast<double>(a) * 67108864.0 + static_cast<double>(b)) / 9007199254740992.0;
  }
  double uniform(double lo, double hi) { return lo + (hi - lo) * random(); }
  /// Legacy randint(lo, hi), hi exclusive: masked rejection sampling.
  std::int64_t randint(std::int64_t lo, std::int64_t hi) {
    if (hi <= lo) throw std::invalid_argument("randint: empty range");
    const std::uint64_t range = static_cast<std::uint64_t>(hi - lo - 1);
    if (range == 0) return lo;
    std::uint64_t mask = range;
    for (int s = 1; s < 64; s <<= 1) mask |= mask >> s;
    std::uint64_t v;
    if (range <= 0xffffffffULL) {
      do v = next32() & mask;
      while (v > range);
    } else {
      do v = ((static_cast<std::uint64_t>(next32()) << 32) | next32()) & mask;
      while (v > range);
    }
    return lo + static_cast<std::int64_t>(v);
  }
  /// choice over n items: an index.
  std::int64_t choice(std::int64_t n) { return randint(0, n); }

 private:
  std::mt19937 mt_;
};

}  // namespace topos::data
