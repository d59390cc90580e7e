// Tests of topos/util/bootstrap.hpp: intervals against the normal theory they must approach,
// exact cases (a constant sample, a ratio that is the same on every unit), the pairing that
// cancels what two paired samples share, non-finite units left out, and bad options.
#include "topos/util/bootstrap.hpp"

#include <catch2/catch.hpp>

#include <cmath>
#include <limits>
#include <random>
#include <vector>

using topos::bootstrap_mean;
using topos::bootstrap_ratio_of_means;
using topos::BootstrapOptions;

TEST_CASE("bootstrap_mean: a normal sample's interval is the mean ± 1.96 standard errors") {
  std::mt19937_64 gen(7);
  std::normal_distribution<double> normal(3.0, 2.0);
  std::vector<double> v(900);
  for (auto& x : v) x = normal(gen);
  double mean = 0, var = 0;
  for (double x : v) mean += x;
  mean /= static_cast<double>(v.size());
  for (double x : v) var += (x - mean) * (x - mean);
  const double se = std::sqrt(var / static_cast<double>(v.size())) / std::sqrt(900.0);
  BootstrapOptions o;
  o.resamples = 4000;
  const auto ci = bootstrap_mean(v, o);
  CHECK(ci.estimate == Approx(mean).epsilon(1e-12));
  // The percentile interval of a mean over 900 normal units: within 10 % of the normal one.
  CHECK(ci.low == Approx(mean - 1.96 * se).margin(0.1 * 1.96 * se));
  CHECK(ci.high == Approx(mean + 1.96 * se).margin(0.1 * 1.96 * se));
  o.level = 0.5;  // the interquartile range of the means: ± 0.674 standard errors
  const auto half = bootstrap_mean(v, o);
  CHECK(half.high - half.low == Approx(2 * 0.674 * se).epsilon(0.1));
}

TEST_CASE("bootstrap_mean: exact cases, the seed, non-finite units") {
  const auto c = bootstrap_mean({0.25, 0.25, 0.25, 0.25});
  CHECK(c.estimate == 0.25);
  CHECK(c.low == 0.25);
  CHECK(c.high == 0.25);
  const std::vector<double> v{1.1, 4.3, 2.7, 8.2, 5.9, 7.4, 1.6, 3.05};
  const auto a = bootstrap_mean(v), b = bootstrap_mean(v);
  CHECK(a.low == b.low);  // deterministic for a seed
  CHECK(a.high == b.high);
  BootstrapOptions other;
  other.seed = 1;
  CHECK(bootstrap_mean(v, other).low != a.low);
  CHECK(a.low < a.estimate);
  CHECK(a.estimate < a.high);
  CHECK(a.low >= 1.1);  // a mean of resampled units lies within their range
  CHECK(a.high <= 8.2);
  // A horizon some scenes do not reach: those units are left out, as if never given.
  std::vector<double> holes = v;
  holes.insert(holes.begin() + 3, std::numeric_limits<double>::quiet_NaN());
  holes.push_back(std::numeric_limits<double>::infinity());
  const auto h = bootstrap_mean(holes);
  CHECK(h.estimate == a.estimate);
  CHECK(h.low == a.low);
  CHECK(h.high == a.high);
  const auto none = bootstrap_mean({std::numeric_limits<double>::quiet_NaN()});
  CHECK(std::isnan(none.estimate));
  CHECK(std::isnan(none.low));
  CHECK(std::isnan(bootstrap_mean({}).high));
}

TEST_CASE("bootstrap_ratio_of_means: pairing cancels what the units share") {
  // Scenes of very different difficulty s_i; model A's error is 1.1 s_i + small noise, B's s_i.
  std::mt19937_64 gen(3);
  std::lognormal_distribution<double> difficulty(-3.0, 1.0);
  std::normal_distribution<double> noise(0.0, 0.002);
  std::vector<double> a, b;
  for (int i = 0; i < 120; ++i) {
    const double s = difficulty(gen);
    a.push_back(1.1 * s + noise(gen));
    b.push_back(s);
  }
  const auto r = bootstrap_ratio_of_means(a, b);
  double sa = 0, sb = 0;
  for (int i = 0; i < 120; ++i) sa += a[i], sb += b[i];
  CHECK(r.estimate == Approx(sa / sb).epsilon(1e-12));
  CHECK(r.low < r.estimate);
  CHECK(r.estimate < r.high);
  CHECK(r.low > 1.05);  // the 10 % is resolved: the scenes' spread cancels
  CHECK(r.high < 1.15);
  // Unpaired, the two means' own intervals overlap: their spread hides the 10 %.
  const auto ia = bootstrap_mean(a), ib = bootstrap_mean(b);
  CHECK(ia.low < ib.high);
  // A ratio that is the same on every unit is exact.
  const auto exact = bootstrap_ratio_of_means({1, 2, 3, 10}, {2, 4, 6, 20});
  CHECK(exact.estimate == 0.5);
  CHECK(exact.low == Approx(0.5).epsilon(1e-15));
  CHECK(exact.high == Approx(0.5).epsilon(1e-15));
  // A unit non-finite on either side leaves both.
  const double nan = std::numeric_limits<double>::quiet_NaN();
  const auto holes = bootstrap_ratio_of_means({1, nan, 3, 10, 4}, {2, 4, 6, 20, nan});
  const auto kept = bootstrap_ratio_of_means({1, 3, 10}, {2, 6, 20});
  CHECK(holes.estimate == kept.estimate);
  CHECK(holes.low == kept.low);
  // A denominator that sums to 0 in some resamples (a model with no error on some scenes): no
  // interval, rather than one from ratios that are infinite or NaN.
  const auto zero = bootstrap_ratio_of_means({1, 2}, {0, 1});
  CHECK(zero.estimate == 3.0);
  CHECK(std::isnan(zero.low));
  CHECK(std::isnan(zero.high));
  const auto none = bootstrap_ratio_of_means({0, 0}, {0, 0});
  CHECK(std::isnan(none.estimate));
  CHECK(std::isnan(none.low));
}

TEST_CASE("bootstrap: bad options and unpaired samples are errors that say what to write") {
  BootstrapOptions o;
  o.resamples = 0;
  CHECK_THROWS_WITH(bootstrap_mean({1, 2}, o), Catch::Contains("resamples must be at least 1"));
  o = {};
  o.level = 1.0;
  CHECK_THROWS_WITH(bootstrap_mean({1, 2}, o), Catch::Contains("level must lie in (0, 1)"));
  CHECK_THROWS_WITH(bootstrap_ratio_of_means({1, 2, 3}, {1, 2}),
                    Catch::Contains("paired samples of different sizes (3 and 2)"));
}
