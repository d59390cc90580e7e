// topos/models/topobench/batch.hpp
// Many lifted graphs (topobench/lifting.hpp) as one disjoint union, as TopoBench's collate does:
// features of each rank stacked, every named operator block-diagonal, per rank the graph each
// cell belongs to, and the graphs' classes. The operators are concatenated from their sorted
// triplets with shifted indices (still sorted), so building a batch is O(cells + nonzeros); a
// factored operator's factors are each block-diagonal, its scales concatenated.
#pragma once

#include "topos/config.hpp"
#include "topos/models/topobench/lifting.hpp"
#include "topos/nn/sparse_operator.hpp"

#include <torch/torch.h>

#include <algorithm>
#include <cstring>
#include <map>
#include <stdexcept>
#include <string>
#include <vector>

namespace topos::models::topobench {

struct Batch {
  std::vector<torch::Tensor> x;      ///< per rank, cells × width
  std::vector<torch::Tensor> batch;  ///< per rank, the graph of each cell (int64)
  std::map<std::string, nn::SparseOperator> operators;
  torch::Tensor labels;  ///< int64, one per graph
  std::int64_t num_graphs = 0;
};

/// `order` cut into consecutive batches of `size` (the last one shorter): a loader's batches.
inline std::vector<std::vector<std::size_t>> batches_of(const std::vector<std::size_t>& order,
                                                        std::size_t size) {
  if (size == 0) throw std::invalid_argument("topobench::batches_of: a batch size of 0");
  std::vector<std::vector<std::size_t>> out;
  for (std::size_t at = 0; at < order.size(); at += size)
    out.emplace_back(
        order.begin() + static_cast<std::ptrdiff_t>(at),
        order.begin() + static_cast<std::ptrdiff_t>(std::min(order.size(), at + size)));
  return out;
}

/// The block-diagonal union of `graphs[which[i]]`. Every graph must have the same ranks, widths
/// and operator names (one lifting of one dataset).
Batch collate(const std::vector<LiftedGraph>& graphs, const std::vector<std::size_t>& which);

}  // namespace topos::models::topobench

#ifdef TOPOS_HEADER_ONLY
#include "topos/models/topobench/batch-inl.hpp"
#endif
