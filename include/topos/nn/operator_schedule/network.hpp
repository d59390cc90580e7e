// topos/nn/operator_schedule/network.hpp
// OperatorNetwork: the module that runs an OperatorSchedule. Built from a schedule, it infers
// every cochain's width, checks each step (build-inl.hpp) and creates the parameters at the
// schedule's dotted paths (parameters-inl.hpp); its forward interprets the steps
// (interpreter-inl.hpp).
#pragma once

#include "topos/config.hpp"
#include "topos/nn/operator_schedule/builder.hpp"

#include <torch/torch.h>

#include <cstdint>
#include <map>
#include <set>
#include <string>
#include <utility>
#include <vector>

namespace topos::nn {

namespace detail {
class NetworkBuildContext;
class NetworkRunContext;
}  // namespace detail

/// Runs an OperatorSchedule; its parameters sit at the schedule's dotted paths.
class OperatorNetworkImpl : public torch::nn::Module {
 public:
  /// Validates the schedule and creates its parameters; a ScheduleError names the faulty step.
  explicit OperatorNetworkImpl(OperatorSchedule schedule);

  /// Inputs and operators by name -> outputs by name. An operator whose shape does not fit the
  /// cochains it is applied to is an error naming the step.
  std::map<std::string, torch::Tensor> forward(
      const std::map<std::string, torch::Tensor>& inputs,
      const std::map<std::string, SparseOperator>& operators);

  /// The cochains the inputs give, checked against the schedule's inputs.
  Cochains input_cochains(const std::map<std::string, torch::Tensor>& inputs) const;

  /// Runs the steps of one named layer (OperatorSchedule::layer) on h, all of them: a model
  /// whose complex changes between layers (CAN's pooling keeps some cells and restricts the
  /// operators to them) runs its schedule layer by layer. forward() runs only the steps whose
  /// results a later step or an output reads.
  void run_layer(Cochains& h, const std::map<std::string, SparseOperator>& operators,
                 const std::string& name);

  std::map<std::string, torch::Tensor> output_cochains(const Cochains& h) const;

  /// The outputs in the order given (a model's positional return value).
  std::vector<torch::Tensor> run(const std::map<std::string, torch::Tensor>& inputs,
                                 const std::map<std::string, SparseOperator>& operators,
                                 const std::vector<std::string>& names);

  const OperatorSchedule& schedule() const { return schedule_; }
  /// The parameter (or buffer) at a schedule path.
  const torch::Tensor& parameter(const std::string& path) const;

 private:
  OperatorSchedule schedule_;
  std::map<std::string, torch::Tensor> params_;  // parameters and buffers by path
  std::set<std::string> buffers_;                // the paths of params_ that are buffers
  std::map<std::string, torch::nn::BatchNorm1d> batch_norms_;
  std::map<std::string, torch::nn::LayerNorm> layer_norms_;
  std::map<std::string, std::shared_ptr<torch::nn::Module>> modules_;  // user operations' modules
  std::vector<std::vector<bool>> live_;  // per group and step: read by a later step or an output

  friend class detail::NetworkBuildContext;
  friend class detail::NetworkRunContext;
  void run_groups(Cochains& h, const std::map<std::string, SparseOperator>& operators,
                  std::size_t begin, std::size_t end, bool live_only);

  // --- the interpreter (interpreter-inl.hpp) -------------------------------------------------
  struct Operators;  // the given operators, their transposes and this forward's dropped ones
  std::size_t apply_fused(const std::string& where, const CochainKey& target,
                          const std::vector<TermOp>& list, std::size_t i, torch::Tensor& x,
                          Operators& ops, const Cochains& h);
  torch::Tensor apply(const std::string& where, const CochainKey& target, const TermOp& t,
                      torch::Tensor x, Operators& ops, const Cochains& h);
  torch::Tensor attend(const std::string& where, const CochainKey& target, const TermOp& t,
                       const torch::Tensor& x, Operators& ops, const Cochains& h);
  torch::Tensor run_step(const OperatorStep& s, const Cochains& h, Operators& ops);

  // --- construction: channel and rank inference, parameters (build-, parameters-inl) -
  std::pair<torch::nn::Module*, std::string> owner_of(const std::string& path);
  void make_parameter(const std::string& where, const std::string& path,
                      std::vector<std::int64_t> shape, ParameterInit init, bool trainable = true);
  void make_module(const std::string& where, const std::string& path,
                   std::shared_ptr<torch::nn::Module> m);
  void make_norm(const std::string& where, const TermOp& t, std::int64_t channels);
  TermShape infer(detail::NetworkBuildContext& ctx, const TermOp& t, TermShape x);
  TermShape infer_attend(detail::NetworkBuildContext& ctx, const TermOp& t, TermShape x);
  void validate_and_create();
};
TORCH_MODULE(OperatorNetwork);

}  // namespace topos::nn

#ifdef TOPOS_HEADER_ONLY
#include "topos/nn/operator_schedule/build-inl.hpp"
#include "topos/nn/operator_schedule/interpreter-inl.hpp"
#endif
