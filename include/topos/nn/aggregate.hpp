// topos/nn/aggregate.hpp
// Aggregation of messages over a neighbourhood: gather the source rows, optionally weight them
// by the neighbourhood's values or keep one role, and reduce per target by sum, mean or max.
// Differentiable; targets that receive nothing get 0. A neighbourhood with backward values
// weights the gradient of a weighted message by those instead of its values. On the CPU a sum
// over all of a neighbourhood's pairs runs as a sparse product over its pairs in CSR form (spmm,
// both ways), which gathers each target's sources without forming a row per pair.
#pragma once

#include "topos/nn/complex_batch.hpp"
#include "topos/nn/functional.hpp"  // Aggr
#include "topos/nn/sparse_operator.hpp"

#include <torch/torch.h>

#include <algorithm>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

namespace topos::nn {

struct AggregateOptions {
  Aggr reduce = Aggr::sum;
  bool weighted = false;  ///< multiply messages by the neighbourhood's values
  int role = 0;           ///< keep only pairs of this role (0: all)
  AggregateOptions& with_reduce(Aggr r) {
    reduce = r;
    return *this;
  }
  AggregateOptions& with_weighted(bool w) {
    weighted = w;
    return *this;
  }
  AggregateOptions& with_role(int r) {
    role = r;
    return *this;
  }
  /// A sum over every pair on the CPU as a sparse product over the pairs in CSR form (the
  /// same sums in another order; a pair whose weight is exactly zero is skipped, so an inf or
  /// NaN it would carry is not summed); false: gather the pairs' rows, then add them up per
  /// target. Values that require a gradient keep the gathered sum.
  bool csr = true;
  AggregateOptions& with_csr(bool c) {
    csr = c;
    return *this;
  }
};

namespace detail {
/// rows · w going forward, grad · w_backward going back (Neighborhood::backward_values).
struct WeightRows : torch::autograd::Function<WeightRows> {
  static torch::Tensor forward(torch::autograd::AutogradContext* ctx, const torch::Tensor& x,
                               const torch::Tensor& w, const torch::Tensor& w_backward) {
    ctx->saved_data["w"] = w_backward;
    return x * w.unsqueeze(1);
  }
  static torch::autograd::variable_list backward(torch::autograd::AutogradContext* ctx,
                                                 torch::autograd::variable_list g) {
    return {g[0] * ctx->saved_data["w"].toTensor().unsqueeze(1), torch::Tensor(), torch::Tensor()};
  }
};

// A tensor as a cache key: its storage (held weakly, so that a new tensor at a freed address
// cannot match), offset, size and version counter; an undefined tensor matches undefined ones.
struct TensorKey {
  c10::weak_intrusive_ptr<c10::StorageImpl> storage{c10::intrusive_ptr<c10::StorageImpl>()};
  const c10::StorageImpl* key = nullptr;
  std::int64_t offset = 0, numel = 0, version = -1;
  std::vector<std::int64_t> strides;
  torch::Dtype dtype = torch::kLong;
  static TensorKey of(const torch::Tensor& t) {
    TensorKey k;
    if (!t.defined() || !t.has_storage()) return k;
    k.storage = t.storage().getWeakStorageImpl();
    k.key = t.storage().unsafeGetStorageImpl();
    k.offset = t.storage_offset(), k.numel = t.numel(), k.version = t._version();
    k.strides = t.strides().vec(), k.dtype = t.scalar_type();
    return k;
  }
  bool matches(const torch::Tensor& t) const {
    if (!t.defined() || !t.has_storage()) return key == nullptr;
    return key == t.storage().unsafeGetStorageImpl() && !storage.expired() &&
           offset == t.storage_offset() && numel == t.numel() && version == t._version() &&
           dtype == t.scalar_type() && t.strides() == c10::IntArrayRef(strides);
  }
};

// A neighbourhood's pairs as the num_target × num_source operator (values: the neighbourhood's,
// or ones; pairs repeated are summed into one entry and entries exactly zero dropped), kept per
// thread for the last neighbourhoods aggregated over: a batch's operator is sorted into CSR once
// and serves every term and layer that reads the same neighbourhood tensors. Inference tensors
// (which have no version counter) are not kept.
struct NeighborhoodOperatorCache {
  struct Entry {
    TensorKey source, target, values;
    std::int64_t num_source = 0, num_target = 0;
    torch::Dtype dtype = torch::kFloat;
    std::shared_ptr<const SparseOperator> op;
  };
  std::vector<Entry> entries;
  std::size_t next = 0;
};
inline std::shared_ptr<const SparseOperator> neighborhood_operator(const TensorNeighborhood& n,
                                                                   bool weighted,
                                                                   torch::Dtype dtype) {
  thread_local NeighborhoodOperatorCache cache;
  const torch::Tensor values = weighted ? n.values : torch::Tensor();
  const auto build = [&] {
    return std::make_shared<const SparseOperator>(SparseOperator::from_triplets(
        n.num_target, n.num_source, index_vector(n.target), index_vector(n.source),
        values.defined() ? value_vector(values)
                         : std::vector<double>(static_cast<std::size_t>(n.nnz()), 1.0),
        dtype));
  };
  const auto inference = [](const torch::Tensor& t) { return t.defined() && t.is_inference(); };
  if (inference(n.source) || inference(n.target) || inference(values)) return build();
  for (const auto& e : cache.entries)
    if (e.num_source == n.num_source && e.num_target == n.num_target && e.dtype == dtype &&
        e.source.matches(n.source) && e.target.matches(n.target) && e.values.matches(values))
      return e.op;
  auto& entries = cache.entries;  // those of freed neighbourhoods go first
  entries.erase(std::remove_if(entries.begin(), entries.end(),
                               [](const NeighborhoodOperatorCache::Entry& e) {
                                 return e.source.storage.expired() || e.target.storage.expired();
                               }),
                entries.end());
  NeighborhoodOperatorCache::Entry e;
  e.source = TensorKey::of(n.source), e.target = TensorKey::of(n.target);
  e.values = TensorKey::of(values);
  e.num_source = n.num_source, e.num_target = n.num_target, e.dtype = dtype;
  e.op = build();
  constexpr std::size_t capacity = 64;
  if (entries.size() < capacity)
    entries.push_back(e);
  else
    entries[cache.next++ % capacity] = e;
  return e.op;
}
}  // namespace detail

/// Messages from source rows `x` (num_source × C) to the n.num_target targets.
inline torch::Tensor aggregate(const torch::Tensor& x, const TensorNeighborhood& n,
                               const AggregateOptions& opt = {}) {
  torch::Tensor src = n.source, tgt = n.target, w = n.values, wb = n.backward_values;
  if (opt.role != 0) {
    if (!n.roles.defined()) {
      src = src.slice(0, 0, 0);
      tgt = tgt.slice(0, 0, 0);
    } else {
      const torch::Tensor keep = n.roles.eq(opt.role).nonzero().squeeze(1);
      src = src.index_select(0, keep);
      tgt = tgt.index_select(0, keep);
      if (w.defined()) w = w.index_select(0, keep);
      if (wb.defined()) wb = wb.index_select(0, keep);
    }
  }
  if (opt.csr && opt.reduce == Aggr::sum && opt.role == 0 && !n.one_per_target && n.nnz() > 0 &&
      x.dim() == 2 && x.size(0) == n.num_source && x.device().is_cpu() &&
      n.source.device().is_cpu() &&
      (x.scalar_type() == torch::kFloat || x.scalar_type() == torch::kDouble) &&
      !(opt.weighted && (wb.defined() || (w.defined() && w.requires_grad()))))
    return spmm(*detail::neighborhood_operator(n, opt.weighted, x.scalar_type()), x);
  torch::Tensor msg = x.index_select(0, src);
  if (opt.weighted && w.defined()) {
    if (wb.defined() && msg.requires_grad())
      msg = detail::WeightRows::apply(msg, w.to(msg.dtype()), wb.to(msg.dtype()));
    else
      msg = msg * w.to(msg.dtype()).unsqueeze(1);
  }
  if (opt.role == 0 && n.one_per_target) return msg;  // every target gets exactly its own pair
  auto out = torch::zeros({n.num_target, x.size(1)}, x.options());
  if (opt.reduce == Aggr::sum) return out.index_add(0, tgt, msg);
  if (opt.reduce == Aggr::mean) {
    out = out.index_add(0, tgt, msg);
    auto count = torch::zeros({n.num_target}, x.options())
                     .index_add(0, tgt, torch::ones({tgt.size(0)}, x.options()));
    return out / count.clamp_min(1).unsqueeze(1);
  }
  const auto idx = tgt.unsqueeze(1).expand_as(msg);
  return out.scatter_reduce(0, idx, msg, "amax", /*include_self=*/false);
}

}  // namespace topos::nn
