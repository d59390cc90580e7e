// topos/models/topobench/batch.hpp
// Many lifted graphs (topobench/lifting.hpp) as one disjoint union, as TopoBench's collate does:
// features of each rank stacked, every named operator block-diagonal, per rank the graph each
// cell belongs to, and the graphs' classes. The operators are concatenated from their sorted
// triplets with shifted indices (still sorted), so building a batch is O(cells + nonzeros); a
// factored operator's factors are each block-diagonal, its scales concatenated. A Collator does
// the same for a split's many shuffled batches from each graph's CSR, prepared once.
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

/// collate for many batches of the same graphs (a split's training graphs, shuffled into new
/// batches every epoch): each graph's operators are put in CSR form once, with their transposes
/// (the row starts of both and the order of Aᵀ's entries, 32-bit, graph-local), so a batch is
/// the concatenation of those arrays with shifted indices, one pass over each and no sort.
/// `collator(which)` equals `collate(graphs, which)` tensor for tensor. It reads `graphs`, which
/// must outlive it; only the graphs of `part` are prepared (all when `part` is empty), and a
/// batch of others is an error. Factored operators are collated as collate does.
class Collator {
 public:
  explicit Collator(const std::vector<LiftedGraph>& graphs,
                    const std::vector<std::size_t>& part = {});
  Batch operator()(const std::vector<std::size_t>& which) const;

 private:
  /// One graph's operator in CSR form beside its Triplets (which hold the entries' rows,
  /// columns and values): the row starts of A and of Aᵀ, and t_perm (Aᵀ's k-th entry is A's
  /// t_perm[k]-th).
  struct Csr {
    const Triplets* entries = nullptr;
    std::vector<std::int32_t> crow, t_crow, t_perm;
  };
  const std::vector<LiftedGraph>& graphs_;
  std::vector<std::string> names_;     ///< the explicit operators, by name
  std::vector<std::vector<Csr>> csr_;  ///< [graph][operator], empty: not prepared
};

}  // namespace topos::models::topobench

#ifdef TOPOS_HEADER_ONLY
#include "topos/models/topobench/batch-inl.hpp"
#endif
