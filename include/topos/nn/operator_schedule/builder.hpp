// topos/nn/operator_schedule/builder.hpp
// The operator schedule's vocabulary: a term (`from`) and the operations it chains, a step
// (`into`) that mixes its terms, and the schedule of steps with its inputs, operators and
// outputs. Building one checks nothing; OperatorNetwork (network.hpp) checks and runs it.
#pragma once

#include "topos/config.hpp"
#include "topos/nn/cochains.hpp"
#include "topos/nn/functional.hpp"
#include "topos/nn/mlp.hpp"
#include "topos/nn/operator_schedule/elementwise.hpp"
#include "topos/nn/operator_schedule/gnn.hpp"
#include "topos/nn/operator_schedule/layers.hpp"
#include "topos/nn/operator_schedule/operation.hpp"
#include "topos/nn/operator_schedule/products.hpp"
#include "topos/nn/schedule_error.hpp"

#include <torch/torch.h>

#include <algorithm>
#include <cmath>
#include <map>
#include <memory>
#include <optional>
#include <set>
#include <sstream>
#include <string>
#include <utility>
#include <vector>

namespace topos::nn {

/// One operation of a term or of a step's tail: an Operation (the built-ins of products.hpp,
/// layers.hpp, elementwise.hpp and gnn.hpp, or a user's) and its traits, read once, which the
/// network's fast paths consult.
struct TermOp {
  TermOp();
  // The special members are compiled once (builder-inl.hpp): steps copy and move their
  // operations, and a user's translation unit would otherwise generate that code for every one
  // of these members (a third of a small model's compile time).
  TermOp(const TermOp&);
  TermOp(TermOp&&) noexcept;
  TermOp& operator=(const TermOp&);
  TermOp& operator=(TermOp&&) noexcept;
  ~TermOp();
  std::shared_ptr<const Operation> operation;
  OperationTraits traits;  ///< operation->traits()
};

namespace detail {
/// The operations of a term or step, with its container code compiled once (builder-inl.hpp).
class OperationList {
 public:
  OperationList();
  OperationList(const OperationList&);
  OperationList(OperationList&&) noexcept;
  OperationList& operator=(const OperationList&);
  OperationList& operator=(OperationList&&) noexcept;
  ~OperationList();
  const std::vector<TermOp>& operations() const { return ops_; }

