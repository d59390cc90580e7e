// topos/nn/operator_schedule/operation.hpp
// The extension point of the operator schedule: an operation defined in user code (its own
// translation unit, no edit of topos) that a term or a step applies exactly like a built-in one.
//
//   using namespace topos::nn;
//   using namespace topos::nn::ops;
//   struct Gate : Operation {  // x ⊙ σ(x W), W at `path`
//     std::string path;
//     explicit Gate(std::string p) : path(std::move(p)) {}
//     std::string str(const std::string& x) const override { return "gate(" + x + ")"; }
//     TermShape infer(BuildContext& ctx, TermShape x) const override {
//       ctx.parameter(path, {x.channels, x.channels});  // Glorot; shared if the path recurs
//       return x;                                        // same rank, same width
//     }
//     torch::Tensor forward(RunContext& ctx, const torch::Tensor& x) const override {
//       return x * torch::sigmoid(x.matmul(ctx.parameter(path)));
//     }
//   };
//   s.step(into(0).sum(from(0).via("adjacency_0").apply(Gate("gate_0"))));
//
// `infer` runs once, when the network is built: it checks what it needs (ctx.fail names the
// step), creates the parameters, buffers and submodules at their dotted paths, and returns the
// (rank, channels) the operation produces. `forward` runs at every forward; a hand-written
// backward is a torch::autograd::Function called from it (docs/schedule-tutorial.md).
#pragma once

#include "topos/nn/cochains.hpp"
#include "topos/nn/functional.hpp"
#include "topos/nn/schedule_error.hpp"
#include "topos/nn/sparse_operator.hpp"

#include <torch/torch.h>

#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <utility>
#include <vector>

namespace topos::nn {

/// An operator as schedules print it and their errors name it: `name`, or `nameᵀ` applied
/// transposed.
inline std::string operator_label(const std::string& name, bool transposed) {
  return transposed ? name + "ᵀ" : name;
}

/// A term's value while the network is built: the rank of its cells and its channels.
struct TermShape {
  int rank = 0;
  std::int64_t channels = 0;
};

/// How a new parameter is filled.
struct ParameterInit {
  enum class Kind { glorot, linear_weight, uniform, zeros, constant };
  Kind kind = Kind::glorot;
  double value = 1.414;  ///< glorot: the gain; uniform: the bound; constant: the value

