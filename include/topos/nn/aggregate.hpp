// topos/nn/aggregate.hpp
// Aggregation of messages over a neighbourhood: gather the source rows, optionally weight them
// by the neighbourhood's values or keep one role, and reduce per target by sum, mean or max.
// Differentiable; targets that receive nothing get 0. A neighbourhood with backward values
// weights the gradient of a weighted message by those instead of its values.
#pragma once

#include "topos/nn/complex_batch.hpp"
#include "topos/nn/functional.hpp"  // Aggr

#include <torch/torch.h>

#include <string>

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
