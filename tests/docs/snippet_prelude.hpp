// What the code examples of the docs and headers take as given (tests/docs/extract_snippets.sh):
// features, operators and a schedule under the names the examples use, one namespace per
// source. A block without a `using namespace` of its own gets its source's SNIPPET_USING_<id>.
#pragma once

#include "topos/core/cell_complex.hpp"
#include "topos/core/sparse_matrix.hpp"
#include "topos/models/simplicial/scn2.hpp"
#include "topos/nn/operator_schedule.hpp"

#include <torch/torch.h>

#include <array>
#include <cstdint>
#include <vector>

namespace snippet_schedule_tutorial {
inline torch::Tensor x, x0, x1, x2, W, a;
inline topos::nn::SparseOperator A, A1, B1, B2, L_down, L_up;
inline int K = 2;
inline std::int64_t C = 4;
inline topos::nn::OperatorSchedule s;
}  // namespace snippet_schedule_tutorial
#define SNIPPET_USING_schedule_tutorial \
  using namespace topos::nn;            \
  using namespace topos::nn::ops;

namespace snippet_tutorial_zoo {
inline torch::Tensor x0, x1, x2, y, train;
inline std::int64_t n_nodes = 5, epochs = 10;
inline std::vector<torch::Tensor> params;
inline topos::models::SCN2 net{nullptr};
inline std::array<topos::nn::SparseOperator, 3> L;
inline topos::nn::SparseOperator A0, A1, coA2, B1, B2;
inline topos::CellComplex cc;
inline topos::nn::OperatorSchedule s;
inline int layers = 2;
inline std::int64_t D = 8;
inline topos::nn::SparseOperator op(const topos::SparseMatrix& m) {
  return topos::nn::SparseOperator::from_eigen(m);
}
}  // namespace snippet_tutorial_zoo
#define SNIPPET_USING_tutorial_zoo \
  using namespace topos;           \
  using namespace topos::nn;       \
  using namespace topos::nn::ops;

namespace snippet_operation {
inline topos::nn::OperatorSchedule s;
}  // namespace snippet_operation
#define SNIPPET_USING_operation \
  using namespace topos::nn;    \
  using namespace topos::nn::ops;

namespace snippet_operator_schedule {
inline torch::Tensor x0, x1;
inline topos::nn::SparseOperator A1, B1, L_down_1, L_up_1;
}  // namespace snippet_operator_schedule
#define SNIPPET_USING_operator_schedule using namespace topos::nn;