  /// Glorot (Xavier) uniform with this gain: TopoModelX's default.
  static ParameterInit glorot(double gain = 1.414) { return {Kind::glorot, gain}; }
  /// torch.nn.Linear's weight: Kaiming uniform with a = √5.
  static ParameterInit linear_weight() { return {Kind::linear_weight, 0}; }
  /// torch.nn.Linear's bias: uniform in ±1/√fan_in.
  static ParameterInit linear_bias(std::int64_t fan_in) {
    return {Kind::uniform, 1 / std::sqrt(static_cast<double>(fan_in))};
  }
  static ParameterInit uniform(double bound) { return {Kind::uniform, bound}; }
  static ParameterInit zeros() { return {Kind::zeros, 0}; }
  static ParameterInit constant(double value) { return {Kind::constant, value}; }
};

/// What an operation sees while the network is built (OperatorNetwork's constructor).
class BuildContext {
 public:
  virtual ~BuildContext() = default;
  /// The step, as errors name it: "layers.0.update (into (1))".
  virtual const std::string& where() const = 0;
  /// Throws ScheduleError("<where>: <why>").
  [[noreturn]] void fail(const std::string& why) const {
    throw ScheduleError(where() + ": " + why);
  }
  /// The cochain the step writes.
  virtual const CochainKey& target() const = 0;
  /// (source rank, target rank) of a declared operator; fails, naming the step, when undeclared.
  virtual std::pair<int, int> operator_ranks(const std::string& name) const = 0;
  /// The same for the operator (or with `transposed` its transpose) applied to a term of rank
  /// `rank`: fails, naming the step, when it maps cochains of another rank.
  std::pair<int, int> operator_from(const std::string& name, int rank,
                                    bool transposed = false) const {
    auto [src, dst] = operator_ranks(name);
    if (transposed) std::swap(src, dst);
    if (src != rank)
      fail("operator '" + operator_label(name, transposed) + "' applies to rank " +
           std::to_string(src) + " cochains, not rank " + std::to_string(rank));
    return {src, dst};
  }
  /// The width of a cochain as the step reads it (before the step); fails when no input or
  /// earlier step produces it. The network keeps the steps that produce what is read here.
  virtual std::int64_t cochain_width(const CochainKey& key) = 0;
  /// The same, or nothing when no input or earlier step produces it (then it is not read).
  virtual std::optional<std::int64_t> find_width(const CochainKey& key) = 0;
  /// Does one of the step's terms start at `key`?
  virtual bool step_reads(const CochainKey& key) const = 0;
  /// Was `key` written by an earlier step (rather than given as an input)?
  virtual bool written_by_a_step(const CochainKey& key) const = 0;
  /// A parameter at a dotted path, created with `init`; a path used again must have the same
  /// shape and is the same parameter (shared weights).
  virtual void parameter(const std::string& path, const std::vector<std::int64_t>& shape,
                         ParameterInit init = ParameterInit::glorot()) = 0;
  /// A buffer at a dotted path: saved in the state_dict, not trained.
  virtual void buffer(const std::string& path, const std::vector<std::int64_t>& shape,
                      double value) = 0;
  /// A submodule at a dotted path (a torch::nn::Linear, an Mlp, ...), registered the first time
  /// and shared by every operation that names the same path (of the same type, else an error).
  /// Returns the registered one: `m`, or the module an earlier operation made at the path, whose
  /// options the caller checks against its own.
  virtual std::shared_ptr<torch::nn::Module> module(const std::string& path,
                                                    std::shared_ptr<torch::nn::Module> m) = 0;
  /// The module an earlier operation made at `path`, or null: an operation sharing a module
  /// makes a new one (which may draw random initial values) only when there is none.
  virtual std::shared_ptr<torch::nn::Module> find_module(const std::string& path) const = 0;
};

/// The interpreter's fast paths, each switchable (all on by default). Each gives the plain
/// version's numbers up to float rounding (sums in another order); a test runs every zoo model
/// and HOPNet with each on alone against all off, outputs and gradients.
struct FastPaths {
  /// Over a batch's neighbourhoods: a term's row-wise prefix (mlp, linear, activations, ...)
  /// before an aggregation runs on the source rows the neighbourhood reads only.
  TORCH_ARG(bool, row_subset) = true;
  /// Over a batch's neighbourhoods: a term's row-wise prefix that several steps of a parallel
  /// group share is computed once.
  TORCH_ARG(bool, prefix_cache) = true;
  /// Over a batch: a cochain only ever aggregated is computed on the rows aggregations read
  /// (HOPNet's edges reach it only through contacts).
  TORCH_ARG(bool, compact_cochains) = true;
  /// Over a batch: a concatenating step into an mlp applies the first Linear layer's block to a
  /// term before its sum over a neighbourhood when the term has fewer rows than the target
  /// (W Σ x = Σ W x: the aggregation deferred past the product).
  TORCH_ARG(bool, split_first_layer) = true;
  /// Over sparse operators: a filter's taps share their chains' prefixes within a group, and a
  /// source's taps are multiplied by their weights before the chains when that costs less.
  TORCH_ARG(bool, filter_taps) = true;
  /// Over sparse operators: a weight next to a sparse product runs on the side with fewer rows
  /// (A (x W) = (A x) W) when that costs less.
  TORCH_ARG(bool, reorder_products) = true;
  /// A sparse product or linear layer and the activation after it run as one kernel.
  TORCH_ARG(bool, fuse_activations) = true;
  /// Over sparse operators: a weight next to a sparse product (and the activation after them)
  /// run as one autograd node (sparse_linear_act), in the order reorder_products picks; where
  /// both orders cost the same and an activation follows, the weight last (its backward then
  /// takes the activation's derivative inside the dense kernel).
  TORCH_ARG(bool, fuse_products) = true;
  /// Attention over a sparse operator (`attend`) from per-cell scores as one autograd node
  /// (multi_head_attention_from_cells): the scores' activation, the per-target norm and every
  /// head's weighted messages in one kernel.
  TORCH_ARG(bool, fuse_attention) = true;
  /// A step's sum of two terms, or a bias, and the layer norm after it (with its activation)
  /// run as one kernel that forms the sum (add_layer_norm): a residual connection's add and a
  /// transformer block's skip term cost no autograd node and no pass of their own.
  TORCH_ARG(bool, fuse_residuals) = true;
  /// Over a batch's neighbourhoods: a sum or mean over a neighbourhood's pairs (all, or one
  /// role's) as a sparse product over them in CSR form (AggregateOptions::csr), forward and
  /// backward, instead of a gathered row per pair added up per target.
  TORCH_ARG(bool, csr_aggregation) = true;

