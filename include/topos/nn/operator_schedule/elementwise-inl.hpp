// topos/nn/operator_schedule/elementwise-inl.hpp
// The built-in elementwise and row-wise operations (elementwise.hpp): their printed forms, checks,
// parameters and forwards. Compiled into topos::nn, or inline with TOPOS_HEADER_ONLY
// (topos/config.hpp).
#pragma once

#include "topos/nn/kernels.hpp"
#include "topos/nn/operator_schedule/elementwise.hpp"
#include "topos/nn/operator_schedule/printer-inl.hpp"  // detail::num

#include <iomanip>
#include <sstream>

namespace topos::nn::builtin {

namespace {
/// A double written exactly: an operation's identity (OperationTraits::identity).
inline std::string exact(double v) {
  std::ostringstream o;
  o << std::setprecision(17) << v;
  return o.str();
}
/// The traits of an operation that maps each row alone and reads nothing else.
inline OperationTraits row_wise(std::string identity = {}) {
  OperationTraits t;
  t.row_wise = true;
  t.reads_cochains = false;
  t.identity = std::move(identity);
  return t;
}
}  // namespace

TOPOS_INLINE std::string Activate::str(const std::string& x) const {
  return activation_name(update_) + "(" + x + ")";
}
TOPOS_INLINE TermShape Activate::infer(BuildContext&, TermShape x) const {
  return x;
}
TOPOS_INLINE torch::Tensor Activate::forward(RunContext&, const torch::Tensor& x) const {
  return apply_activation(x, update_, slope_);
}
TOPOS_INLINE OperationTraits Activate::traits() const {
  auto t = row_wise(exact(slope_));
  t.activation = update_;
  t.negative_slope = slope_;
  return t;
}

TOPOS_INLINE std::string Dropout::str(const std::string& x) const {
  return "dropout(" + x + ")";
}
TOPOS_INLINE TermShape Dropout::infer(BuildContext& ctx, TermShape x) const {
  if (!(rate_ >= 0 && rate_ <= 1))
    ctx.fail("a dropout rate must be in [0, 1], got " + std::to_string(rate_));
  return x;
}
TOPOS_INLINE torch::Tensor Dropout::forward(RunContext& ctx, const torch::Tensor& x) const {
  return nn::dropout(x, rate_, ctx.is_training());
}
TOPOS_INLINE OperationTraits Dropout::traits() const {
  OperationTraits t;
  t.reads_cochains = false;
  t.identity = exact(rate_);
  return t;
}

TOPOS_INLINE std::string UnitRows::str(const std::string& x) const {
  return "unit_rows(" + x + ")";
}
TOPOS_INLINE TermShape UnitRows::infer(BuildContext&, TermShape x) const {
  return x;
}
TOPOS_INLINE torch::Tensor UnitRows::forward(RunContext&, const torch::Tensor& x) const {
  return nn::unit_rows(x);
}
TOPOS_INLINE OperationTraits UnitRows::traits() const {
  return row_wise("unit_rows");
}

TOPOS_INLINE std::string Scale::str(const std::string& x) const {
  return nn::detail::num(factor_) + "·" + x;
}
TOPOS_INLINE TermShape Scale::infer(BuildContext&, TermShape x) const {
  return x;
}
TOPOS_INLINE torch::Tensor Scale::forward(RunContext&, const torch::Tensor& x) const {
  return x * factor_;
}
TOPOS_INLINE OperationTraits Scale::traits() const {
  return row_wise(exact(factor_));
}

TOPOS_INLINE std::string LearnedScale::str(const std::string& x) const {
  return "(" + nn::detail::num(offset_) + "+" + path_ + ")·" + x;
}
TOPOS_INLINE TermShape LearnedScale::infer(BuildContext& ctx, TermShape x) const {
  if (trainable_)
    ctx.parameter(path_, {1}, ParameterInit::constant(value_));
  else
    ctx.buffer(path_, {1}, value_);
  return x;
}
TOPOS_INLINE torch::Tensor LearnedScale::forward(RunContext& ctx, const torch::Tensor& x) const {
  return (offset_ + ctx.parameter(path_)) * x;
}
TOPOS_INLINE OperationTraits LearnedScale::traits() const {
  return row_wise(exact(offset_));
}

TOPOS_INLINE std::string Bias::str(const std::string& x) const {
  return x + " + " + path_;
}
TOPOS_INLINE TermShape Bias::infer(BuildContext& ctx, TermShape x) const {
  const auto shape = shape_.empty() ? std::vector<std::int64_t>{x.channels} : shape_;
  std::int64_t n = 1;
  for (auto d : shape) n *= d;
  if (n != x.channels) {
    std::ostringstream o;
    o << "bias '" << path_ << "' of shape " << torch::IntArrayRef(shape) << " added to "
      << x.channels << " channels";
    ctx.fail(o.str());
  }
  ctx.parameter(path_, shape, gain_ > 0 ? ParameterInit::glorot(gain_) : ParameterInit::zeros());
  return x;
}
TOPOS_INLINE torch::Tensor Bias::forward(RunContext& ctx, const torch::Tensor& x) const {
  return x + ctx.parameter(path_).reshape({-1});
}
TOPOS_INLINE OperationTraits Bias::traits() const {
  auto t = row_wise("bias");  // with its printed path
  t.row_offset = path_;
  return t;
}

TOPOS_INLINE std::string HeadWeights::str(const std::string& x) const {
  return x + "·" + path_ + "[×" + std::to_string(heads_) + "]";
}
TOPOS_INLINE TermShape HeadWeights::infer(BuildContext& ctx, TermShape x) const {
  if (heads_ < 1) ctx.fail("head weights '" + path_ + "' need at least one head");
  ctx.parameter(path_, {heads_, x.channels, out_}, ParameterInit::glorot(gain_));
  return {x.rank, heads_ * out_};
}
TOPOS_INLINE torch::Tensor HeadWeights::forward(RunContext& ctx, const torch::Tensor& x) const {
  const auto& W = ctx.parameter(path_);  // heads × in × out: one product, head-major
  return linear_act(x, W.permute({1, 0, 2}).reshape({W.size(1), -1}).t(), {});
}
TOPOS_INLINE OperationTraits HeadWeights::traits() const {
  return row_wise("heads");  // with its printed path
}
TOPOS_INLINE OperationCost HeadWeights::cost(const CostContext& c) const {
  return OperationCost::dense(c.rows, c.x.channels, c.y.channels);  // the heads side by side
}

TOPOS_INLINE std::string Pow::str(const std::string& x) const {
  return "(" + x + ")^" + nn::detail::num(exponent_);
}
TOPOS_INLINE TermShape Pow::infer(BuildContext&, TermShape x) const {
  return x;
}
TOPOS_INLINE torch::Tensor Pow::forward(RunContext&, const torch::Tensor& x) const {
  return x.pow(exponent_);
}
TOPOS_INLINE OperationTraits Pow::traits() const {
  return row_wise(exact(exponent_));
}

TOPOS_INLINE std::string Normalize::str(const std::string& x) const {
  return (per_row_ ? "normalize_rows(" : "normalize(") + x + ")";
}
TOPOS_INLINE TermShape Normalize::infer(BuildContext&, TermShape x) const {
  return x;
}
TOPOS_INLINE torch::Tensor Normalize::forward(RunContext&, const torch::Tensor& x) const {
  return x / (per_row_ ? x.norm(2, 1, true) : x.norm()).clamp_min(1e-12);
}
TOPOS_INLINE OperationTraits Normalize::traits() const {
  if (per_row_) return row_wise("rows");
  OperationTraits t;
  t.reads_cochains = false;
  return t;
}

}  // namespace topos::nn::builtin
