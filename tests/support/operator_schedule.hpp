// Helpers of the operator schedule's tests: a random sparse operator and the error a schedule
// reports when its network is built.
#pragma once

#include "topos/nn/operator_schedule.hpp"

#include <torch/torch.h>

#include <cstdint>
#include <string>

namespace topos::test {

/// A rows × cols operator (double) with Gaussian entries, each present with probability
/// `density`, drawn from `seed`.
inline nn::SparseOperator random_operator(std::int64_t rows, std::int64_t cols, int seed,
                                          double density = 0.4) {
  torch::manual_seed(seed);
  const auto d = torch::randn({rows, cols}, torch::kDouble) *
                 (torch::rand({rows, cols}, torch::kDouble) < density).to(torch::kDouble);
  return nn::SparseOperator::from_dense(d);
}

/// The error message of building `s`, or "" when it builds.
inline std::string build_error(const nn::OperatorSchedule& s) {
  try {
    nn::OperatorNetwork net(s);
  } catch (const nn::ScheduleError& e) {
    return e.what();
  }
  return "";
}

}  // namespace topos::test
