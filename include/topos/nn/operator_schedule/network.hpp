// topos/nn/operator_schedule/network.hpp
// OperatorNetwork: the module that runs an OperatorSchedule. Built from a schedule, it infers
// every cochain's width, checks each step (build-inl.hpp) and creates the parameters at the
// schedule's dotted paths (parameters-inl.hpp); its forward checks its arguments
// (checks-inl.hpp), plans what to run (plan.hpp, plan-inl.hpp) and runs the plan
// (interpreter-inl.hpp; a filter's taps: filter-inl.hpp).
#pragma once

#include "topos/config.hpp"
#include "topos/core/sparse_matrix.hpp"  // detail::never, detail::Unavailable
#include "topos/nn/aggregate.hpp"
#include "topos/nn/complex_batch.hpp"
#include "topos/nn/helper_thread.hpp"
#include "topos/nn/kernels/packed_weights.hpp"  // helpers keep the caller's packed weights
#include "topos/nn/operator_schedule/builder.hpp"
#include "topos/nn/operator_schedule/plan.hpp"

#include <torch/torch.h>

#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <set>
#include <stdexcept>
#include <string>
#include <type_traits>
#include <utility>
#include <vector>

namespace topos::nn {

namespace detail {
class NetworkBuildContext;
class NetworkRunContext;
struct FilterTaps;

/// A term's operations followed by a step's (a step of one term runs them as one list, so that
/// a product ending the term fuses with the step's activation), without copying them.
class OperationSeq {
 public:
  OperationSeq(const std::vector<TermOp>& first,  // NOLINT: a list is a sequence
               const std::vector<TermOp>* then = nullptr)
      : first_(first), then_(then) {}
  std::size_t size() const { return first_.size() + (then_ ? then_->size() : 0); }
  const TermOp& operator[](std::size_t i) const {
    return i < first_.size() ? first_[i] : (*then_)[i - first_.size()];
  }

 private:
  const std::vector<TermOp>& first_;
  const std::vector<TermOp>* then_;
};
}  // namespace detail

/// Runs an OperatorSchedule; its parameters sit at the schedule's dotted paths.
class OperatorNetworkImpl : public torch::nn::Module {
 public:
  /// Validates the schedule and creates its parameters; a ScheduleError names the faulty step.
  explicit OperatorNetworkImpl(OperatorSchedule schedule);
  // Out of line, so that it is the class's key function: the vtable, and the destruction of
  // every member it reaches, are compiled once in topos::nn, not in each model's translation
  // unit (a third of a small model's compile time).
  ~OperatorNetworkImpl() override;

  /// Inputs and operators by name -> outputs by name, checked on entry against the schedule: a
  /// dtype or device other than the parameters', or an operator whose rows or columns are not the
  /// cells of its target or source rank, is an error naming the argument; a name the schedule does
  /// not declare is ignored with a warning (an error where a declared optional operator is then
  /// missing: likely its misspelling). Inputs may carry leading batch dimensions, (..., cells,
  /// channels), the same for every input (TopoModelX's SCoNe trains on batches of trajectories):
  /// each element runs through the network and the outputs come back with the same leading
  /// dimensions.
  std::map<std::string, torch::Tensor> forward(
      const std::map<std::string, torch::Tensor>& inputs,
      const std::map<std::string, SparseOperator>& operators);

  /// The same over a batch of complexes: an operator not given in `operators` is the batch's
  /// neighbourhood of that name (aggregated by index, with its values, roles and backward
  /// values), and `when_nonempty` steps see which complexes have cells of a rank.
  /// (A template only so that `forward(inputs, {})` still means no operators.)
  template <class Batch, class = std::enable_if_t<std::is_same_v<Batch, ComplexBatch>>>
  std::map<std::string, torch::Tensor> forward(
      const std::map<std::string, torch::Tensor>& inputs, const Batch& batch,
      const std::map<std::string, SparseOperator>& operators = {}) {
    return forward_batch(inputs, batch, operators);
  }
  std::map<std::string, torch::Tensor> forward_batch(
      const std::map<std::string, torch::Tensor>& inputs, const ComplexBatch& batch,
      const std::map<std::string, SparseOperator>& operators);

