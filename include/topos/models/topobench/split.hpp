// topos/models/topobench/split.hpp
// TopoBench's random train/validation/test split of n graphs or nodes, numpy's legacy RandomState
// replayed so that the same data seed gives TopoBench's split (std only; protocol.hpp has the
// rest of the protocol, and includes this).
#pragma once

#include "topos/data/numpy_random.hpp"

#include <cstddef>
#include <cstdint>
#include <numeric>
#include <utility>
#include <vector>

namespace topos::models::topobench {

/// numpy.random.permutation(n) on a legacy RandomState: Fisher-Yates from the top, j drawn with
/// the masked rejection of randint(0, i + 1).
inline std::vector<std::int64_t> numpy_permutation(data::NumpyRandomState& rs, std::int64_t n) {
  std::vector<std::int64_t> a(static_cast<std::size_t>(n));
  std::iota(a.begin(), a.end(), std::int64_t{0});
  for (std::int64_t i = n - 1; i >= 1; --i)
    std::swap(a[static_cast<std::size_t>(i)], a[static_cast<std::size_t>(rs.randint(0, i + 1))]);
  return a;
}

struct Split {
  std::vector<std::size_t> train, val, test;
};

/// TopoBench's random split (split_utils.py): np.random.seed(42), ten permutations drawn in a
/// row, the (data_seed mod 10)-th taken; the first int(0.5 n) train, the next int(0.25 n)
/// validation, the rest test. Not stratified.
inline Split random_split(std::int64_t n, std::int64_t data_seed) {
  data::NumpyRandomState rs(42);
  std::vector<std::int64_t> perm;
  for (std::int64_t f = 0; f <= ((data_seed % 10) + 10) % 10; ++f) perm = numpy_permutation(rs, n);
  const auto n_train = static_cast<std::size_t>(n / 2), n_val = static_cast<std::size_t>(n / 4);
  Split s;
  for (std::size_t i = 0; i < perm.size(); ++i)
    (i < n_train           ? s.train
     : i < n_train + n_val ? s.val
                           : s.test)
        .push_back(static_cast<std::size_t>(perm[i]));
  return s;
}

}  // namespace topos::models::topobench
