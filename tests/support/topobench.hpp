// A lifted graph's operator (topobench::Triplets) as a dense tensor: the TopoBench tests' reference
// form of the lifting's and the batch's sparse operators.
#pragma once
#include "topos/models/topobench/lifting.hpp"

#include <torch/torch.h>

namespace topos::testing {

inline torch::Tensor dense(const models::topobench::Triplets& t) {
  auto d = torch::zeros({t.rows, t.cols});
  for (std::int64_t k = 0; k < t.nnz(); ++k)
    d[t.row[static_cast<std::size_t>(k)]][t.col[static_cast<std::size_t>(k)]] =
        t.value[static_cast<std::size_t>(k)];
  return d;
}

}  // namespace topos::testing
