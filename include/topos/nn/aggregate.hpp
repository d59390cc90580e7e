// topos/nn/aggregate.hpp
// Aggregation of messages over a neighbourhood: gather the source rows, optionally weight them
// by the neighbourhood's values or keep one role, and reduce per target by sum, mean or max.
// Differentiable; targets that receive nothing get 0. A neighbourhood with backward values
// weights the gradient of a weighted message by those instead of its values. On the CPU a sum
// or mean over a neighbourhood's pairs (all, or one role's) runs as a sparse product over those
// pairs in CSR form (spmm, both ways; with backward values, the backward by their own operator),
// which gathers each target's sources without forming a row per pair.
#pragma once

#include "topos/nn/complex_batch.hpp"
#include "topos/nn/functional.hpp"  // Aggr
#include "topos/nn/sparse_operator.hpp"
#include "topos/nn/tensor_cache.hpp"

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
  /// A sum or mean over the pairs (all, or one role's) on the CPU as a sparse product over the
  /// pairs in CSR form (the same sums in another order, a mean divided by the same counts; a
  /// pair whose weight is exactly zero is skipped, so an inf or NaN it would carry is not
  /// summed); false: gather the pairs' rows, then add them up per target. Values that require a
  /// gradient keep the gathered path; backward values go back by their own CSR operator.
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