  /// The operators of `all` that the schedule declares, for a caller that holds a larger
  /// dictionary (a dataset's operators for every model).
  std::map<std::string, SparseOperator> declared_operators(
      const std::map<std::string, SparseOperator>& all) const;

  /// The cochains the inputs give, checked against the schedule's inputs.
  Cochains input_cochains(const std::map<std::string, torch::Tensor>& inputs) const;

  /// Runs the steps of one named layer (OperatorSchedule::layer) on h, all of them: a model
  /// whose complex changes between layers (CAN's pooling keeps some cells and restricts the
  /// operators to them) runs its schedule layer by layer. forward() runs only the steps whose
  /// results a later step or an output reads.
  void run_layer(Cochains& h, const std::map<std::string, SparseOperator>& operators,
                 const std::string& name, const ComplexBatch* batch = nullptr);

  std::map<std::string, torch::Tensor> output_cochains(const Cochains& h) const;

  /// Internal now: a layer runs with run_layer, the whole schedule with forward. (A template, so
  /// that a call says so instead of proposing the private overload.)
  template <class... Args>
  topos::detail::Unavailable run_groups(Args&&...) {
    static_assert(topos::detail::never<Args...>,
                  "OperatorNetwork::run_groups is internal: write run_layer(h, operators, "
                  "\"<layer>\", batch) to run one layer, or forward(inputs, operators) to run "
                  "the whole schedule");
    return {};
  }

  /// The outputs in the order given (a model's positional return value).
  std::vector<torch::Tensor> run(const std::map<std::string, torch::Tensor>& inputs,
                                 const std::map<std::string, SparseOperator>& operators,
                                 const std::vector<std::string>& names);

  /// What forward(inputs, operators) will run, step by step: each live step's terms (a term
  /// that applies an optional operator left out is skipped) and operations, each with its FLOPs
  /// on this complex: a product by a sparse operator (via, attention's messages, each power of a
  /// polynomial filter) 2·nnz·width, a dense product (weight, linear, each Linear of an mlp, a
  /// filter's taps) 2·rows·in·out; other operations are listed without. The plain order (with
  /// the fast paths off: reorder_products may run a product on the other side).
  std::string plan_str(const std::map<std::string, torch::Tensor>& inputs,
                       const std::map<std::string, SparseOperator>& operators) const {
    return plan(inputs, operators).str();
  }

  /// The plan forward(inputs, operators) runs with the fast paths on now: the live steps, each
  /// with its route (StepRoute), terms and operations, and their FLOPs on this complex counted as
  /// plan_str says (Plan::str prints it, Plan::total_flops sums it) and the buffers they write
  /// (PlanLine::rows × channels, Plan::total_values).
  Plan plan(const std::map<std::string, torch::Tensor>& inputs,
            const std::map<std::string, SparseOperator>& operators) const {
    return plan_over(inputs, operators, nullptr);
  }
  /// The plan forward(inputs, batch, operators) runs: a neighbourhood's pairs count as its
  /// nonzeros. (A template for the reason forward's is.)
  template <class Batch, class = std::enable_if_t<std::is_same_v<Batch, ComplexBatch>>>
  Plan plan(const std::map<std::string, torch::Tensor>& inputs, const Batch& batch,
            const std::map<std::string, SparseOperator>& operators = {}) const {
    return plan_batch(inputs, batch, operators);
  }
  Plan plan_batch(const std::map<std::string, torch::Tensor>& inputs, const ComplexBatch& batch,
                  const std::map<std::string, SparseOperator>& operators) const {
    return plan_over(inputs, operators, &batch);
  }

  const OperatorSchedule& schedule() const { return schedule_; }
  /// The parameter (or buffer) at a schedule path.
  const torch::Tensor& parameter(const std::string& path) const;
  /// The MLP at a schedule path (OperatorSchedule's mlp).
  Mlp mlp(const std::string& path) const;