 public:
  static FastPaths all() { return {}; }
  static FastPaths none() {
    FastPaths f;
    for (const auto& name : names()) f.set(name, false);
    return f;
  }
  /// The fast paths' names, as the setters spell them.
  static const std::vector<std::string>& names() {
    static const std::vector<std::string> n{
        "row_subset",     "prefix_cache",     "compact_cochains", "split_first_layer",
        "filter_taps",    "reorder_products", "fuse_activations", "fuse_products",
        "fuse_attention", "fuse_residuals",   "csr_aggregation"};
    return n;
  }
  /// Sets the fast path `name` (one of names(); another is an error listing them).
  FastPaths& set(const std::string& name, bool on) {
    flag(name) = on;
    return *this;
  }
  bool get(const std::string& name) const { return FastPaths(*this).flag(name); }
  /// The names of those on, comma-separated ("none" when all are off).
  std::string str() const {
    std::string on;
    for (const auto& n : names())
      if (get(n)) on += (on.empty() ? "" : ", ") + n;
    return on.empty() ? "none" : on;
  }

 private:
  bool& flag(const std::string& name) {
    if (name == "row_subset") return row_subset_;
    if (name == "prefix_cache") return prefix_cache_;
    if (name == "compact_cochains") return compact_cochains_;
    if (name == "split_first_layer") return split_first_layer_;
    if (name == "filter_taps") return filter_taps_;
    if (name == "reorder_products") return reorder_products_;
    if (name == "fuse_activations") return fuse_activations_;
    if (name == "fuse_products") return fuse_products_;
    if (name == "fuse_attention") return fuse_attention_;
    if (name == "fuse_residuals") return fuse_residuals_;
    if (name == "csr_aggregation") return csr_aggregation_;
    std::string known;
    for (const auto& n : names()) known += (known.empty() ? "" : ", ") + n;
    throw std::invalid_argument("no fast path '" + name + "' (fast paths: " + known + ")");
  }
};

/// What an operation sees while the network runs.
class RunContext {
 public:
  virtual ~RunContext() = default;
  virtual const std::string& where() const = 0;
  [[noreturn]] void fail(const std::string& why) const {
    throw ScheduleError(where() + ": " + why);
  }
  /// The cochain the step writes (its value before the step: cochain(target())).
  virtual const CochainKey& target() const = 0;
  /// A given operator by name, and its transpose (computed once per forward).
  virtual const SparseOperator& op(const std::string& name) = 0;
  virtual const SparseOperator& op_transposed(const std::string& name) = 0;
  /// A parameter or buffer made by `BuildContext::parameter` / `buffer`.
  virtual const torch::Tensor& parameter(const std::string& path) const = 0;
  /// A submodule made by `BuildContext::module`, as its type (an error if it is another).
  template <class M>
  M& module(const std::string& path) const {
    auto* m = dynamic_cast<M*>(module_at(path).get());
    if (m == nullptr) fail("module '" + path + "' is not of the type asked for");
    return *m;
  }
  /// A cochain as the step reads it (before the step); it must have been read at build time
  /// (BuildContext::cochain_width).
  virtual const torch::Tensor& cochain(const CochainKey& key) const = 0;
  virtual bool is_training() const = 0;
  /// A tensor kept for one run of the schedule (one forward, or one run_layer), shared by every
  /// operation naming the key: a random mask drawn once and used by several steps (HMPNN's
  /// dropped incidence entries, models::DroppedPattern). Undefined until an operation sets it.
  virtual torch::Tensor& scratch(const std::string& key) = 0;
  /// The network's fast paths: an operation with a fused kernel of its own runs it where its
  /// fast path is on, so that the test suite can check it against the plain version.
  virtual const FastPaths& fast_paths() const {
    static const FastPaths all;
    return all;
  }

