// topos/testing/conv.hpp
// TopoModelX's Conv as a module of its own: the reference the operator schedule's
// conv/attend/via chain is tested against (tests/nn/test_operator_schedule.cpp). Test support,
// not part of the installed library.
#pragma once

#include "topos/nn/functional.hpp"

#include <torch/torch.h>

#include <stdexcept>
#include <string>

namespace topos::testing {

using nn::Activation;
using nn::attention_weights;
using nn::AttentionNorm;
using nn::divide_by_row_sums;
using nn::pair_scores;
using nn::SparseOperator;
using nn::xavier_uniform;

struct ConvOptions {
  ConvOptions(std::int64_t in, std::int64_t out) : in_channels_(in), out_channels_(out) {}
  TORCH_ARG(std::int64_t, in_channels);
  TORCH_ARG(std::int64_t, out_channels);
  TORCH_ARG(bool, aggr_norm) = false;  ///< divide by the operator's row sums
  TORCH_ARG(Activation, update_func) = Activation::none;
  TORCH_ARG(bool, att) = false;  ///< elu attention on [x_source_j, x_target_i]
  TORCH_ARG(bool, with_linear_transform) = true;
};

/// TopoModelX's Conv: y = update(A · (x W)) with A's values (optionally times attention), where
/// A is target × source. Parameters "weight" (in × out) and, with att, "att_weight" (2·in).
class ConvImpl : public torch::nn::Module {
 public:
  explicit ConvImpl(ConvOptions o) : options(std::move(o)) {
    if (!options.with_linear_transform() && options.in_channels() != options.out_channels())
      throw std::invalid_argument(
          "Conv: without a linear transform in_channels must equal out_channels");
    if (options.with_linear_transform())
      weight = register_parameter("weight",
                                  torch::empty({options.in_channels(), options.out_channels()}));
    if (options.att())
      att_weight = register_parameter("att_weight", torch::empty({2 * options.in_channels()}));
    reset_parameters();
  }
  void reset_parameters() {
    if (weight.defined()) xavier_uniform(weight);
    if (att_weight.defined()) xavier_uniform(att_weight);
  }
  torch::Tensor forward(const torch::Tensor& x_source, const SparseOperator& A,
                        const torch::Tensor& x_target = {}) {
    if (x_source.size(1) != options.in_channels())
      throw std::invalid_argument("Conv: features have " + std::to_string(x_source.size(1)) +
                                  " channels, the layer takes " +
                                  std::to_string(options.in_channels()));
    SparseOperator N = A;
    if (options.att()) {
      const auto C = options.in_channels();
      const auto raw =
          pair_scores(A, x_source, att_weight.narrow(0, 0, C),
                      x_target.defined() ? x_target : x_source, att_weight.narrow(0, C, C));
      N = A.with_values(attention_weights(A, raw, Activation::elu, 0, AttentionNorm::none) *
                        A.values.to(raw.scalar_type()));
    }
    const auto m = weight.defined() ? x_source.matmul(weight) : x_source;
    auto y = spmm(N, m);
    if (options.aggr_norm()) y = divide_by_row_sums(N, y);
    return apply_activation(y, options.update_func());
  }
  ConvOptions options;
  torch::Tensor weight, att_weight;
};
TORCH_MODULE(Conv);

}  // namespace topos::testing