 protected:
  void push(TermOp t);
  /// A custom TermOp holding `op` and its traits.
  void push_operation(std::shared_ptr<const Operation> op);
  std::vector<TermOp> ops_;
};
}  // namespace detail

namespace ops {

/// The fluent operations shared by terms (which start at a cochain) and steps (whose operations
/// act on the mixed terms). Every method has an &&-qualified twin: called on a temporary
/// (`from(0).via("A").act(u)`) the chain stays an rvalue, so it moves into `sum`, `step` or a
/// return without std::move. The twins are written out, not forwarded, so that braced arguments
/// (`bias(path, {1, C})`) still convert.
template <class Derived>
class Chain : public detail::OperationList {
 public:
  /// A · x, optionally divided by A's row sums (TopoModelX Conv's aggr_norm).
  Derived& via(std::string op, bool row_norm = false) & {
    OperatorProduct p;
    p.op = std::move(op);
    p.row_norm = row_norm;
    return apply(builtin::Product(std::move(p)));
  }
  Derived&& via(std::string op, bool row_norm = false) && {
    return std::move(via(std::move(op), row_norm));
  }
  /// Aᵀ · x (the transpose is made once per forward), optionally divided by Aᵀ's row sums.
  Derived& via_t(std::string op, bool row_norm = false) & {
    OperatorProduct p;
    p.op = std::move(op);
    p.transposed = true;
    p.row_norm = row_norm;
    return apply(builtin::Product(std::move(p)));
  }
  Derived&& via_t(std::string op, bool row_norm = false) && {
    return std::move(via_t(std::move(op), row_norm));
  }
  /// Sum (or mean) over A's sparsity pattern, its values ignored (torch_scatter's messages).
  Derived& pattern(std::string op, Aggr aggr = Aggr::sum) & {
    OperatorProduct p;
    p.op = std::move(op);
    p.weighted = false;
    p.reduce = aggr;
    return apply(builtin::Product(std::move(p)));
  }
  Derived&& pattern(std::string op, Aggr aggr = Aggr::sum) && {
    return std::move(pattern(std::move(op), aggr));
  }
  /// x · W with W (in × out) at `path` (Glorot-initialised with `gain`).
  Derived& weight(std::string path, std::int64_t out, double gain = 1.414) & {
    return apply(builtin::Weight(std::move(path), out, gain));
  }
  Derived&& weight(std::string path, std::int64_t out, double gain = 1.414) && {
    return std::move(weight(std::move(path), out, gain));
  }
  /// TopoModelX's Conv weight: weight(path + ".weight", out).
  Derived& conv(const std::string& path, std::int64_t out) & {
    return weight(path + ".weight", out);
  }
  Derived&& conv(const std::string& path, std::int64_t out) && {
    return std::move(conv(path, out));
  }
  /// torch.nn.Linear at `path`: parameters path.weight (out × in) and path.bias, initialised as
  /// `init` says (LinearInit).
  Derived& linear(std::string path, std::int64_t out, bool bias = true,
                  LinearInit init = LinearInit::torch) & {
    return apply(builtin::Linear(std::move(path), out, bias, init));
  }
  Derived&& linear(std::string path, std::int64_t out, bool bias = true,
                   LinearInit init = LinearInit::torch) && {
    return std::move(linear(std::move(path), out, bias, init));
  }
  Derived& act(Activation u, double negative_slope = 0.01) & {
    return apply(builtin::Activate(u, negative_slope));
  }
  Derived&& act(Activation u, double negative_slope = 0.01) && {
    return std::move(act(u, negative_slope));
  }
  /// Dropout at rate p. Rate 0 is no operation and is left out, so that what is around it fuses
  /// (a Linear and the relu after it: a TopoBench model run without dropout).
  Derived& dropout(double p) & {
    return p == 0 ? static_cast<Derived&>(*this) : apply(builtin::Dropout(p));
  }
  Derived&& dropout(double p) && { return std::move(dropout(p)); }
  Derived& unit_rows() & { return apply(builtin::UnitRows()); }
  Derived&& unit_rows() && { return std::move(unit_rows()); }
  /// torch.nn.BatchNorm1d over the channels at `path` (weight, bias, running statistics).
  Derived& batch_norm(std::string path) & {
    return apply(builtin::ChannelNorm(std::move(path), /*batch_norm=*/true));
  }
  Derived&& batch_norm(std::string path) && { return std::move(batch_norm(std::move(path))); }
  /// torch.nn.BatchNorm1d at `path` whose batch statistics are those of the rows of the cochains
  /// `union_of` together, x being their part `part` (a GNN's norm on the union graph of an
  /// inter-rank neighbourhood; gnn.hpp). Apply it to every part.
  Derived& batch_norm(std::string path, std::vector<CochainKey> union_of, std::size_t part) & {
    return apply(builtin::UnionBatchNorm(std::move(path), std::move(union_of), part));
  }
  Derived&& batch_norm(std::string path, std::vector<CochainKey> union_of, std::size_t part) && {
    return std::move(batch_norm(std::move(path), std::move(union_of), part));
  }
  /// PyG's GCNConv propagation over `op`'s pattern with self-loops: over one rank's graph, or one
  /// side of the union graph of an inter-rank neighbourhood (GcnPart, gnn.hpp).
  Derived& gcn(std::string op, GcnPart part = GcnPart::graph) & {
    return apply(builtin::GcnPropagation(std::move(op), part));
  }
  Derived&& gcn(std::string op, GcnPart part = GcnPart::graph) && {
    return std::move(gcn(std::move(op), part));
  }
  /// PyG's GATConv attention (after its `lin`) over `op`'s pattern with self-loops: over one
  /// rank's graph, or the targets or sources of the union graph of an inter-rank neighbourhood;
  /// its vectors at `path`.att_src and `path`.att_dst (GatOptions, gnn.hpp).
  Derived& gat(std::string op, std::string path, GatOptions o = {}) & {
    return apply(builtin::GatAttention(std::move(op), std::move(path), std::move(o)));
  }
  Derived&& gat(std::string op, std::string path, GatOptions o = {}) && {
    return std::move(gat(std::move(op), std::move(path), std::move(o)));
  }
  /// torch.nn.LayerNorm over the channels at `path`.
  Derived& layer_norm(std::string path) & {
    return apply(builtin::ChannelNorm(std::move(path), /*batch_norm=*/false));
  }
  Derived&& layer_norm(std::string path) && { return std::move(layer_norm(std::move(path))); }
  /// x · factor (CAN's skip connection scales its linear map by 1 + 1e-6).
  Derived& scale(double factor) & { return apply(builtin::Scale(factor)); }
  Derived&& scale(double factor) && { return std::move(scale(factor)); }
  /// One map per head, side by side: [x W_1 | ... | x W_H] with W (heads × in × out) at `path`,
  /// TopoModelX's multi-head layout (AllSetTransformer's K and V).
  Derived& head_weights(std::string path, std::int64_t heads, std::int64_t out,
                        double gain = 1.414) & {
    return apply(builtin::HeadWeights(std::move(path), heads, out, gain));
  }
  Derived&& head_weights(std::string path, std::int64_t heads, std::int64_t out,
                         double gain = 1.414) && {
    return std::move(head_weights(std::move(path), heads, out, gain));
  }
  /// x + b on every row, b at `path` of `shape` (default: a vector), flattened; zeros when new,
  /// or with a `gain` Glorot-initialised (HNHN's biases, 1 × channels).
  Derived& bias(std::string path, std::vector<std::int64_t> shape = {}, double gain = 0) & {
    return apply(builtin::Bias(std::move(path), std::move(shape), gain));
  }
  Derived&& bias(std::string path, std::vector<std::int64_t> shape = {}, double gain = 0) && {
    return std::move(bias(std::move(path), std::move(shape), gain));
  }
  /// (offset + s) · x, s a scalar (shape {1}) at `path` starting at `value`: a parameter when
  /// `trainable`, else a buffer (GIN's (1 + ε) x).
  Derived& scale(std::string path, double value, bool trainable = true, double offset = 0) & {
    return apply(builtin::LearnedScale(std::move(path), value, trainable, offset));
  }
  Derived&& scale(std::string path, double value, bool trainable = true, double offset = 0) && {
    return std::move(scale(std::move(path), value, trainable, offset));
  }
  /// x^exponent elementwise (a generalised mean: pow(p), a mean, pow(1 / p)).
  Derived& pow(double exponent) & { return apply(builtin::Pow(exponent)); }
  Derived&& pow(double exponent) && { return std::move(pow(exponent)); }
  /// x divided by its L2 norm, differentiated (unlike unit_rows), the norm clamped at 1e-12: each
  /// row's (torch's F.normalize), or with per_row false the whole matrix's.
  Derived& normalize(bool per_row = true) & { return apply(builtin::Normalize(per_row)); }
  Derived&& normalize(bool per_row = true) && { return std::move(normalize(per_row)); }
  /// The MLP (nn::Mlp: Linear layers with activations, optionally a LayerNorm) at `path`, shared
  /// by every operation that names the path (its options must then be the same). Followed by
  /// nothing but a concatenating step's mix, its first Linear layer is applied per term where that
  /// is cheaper (W [x; Σ y] = W_x x + Σ W_y y): HOPNet's updates.
  Derived& mlp(std::string path, MlpOptions options) & {
    return apply(builtin::MlpBlock(std::move(path), std::move(options)));
  }
  Derived&& mlp(std::string path, MlpOptions options) && {
    return std::move(mlp(std::move(path), std::move(options)));
  }
  /// Keeps only the pairs of one role of the `via` or `pattern` before it: a batch neighbourhood's
  /// roles (ComplexBatch; HOPNet's contact cells reach a face as its side +1 or -1).
  Derived& only(int role) & {
    const auto* p =
        ops_.empty() || !ops_.back().traits.product ? nullptr : &*ops_.back().traits.product;
    if (p == nullptr || p->transposed)
      throw ScheduleError("only(" + std::to_string(role) + ") must follow a via or a pattern");
    auto q = *p;
    q.role = role;
    ops_.pop_back();
    return apply(builtin::Product(std::move(q)));
  }
  Derived&& only(int role) && { return std::move(only(role)); }
  /// An operation (operation.hpp): a user's, or a built-in one.
  template <class Op, class = std::enable_if_t<std::is_base_of_v<Operation, std::decay_t<Op>>>>
  Derived& apply(Op&& op) & {
    return apply(
        std::shared_ptr<const Operation>(std::make_shared<std::decay_t<Op>>(std::forward<Op>(op))));
  }
  template <class Op, class = std::enable_if_t<std::is_base_of_v<Operation, std::decay_t<Op>>>>
  Derived&& apply(Op&& op) && {
    return std::move(apply(std::forward<Op>(op)));
  }
  Derived& apply(std::shared_ptr<const Operation> op) & {
    push_operation(std::move(op));
    return static_cast<Derived&>(*this);
  }
  Derived&& apply(std::shared_ptr<const Operation> op) && {
    return std::move(apply(std::move(op)));
  }