  /// All the fast paths on or off (FastPaths::all / none); off runs the plain version, the
  /// same numbers up to float rounding, slower (for checking the fast paths).
  void set_fast_paths(bool on) { fast_ = on ? FastPaths::all() : FastPaths::none(); }
  /// Each fast path on its own (FastPaths): `net->fast_paths().prefix_cache(false)`.
  FastPaths& fast_paths() { return fast_; }
  const FastPaths& fast_paths() const { return fast_; }

  /// Threads that the steps of one parallel group share in a CPU forward outside training (1,
  /// the default: the calling thread alone). With n > 1 the calling thread and n - 1 helpers
  /// take the group's independent steps in turn (steps that may share a cached term prefix stay
  /// together); in a group that runs as one, a step's terms that aggregate over a batch's
  /// neighbourhood after row-wise operations run at once where two of them read 32 rows or more
  /// (terms that share a prefix together). The same outputs bit for bit, gradients equal up to
  /// the order of their sums. A training forward keeps one thread, so that its random draws
  /// (dropout) keep their order. Keep LibTorch's intra-op threads at 1 beside it; an Operation's
  /// forward must then not write state that another step of its group, or another term of its
  /// step, reads (scratch included). n < 1 is an error.
  void step_threads(int n);
  int step_threads() const { return step_threads_; }
  /// How many parallel groups this network's forwards have run on more than one thread since it
  /// was built, and how many of its steps ran their terms at once: 0 and 0 mean step_threads
  /// never took effect (nothing to share, or training forwards only). For tests and profiles:
  /// read them while no forward of this network runs.
  std::int64_t split_groups() const { return split_groups_; }
  std::int64_t split_steps() const { return split_steps_; }

 private:
  OperatorSchedule schedule_;
  std::map<std::string, torch::Tensor> params_;  // parameters and buffers by path
  std::set<std::string> buffers_;                // the paths of params_ that are buffers
  std::map<std::string, std::shared_ptr<torch::nn::Module>> modules_;  // operations' modules
  std::vector<std::vector<bool>> live_;  // per group and step: read by a later step or an output
  // Steps whose target only aggregations read, by (group, step): the operators they read through.
  std::map<std::pair<std::size_t, std::size_t>, std::vector<std::string>> compact_steps_;
  // Each Operation of the schedule, by its place: the rank it is applied to and the (rank,
  // channels) its infer returned, against which its forward's result is checked.
  std::map<const TermOp*, std::pair<int, TermShape>> inferred_;
  // For plan_str: each operation's result, each term's source width, each step's mixed width.
  std::map<const TermOp*, TermShape> shapes_;
  std::map<const ops::Term*, std::int64_t> term_width_;
  std::map<const OperatorStep*, std::int64_t> mix_width_;
  FastPaths fast_;
  int step_threads_ = 1;
  std::vector<std::unique_ptr<detail::HelperThread>> helpers_;  // step_threads_ - 1, made lazily
  std::int64_t split_groups_ = 0, split_steps_ = 0;  // counted by the forward holding the helpers

  // --- planning (plan-inl.hpp, cost-inl.hpp) ---------------------------------------------------
  struct Operators;  // the given operators, their transposes and this forward's dropped ones
  /// The optional operators a forward over `operators` (and `batch`'s neighbourhoods) lacks.
  std::set<std::string> absent_operators(const std::map<std::string, SparseOperator>& operators,
                                         const ComplexBatch* batch) const;
  /// The routes for a forward over `ops` with the fast paths on now (no FLOPs).
  Plan make_plan(const Operators& ops) const;
  /// plan and plan_batch: the arguments checked, the cells and nonzeros counted, the plan made.
  Plan plan_over(const std::map<std::string, torch::Tensor>& inputs,
                 const std::map<std::string, SparseOperator>& operators,
                 const ComplexBatch* batch) const;
  /// make_plan's, kept per fast paths and kind of each declared operator (given, a neighbourhood
  /// of the batch, left out): planning is string work a forward need not repeat.
  const Plan& plan_for(const Operators& ops);
  std::map<std::string, std::shared_ptr<const Plan>> plans_;
  std::mutex plans_mutex_;
  PlannedTerm plan_term(const ops::Term& term, const Operators& ops) const;
  StepRoute route_of(const OperatorStep& s, const std::vector<PlannedTerm>& terms,
                     const Operators& ops) const;
  /// The plan's lines with their FLOPs: `cells` per rank, `nnz` of each operator by name.
  Plan plan_with_costs(const Operators& ops, const std::map<int, std::int64_t>& cells,
                       const std::function<std::int64_t(const std::string&)>& nnz) const;
  PlanLine op_cost(const TermOp& t, TermShape x, const std::map<int, std::int64_t>& cells,
                   const std::function<std::int64_t(const std::string&)>& nnz) const;

