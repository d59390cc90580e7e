// topos/util/bootstrap.hpp
// Percentile bootstrap intervals over independent units (a split's scenes, a table's runs): the
// mean of one sample, and the ratio of the means of two paired samples (one model against another
// on the same scenes: each resample draws the same units for both, so what the two share, the
// scenes' difficulty, cancels). Deterministic for a seed. std only.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <random>
#include <stdexcept>
#include <string>
#include <vector>

namespace topos {

/// A statistic and its bootstrap interval; all three NaN where no unit had a finite value.
struct BootstrapInterval {
  double estimate = std::numeric_limits<double>::quiet_NaN();
  double low = std::numeric_limits<double>::quiet_NaN();
  double high = std::numeric_limits<double>::quiet_NaN();
};

struct BootstrapOptions {
  int resamples = 2000;
  double level = 0.95;  ///< the interval's coverage, in (0, 1)
  std::uint64_t seed = 0;
};

namespace detail {

inline void check_bootstrap_options(const BootstrapOptions& o, const char* who) {
  if (o.resamples < 1)
    throw std::invalid_argument(std::string(who) + ": resamples must be at least 1, got " +
                                std::to_string(o.resamples));
  if (!(o.level > 0 && o.level < 1))
    throw std::invalid_argument(std::string(who) + ": level must lie in (0, 1), e.g. 0.95; got " +
                                std::to_string(o.level));
}

// Quantile q of sorted values, interpolated linearly between order statistics (numpy's default).
inline double sorted_quantile(const std::vector<double>& sorted, double q) {
  const double at = q * static_cast<double>(sorted.size() - 1);
  const auto below = static_cast<std::size_t>(std::floor(at));
  const std::size_t above = std::min(below + 1, sorted.size() - 1);
  return sorted[below] + (at - static_cast<double>(below)) * (sorted[above] - sorted[below]);
}

// The statistic num/den of means over `resamples` draws of the n units with replacement (den
// null: the mean of num), and its percentile interval.
inline BootstrapInterval bootstrap_means(const std::vector<double>& num,
                                         const std::vector<double>* den,
                                         const BootstrapOptions& o) {
  BootstrapInterval out;
  const std::size_t n = num.size();
  if (n == 0) return out;
  const auto statistic = [&](const auto& pick) {
    double a = 0, b = 0;
    for (std::size_t i = 0; i < n; ++i) {
      const std::size_t j = pick(i);
      a += num[j];
      b += den ? (*den)[j] : 1.0;
    }
    return a / b;
  };
  out.estimate = statistic([](std::size_t i) { return i; });
  std::mt19937_64 gen(o.seed);
  std::uniform_int_distribution<std::size_t> unit(0, n - 1);
  std::vector<double> draws(static_cast<std::size_t>(o.resamples));
  for (auto& d : draws) {
    d = statistic([&](std::size_t) { return unit(gen); });
    // A resample whose denominator sums to 0 has no ratio: then the interval is undefined (and
    // NaN would break the sort's ordering).
    if (!std::isfinite(d)) return out;
  }
  std::sort(draws.begin(), draws.end());
  out.low = sorted_quantile(draws, (1 - o.level) / 2);
  out.high = sorted_quantile(draws, 1 - (1 - o.level) / 2);
  return out;
}

}  // namespace detail

/// The mean of `values` and its percentile bootstrap interval. Non-finite values (a horizon a
/// scene does not reach) are left out before resampling.
inline BootstrapInterval bootstrap_mean(const std::vector<double>& values,
                                        const BootstrapOptions& o = {}) {
  detail::check_bootstrap_options(o, "bootstrap_mean");
  std::vector<double> kept;
  for (double v : values)
    if (std::isfinite(v)) kept.push_back(v);
  return detail::bootstrap_means(kept, nullptr, o);
}

/// mean(num) / mean(den) over paired units (num[i] and den[i] measured on the same unit) and its
/// percentile bootstrap interval, each resample drawing the same units for both. A unit with a
/// non-finite value on either side is left out of both. Where some resample's den sums to 0 the
/// interval is NaN (the estimate too, where den's own sum is 0).
inline BootstrapInterval bootstrap_ratio_of_means(const std::vector<double>& num,
                                                  const std::vector<double>& den,
                                                  const BootstrapOptions& o = {}) {
  detail::check_bootstrap_options(o, "bootstrap_ratio_of_means");
  if (num.size() != den.size())
    throw std::invalid_argument("bootstrap_ratio_of_means: paired samples of different sizes (" +
                                std::to_string(num.size()) + " and " + std::to_string(den.size()) +
                                "); pair each unit's two values");
  std::vector<double> a, b;
  for (std::size_t i = 0; i < num.size(); ++i)
    if (std::isfinite(num[i]) && std::isfinite(den[i])) a.push_back(num[i]), b.push_back(den[i]);
  return detail::bootstrap_means(a, &b, o);
}

}  // namespace topos