 protected:
};

/// A term: a cochain and what is done to it.
class Term : public Chain<Term> {
 public:
  explicit Term(CochainKey source) : source(std::move(source)) {}
  /// Messages over A weighted by attention: entry (i, j) scores a_s·x_j + a_t·t_i, with x the
  /// term's features here and t the step's target cochain (its features before the step), then
  /// `activation` and `norm` (a per-target softmax, division by the row sums, or none); A's values
  /// are multiplied by the weights and applied to x. `path` holds a (2·C): the source half, then
  /// the target half (TopoModelX's Conv.att_weight). Followed by conv(), this is TopoModelX's
  /// Conv with att=True (A (x W) = (A x) W: the weights depend on x alone).
  Term& attend(std::string op, std::string path, Activation activation = Activation::elu,
               AttentionNorm norm = AttentionNorm::none, double negative_slope = 0.2) & {
    return attend(std::move(op), AttendOptions(std::move(path))
                                     .activation(activation)
                                     .norm(norm)
                                     .negative_slope(negative_slope));
  }
  Term&& attend(std::string op, std::string path, Activation activation = Activation::elu,
                AttentionNorm norm = AttentionNorm::none, double negative_slope = 0.2) && {
    return std::move(attend(std::move(op), std::move(path), activation, norm, negative_slope));
  }
  /// Attention with its options: heads, keys and queries from other cochains, source-only
  /// scores, dropout, Aᵀ (AttendOptions).
  Term& attend(std::string op, AttendOptions o) & {
    return apply(builtin::Attend(std::move(op), std::move(o)));
  }
  Term&& attend(std::string op, AttendOptions o) && {
    return std::move(attend(std::move(op), std::move(o)));
  }
  /// Polynomial filter terms [y, A₁y, ..., A₁^K₁y, A₂y, ...] (identity once); with row_norm each
  /// power from `norm_from` on is divided by its operator's row sums (0 where they are 0).
  Term& powers(std::vector<std::pair<std::string, int>> filters, bool row_norm = false,
               int norm_from = 1) & {
    return apply(builtin::Powers(std::move(filters), row_norm, norm_from));
  }
  Term&& powers(std::vector<std::pair<std::string, int>> filters, bool row_norm = false,
                int norm_from = 1) && {
    return std::move(powers(std::move(filters), row_norm, norm_from));
  }
  CochainKey source;
};

inline Term from(int rank, std::string state = "") {
  return Term({rank, std::move(state)});
}

}  // namespace ops

/// A step: its terms, how they are mixed, the operations after the mix, the cochain written.
class OperatorStep : public ops::Chain<OperatorStep> {
 public:
  enum class Mix { sum, mean, filter, concat };
  explicit OperatorStep(CochainKey target);
  OperatorStep(const OperatorStep&);
  OperatorStep(OperatorStep&&) noexcept;
  OperatorStep& operator=(const OperatorStep&);
  OperatorStep& operator=(OperatorStep&&) noexcept;
  ~OperatorStep();

