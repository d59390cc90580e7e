// topos/nn/operator_schedule/elementwise.hpp
// The schedule's built-in operations that act on each entry or row without an operator:
// activations, dropout, constant and learned scales, biases, per-head maps, powers and
// normalisations. Each is
// an Operation, written as a user's would be, and declares the traits the network's fast paths
// read (row-wise, a fusable activation); the builder's `act`, `dropout`, `scale`, `bias`, `pow`,
// `normalize` and `unit_rows` apply them.
#pragma once

#include "topos/config.hpp"
#include "topos/nn/operator_schedule/operation.hpp"

#include <cstdint>
#include <string>
#include <vector>

namespace topos::nn::builtin {

/// apply_activation(x, update, negative_slope): fused into the product before it where it can be.
class Activate final : public Operation {
 public:
  explicit Activate(Activation update, double negative_slope = 0.01)
      : update_(update), slope_(negative_slope) {}
  std::string str(const std::string& x) const override;
  TermShape infer(BuildContext& ctx, TermShape x) const override;
  torch::Tensor forward(RunContext& ctx, const torch::Tensor& x) const override;
  OperationTraits traits() const override;

 private:
  Activation update_;
  double slope_;
};

/// Inverted dropout with rate `rate` in [0, 1], in training only (not row-wise: a fresh mask per
/// entry of whatever rows it is given).
class Dropout final : public Operation {
 public:
  explicit Dropout(double rate) : rate_(rate) {}
  std::string str(const std::string& x) const override;
  TermShape infer(BuildContext& ctx, TermShape x) const override;
  torch::Tensor forward(RunContext& ctx, const torch::Tensor& x) const override;
  OperationTraits traits() const override;

 private:
  double rate_;
};

/// Each row divided by its (undifferentiated) L2 norm; zero rows stay 0.
class UnitRows final : public Operation {
 public:
  std::string str(const std::string& x) const override;
  TermShape infer(BuildContext& ctx, TermShape x) const override;
  torch::Tensor forward(RunContext& ctx, const torch::Tensor& x) const override;
  OperationTraits traits() const override;
};

/// x · factor, a constant.
class Scale final : public Operation {
 public:
  explicit Scale(double factor) : factor_(factor) {}
  std::string str(const std::string& x) const override;
  TermShape infer(BuildContext& ctx, TermShape x) const override;
  torch::Tensor forward(RunContext& ctx, const torch::Tensor& x) const override;
  OperationTraits traits() const override;

 private:
  double factor_;
};

/// (offset + s) · x, s a scalar (shape {1}) at `path` starting at `value`: a parameter when
/// `trainable`, else a buffer.
class LearnedScale final : public Operation {
 public:
  LearnedScale(std::string path, double value, bool trainable, double offset)
      : path_(std::move(path)), value_(value), trainable_(trainable), offset_(offset) {}
  std::string str(const std::string& x) const override;
  TermShape infer(BuildContext& ctx, TermShape x) const override;
  torch::Tensor forward(RunContext& ctx, const torch::Tensor& x) const override;
  OperationTraits traits() const override;

 private:
  std::string path_;
  double value_;
  bool trainable_;
  double offset_;
};

/// x + b on every row, b at `path` of `shape` (default: a vector of the channels) flattened;
/// zeros when new, or Glorot-initialised with a positive `gain`.
class Bias final : public Operation {
 public:
  Bias(std::string path, std::vector<std::int64_t> shape, double gain)
      : path_(std::move(path)), shape_(std::move(shape)), gain_(gain) {}
  std::string str(const std::string& x) const override;
  TermShape infer(BuildContext& ctx, TermShape x) const override;
  torch::Tensor forward(RunContext& ctx, const torch::Tensor& x) const override;
  OperationTraits traits() const override;

 private:
  std::string path_;
  std::vector<std::int64_t> shape_;
  double gain_;
};

/// One map per head, side by side: [x W_1 | ... | x W_H] with W (heads × in × out) at `path`,
/// Glorot-initialised with `gain` (TopoModelX's multi-head layout).
class HeadWeights final : public Operation {
 public:
  HeadWeights(std::string path, std::int64_t heads, std::int64_t out, double gain)
      : path_(std::move(path)), heads_(heads), out_(out), gain_(gain) {}
  std::string str(const std::string& x) const override;
  TermShape infer(BuildContext& ctx, TermShape x) const override;
  torch::Tensor forward(RunContext& ctx, const torch::Tensor& x) const override;
  OperationTraits traits() const override;
  OperationCost cost(const CostContext& c) const override;

 private:
  std::string path_;
  std::int64_t heads_, out_;
  double gain_;
};

/// x^exponent elementwise.
class Pow final : public Operation {
 public:
  explicit Pow(double exponent) : exponent_(exponent) {}
  std::string str(const std::string& x) const override;
  TermShape infer(BuildContext& ctx, TermShape x) const override;
  torch::Tensor forward(RunContext& ctx, const torch::Tensor& x) const override;
  OperationTraits traits() const override;

 private:
  double exponent_;
};

/// x / ‖x‖₂ (differentiated, the norm clamped at 1e-12): each row's, or with per_row false the
/// whole matrix's (then not row-wise).
class Normalize final : public Operation {
 public:
  explicit Normalize(bool per_row) : per_row_(per_row) {}
  std::string str(const std::string& x) const override;
  TermShape infer(BuildContext& ctx, TermShape x) const override;
  torch::Tensor forward(RunContext& ctx, const torch::Tensor& x) const override;
  OperationTraits traits() const override;

 private:
  bool per_row_;
};

}  // namespace topos::nn::builtin