// A neighbourhood's pairs (all, or those of one role) as the num_target × num_source operator
// (values: the neighbourhood's, or ones; pairs repeated are summed into one entry and entries
// exactly zero dropped), for a weighted neighbourhood with backward values their operator too
// (the gradient's), and, once a mean asks, each target's count of pairs (at least 1), kept
// per thread for the last neighbourhoods aggregated over: a batch's operator is sorted into CSR
// once and serves every term and layer that reads the same neighbourhood tensors. Inference
// tensors (which have no version counter) are not kept.
struct NeighborhoodOperator {
  TensorKey source, target, values, backward_values, roles;
  std::int64_t num_source = 0, num_target = 0, role = 0;
  torch::Dtype dtype = torch::kFloat;
  std::shared_ptr<const SparseOperator> op, backward;  // backward: null without backward values
  torch::Tensor count;                                 // num_target × 1
  bool expired() const {
    return source.expired() || target.expired() || values.expired() || backward_values.expired() ||
           roles.expired();
  }
};
struct AggregationOperators {
  std::shared_ptr<const SparseOperator> op, backward;
  torch::Tensor count;
};
// The operators and, for a mean, the counts. Under InferenceMode nothing new is kept: what it
// makes is an inference tensor, which a later forward with gradients could not save.
inline AggregationOperators neighborhood_operator(const TensorNeighborhood& n, bool weighted,
                                                  int role, bool mean, torch::Dtype dtype) {
  thread_local TensorCache<NeighborhoodOperator> cache(64);
  const torch::Tensor values = weighted ? n.values : torch::Tensor();
  // Backward values weight a weighted message's gradient (the gathered path ignores them where
  // the neighbourhood has no values: so does this).
  const torch::Tensor backward_values =
      weighted && n.values.defined() ? n.backward_values : torch::Tensor();
  const torch::Tensor roles = role != 0 ? n.roles : torch::Tensor();
  struct Pairs {
    std::vector<std::int64_t> source, target;
    std::vector<double> w, w_backward;
  };
  const auto kept_pairs = [&] {
    Pairs p{index_vector(n.source), index_vector(n.target),
            values.defined() ? value_vector(values)
                             : std::vector<double>(static_cast<std::size_t>(n.nnz()), 1.0),
            backward_values.defined() ? value_vector(backward_values) : std::vector<double>()};
    if (roles.defined()) {
      const auto r = roles.to(torch::kLong).contiguous();
      const auto* rp = r.data_ptr<std::int64_t>();
      const bool wb = !p.w_backward.empty();
      std::size_t kept = 0;
      for (std::size_t k = 0; k < p.target.size(); ++k)
        if (rp[k] == role) {
          p.source[kept] = p.source[k], p.target[kept] = p.target[k], p.w[kept] = p.w[k];
          if (wb) p.w_backward[kept] = p.w_backward[k];
          ++kept;
        }
      p.source.resize(kept), p.target.resize(kept), p.w.resize(kept);
      if (wb) p.w_backward.resize(kept);
    }
    return p;
  };
  const auto count = [&](const std::vector<std::int64_t>& target) {  // pairs per target, >= 1
    std::vector<double> c(static_cast<std::size_t>(n.num_target), 0.0);
    for (const auto t : target) c[static_cast<std::size_t>(t)] += 1;
    for (auto& v : c) v = std::max(v, 1.0);
    return torch::tensor(c, torch::kDouble).to(dtype).unsqueeze(1);
  };
  const auto fill = [&](NeighborhoodOperator& e) {
    const auto p = kept_pairs();
    e.op = std::make_shared<const SparseOperator>(
        SparseOperator::from_triplets(n.num_target, n.num_source, p.target, p.source, p.w, dtype));
    if (!p.w_backward.empty())
      e.backward = std::make_shared<const SparseOperator>(SparseOperator::from_triplets(
          n.num_target, n.num_source, p.target, p.source, p.w_backward, dtype));
    if (mean) e.count = count(p.target);
  };
  const bool keep = !c10::InferenceMode::is_enabled();
  NeighborhoodOperator fresh;
  if (!TensorKey::keyable(n.source) || !TensorKey::keyable(n.target) ||
      !TensorKey::keyable(values) || !TensorKey::keyable(backward_values) ||
      !TensorKey::keyable(roles)) {
    fill(fresh);
    return {fresh.op, fresh.backward, fresh.count};
  }
  if (auto* e = cache.find([&](const NeighborhoodOperator& e) {
        return e.num_source == n.num_source && e.num_target == n.num_target && e.dtype == dtype &&
               e.role == role && e.source.matches(n.source) && e.target.matches(n.target) &&
               e.values.matches(values) && e.backward_values.matches(backward_values) &&
               e.roles.matches(roles);
      })) {
    if (!mean || e->count.defined()) return {e->op, e->backward, e->count};
    auto c = count(kept_pairs().target);
    if (keep) e->count = c;
    return {e->op, e->backward, c};
  }
  fresh.source = TensorKey::of(n.source), fresh.target = TensorKey::of(n.target);
  fresh.values = TensorKey::of(values), fresh.roles = TensorKey::of(roles);
  fresh.backward_values = TensorKey::of(backward_values);
  fresh.num_source = n.num_source, fresh.num_target = n.num_target, fresh.role = role;
  fresh.dtype = dtype;
  fill(fresh);
  if (!keep) return {fresh.op, fresh.backward, fresh.count};
  const auto& e = cache.insert(std::move(fresh));
  return {e.op, e.backward, e.count};
}
}  // namespace detail

/// Messages from source rows `x` (num_source × C) to the n.num_target targets.
inline torch::Tensor aggregate(const torch::Tensor& x, const TensorNeighborhood& n,
                               const AggregateOptions& opt = {}) {
  if (opt.csr && (opt.reduce == Aggr::sum || opt.reduce == Aggr::mean) &&
      (opt.role == 0 ? !n.one_per_target : n.roles.defined()) && n.nnz() > 0 && x.dim() == 2 &&
      x.size(0) == n.num_source && x.device().is_cpu() && n.source.device().is_cpu() &&
      (x.scalar_type() == torch::kFloat || x.scalar_type() == torch::kDouble) &&
      !(opt.weighted && n.values.defined() && n.values.requires_grad())) {
    const bool mean = opt.reduce == Aggr::mean;
    const auto ops =
        detail::neighborhood_operator(n, opt.weighted, opt.role, mean, x.scalar_type());
    const auto sum =
        ops.backward ? detail::spmm_backward_by(*ops.op, x, *ops.backward) : spmm(*ops.op, x);
    return mean ? sum / ops.count : sum;
  }
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