  template <class... T>
  OperatorStep& sum(T&&... t) & {
    mix = Mix::sum;
    (add_term(std::forward<T>(t)), ...);
    return *this;
  }
  template <class... T>
  OperatorStep&& sum(T&&... t) && {
    return std::move(sum(std::forward<T>(t)...));
  }
  /// Terms built in a loop.
  OperatorStep& sum(std::vector<ops::Term> t) &;
  OperatorStep&& sum(std::vector<ops::Term> t) && { return std::move(sum(std::move(t))); }
  template <class... T>
  OperatorStep& mean(T&&... t) & {
    sum(std::forward<T>(t)...);
    mix = Mix::mean;
    return *this;
  }
  template <class... T>
  OperatorStep&& mean(T&&... t) && {
    return std::move(mean(std::forward<T>(t)...));
  }
  /// y = Σ_k T_k · W[:, :, k] over every term (powers fanned out), W (in × out × terms) at
  /// `path`: SCCNN's and SCNN's einsum over stacked filter terms.
  template <class... T>
  OperatorStep& filter(std::string path, std::int64_t out, T&&... t) & {
    sum(std::forward<T>(t)...);
    mix = Mix::filter;
    filter_path = std::move(path);
    filter_out = out;
    return *this;
  }
  template <class... T>
  OperatorStep&& filter(std::string path, std::int64_t out, T&&... t) && {
    return std::move(filter(std::move(path), out, std::forward<T>(t)...));
  }
  /// The terms side by side (channels concatenated in order).
  template <class... T>
  OperatorStep& concat(T&&... t) & {
    sum(std::forward<T>(t)...);
    mix = Mix::concat;
    return *this;
  }
  template <class... T>
  OperatorStep&& concat(T&&... t) && {
    return std::move(concat(std::forward<T>(t)...));
  }
  /// Terms built in a loop, side by side.
  OperatorStep& concat(std::vector<ops::Term> t) &;
  OperatorStep&& concat(std::vector<ops::Term> t) && { return std::move(concat(std::move(t))); }
  OperatorStep& named(std::string n) & {
    name = std::move(n);
    return *this;
  }
  OperatorStep&& named(std::string n) && { return std::move(named(std::move(n))); }
  /// Only in the complexes of a batch that have a cell of `rank`: elsewhere the target keeps its
  /// value (HOPNet updates objects from faces only where there are contacts). Needs a ComplexBatch
  /// and a step that keeps the target's width.
  OperatorStep& when_nonempty(int rank) & {
    guard_rank = rank;
    return *this;
  }
  OperatorStep&& when_nonempty(int rank) && { return std::move(when_nonempty(rank)); }

