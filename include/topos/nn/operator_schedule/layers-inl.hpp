// topos/nn/operator_schedule/layers-inl.hpp
// The built-in learned maps and normalisations (layers.hpp): their printed forms, checks,
// parameters, forwards and costs. Compiled into topos::nn, or inline with TOPOS_HEADER_ONLY
// (topos/config.hpp).
#pragma once

#include "topos/nn/kernels.hpp"
#include "topos/nn/operator_schedule/elementwise-inl.hpp"  // row_wise
#include "topos/nn/operator_schedule/layers.hpp"

#include <memory>
#include <string>

namespace topos::nn::builtin {

TOPOS_INLINE std::string Weight::str(const std::string& x) const {
  return x + "·" + path_;
}
TOPOS_INLINE TermShape Weight::infer(BuildContext& ctx, TermShape x) const {
  ctx.parameter(path_, {x.channels, out_}, ParameterInit::glorot(gain_));
  return {x.rank, out_};
}
TOPOS_INLINE torch::Tensor Weight::forward(RunContext& ctx, const torch::Tensor& x) const {
  const auto& W = ctx.parameter(path_);
  return x.dim() == 2 && W.dim() == 2 ? linear_act(x, W.t(), {}) : x.matmul(W);
}
TOPOS_INLINE OperationTraits Weight::traits() const {
  auto t = row_wise("weight");
  t.right_factor = path_;
  return t;
}
TOPOS_INLINE OperationCost Weight::cost(const CostContext& c) const {
  return OperationCost::dense(c.rows, c.x.channels, c.y.channels);
}

TOPOS_INLINE std::string Linear::str(const std::string& x) const {
  return path_ + "(" + x + ")";
}
TOPOS_INLINE TermShape Linear::infer(BuildContext& ctx, TermShape x) const {
  ctx.parameter(
      path_ + ".weight", {out_, x.channels},
      init_ == LinearInit::glorot ? ParameterInit::glorot(1.0) : ParameterInit::linear_weight());
  if (bias_) ctx.parameter(path_ + ".bias", {out_}, ParameterInit::linear_bias(x.channels));
  return {x.rank, out_};
}
TOPOS_INLINE torch::Tensor Linear::product(RunContext& ctx, const torch::Tensor& x,
                                           Epilogue act) const {
  return linear_act(x, ctx.parameter(path_ + ".weight"),
                    bias_ ? ctx.parameter(path_ + ".bias") : torch::Tensor(), act);
}
TOPOS_INLINE torch::Tensor Linear::forward(RunContext& ctx, const torch::Tensor& x) const {
  return product(ctx, x, Epilogue::none);
}
TOPOS_INLINE torch::Tensor Linear::forward_activated(RunContext& ctx, const torch::Tensor& x,
                                                     Activation activation, double) const {
  return product(ctx, x, epilogue_of(activation));
}
TOPOS_INLINE OperationTraits Linear::traits() const {
  auto t = row_wise(bias_ ? "linear" : "linear, no bias");
  t.fuses_activation = true;
  return t;
}
TOPOS_INLINE OperationCost Linear::cost(const CostContext& c) const {
  return OperationCost::dense(c.rows, c.x.channels, c.y.channels);
}

TOPOS_INLINE std::string ChannelNorm::str(const std::string& x) const {
  return path_ + "(" + x + ")";
}
TOPOS_INLINE TermShape ChannelNorm::infer(BuildContext& ctx, TermShape x) const {
  std::int64_t width = 0;
  if (batch_) {
    auto m = ctx.module(path_, std::make_shared<torch::nn::BatchNorm1dImpl>(x.channels));
    width = std::dynamic_pointer_cast<torch::nn::BatchNorm1dImpl>(m)->options.num_features();
  } else {
    auto m = ctx.module(path_, std::make_shared<torch::nn::LayerNormImpl>(
                                   torch::nn::LayerNormOptions({x.channels})));
    width = std::dynamic_pointer_cast<torch::nn::LayerNormImpl>(m)->options.normalized_shape()[0];
  }
  if (width != x.channels)
    ctx.fail("normalisation '" + path_ + "' of " + std::to_string(width) + " channels applied to " +
             std::to_string(x.channels));
  return x;
}
TOPOS_INLINE torch::Tensor ChannelNorm::forward(RunContext& ctx, const torch::Tensor& x) const {
  if (batch_) return ctx.module<torch::nn::BatchNorm1dImpl>(path_).forward(x);
  return nn::layer_norm(x, ctx.module<torch::nn::LayerNormImpl>(path_));
}
TOPOS_INLINE torch::Tensor ChannelNorm::forward_activated(RunContext& ctx, const torch::Tensor& x,
                                                          Activation activation,
                                                          double negative_slope) const {
  if (batch_) return apply_activation(forward(ctx, x), activation, negative_slope);
  return nn::layer_norm(x, ctx.module<torch::nn::LayerNormImpl>(path_), epilogue_of(activation));
}
TOPOS_INLINE torch::Tensor ChannelNorm::forward_residual(RunContext& ctx, const torch::Tensor& x,
                                                         const torch::Tensor& r,
                                                         std::optional<Activation> activation,
                                                         double negative_slope) const {
  if (batch_ || (activation && !fusable(*activation)))
    return Operation::forward_residual(ctx, x, r, activation, negative_slope);
  return nn::add_layer_norm(x, r, ctx.module<torch::nn::LayerNormImpl>(path_),
                            activation ? epilogue_of(*activation) : Epilogue::none);
}
TOPOS_INLINE OperationTraits ChannelNorm::traits() const {
  if (!batch_) {
    auto t = row_wise("layer_norm");
    t.fuses_activation = true;
    t.fuses_residual = true;
    return t;
  }
  OperationTraits t;  // batch statistics: every row counts
  t.reads_cochains = false;
  t.identity = "batch_norm";
  return t;
}

TOPOS_INLINE std::string MlpBlock::str(const std::string& x) const {
  return path_ + "(" + x + ")";
}
TOPOS_INLINE TermShape MlpBlock::infer(BuildContext& ctx, TermShape x) const {
  const auto& o = options_;
  if (o.in() != x.channels)
    ctx.fail("mlp '" + path_ + "' takes " + std::to_string(o.in()) + " channels but gets " +
             std::to_string(x.channels));
  auto m = ctx.find_module(path_);
  if (!m) {
    try {
      m = std::make_shared<MlpImpl>(o);
    } catch (const std::exception& e) {
      ctx.fail("mlp '" + path_ + "': " + e.what());
    }
  }
  const auto mlp = std::dynamic_pointer_cast<MlpImpl>(ctx.module(path_, m));
  if (!mlp) ctx.fail("'" + path_ + "' is already a module of another kind than an mlp");
  const auto& p = mlp->options;
  if (p.in() != o.in() || p.hidden() != o.hidden() || p.out() != o.out() ||
      p.layers() != o.layers() || p.activation() != o.activation() ||
      p.final_activation() != o.final_activation() || p.layer_norm() != o.layer_norm())
    ctx.fail("mlp '" + path_ + "' is used again with other options (shared by its path)");
  return {x.rank, o.out()};
}
TOPOS_INLINE torch::Tensor MlpBlock::forward(RunContext& ctx, const torch::Tensor& x) const {
  return ctx.module<MlpImpl>(path_).forward(x);
}
TOPOS_INLINE OperationTraits MlpBlock::traits() const {
  auto t = row_wise("mlp");
  t.leading_linear = true;
  return t;
}
TOPOS_INLINE OperationCost MlpBlock::cost(const CostContext& c) const {
  const auto& o = options_;  // its Linear layers (MlpImpl): in → hidden → ... → out
  std::int64_t per_row = o.layers() == 1 ? o.in() * o.out()
                                         : o.in() * o.hidden() + o.hidden() * o.out() +
                                               (o.layers() - 2) * o.hidden() * o.hidden();
  return {2 * c.rows * per_row, "dense"};
}
TOPOS_INLINE std::shared_ptr<torch::nn::LinearImpl> MlpBlock::first_linear(RunContext& ctx) const {
  return ctx.module<MlpImpl>(path_).first_linear().ptr();
}
TOPOS_INLINE torch::Tensor MlpBlock::forward_after_first(RunContext& ctx,
                                                         const torch::Tensor& z) const {
  return ctx.module<MlpImpl>(path_).forward_after_first(z);
}
TOPOS_INLINE std::optional<Activation> MlpBlock::leading_activation(RunContext& ctx) const {
  return ctx.module<MlpImpl>(path_).first_activation();
}
TOPOS_INLINE torch::Tensor MlpBlock::forward_after_leading_activation(
    RunContext& ctx, const torch::Tensor& a) const {
  return ctx.module<MlpImpl>(path_).forward_after_first_activation(a);
}

}  // namespace topos::nn::builtin