  friend class detail::NetworkBuildContext;
  friend class detail::NetworkRunContext;
  void run_range(Cochains& h, const std::map<std::string, SparseOperator>& operators,
                 const ComplexBatch* batch, std::size_t begin, std::size_t end, bool live_only);
  struct Written;  // a step's value and where it goes
  /// A group's live steps on the calling thread and, where step_threads allows, the helpers.
  std::vector<Written> run_group(const std::vector<PlannedStep>& steps, const Cochains& snapshot,
                                 Operators& ops, bool live_only);

  // --- the checks at the boundaries (checks-inl.hpp) ------------------------------------------
  /// A forward's arguments against the schedule: names declared, one dtype and device (the
  /// parameters'), each rank's cells the same in every input and operator (rows: the target
  /// rank's, columns: the source rank's).
  void check_arguments(const std::map<std::string, torch::Tensor>& inputs,
                       const std::map<std::string, SparseOperator>& operators,
                       const ComplexBatch* batch) const;
  /// Undeclared names: a warning, or an error where a declared optional operator is missing.
  void check_names(const std::map<std::string, torch::Tensor>& inputs,
                   const std::map<std::string, SparseOperator>& operators,
                   const ComplexBatch* batch) const;
  void check_dtypes(const std::map<std::string, torch::Tensor>& inputs,
                    const std::map<std::string, SparseOperator>& operators) const;
  void check_cells(const std::map<std::string, torch::Tensor>& inputs,
                   const std::map<std::string, SparseOperator>& operators,
                   const ComplexBatch* batch) const;
  mutable std::set<std::string> warned_;  // the undeclared names already warned about
  // check_dtypes's reference when the network has no parameter of its own: a submodule's, found
  // once when the network is built (walking them, named_parameters, cost 3-4 % of a HOPNet
  // rollout step), then only read, also by workers running forwards at once. A parameter keeps
  // its identity when the module moves (to() sets its data in place).
  torch::Tensor first_submodule_parameter() const;
  torch::Tensor dtype_reference_;

