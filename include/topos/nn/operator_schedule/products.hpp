// topos/nn/operator_schedule/products.hpp
// The schedule's built-in operations that apply operators: a product by an operator or its
// pattern (`via`, `via_t`, `pattern`, `only`), attention over an operator (`attend`) and the
// powers of a polynomial filter (`powers`). Each is an Operation, as a user's is; the traits they
// declare (the product they are, the operators they apply, the terms they fan out into) are what
// the network's aggregation paths read: over a batch's neighbourhoods a product runs as an
// aggregation, possibly deferred past a split first layer or on the rows it reads.
#pragma once

#include "topos/config.hpp"
#include "topos/nn/operator_schedule/operation.hpp"

#include <cstdint>
#include <string>
#include <utility>
#include <vector>

namespace topos::nn {

/// Keys that are per-head linear maps of the keys' cochain, k_j,h = x_j K_h with K (heads × in ×
/// channels) at `path` (Glorot with `gain`, as head_weights makes it): attend folds them into the
/// source scores, <x_j K_h, a_h> = x_j (K_h a_h), one product of H columns where forming the keys
/// takes one of heads·channels columns and its backward (AllSetTransformer's K).
struct KeyWeights {
  KeyWeights(std::string path, std::int64_t channels)
      : path_(std::move(path)), channels_(channels) {}
  TORCH_ARG(std::string, path);
  TORCH_ARG(std::int64_t, channels);  ///< per head
  TORCH_ARG(double, gain) = 1.414;
};

/// How `attend` scores and weighs a term's messages; the defaults are TopoModelX Conv's attention
/// (one head, one (2·C) vector). Per head, scores from keys k (the term's features, or a cochain
/// of the source rank) and queries q (the step's target before the step, or a cochain of the
/// target rank): GAT's act(a_s·k_j + a_t·q_i), or act(a_s·k_j) (`source_only`); then the
/// per-target norm, dropout (training only), times A's values (nn::attention_operator). Head h's
/// messages are its slice of the term's features; the heads are concatenated or averaged
/// (nn::multi_head_attention). Attention that one model alone needs is an Operation of that
/// model's (models::HmcAttention, models::CanAttention, models::SanFilterAttention).
struct AttendOptions {
  explicit AttendOptions(std::string param) : param_(std::move(param)) {}
  /// The source part a_s then the target part a_t, in one parameter.
  TORCH_ARG(std::string, param);
  /// The parameter's shape (default: a vector); only its element count is fixed (heads-major).
  TORCH_ARG(std::vector<std::int64_t>, shape);
  TORCH_ARG(double, gain) = 1.414;  ///< Glorot gain of the parameter
  TORCH_ARG(Activation, activation) = Activation::elu;
  TORCH_ARG(double, negative_slope) = 0.2;
  TORCH_ARG(AttentionNorm, norm) = AttentionNorm::none;
  TORCH_ARG(std::optional<CochainKey>, keys);  ///< default: the term's features
  /// The keys are `keys` times these per-head weights (folded into the scores), not `keys`.
  TORCH_ARG(std::optional<KeyWeights>, key_weights);
  TORCH_ARG(std::optional<CochainKey>, queries);  ///< default: the step's target
  TORCH_ARG(bool, source_only) = false;           ///< no queries and no a_t
  TORCH_ARG(std::int64_t, heads) = 1;
  TORCH_ARG(bool, concat) = true;       ///< the heads side by side, or their mean
  TORCH_ARG(double, dropout) = 0;       ///< on the weights
  TORCH_ARG(bool, transposed) = false;  ///< attend over Aᵀ
};

namespace builtin {

/// A product by an operator (OperatorProduct): `via`, `via_t`, `pattern`, and `only`'s role.
class Product final : public Operation {
 public:
  explicit Product(OperatorProduct p) : p_(std::move(p)) {}
  std::string str(const std::string& x) const override;
  TermShape infer(BuildContext& ctx, TermShape x) const override;
  torch::Tensor forward(RunContext& ctx, const torch::Tensor& x) const override;
  OperationTraits traits() const override;
  OperationCost cost(const CostContext& c) const override;
  const OperatorProduct& product() const { return p_; }

 private:
  OperatorProduct p_;
};

/// A · x with A's values times attention weights (AttendOptions).
class Attend final : public Operation {
 public:
  Attend(std::string op, AttendOptions o) : op_(std::move(op)), o_(std::move(o)) {}
  std::string str(const std::string& x) const override;
  TermShape infer(BuildContext& ctx, TermShape x) const override;
  torch::Tensor forward(RunContext& ctx, const torch::Tensor& x) const override;
  OperationTraits traits() const override;
  OperationCost cost(const CostContext& c) const override;

 private:
  std::string op_;
  AttendOptions o_;
};

/// [y, A₁y, ..., A₁^K₁y, A₂y, ...] (y once): a term fanned out into the taps of a polynomial
/// filter; with row_norm each power from `norm_from` on is divided by its operator's row sums.
class Powers final : public Operation {
 public:
  Powers(std::vector<std::pair<std::string, int>> filters, bool row_norm, int norm_from)
      : filters_(std::move(filters)), row_norm_(row_norm), norm_from_(norm_from) {}
  std::string str(const std::string& x) const override;
  TermShape infer(BuildContext& ctx, TermShape x) const override;
  torch::Tensor forward(RunContext& ctx, const torch::Tensor& x) const override;
  std::vector<torch::Tensor> forward_terms(RunContext& ctx, const torch::Tensor& x) const override;
  OperationTraits traits() const override;
  OperationCost cost(const CostContext& c) const override;

 private:
  std::vector<std::pair<std::string, int>> filters_;
  bool row_norm_;
  int norm_from_;
};

}  // namespace builtin
}  // namespace topos::nn