 protected:
  virtual std::shared_ptr<torch::nn::Module> module_at(const std::string& path) const = 0;
};

/// A product by an operator (OperationTraits::product): A·x with A's values (`weighted`), or the
/// sum, mean or max of x over A's pattern (its values ignored); over Aᵀ (`transposed`); divided
/// by the operator's row sums (`row_norm`); over a batch neighbourhood, only its pairs of one
/// role (`role`, 0: all).
struct OperatorProduct {
  std::string op;
  bool transposed = false;
  bool weighted = true;
  Aggr reduce = Aggr::sum;
  bool row_norm = false;
  int role = 0;
  /// An aggregation over a neighbourhood: a weighted sum without row sums, or a pattern's
  /// sum, mean or max; what a batch neighbourhood can run.
  bool aggregation() const { return !transposed && (!weighted || !row_norm); }
};

/// What an operation declares about itself so that the network may run it faster with the same
/// numbers (OperatorNetwork::set_fast_paths). The defaults promise nothing: the operation runs
/// where it stands, on every row, and may read any cochain.
struct OperationTraits {
  /// Each output row is a function of its input row alone, the same whichever rows are given,
  /// and forward reads neither cochains nor operators. Over a batch's neighbourhoods the network
  /// may then run it on just the rows an aggregation after it reads, once for the terms of a
  /// parallel group that start with it, and in a step computed on only the rows its readers
  /// aggregate.
  bool row_wise = false;
  /// forward reads cochains through RunContext::cochain. While an operation of a step may, no
  /// cochain that step reads is computed on a subset of its rows. (Implied false when row_wise.)
  bool reads_cochains = true;
  /// The operators forward applies (RunContext::op): a term that applies an optional operator a
  /// forward leaves out is skipped (OperatorSchedule::optional_operator), as a via's is.
  std::vector<std::string> operators;
  /// The operation is apply_activation(x, *activation, negative_slope): a product before it (a via
  /// without row normalisation, a linear) applies relu, elu or sigmoid in its kernel instead of
  /// calling forward.
  std::optional<Activation> activation;
  double negative_slope = 0.01;
  /// With `str`, tells operations apart: two row-wise operations printed alike and with the same
  /// identity compute the same, so a prefix of them shared by several terms runs once. Empty:
  /// the operation object alone is its identity (no sharing between separate objects).
  std::string identity;
  /// forward(x) is x · P for the 2-D parameter P (in × out) at this path: next to a sparse
  /// product the network may run the two in the cheaper order, A (x P) = (A x) P
  /// (FastPaths::reorder_products).
  std::string right_factor;
  /// forward_activated is a fused kernel: the network calls it for this operation followed by an
  /// activation operation (FastPaths::fuse_activations).
  bool fuses_activation = false;
  /// forward_residual is a fused kernel: the network calls it with the two terms of a summing
  /// step that this operation starts the operations of, or after an operation with `row_offset`
  /// (FastPaths::fuse_residuals).
  bool fuses_residual = false;
  /// forward(x) is x + the parameter at this path, flattened to one row of x's channels (a
  /// bias): an operation after it that fuses a residual adds it in its kernel.
  std::string row_offset;
  /// forward(x) = forward_after_first(x · Wᵀ + b) for the Linear layer first_linear() returns:
  /// in a concatenating step the network may multiply each term by its block of W before the
  /// terms are summed over a neighbourhood (W [x; Σ y] = W x + Σ W y;
  /// FastPaths::split_first_layer).
  bool leading_linear = false;
  /// forward(x) is this product by an operator: over a batch's neighbourhood the network runs
  /// it as an aggregation (and may defer it, or run what precedes it on the rows it reads), and
  /// next to a right factor or an activation it may reorder or fuse it. builtin::Product.
  std::optional<OperatorProduct> product;
  /// forward_terms gives several values, each a term of the step (a polynomial filter's powers,
  /// builtin::Powers): `terms` of them, mixed by the step's filter weight; it must be a term's
  /// last operation.
  bool fans_out = false;
  std::int64_t terms = 1;
};

/// What an operation's cost is counted on (plan_str): the operand's rows, its and the result's
/// shapes, the result's rows, and the nonzeros of an operator by name (0 when not given).
struct CostContext {
  std::int64_t rows = 0;
  TermShape x, y;
  std::int64_t y_rows = 0;  ///< the result's rows: its rank's cells (0 when not known)
  std::function<std::int64_t(const std::string&)> nnz;
};

/// What forward costs on given rows (OperatorNetwork::plan_str): its FLOPs and how they were
/// counted ("dense 2·5·3·4"); flops -1 when the operation does not say.
struct OperationCost {
  std::int64_t flops = -1;
  std::string formula;
  /// A dense product's: 2·rows·in·out ("dense 2·rows·in·out").
  static OperationCost dense(std::int64_t rows, std::int64_t in, std::int64_t out) {
    return {2 * rows * in * out, "dense 2·" + std::to_string(rows) + "·" + std::to_string(in) +
                                     "·" + std::to_string(out)};
  }
  /// A product by a sparse operator's: 2·nnz·width ("sparse 2·nnz·width").
  static OperationCost sparse(std::int64_t nnz, std::int64_t width) {
    return {2 * nnz * width, "sparse 2·" + std::to_string(nnz) + "·" + std::to_string(width)};
  }
};

/// An operation written outside topos. Immutable once in a schedule: it holds options (paths,
/// widths, operator names), while parameters live in the network at their paths.
class Operation {
 public:
  virtual ~Operation() = default;
  /// Its printed form applied to `x`, the operand's printed form: "gate[g](x)".
  virtual std::string str(const std::string& x) const = 0;
  /// Build time: the checks, the parameters and the (rank, channels) produced from x's.
  virtual TermShape infer(BuildContext& ctx, TermShape x) const = 0;
  /// Run time: the operation applied to x (cells × channels). The network checks the result
  /// against what `infer` returned: as many channels, x's dtype and device, and one row per
  /// cell of the rank (as many as x has when the rank is kept).
  virtual torch::Tensor forward(RunContext& ctx, const torch::Tensor& x) const = 0;
  /// What the network may assume of it (read once, when the operation is added to a term).
  virtual OperationTraits traits() const { return {}; }
  /// Its cost (plan_str): the default says nothing.
  virtual OperationCost cost(const CostContext& c) const {
    (void)c;
    return {};
  }
  /// With traits().fans_out: the values it gives, each a term of the step.
  virtual std::vector<torch::Tensor> forward_terms(RunContext& ctx, const torch::Tensor& x) const {
    return {forward(ctx, x)};
  }
  /// With traits().fuses_activation: apply_activation(forward(x), activation, negative_slope)
  /// in one kernel; called only with a fusable activation (nn::fusable).
  virtual torch::Tensor forward_activated(RunContext& ctx, const torch::Tensor& x,
                                          Activation activation, double negative_slope) const {
    return apply_activation(forward(ctx, x), activation, negative_slope);
  }
  /// With traits().fuses_residual: forward(x + r), then the activation when one is given (a
  /// fusable one: nn::fusable), in one kernel; r is a tensor of x's shape or one row of its
  /// channels.
  virtual torch::Tensor forward_residual(RunContext& ctx, const torch::Tensor& x,
                                         const torch::Tensor& r,
                                         std::optional<Activation> activation,
                                         double negative_slope) const {
    auto y = forward(ctx, x + r);
    return activation ? apply_activation(y, *activation, negative_slope) : y;
  }
  /// With traits().leading_linear: the Linear layer forward starts with, and the rest of forward
  /// applied to that layer's output.
  virtual std::shared_ptr<torch::nn::LinearImpl> first_linear(RunContext& ctx) const {
    ctx.fail("operation " + str("x") + " declares no leading Linear layer");
  }
  virtual torch::Tensor forward_after_first(RunContext& ctx, const torch::Tensor& z) const {
    (void)z;
    ctx.fail("operation " + str("x") + " declares no leading Linear layer");
  }
  /// With traits().leading_linear: the activation forward applies right after its leading Linear
  /// layer (nullopt: none there), and the rest of forward after that activation. The network may
  /// apply a fusable one (relu, elu, sigmoid) in the first layer's product and continue with
  /// forward_after_leading_activation; without an override, it calls forward_after_first.
  virtual std::optional<Activation> leading_activation(RunContext& ctx) const {
    (void)ctx;
    return std::nullopt;
  }
  virtual torch::Tensor forward_after_leading_activation(RunContext& ctx,
                                                         const torch::Tensor& a) const {
    (void)a;
    ctx.fail("operation " + str("x") + " declares no activation after its leading Linear layer");
  }
};

}  // namespace topos::nn
