// topos/nn/operator_schedule/layers.hpp
// The schedule's built-in operations that hold learned maps or normalisations of the channels:
// a weight (x · W), torch.nn.Linear, BatchNorm1d, LayerNorm and the MLP block (nn::Mlp). Each is
// an Operation, written as a user's would be, declaring the traits the network's fast paths read
// (row-wise; a right factor to reorder around sparse products; an activation fused into the
// product; a leading Linear layer split over a step's terms). The builder's `weight`, `conv`,
// `linear`, `batch_norm`, `layer_norm` and `mlp` apply them.
#pragma once

#include "topos/config.hpp"
#include "topos/nn/mlp.hpp"
#include "topos/nn/operator_schedule/operation.hpp"

#include <cstdint>
#include <string>

namespace topos::nn {

/// How `linear` initialises a new weight: torch.nn.Linear's Kaiming uniform (a = √5, bound
/// 1/√in), or PyG's weight_initializer='glorot' (Xavier uniform, bound √(6 / (in + out)), as
/// GCNConv's and GATConv's `lin`). The bias is torch.nn.Linear's (±1/√in) either way, as PyG's.
enum class LinearInit { torch, glorot };

namespace builtin {

/// x · W with W (in × out) at `path`, Glorot-initialised with `gain` (TopoModelX's Conv weight).
class Weight final : public Operation {
 public:
  Weight(std::string path, std::int64_t out, double gain)
      : path_(std::move(path)), out_(out), gain_(gain) {}
  std::string str(const std::string& x) const override;
  TermShape infer(BuildContext& ctx, TermShape x) const override;
  torch::Tensor forward(RunContext& ctx, const torch::Tensor& x) const override;
  OperationTraits traits() const override;
  OperationCost cost(const CostContext& c) const override;

 private:
  std::string path_;
  std::int64_t out_;
  double gain_;
};

/// torch.nn.Linear at `path`: path.weight (out × in) and path.bias; relu, elu or sigmoid after it
/// runs in the product's kernel.
class Linear final : public Operation {
 public:
  Linear(std::string path, std::int64_t out, bool bias, LinearInit init)
      : path_(std::move(path)), out_(out), bias_(bias), init_(init) {}
  std::string str(const std::string& x) const override;
  TermShape infer(BuildContext& ctx, TermShape x) const override;
  torch::Tensor forward(RunContext& ctx, const torch::Tensor& x) const override;
  OperationTraits traits() const override;
  OperationCost cost(const CostContext& c) const override;
  torch::Tensor forward_activated(RunContext& ctx, const torch::Tensor& x, Activation activation,
                                  double negative_slope) const override;

 private:
  torch::Tensor product(RunContext& ctx, const torch::Tensor& x, Epilogue act) const;
  std::string path_;
  std::int64_t out_;
  bool bias_;
  LinearInit init_;
};

/// torch.nn.BatchNorm1d (batch_norm) or torch.nn.LayerNorm (not batch_norm) over the channels at
/// `path`, shared by every operation naming the path (of as many channels).
class ChannelNorm final : public Operation {
 public:
  ChannelNorm(std::string path, bool batch_norm) : path_(std::move(path)), batch_(batch_norm) {}
  std::string str(const std::string& x) const override;
  TermShape infer(BuildContext& ctx, TermShape x) const override;
  torch::Tensor forward(RunContext& ctx, const torch::Tensor& x) const override;
  /// LayerNorm's kernel applies relu, elu or sigmoid before its store (BatchNorm: forward, then
  /// act).
  torch::Tensor forward_activated(RunContext& ctx, const torch::Tensor& x, Activation activation,
                                  double negative_slope) const override;
  /// LayerNorm's kernel forms x + r itself (nn::add_layer_norm).
  torch::Tensor forward_residual(RunContext& ctx, const torch::Tensor& x, const torch::Tensor& r,
                                 std::optional<Activation> activation,
                                 double negative_slope) const override;
  OperationTraits traits() const override;

 private:
  std::string path_;
  bool batch_;
};

/// The MLP (nn::Mlp) at `path`, shared by every operation naming the path (with the same
/// options). It declares its first Linear layer, which a concatenating step splits over its terms.
class MlpBlock final : public Operation {
 public:
  MlpBlock(std::string path, MlpOptions options)
      : path_(std::move(path)), options_(std::move(options)) {}
  std::string str(const std::string& x) const override;
  TermShape infer(BuildContext& ctx, TermShape x) const override;
  torch::Tensor forward(RunContext& ctx, const torch::Tensor& x) const override;
  OperationTraits traits() const override;
  OperationCost cost(const CostContext& c) const override;
  std::shared_ptr<torch::nn::LinearImpl> first_linear(RunContext& ctx) const override;
  torch::Tensor forward_after_first(RunContext& ctx, const torch::Tensor& z) const override;
  std::optional<Activation> leading_activation(RunContext& ctx) const override;
  torch::Tensor forward_after_leading_activation(RunContext& ctx,
                                                 const torch::Tensor& a) const override;

 private:
  std::string path_;
  MlpOptions options_;
};

}  // namespace builtin
}  // namespace topos::nn