  // --- the interpreter (interpreter-inl.hpp) -------------------------------------------------
  std::size_t apply_fused(const std::string& where, const CochainKey& target,
                          const detail::OperationSeq& list, std::size_t i, torch::Tensor& x,
                          Operators& ops, const Cochains& h);
  torch::Tensor apply(const std::string& where, const CochainKey& target, const TermOp& t,
                      torch::Tensor x, Operators& ops, const Cochains& h);
  /// t's forward on x (with `residual`: on x + residual, forward_residual), with `activation`
  /// (an activation operation t fuses) applied in the same kernel.
  torch::Tensor run_operation(const std::string& where, const CochainKey& target, const TermOp& t,
                              const torch::Tensor& x, Operators& ops, const Cochains& h,
                              const TermOp* activation, const torch::Tensor& residual = {});
  /// list[j] when it is an activation that an operation before it may fuse (fuse_activations).
  const TermOp* fusable_activation_at(const detail::OperationSeq& list, std::size_t j) const;
  struct TermValue;  // a term's value, or its rows and the aggregation still to apply
  using PrefixCache = std::map<std::string, torch::Tensor>;  // per group: shared term prefixes
  TermValue evaluate_term(const std::string& where, const CochainKey& target, const PlannedTerm& t,
                          const Cochains& h, Operators& ops, PrefixCache& cache, bool may_defer);
  torch::Tensor run_step(const PlannedStep& p, const Cochains& h, Operators& ops,
                         PrefixCache& cache);
  torch::Tensor run_chain(const PlannedStep& p, const Cochains& h, Operators& ops);
  struct StepTerms;  // the values a step mixes
  /// A term's value(s) added to `out`, or with `out.W` its product by its block of W.
  void evaluate_into(const std::string& where, const CochainKey& target, const PlannedTerm& term,
                     const Cochains& h, Operators& ops, PrefixCache& cache, StepTerms& out);
  /// What LibTorch would say of the terms' rows and dtypes, said with the terms.
  void check_terms(const std::string& where, const StepTerms& t) const;
  /// The step's terms mixed (with a split leading Linear layer, through its operation).
  torch::Tensor mix(const std::string& where, const OperatorStep& s, StepTerms& terms,
                    const Cochains& h, Operators& ops);
  /// A filter step whose terms are chains of sparse products, each source's taps weighted on
  /// the side with fewer rows, then `act` (may be none); undefined where the step is not one
  /// (the general path runs it).
  torch::Tensor run_filter(const std::string& where, const OperatorStep& s, const Cochains& h,
                           Operators& ops, PrefixCache& cache, Epilogue act);
  /// The filter's taps as chains of sparse products; false where they are not.
  bool filter_chains(const std::string& where, detail::FilterTaps& f, Operators& ops);
  /// The taps not `skip`ped, each distinct prefix once, combined with their slices of W onto
  /// `base` (may be undefined), then `act`; undefined where every tap is skipped.
  torch::Tensor other_taps(const std::string& where, const detail::FilterTaps& f,
                           const std::vector<bool>& skip, const torch::Tensor& W, Operators& ops,
                           PrefixCache& cache, Epilogue act, const torch::Tensor& base);
  /// A compact step (compact_steps_) on the rows its readers aggregate: (value, each row's
  /// compact row or -1), or (undefined, undefined) where it must run on every row.
  std::pair<torch::Tensor, torch::Tensor> run_compact(const PlannedStep& p, const Cochains& h,
                                                      Operators& ops, PrefixCache& cache);
  torch::Tensor guard(const std::string& where, const OperatorStep& s, torch::Tensor updated,
                      const Cochains& h, const Operators& ops) const;

  // --- construction: channel and rank inference, parameters (build-, parameters-inl) -
  std::pair<torch::nn::Module*, std::string> owner_of(const std::string& path);
  void make_parameter(const std::string& where, const std::string& path,
                      std::vector<std::int64_t> shape, ParameterInit init, bool trainable = true);
  std::shared_ptr<torch::nn::Module> make_module(const std::string& where, const std::string& path,
                                                 std::shared_ptr<torch::nn::Module> m);
  TermShape infer(detail::NetworkBuildContext& ctx, const TermOp& t, TermShape x);
  void validate_and_create();
  std::map<CochainKey, std::int64_t> declared_widths() const;
  void check_optional_uses(const std::string& where, const OperatorStep& s) const;
  std::pair<std::int64_t, std::int64_t> infer_terms(detail::NetworkBuildContext& ctx,
                                                    const OperatorStep& s);
  std::int64_t infer_step(detail::NetworkBuildContext& ctx, const OperatorStep& s);
  void check_outputs(const std::map<CochainKey, std::int64_t>& width,
                     const std::set<std::string>& applied) const;
  void find_compact_steps(const std::vector<std::vector<std::set<CochainKey>>>& reads);
  void find_live_steps(const std::vector<std::vector<std::set<CochainKey>>>& reads);
};
TORCH_MODULE(OperatorNetwork);

}  // namespace topos::nn

#ifdef TOPOS_HEADER_ONLY
#include "topos/nn/operator_schedule/build-inl.hpp"
#include "topos/nn/operator_schedule/checks-inl.hpp"
#include "topos/nn/operator_schedule/cost-inl.hpp"
#include "topos/nn/operator_schedule/filter-inl.hpp"
#include "topos/nn/operator_schedule/interpreter-inl.hpp"
#include "topos/nn/operator_schedule/plan-inl.hpp"
#endif