  CochainKey target;
  std::vector<ops::Term> terms;
  Mix mix = Mix::sum;
  std::string filter_path;
  std::int64_t filter_out = 0;
  std::string name;
  int guard_rank = -1;  ///< >= 0: when_nonempty

 private:
  void add_term(ops::Term t);
};

namespace ops {
inline OperatorStep into(int rank, std::string state = "") {
  return OperatorStep({rank, std::move(state)});
}
}  // namespace ops

namespace detail {

/// Operations that map each row on its own, the same whichever rows they are given (so that
/// they can run on the rows an aggregation reads, or once for several terms).
inline bool row_wise(const TermOp& t) {
  return t.traits.row_wise;
}

/// Operations that may read a cochain other than their operand.
inline bool reads_cochains(const TermOp& t) {
  return !t.traits.row_wise && t.traits.reads_cochains;
}

/// The activation an operation is (OperationTraits::activation), for a product to fuse.
inline const std::optional<Activation>& activation_of(const TermOp& t) {
  return t.traits.activation;
}

/// The product by an operator an operation is, or null.
inline const OperatorProduct* product_of(const TermOp& t) {
  return t.traits.product ? &*t.traits.product : nullptr;
}

/// An operation that can aggregate over a batch neighbourhood: via (its values, summed) and a
/// pattern (sum, mean or max).
inline bool aggregation(const TermOp& t) {
  return t.traits.product && t.traits.product->aggregation();
}

/// The operators an operation applies (none for most).
inline const std::vector<std::string>& operators_of(const TermOp& t) {
  return t.traits.operators;
}

}  // namespace detail

class OperatorSchedule {
 public:
  OperatorSchedule();
  OperatorSchedule(const OperatorSchedule&);
  OperatorSchedule(OperatorSchedule&&) noexcept;
  OperatorSchedule& operator=(const OperatorSchedule&);
  OperatorSchedule& operator=(OperatorSchedule&&) noexcept;
  ~OperatorSchedule();
  /// Cochain (rank, state) is given as input `name` with `channels` columns.
  OperatorSchedule& input(std::string name, int rank, std::int64_t channels,
                          std::string state = "");
  /// Operator `name` maps rank `source_rank` cochains to rank `target_rank` (target × source).
  /// At run time it is a SparseOperator given by name or, failing that, the neighbourhood of that
  /// name of the ComplexBatch given (index pairs with optional values and roles).
  OperatorSchedule& operator_input(std::string name, int source_rank, int target_rank);
  /// An operator a forward may leave out (TopoModelX's `None`): a term that applies it is then
  /// skipped, in a step that sums or averages its terms (checked when the network is built); a
  /// step left with no term keeps its target as it was.
  OperatorSchedule& optional_operator(std::string name, int source_rank, int target_rank);
  const std::set<std::string>& optional_operators() const { return optional_; }
  OperatorSchedule& step(OperatorStep s);
  /// Steps that read one snapshot of the cochains.
  OperatorSchedule& parallel(std::vector<OperatorStep> steps);
  /// Starts a named layer: the steps added from here to the next layer() form it, and
  /// OperatorNetwork::run_layer runs them alone (a model that changes its complex between
  /// layers, as CAN's pooling does).
  OperatorSchedule& layer(std::string name);
  /// The layers in order: name and first step group.
  const std::vector<std::pair<std::string, std::size_t>>& layers() const { return layers_; }
  OperatorSchedule& output(std::string name, int rank, std::string state = "");
  /// A Glorot-initialised parameter that no step need use: a state_dict name kept where a mode
  /// ignores it (HyperGAT's TopoModelX-compatible attention vectors).
  OperatorSchedule& parameter(std::string path, std::vector<std::int64_t> shape,
                              double gain = 1.414);

  struct Port {
    std::string name;
    CochainKey key;
    std::int64_t channels;
  };
  const std::vector<Port>& inputs() const { return inputs_; }
  const std::vector<Port>& outputs() const { return outputs_; }
  const std::map<std::string, std::pair<int, int>>& operators() const { return operators_; }
  const std::vector<std::vector<OperatorStep>>& groups() const { return groups_; }
  struct Parameter {
    std::string path;
    std::vector<std::int64_t> shape;
    double gain;
  };
  const std::vector<Parameter>& parameters() const { return parameters_; }

  /// One line per step, e.g. "layer 0 rank 1: (1) = elu(linear(Σ[conv(1)·A1, ...]))".
  std::string str() const;

 private:
  void name_step(OperatorStep& s);
  std::vector<Port> inputs_, outputs_;
  std::map<std::string, std::pair<int, int>> operators_;
  std::vector<std::vector<OperatorStep>> groups_;
  int num_steps_ = 0;
  std::vector<Parameter> parameters_;
  std::set<std::string> optional_;
  std::vector<std::pair<std::string, std::size_t>> layers_;
};

}  // namespace topos::nn

#ifdef TOPOS_HEADER_ONLY
#include "topos/nn/operator_schedule/builder-inl.hpp"
#include "topos/nn/operator_schedule/elementwise-inl.hpp"
#include "topos/nn/operator_schedule/layers-inl.hpp"
#include "topos/nn/operator_schedule/printer-inl.hpp"
#include "topos/nn/operator_schedule/products-inl.hpp"
#endif
