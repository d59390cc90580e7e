// topos/nn/operator_schedule.hpp
// The operator schedule: a message-passing network over named sparse operators (incidences,
// adjacencies, Laplacians with their values) written as data, the way TopoModelX's models are
// written as layers of convolutions. The zoo's models are schedules of this kind.
//
//   using namespace topos::nn::ops;
//   OperatorSchedule s;
//   s.input("x_0", 0, 8).input("x_1", 1, 4)                  // cochains fed by name
//    .operator_input("adjacency_1", 1, 1)                     // source rank -> target rank
//    .operator_input("incidence_1", 1, 0);                    // B_1: nodes × edges, 1 -> 0
//   s.step(into(1).sum(from(1).conv("conv_1_to_1", 16).via("adjacency_1").act(Update::elu),
//                      from(0).conv("conv_0_to_1", 16).via_t("incidence_1"))
//                 .linear("update", 16).act(Update::relu));   // after the messages are mixed
//   s.step(into(1).filter("weight", 16,                       // Σ_k T_k W[:, :, k] over the terms
//                         from(1).powers({{"laplacian_down_1", 2}, {"laplacian_up_1", 2}})));
//   s.output("x_1", 1);
//   OperatorNetwork net(s);                                   // validated here
//   auto out = net->forward({{"x_0", x0}, {"x_1", x1}}, {{"adjacency_1", A1}, ...});
//
// A term starts at a cochain (rank, state) and applies its operations in order: operators
// (`via`, `via_t` for the transpose, `pattern` for the sparsity pattern alone), learned maps
// (`conv`/`weight`: x·W with W in × out, TopoModelX's Conv layout; `linear`: torch.nn.Linear;
// `head_weights`, `bias`, `scale` by a learned or buffered scalar), activations, dropout,
// attention (`attend`: GAT or GATv2 scores, one or several heads, keys and queries from other
// cochains), `pow`, `normalize`, and last, optionally, a polynomial filter (`powers`) that fans
// the term out into [y, A y, ..., A^K y]. A step mixes its terms (sum, mean, concatenation, or a
// filter weight over all of them), applies its own operations, and writes the target cochain.
// Steps run in sequence; a parallel group reads one snapshot (a layer that updates every rank at
// once). A buffer (a scale that is not trained) is saved at its path like a parameter.
//
// Parameters are created at the dotted paths the schedule names ("layers.0.conv_0_to_0.weight"),
// with their shapes inferred from the channels, so a TopoModelX state_dict loads by its own
// names; a path used twice is one shared parameter. Building the network checks every step:
// unknown cochains, inputs or operators, operators applied to the wrong rank, terms of mismatched
// channels or ranks, a parameter path reused with another shape; each error names the step.
#pragma once

#include "topos/nn/cochains.hpp"
#include "topos/nn/conv.hpp"
#include "topos/nn/schedule.hpp"  // ScheduleError

#include <torch/torch.h>

#include <algorithm>
#include <cmath>
#include <map>
#include <optional>
#include <set>
#include <sstream>
#include <string>
#include <utility>
#include <vector>

namespace topos::nn {

/// How `attend` scores and weighs a term's messages; the defaults are TopoModelX Conv's attention
/// (one head, one (2·C) vector). Per head, scores from keys k (the term's features, or a cochain
/// of the source rank) and queries q (the step's target before the step, or a cochain of the
/// target rank): GAT's act(a_s·k_j + a_t·q_i), GATv2's a·act(k_j + q_i) (`v2`), or act(a_s·k_j)
/// (`source_only`); then the per-target norm, dropout (training only), times A's values. Head h's
/// messages are its slice of the term's features; the heads are concatenated or averaged.
struct AttendOptions {
  explicit AttendOptions(std::string param) : param_(std::move(param)) {}
  /// The source part a_s then the target part a_t, in one parameter unless `target_param`.
  TORCH_ARG(std::string, param);
  TORCH_ARG(std::string, target_param);  ///< a_t as a parameter of its own (CAN's att_weight_dst)
  /// Parameter shapes (default: vectors); only their element counts are fixed (heads-major).
  TORCH_ARG(std::vector<std::int64_t>, shape);
  TORCH_ARG(std::vector<std::int64_t>, target_shape);
  TORCH_ARG(double, gain) = 1.414;  ///< Glorot gain of the parameters
  TORCH_ARG(Update, activation) = Update::elu;
  TORCH_ARG(double, negative_slope) = 0.2;
  TORCH_ARG(AttentionNorm, norm) = AttentionNorm::none;
  TORCH_ARG(std::optional<CochainKey>, keys);            ///< default: the term's features
  TORCH_ARG(std::optional<CochainKey>, queries);         ///< default: the step's target
  TORCH_ARG(bool, source_only) = false;                  ///< no queries and no a_t
  TORCH_ARG(Update, feature_activation) = Update::none;  ///< on keys and queries before scoring
  TORCH_ARG(double, feature_slope) = 0.01;
  TORCH_ARG(bool, v2) = false;  ///< GATv2: one vector a, after the activation
  TORCH_ARG(std::int64_t, heads) = 1;
  TORCH_ARG(bool, concat) = true;       ///< the heads side by side, or their mean
  TORCH_ARG(double, dropout) = 0;       ///< on the weights
  TORCH_ARG(bool, transposed) = false;  ///< attend over Aᵀ
  /// Where a_s and a_t start in the one parameter (default: 0 and a_s's length), read cyclically:
  /// TopoModelX's HMC takes [a_t | a_s] for same-rank attention and a rotated vector for the
  /// reverse direction of an incidence.
  TORCH_ARG(std::optional<std::int64_t>, source_offset);
  TORCH_ARG(std::optional<std::int64_t>, target_offset);
  /// Entry k of a row takes the weight of the row's mirrored entry (the (n-1-k)-th): TopoModelX's
  /// HBS pairs softmax weights in ascending column order with a product's descending indices.
  TORCH_ARG(bool, mirrored_rows) = false;
  /// A filter bank (SAN): the messages are `filters` slices of equal width, slice p (from 0)
  /// propagated p + 1 times by the one attention-weighted operator, the results summed (one
  /// head; the keys and queries are all the slices side by side).
  TORCH_ARG(std::int64_t, filters) = 1;
};

/// One operation of a term or of a step's tail.
struct TermOp {
  enum class Kind {
    via,               ///< A · x
    via_transposed,    ///< Aᵀ · x
    pattern,           ///< pattern(A) · x, summed or averaged (A's values ignored)
    weight,            ///< x · W, W (in × out) at `name`
    linear,            ///< torch.nn.Linear at `name` (weight out × in, optional bias)
    act,               ///< an update function
    dropout,           ///< training only
    unit_rows,         ///< each row divided by its (undifferentiated) L2 norm; zero rows stay 0
    batch_norm,        ///< torch.nn.BatchNorm1d at `name`
    layer_norm,        ///< torch.nn.LayerNorm at `name`
    attend,            ///< A · x with A's values times attention weights (`param`: the vector)
    initial_residual,  ///< GCNII: x̃ = (1-α) x + α skip, then (1-β) x̃ + β Linear(x̃)
    powers,        ///< [y, A₁y..A₁^K₁y, A₂y..A₂^K₂y, ...]: fans the term out, last only
    scale,         ///< x · p, a constant
    head_weights,  ///< [x W_1 | ... | x W_H], W (heads × in × out) at `name`
    bias,          ///< x + b on every row, b at `name` (any shape of as many entries as channels)
    learned_scale,    ///< (offset + s) · x, s a learned or buffered scalar at `name`
    pow,              ///< x^value elementwise
    normalize,        ///< x / ‖x‖₂ (differentiated), per row or over the whole matrix
    intra_aggregate,  ///< x_i · σ(<relu(Σ_j x_j), x_i>): each cell weighted against the whole
    affine_power      ///< (a I + b Σ_i A_i)^k x: `filters` the (A_i, k), `value` a, `offset` b
  };
  explicit TermOp(Kind k, std::string n = {}) : kind(k), name(std::move(n)) {}
  Kind kind;
  std::string name;       ///< operator or parameter path
  bool row_norm = false;  ///< via: divide by the operator's row sums; powers: from `norm_from`
  Aggr aggr = Aggr::sum;
  std::int64_t out = 0;
  bool bias = true;
  double gain = 1.414;
  Update update = Update::none;
  double slope = 0.01;
  double p = 0;  ///< dropout rate, or α of the initial residual
  double beta = 0;
  CochainKey skip;
  std::vector<std::pair<std::string, int>> filters;  ///< powers: (operator, order)
  std::string param;                                 ///< attend: the attention vector's path
  AttentionNorm attention_norm = AttentionNorm::none;
  int norm_from = 1;
  AttendOptions attention{""};      ///< attend: its options (param, update, slope repeat some)
  std::int64_t heads = 1;           ///< head_weights
  std::vector<std::int64_t> shape;  ///< bias: the parameter's shape
  double value = 0;                 ///< scale: the scalar's initial value; pow: the exponent
  double offset = 0;                ///< scale: added to the scalar
  bool trainable = true;            ///< scale: a parameter, else a buffer
  bool per_row = true;              ///< normalize: each row, else the whole matrix
  bool transposed = false;          ///< pattern: over Aᵀ
  bool rescale_rows = false;        ///< dropout: TopoModelX HMPNN's (rescaled_dropout)
};

namespace ops {

/// The fluent operations shared by terms (which start at a cochain) and steps (whose operations
/// act on the mixed terms).
template <class Derived>
class Chain {
 public:
  /// A · x, optionally divided by A's row sums (TopoModelX Conv's aggr_norm).
  Derived& via(std::string op, bool row_norm = false) {
    return add(TermOp(TermOp::Kind::via, std::move(op))).row_norm_last(row_norm);
  }
  /// Aᵀ · x (the transpose is made once per forward), optionally divided by Aᵀ's row sums.
  Derived& via_t(std::string op, bool row_norm = false) {
    return add(TermOp(TermOp::Kind::via_transposed, std::move(op))).row_norm_last(row_norm);
  }
  /// Sum (or mean) over A's sparsity pattern, its values ignored (torch_scatter's messages).
  Derived& pattern(std::string op, Aggr aggr = Aggr::sum) {
    TermOp t(TermOp::Kind::pattern, std::move(op));
    t.aggr = aggr;
    return add(std::move(t));
  }
  /// The same over Aᵀ (a hypergraph's nodes to its hyperedges over B).
  Derived& pattern_t(std::string op, Aggr aggr = Aggr::sum) {
    pattern(std::move(op), aggr);
    ops_.back().transposed = true;
    return static_cast<Derived&>(*this);
  }
  /// x · W with W (in × out) at `path` (Glorot-initialised with `gain`).
  Derived& weight(std::string path, std::int64_t out, double gain = 1.414) {
    TermOp t(TermOp::Kind::weight, std::move(path));
    t.out = out;
    t.gain = gain;
    return add(std::move(t));
  }
  /// TopoModelX's Conv weight: weight(path + ".weight", out).
  Derived& conv(const std::string& path, std::int64_t out) { return weight(path + ".weight", out); }
  /// torch.nn.Linear at `path`: parameters path.weight (out × in) and path.bias.
  Derived& linear(std::string path, std::int64_t out, bool bias = true) {
    TermOp t(TermOp::Kind::linear, std::move(path));
    t.out = out;
    t.bias = bias;
    return add(std::move(t));
  }
  Derived& act(Update u, double negative_slope = 0.01) {
    TermOp t(TermOp::Kind::act);
    t.update = u;
    t.slope = negative_slope;
    return add(std::move(t));
  }
  Derived& dropout(double p) {
    TermOp t(TermOp::Kind::dropout);
    t.p = p;
    return add(std::move(t));
  }
  /// TopoModelX HMPNN's feature dropout (training only): each entry kept with probability
  /// `keep`, then row i multiplied by (2n - kept_i) / n, n the number of rows.
  Derived& rescaled_dropout(double keep) {
    dropout(keep);
    ops_.back().rescale_rows = true;
    return static_cast<Derived&>(*this);
  }
  Derived& unit_rows() { return add(TermOp(TermOp::Kind::unit_rows)); }
  /// torch.nn.BatchNorm1d over the channels at `path` (weight, bias, running statistics).
  Derived& batch_norm(std::string path) {
    return add(TermOp(TermOp::Kind::batch_norm, std::move(path)));
  }
  /// torch.nn.LayerNorm over the channels at `path`.
  Derived& layer_norm(std::string path) {
    return add(TermOp(TermOp::Kind::layer_norm, std::move(path)));
  }
  /// GCNII's initial residual and identity mapping, the bias-free Linear at `path`.
  Derived& initial_residual(CochainKey skip, double alpha, double beta, std::string path) {
    TermOp t(TermOp::Kind::initial_residual, std::move(path));
    t.skip = std::move(skip);
    t.p = alpha;
    t.beta = beta;
    return add(std::move(t));
  }
  /// x · factor (CAN's skip connection scales its linear map by 1 + 1e-6).
  Derived& scale(double factor) {
    TermOp t(TermOp::Kind::scale);
    t.p = factor;
    return add(std::move(t));
  }
  /// One map per head, side by side: [x W_1 | ... | x W_H] with W (heads × in × out) at `path`,
  /// TopoModelX's multi-head layout (AllSetTransformer's K and V).
  Derived& head_weights(std::string path, std::int64_t heads, std::int64_t out,
                        double gain = 1.414) {
    TermOp t(TermOp::Kind::head_weights, std::move(path));
    t.heads = heads;
    t.out = out;
    t.gain = gain;
    return add(std::move(t));
  }
  /// x + b on every row, b at `path` of `shape` (default: a vector), flattened; zeros when new,
  /// or with a `gain` Glorot-initialised (HNHN's biases, 1 × channels).
  Derived& bias(std::string path, std::vector<std::int64_t> shape = {}, double gain = 0) {
    TermOp t(TermOp::Kind::bias, std::move(path));
    t.shape = std::move(shape);
    t.gain = gain;
    return add(std::move(t));
  }
  /// (offset + s) · x, s a scalar (shape {1}) at `path` starting at `value`: a parameter when
  /// `trainable`, else a buffer (GIN's (1 + ε) x).
  Derived& scale(std::string path, double value, bool trainable = true, double offset = 0) {
    TermOp t(TermOp::Kind::learned_scale, std::move(path));
    t.value = value;
    t.trainable = trainable;
    t.offset = offset;
    return add(std::move(t));
  }
  /// x^exponent elementwise (a generalised mean: pow(p), a mean, pow(1 / p)).
  Derived& pow(double exponent) {
    TermOp t(TermOp::Kind::pow);
    t.value = exponent;
    return add(std::move(t));
  }
  /// x divided by its L2 norm, differentiated (unlike unit_rows), the norm clamped at 1e-12: each
  /// row's (torch's F.normalize), or with per_row false the whole matrix's.
  Derived& normalize(bool per_row = true) {
    TermOp t(TermOp::Kind::normalize);
    t.per_row = per_row;
    return add(std::move(t));
  }
  /// Intra-neighbourhood aggregation (Hajij et al.'s CMPS, TopoModelX SCACMPS's intra_aggr): each
  /// row scaled by σ(<relu(Σ_j x_j), x_i>), its agreement with the whole cochain.
  Derived& intra_aggregate() { return add(TermOp(TermOp::Kind::intra_aggregate)); }
  /// (a I + b Σ_i A_i)^k x by k rounds of sparse products, the sum and its power never formed
  /// (SAN's harmonic filter (I - ε(L↑ + L↓))^k); the A_i square, their values not trained.
  Derived& affine_power(const std::vector<std::string>& ops, int k, double a, double b) {
    TermOp t(TermOp::Kind::affine_power);
    for (const auto& op : ops) t.filters.emplace_back(op, k);
    t.value = a;
    t.offset = b;
    return add(std::move(t));
  }
  const std::vector<TermOp>& operations() const { return ops_; }

 protected:
  Derived& add(TermOp t) {
    ops_.push_back(std::move(t));
    return static_cast<Derived&>(*this);
  }
  Derived& row_norm_last(bool on) {
    ops_.back().row_norm = on;
    return static_cast<Derived&>(*this);
  }
  std::vector<TermOp> ops_;
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
  Term& attend(std::string op, std::string path, Update activation = Update::elu,
               AttentionNorm norm = AttentionNorm::none, double negative_slope = 0.2) {
    return attend(std::move(op), AttendOptions(std::move(path))
                                     .activation(activation)
                                     .norm(norm)
                                     .negative_slope(negative_slope));
  }
  /// Attention with its options: heads, keys and queries from other cochains, GATv2 or
  /// source-only scores, a separate target part, dropout (AttendOptions).
  Term& attend(std::string op, AttendOptions o) {
    TermOp t(TermOp::Kind::attend, std::move(op));
    t.param = o.param();
    t.update = o.activation();
    t.attention_norm = o.norm();
    t.slope = o.negative_slope();
    t.attention = std::move(o);
    return add(std::move(t));
  }
  /// Polynomial filter terms [y, A₁y, ..., A₁^K₁y, A₂y, ...] (identity once); with row_norm each
  /// power from `norm_from` on is divided by its operator's row sums (0 where they are 0).
  Term& powers(std::vector<std::pair<std::string, int>> filters, bool row_norm = false,
               int norm_from = 1) {
    TermOp t(TermOp::Kind::powers);
    t.filters = std::move(filters);
    t.row_norm = row_norm;
    t.norm_from = norm_from;
    return add(std::move(t));
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
  explicit OperatorStep(CochainKey target) : target(std::move(target)) {}

  template <class... T>
  OperatorStep& sum(T&&... t) {
    mix = Mix::sum;
    (terms.push_back(std::forward<T>(t)), ...);
    return *this;
  }
  /// Terms built in a loop.
  OperatorStep& sum(std::vector<ops::Term> t) {
    mix = Mix::sum;
    terms.insert(terms.end(), t.begin(), t.end());
    return *this;
  }
  template <class... T>
  OperatorStep& mean(T&&... t) {
    sum(std::forward<T>(t)...);
    mix = Mix::mean;
    return *this;
  }
  /// y = Σ_k T_k · W[:, :, k] over every term (powers fanned out), W (in × out × terms) at
  /// `path`: SCCNN's and SCNN's einsum over stacked filter terms.
  template <class... T>
  OperatorStep& filter(std::string path, std::int64_t out, T&&... t) {
    sum(std::forward<T>(t)...);
    mix = Mix::filter;
    filter_path = std::move(path);
    filter_out = out;
    return *this;
  }
  /// The terms side by side (channels concatenated in order).
  template <class... T>
  OperatorStep& concat(T&&... t) {
    sum(std::forward<T>(t)...);
    mix = Mix::concat;
    return *this;
  }
  OperatorStep& named(std::string n) {
    name = std::move(n);
    return *this;
  }

  CochainKey target;
  std::vector<ops::Term> terms;
  Mix mix = Mix::sum;
  std::string filter_path;
  std::int64_t filter_out = 0;
  std::string name;
};

namespace ops {
inline OperatorStep into(int rank, std::string state = "") {
  return OperatorStep({rank, std::move(state)});
}
}  // namespace ops

class OperatorSchedule {
 public:
  /// Cochain (rank, state) is given as input `name` with `channels` columns.
  OperatorSchedule& input(std::string name, int rank, std::int64_t channels,
                          std::string state = "") {
    inputs_.push_back({std::move(name), {rank, std::move(state)}, channels});
    return *this;
  }
  /// Operator `name` maps rank `source_rank` cochains to rank `target_rank` (target × source).
  OperatorSchedule& operator_input(std::string name, int source_rank, int target_rank) {
    operators_[std::move(name)] = {source_rank, target_rank};
    return *this;
  }
  /// Operator `name`: `source`'s entries, each kept with probability 1 - rate in training (all
  /// of them in evaluation), drawn once per forward and shared by every step that names it (both
  /// directions of an incidence). Ranks as `source`'s.
  OperatorSchedule& dropped_operator(std::string name, std::string source, double rate) {
    dropped_.push_back({std::move(name), std::move(source), rate});
    return *this;
  }
  OperatorSchedule& step(OperatorStep s) {
    name_step(s);
    groups_.push_back({std::move(s)});
    return *this;
  }
  /// Steps that read one snapshot of the cochains.
  OperatorSchedule& parallel(std::vector<OperatorStep> steps) {
    for (auto& s : steps) name_step(s);
    groups_.push_back(std::move(steps));
    return *this;
  }
  OperatorSchedule& output(std::string name, int rank, std::string state = "") {
    outputs_.push_back({std::move(name), {rank, std::move(state)}, 0});
    return *this;
  }
  /// A Glorot-initialised parameter that no step need use: a state_dict name kept where a mode
  /// ignores it (HyperGAT's TopoModelX-compatible attention vectors).
  OperatorSchedule& parameter(std::string path, std::vector<std::int64_t> shape,
                              double gain = 1.414) {
    parameters_.push_back({std::move(path), std::move(shape), gain});
    return *this;
  }

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
  struct DroppedOperator {
    std::string name, source;
    double rate;
  };
  const std::vector<DroppedOperator>& dropped_operators() const { return dropped_; }

  /// One line per step, e.g. "layer 0 rank 1: (1) = elu(linear(Σ[conv(1)·A1, ...]))".
  std::string str() const {
    std::ostringstream o;
    for (const auto& in : inputs_) o << "input " << in.name << " -> " << in.key.str() << "\n";
    for (const auto& g : groups_) {
      if (g.size() > 1) o << "parallel {\n";
      for (const auto& s : g) o << (g.size() > 1 ? "  " : "") << step_str(s) << "\n";
      if (g.size() > 1) o << "}\n";
    }
    for (const auto& out : outputs_) o << "output " << out.key.str() << " -> " << out.name << "\n";
    for (const auto& p : parameters_) o << "parameter " << p.path << "\n";
    return o.str();
  }

 private:
  void name_step(OperatorStep& s) {
    if (s.name.empty()) s.name = "step " + std::to_string(num_steps_);
    ++num_steps_;
  }
  static std::string ops_str(std::string x, const std::vector<TermOp>& ops) {
    for (const auto& t : ops) {
      switch (t.kind) {
        case TermOp::Kind::via:
          x = t.name + (t.row_norm ? "~" : "") + "·" + x;
          break;
        case TermOp::Kind::via_transposed:
          x = t.name + "ᵀ" + (t.row_norm ? "~" : "") + "·" + x;
          break;
        case TermOp::Kind::pattern:
          x = std::string(t.aggr == Aggr::mean ? "mean" : "sum") + "|" + t.name +
              (t.transposed ? "ᵀ" : "") + "|·" + x;
          break;
        case TermOp::Kind::weight:
          x = x + "·" + t.name;
          break;
        case TermOp::Kind::linear:
          x = t.name + "(" + x + ")";
          break;
        case TermOp::Kind::act:
          x = "act" + std::to_string(static_cast<int>(t.update)) + "(" + x + ")";
          break;
        case TermOp::Kind::dropout:
          x = "dropout(" + x + ")";
          break;
        case TermOp::Kind::unit_rows:
          x = "unit_rows(" + x + ")";
          break;
        case TermOp::Kind::attend: {
          const auto& a = t.attention;
          x = "att[" + t.param + (a.heads() > 1 ? " ×" + std::to_string(a.heads()) : "") + "]" +
              t.name + (a.transposed() ? "ᵀ" : "") + "·" + x;
          break;
        }
        case TermOp::Kind::batch_norm:
        case TermOp::Kind::layer_norm:
          x = t.name + "(" + x + ")";
          break;
        case TermOp::Kind::initial_residual:
          x = "residual(" + x + ", " + t.skip.str() + ", " + t.name + ")";
          break;
        case TermOp::Kind::powers: {
          std::string f;
          for (const auto& [op, k] : t.filters) f += " " + op + "^1.." + std::to_string(k);
          x = "powers[" + x + ";" + f + "]";
          break;
        }
        case TermOp::Kind::scale:
          x = std::to_string(t.p) + "·" + x;
          break;
        case TermOp::Kind::head_weights:
          x = x + "·" + t.name + "[×" + std::to_string(t.heads) + "]";
          break;
        case TermOp::Kind::bias:
          x = x + " + " + t.name;
          break;
        case TermOp::Kind::learned_scale:
          x = "(" + num(t.offset) + "+" + t.name + ")·" + x;
          break;
        case TermOp::Kind::pow:
          x = "(" + x + ")^" + num(t.value);
          break;
        case TermOp::Kind::normalize:
          x = (t.per_row ? "normalize_rows(" : "normalize(") + x + ")";
          break;
        case TermOp::Kind::intra_aggregate:
          x = "intra(" + x + ")";
          break;
        case TermOp::Kind::affine_power: {
          std::string sum;
          for (const auto& f : t.filters) sum += (sum.empty() ? "" : " + ") + f.first;
          x = "(" + num(t.value) + " I + " + num(t.offset) + " (" + sum + "))^" +
              std::to_string(t.filters.empty() ? 0 : t.filters[0].second) + "·" + x;
          break;
        }
      }
    }
    return x;
  }
  static std::string num(double v) {
    std::ostringstream o;
    o << v;
    return o.str();
  }
  static std::string step_str(const OperatorStep& s) {
    std::string mixed = s.mix == OperatorStep::Mix::filter   ? "filter " + s.filter_path + "["
                        : s.mix == OperatorStep::Mix::mean   ? "mean["
                        : s.mix == OperatorStep::Mix::concat ? "cat["
                                                             : "sum[";
    for (std::size_t i = 0; i < s.terms.size(); ++i)
      mixed += (i ? ", " : "") + ops_str(s.terms[i].source.str(), s.terms[i].operations());
    mixed += "]";
    return s.name + ": " + s.target.str() + " = " + ops_str(mixed, s.operations());
  }

  std::vector<Port> inputs_, outputs_;
  std::map<std::string, std::pair<int, int>> operators_;
  std::vector<std::vector<OperatorStep>> groups_;
  int num_steps_ = 0;
  std::vector<Parameter> parameters_;
  std::vector<DroppedOperator> dropped_;
};

/// Runs an OperatorSchedule; its parameters sit at the schedule's dotted paths.
class OperatorNetworkImpl : public torch::nn::Module {
 public:
  explicit OperatorNetworkImpl(OperatorSchedule schedule) : schedule_(std::move(schedule)) {
    validate_and_create();
  }

  /// Inputs and operators by name -> outputs by name. An operator whose shape does not fit the
  /// cochains it is applied to is an error naming the step.
  std::map<std::string, torch::Tensor> forward(
      const std::map<std::string, torch::Tensor>& inputs,
      const std::map<std::string, SparseOperator>& operators) {
    auto h = input_cochains(inputs);
    run_groups(h, operators, 0, schedule_.groups().size());
    return output_cochains(h);
  }

  /// The cochains the inputs give, checked against the schedule's inputs.
  Cochains input_cochains(const std::map<std::string, torch::Tensor>& inputs) const {
    Cochains h;
    for (const auto& in : schedule_.inputs()) {
      auto it = inputs.find(in.name);
      if (it == inputs.end()) throw ScheduleError("input '" + in.name + "' was not given");
      const auto& x = it->second;
      if (x.dim() != 2 || x.size(1) != in.channels)
        throw ScheduleError("input '" + in.name + "' must be (cells × " +
                            std::to_string(in.channels) + "), got " + shape_str(x));
      h.set(in.key.rank, in.key.state, x);
    }
    return h;
  }

  /// Runs the step groups [begin, end) on h. A model whose complex changes between layers (CAN's
  /// pooling keeps some cells and restricts the operators to them) runs its schedule in pieces.
  void run_groups(Cochains& h, const std::map<std::string, SparseOperator>& operators,
                  std::size_t begin, std::size_t end) {
    Operators ops{&operators, {}, {}};
    for (const auto& d : schedule_.dropped_operators()) {
      const auto& A = ops.at("dropped operator '" + d.name + "'", d.source);
      ops.derived.emplace(d.name, is_training() && d.rate > 0 ? drop_entries(A, d.rate) : A);
    }
    const auto& groups = schedule_.groups();
    for (std::size_t g = begin; g < end && g < groups.size(); ++g) {
      const Cochains snapshot = h;
      std::vector<std::pair<CochainKey, torch::Tensor>> updates;
      for (const auto& s : groups[g]) updates.emplace_back(s.target, run_step(s, snapshot, ops));
      for (auto& [k, v] : updates) h.set(k.rank, k.state, std::move(v));
    }
  }

  std::map<std::string, torch::Tensor> output_cochains(const Cochains& h) const {
    std::map<std::string, torch::Tensor> out;
    for (const auto& o : schedule_.outputs()) out[o.name] = h.at(o.key.rank, o.key.state);
    return out;
  }

  /// The outputs in the order given (a model's positional return value).
  std::vector<torch::Tensor> run(const std::map<std::string, torch::Tensor>& inputs,
                                 const std::map<std::string, SparseOperator>& operators,
                                 const std::vector<std::string>& names) {
    auto out = forward(inputs, operators);
    std::vector<torch::Tensor> v;
    for (const auto& n : names) v.push_back(out.at(n));
    return v;
  }

  const OperatorSchedule& schedule() const { return schedule_; }
  /// The parameter (or buffer) at a schedule path.
  const torch::Tensor& parameter(const std::string& path) const {
    auto it = params_.find(path);
    if (it == params_.end()) throw ScheduleError("no parameter '" + path + "'");
    return it->second;
  }

 private:
  OperatorSchedule schedule_;
  std::map<std::string, torch::Tensor> params_;  // parameters and buffers by path
  std::set<std::string> buffers_;                // the paths of params_ that are buffers
  std::map<std::string, torch::nn::BatchNorm1d> batch_norms_;
  std::map<std::string, torch::nn::LayerNorm> layer_norms_;

  struct Operators {
    const std::map<std::string, SparseOperator>* given;
    std::map<std::string, SparseOperator> transposed;
    std::map<std::string, SparseOperator> derived;  // the dropped operators of this forward
    const SparseOperator& at(const std::string& where, const std::string& name) const {
      if (auto d = derived.find(name); d != derived.end()) return d->second;
      auto it = given->find(name);
      if (it == given->end())
        throw ScheduleError(where + ": operator '" + name + "' was not given");
      return it->second;
    }
    const SparseOperator& t(const std::string& where, const std::string& name) {
      auto it = transposed.find(name);
      if (it == transposed.end()) it = transposed.emplace(name, at(where, name).t()).first;
      return it->second;
    }
  };

  static std::string shape_str(const torch::Tensor& x) {
    std::ostringstream o;
    o << x.sizes();
    return o.str();
  }

  /// A's entries, each kept with probability 1 - rate.
  static SparseOperator drop_entries(const SparseOperator& A, double rate) {
    const auto keep = (torch::rand({A.nnz()}) >= rate).nonzero().squeeze(1).to(A.row.device());
    return SparseOperator::from_sorted(A.rows, A.cols, index_vector(A.row.index_select(0, keep)),
                                       index_vector(A.col.index_select(0, keep)),
                                       A.values.index_select(0, keep));
  }

  /// A clear error naming the step and the operator when A cannot be applied to x.
  static void check_fits(const std::string& where, const std::string& name, const SparseOperator& A,
                         const torch::Tensor& x) {
    if (A.cols != x.size(0))
      throw ScheduleError(where + ": operator '" + name + "' has " + std::to_string(A.cols) +
                          " columns but the cochain it is applied to has " +
                          std::to_string(x.size(0)) + " rows");
  }

  /// A · x, divided by A's row sums with `row_norm` (0 where a row sums to 0).
  static torch::Tensor multiply(const std::string& where, const std::string& name,
                                const SparseOperator& A, const torch::Tensor& x, bool row_norm) {
    check_fits(where, name, A, x);
    const auto y = spmm(A, x);
    return row_norm ? divide_by_row_sums(A, y) : y;
  }

  /// list[i] on x, and list[i + 1] with it when that is an activation the product kernels apply
  /// in their row loop (a via without row normalisation or a linear, then relu or elu): one pass
  /// over the output, and a backward that needs no exponential. Returns the last index used.
  std::size_t apply_fused(const std::string& where, const CochainKey& target,
                          const std::vector<TermOp>& list, std::size_t i, torch::Tensor& x,
                          Operators& ops, const Cochains& h) {
    const auto& t = list[i];
    const bool product =
        ((t.kind == TermOp::Kind::via || t.kind == TermOp::Kind::via_transposed) && !t.row_norm) ||
        t.kind == TermOp::Kind::linear;
    if (!product || i + 1 >= list.size() || list[i + 1].kind != TermOp::Kind::act ||
        !fusable(list[i + 1].update)) {
      x = apply(where, target, t, x, ops, h);
      return i;
    }
    const auto act = epilogue_of(list[i + 1].update);
    if (t.kind == TermOp::Kind::linear) {
      x = linear_act(x, params_.at(t.name + ".weight"),
                     t.bias ? params_.at(t.name + ".bias") : torch::Tensor(), act);
    } else {
      const bool transposed = t.kind == TermOp::Kind::via_transposed;
      const auto& A = transposed ? ops.t(where, t.name) : ops.at(where, t.name);
      check_fits(where, transposed ? t.name + "ᵀ" : t.name, A, x);
      x = spmm(A, x, act);
    }
    return i + 1;
  }

  torch::Tensor apply(const std::string& where, const CochainKey& target, const TermOp& t,
                      torch::Tensor x, Operators& ops, const Cochains& h) {
    switch (t.kind) {
      case TermOp::Kind::via: {
        return multiply(where, t.name, ops.at(where, t.name), x, t.row_norm);
      }
      case TermOp::Kind::via_transposed: {
        return multiply(where, t.name + "ᵀ", ops.t(where, t.name), x, t.row_norm);
      }
      case TermOp::Kind::attend:
        return attend(where, target, t, x, ops, h);
      case TermOp::Kind::batch_norm:
        return batch_norms_.at(t.name)->forward(x);
      case TermOp::Kind::layer_norm:
        return layer_norms_.at(t.name)->forward(x);
      case TermOp::Kind::pattern: {
        const auto& A = t.transposed ? ops.t(where, t.name) : ops.at(where, t.name);
        check_fits(where, t.name + (t.transposed ? "ᵀ" : ""), A, x);
        return pattern_aggregate(A, x, t.aggr);
      }
      case TermOp::Kind::weight: {
        const auto& W = params_.at(t.name);
        return x.dim() == 2 && W.dim() == 2 ? linear_act(x, W.t(), {}) : x.matmul(W);
      }
      case TermOp::Kind::linear: {
        const auto& b = t.bias ? params_.at(t.name + ".bias") : torch::Tensor();
        return torch::linear(x, params_.at(t.name + ".weight"), b);
      }
      case TermOp::Kind::act:
        return apply_update(x, t.update, t.slope);
      case TermOp::Kind::dropout: {
        if (!t.rescale_rows || !is_training()) return torch::dropout(x, t.p, is_training());
        const auto mask = torch::bernoulli(torch::full_like(x, t.p));
        const double n = static_cast<double>(x.size(0));
        return x * mask * ((2 * n - mask.sum(1, true)) / n);
      }
      case TermOp::Kind::unit_rows:
        return unit_rows(x);
      case TermOp::Kind::initial_residual: {
        const auto mixed = (1 - t.p) * x + t.p * h.at(t.skip.rank, t.skip.state);
        return (1 - t.beta) * mixed + t.beta * torch::linear(mixed, params_.at(t.name + ".weight"));
      }
      case TermOp::Kind::powers:
        break;  // handled by the caller (it fans out)
      case TermOp::Kind::scale:
        return x * t.p;
      case TermOp::Kind::head_weights: {     // x [W_1 | ... | W_H]: one product, head-major
        const auto& W = params_.at(t.name);  // heads × in × out
        return linear_act(x, W.permute({1, 0, 2}).reshape({W.size(1), -1}).t(), {});
      }
      case TermOp::Kind::bias:
        return x + params_.at(t.name).reshape({-1});
      case TermOp::Kind::learned_scale:
        return (t.offset + params_.at(t.name)) * x;
      case TermOp::Kind::pow:
        return x.pow(t.value);
      case TermOp::Kind::normalize:
        return x / (t.per_row ? x.norm(2, 1, true) : x.norm()).clamp_min(1e-12);
      case TermOp::Kind::intra_aggregate:
        return x * torch::sigmoid(x.matmul(torch::relu(x.sum(0)))).unsqueeze(1);
      case TermOp::Kind::affine_power: {
        std::vector<SparseOperator> terms;
        for (const auto& f : t.filters) {
          terms.push_back(ops.at(where, f.first));
          check_fits(where, f.first, terms.back(), x);
        }
        return apply_affine_power(terms, x, t.filters[0].second, t.value, t.offset);
      }
    }
    return x;
  }

  /// attend (AttendOptions): per-head scores, weights and messages over the operator.
  torch::Tensor attend(const std::string& where, const CochainKey& target, const TermOp& t,
                       const torch::Tensor& x, Operators& ops, const Cochains& h) {
    const auto& o = t.attention;
    const auto& A = o.transposed() ? ops.t(where, t.name) : ops.at(where, t.name);
    const auto name = t.name + (o.transposed() ? "ᵀ" : "");
    check_fits(where, name, A, x);
    auto k = x;
    if (o.keys()) {
      k = h.at(o.keys()->rank, o.keys()->state);
      check_fits(where, name, A, k);
    }
    torch::Tensor q;
    if (!o.source_only()) {
      const auto& key = o.queries() ? *o.queries() : target;
      q = h.at(key.rank, key.state);
      if (A.rows != q.size(0))
        throw ScheduleError(where + ": operator '" + name + "' has " + std::to_string(A.rows) +
                            " rows but the " +
                            (o.queries() ? "query cochain " + key.str() : "target cochain") +
                            " has " + std::to_string(q.size(0)));
    }
    if (o.feature_activation() != Update::none) {
      k = apply_update(k, o.feature_activation(), o.feature_slope());
      if (q.defined()) q = apply_update(q, o.feature_activation(), o.feature_slope());
    }
    const auto H = o.heads();
    // The parameter parts: a_s (and a_t) as vectors, heads-major.
    auto a = params_.at(o.param()).reshape({-1});
    torch::Tensor a_s = a, a_t;
    if (!o.target_param().empty()) {
      a_t = params_.at(o.target_param()).reshape({-1});
    } else if (q.defined() && !o.v2()) {
      // a's entries from `offset` on, wrapping around.
      const auto part = [&a](std::int64_t offset, std::int64_t n) {
        return offset == 0 ? a.narrow(0, 0, n) : a.roll({-offset}).narrow(0, 0, n);
      };
      a_s = part(o.source_offset().value_or(0), k.size(1));
      a_t = part(o.target_offset().value_or(k.size(1)), a.size(0) - k.size(1));
    }
    // Per cell and head <f_h, a_h> (one head: a matrix-vector product, as pair_scores, and
    // the scores a vector: torch's index_select on an n × 1 matrix is 2.5x slower).
    auto dots = [H](const torch::Tensor& f, const torch::Tensor& v) {
      if (H == 1) return f.mv(v);
      return (f.reshape({f.size(0), H, -1}) * v.reshape({1, H, -1})).sum(-1);
    };
    const auto col = A.col.to(x.device()), row = A.row.to(x.device());
    torch::Tensor raw;  // nnz × heads, or nnz with one head
    if (o.v2()) {
      const auto e = apply_update(k.index_select(0, col) + q.index_select(0, row), o.activation(),
                                  o.negative_slope());
      raw = (e.reshape({e.size(0), H, -1}) * a_s.reshape({1, H, -1})).sum(-1);
    } else {
      raw = dots(k, a_s).index_select(0, col);
      if (q.defined()) raw = raw + dots(q, a_t).index_select(0, row);
    }
    const auto act = o.v2() ? Update::none : o.activation();
    // Head i's weights on A's entries, times A's values.
    const auto weighted = [&](std::int64_t i) {
      auto w = attention_weights(A, raw.dim() == 1 ? raw : raw.select(1, i).contiguous(), act,
                                 o.negative_slope(), o.norm());
      if (o.mirrored_rows()) w = w.index_select(0, A.row_mirror());
      if (o.dropout() > 0) w = torch::dropout(w, o.dropout(), is_training());
      return A.with_values(w * A.values.to(w.scalar_type()));
    };
    // The slices by one split: its backward writes every slice's gradient into one matrix, where
    // a narrow per slice allocates a zero-filled one each.
    if (o.filters() > 1) {  // Σ_p W^(p+1) x_p = W(x_0 + W(x_1 + ... W x_(P-1))): P products
      const auto W = weighted(0);
      const auto P = o.filters();
      const auto x_p = x.split(x.size(1) / P, 1);
      auto z = x_p[static_cast<std::size_t>(P - 1)].contiguous();
      for (auto p = P - 2; p >= 0; --p) z = x_p[static_cast<std::size_t>(p)] + spmm(W, z);
      return spmm(W, z);
    }
    std::vector<torch::Tensor> heads;
    const auto x_h = H == 1 ? std::vector<torch::Tensor>{x} : x.split(x.size(1) / H, 1);
    for (std::int64_t i = 0; i < H; ++i)
      heads.push_back(spmm(weighted(i), x_h[static_cast<std::size_t>(i)].contiguous()));
    if (H == 1) return heads[0];
    return o.concat() ? torch::cat(heads, 1) : torch::stack(heads, 0).mean(0);
  }

  torch::Tensor run_step(const OperatorStep& s, const Cochains& h, Operators& ops) {
    const std::string where = s.name + " (into " + s.target.str() + ")";
    const bool single = s.terms.size() == 1 &&
                        (s.mix == OperatorStep::Mix::sum || s.mix == OperatorStep::Mix::mean);
    if (single && std::none_of(s.terms[0].operations().begin(), s.terms[0].operations().end(),
                               [](const TermOp& t) { return t.kind == TermOp::Kind::powers; })) {
      // One term: its operations and the step's as one list, so that a product ending the term
      // fuses with the step's activation.
      auto list = s.terms[0].operations();
      list.insert(list.end(), s.operations().begin(), s.operations().end());
      torch::Tensor x = h.at(s.terms[0].source.rank, s.terms[0].source.state);
      for (std::size_t i = 0; i < list.size(); ++i)
        i = apply_fused(where, s.target, list, i, x, ops, h);
      return x;
    }
    std::vector<torch::Tensor> terms;
    for (const auto& term : s.terms) {
      torch::Tensor x = h.at(term.source.rank, term.source.state);
      const auto& list = term.operations();
      for (std::size_t i = 0; i < list.size(); ++i) {
        const auto& t = list[i];
        if (t.kind != TermOp::Kind::powers) {
          i = apply_fused(where, s.target, list, i, x, ops, h);
          continue;
        }
        terms.push_back(x);
        for (const auto& [name, order] : t.filters) {
          const auto& A = ops.at(where, name);
          check_fits(where, name, A, x);
          for (auto& p : powers(A, x, order, t.row_norm, t.norm_from)) terms.push_back(p);
        }
        x = torch::Tensor();
      }
      if (x.defined()) terms.push_back(x);
    }
    torch::Tensor y;
    if (s.mix == OperatorStep::Mix::filter) {
      y = combine_terms(terms, params_.at(s.filter_path));
    } else if (s.mix == OperatorStep::Mix::concat) {
      y = torch::cat(terms, 1);
    } else {
      y = terms[0];
      for (std::size_t i = 1; i < terms.size(); ++i) y = y + terms[i];
      if (s.mix == OperatorStep::Mix::mean) y = y / static_cast<double>(terms.size());
    }
    const auto& list = s.operations();
    for (std::size_t i = 0; i < list.size(); ++i)
      i = apply_fused(where, s.target, list, i, y, ops, h);
    return y;
  }

  // --- construction: channel and rank inference, parameters created at their paths -----------

  /// The module at a dotted path (created empty where missing) and the last name.
  std::pair<torch::nn::Module*, std::string> owner_of(const std::string& path) {
    torch::nn::Module* m = this;
    std::size_t start = 0;
    for (auto dot = path.find('.'); dot != std::string::npos; dot = path.find('.', start)) {
      const auto part = path.substr(start, dot - start);
      auto children = m->named_children();
      auto* child = children.find(part);
      m = child != nullptr ? child->get()
                           : m->register_module(part, std::make_shared<torch::nn::Module>()).get();
      start = dot + 1;
    }
    return {m, path.substr(start)};
  }

  enum class Init { glorot, linear_weight, linear_bias, zeros, constant };

  /// A parameter at `path`, or when not `trainable` a buffer; Init::constant (the only one a
  /// buffer takes) fills it with gain_or_fan_in.
  void make_parameter(const std::string& where, const std::string& path,
                      std::vector<std::int64_t> shape, Init init, double gain_or_fan_in,
                      bool trainable = true) {
    if (path.empty() || path.front() == '.' || path.back() == '.' ||
        path.find("..") != std::string::npos)
      throw ScheduleError(where + ": parameter path '" + path + "' is not a dotted name");
    auto it = params_.find(path);
    if (it != params_.end()) {
      if (it->second.sizes() != torch::IntArrayRef(shape))
        throw ScheduleError(where + ": parameter '" + path + "' is used with shape " +
                            shape_str(torch::empty(shape)) + " but was made " +
                            shape_str(it->second));
      if (buffers_.count(path) == static_cast<std::size_t>(trainable))
        throw ScheduleError(where + ": '" + path + "' is used as a " +
                            (trainable ? "parameter" : "buffer") + " but was made a " +
                            (trainable ? "buffer" : "parameter"));
      return;
    }
    for (auto d : shape)
      if (d <= 0)
        throw ScheduleError(where + ": parameter '" + path + "' would have shape " +
                            shape_str(torch::empty(shape)));
    auto [owner, leaf] = owner_of(path);
    if (!trainable) {  // non-trainable state, saved in the state_dict at its path
      params_.emplace(path, owner->register_buffer(leaf, torch::full(shape, gain_or_fan_in)));
      buffers_.insert(path);
      return;
    }
    auto p = owner->register_parameter(leaf, torch::empty(shape));
    torch::NoGradGuard g;
    if (init == Init::glorot) {
      xavier_uniform(p, gain_or_fan_in);
    } else if (init == Init::linear_weight) {
      torch::nn::init::kaiming_uniform_(p, std::sqrt(5.0));
    } else if (init == Init::zeros) {
      p.zero_();
    } else if (init == Init::constant) {
      p.fill_(gain_or_fan_in);
    } else {
      const double bound = 1 / std::sqrt(gain_or_fan_in);
      torch::nn::init::uniform_(p, -bound, bound);
    }
    params_.emplace(path, p);
  }

  /// A normalisation module at t.name (shared by name, like parameters).
  void make_norm(const std::string& where, const TermOp& t, std::int64_t channels) {
    const bool batch = t.kind == TermOp::Kind::batch_norm;
    auto same_width = [&](std::int64_t c) {
      if (c != channels)
        throw ScheduleError(where + ": normalisation '" + t.name + "' of " + std::to_string(c) +
                            " channels applied to " + std::to_string(channels));
    };
    if (batch && batch_norms_.count(t.name))
      return same_width(batch_norms_.at(t.name)->options.num_features());
    if (!batch && layer_norms_.count(t.name))
      return same_width(layer_norms_.at(t.name)->options.normalized_shape()[0]);
    if (params_.count(t.name + ".weight") || batch_norms_.count(t.name) ||
        layer_norms_.count(t.name))
      throw ScheduleError(where + ": '" + t.name + "' is already another kind of module");
    auto [owner, leaf] = owner_of(t.name);
    if (batch)
      batch_norms_.emplace(t.name, owner->register_module(leaf, torch::nn::BatchNorm1d(channels)));
    else
      layer_norms_.emplace(
          t.name, owner->register_module(
                      leaf, torch::nn::LayerNorm(torch::nn::LayerNormOptions({channels}))));
  }

  struct Shape {
    int rank;
    std::int64_t channels;
  };

  /// Applies an operation to a term's (rank, channels); creates its parameters.
  Shape infer(const std::string& where, const CochainKey& target, const TermOp& t, Shape x,
              const std::map<CochainKey, std::int64_t>& width) {
    const auto& sig = schedule_.operators();
    auto op = [&](const std::string& name) {
      auto it = sig.find(name);
      if (it == sig.end()) throw ScheduleError(where + ": unknown operator '" + name + "'");
      return it->second;
    };
    auto rank_error = [&](const std::string& name, int expected) {
      return ScheduleError(where + ": operator '" + name + "' applies to rank " +
                           std::to_string(expected) + " cochains, not rank " +
                           std::to_string(x.rank));
    };
    switch (t.kind) {
      case TermOp::Kind::via:
      case TermOp::Kind::pattern: {
        auto [src, dst] = op(t.name);
        if (t.transposed) std::swap(src, dst);
        if (src != x.rank) throw rank_error(t.name + (t.transposed ? "ᵀ" : ""), src);
        return {dst, x.channels};
      }
      case TermOp::Kind::attend:
        return infer_attend(where, target, t, x, width);
      case TermOp::Kind::via_transposed: {
        const auto [src, dst] = op(t.name);
        if (dst != x.rank) throw rank_error(t.name + "ᵀ", dst);
        return {src, x.channels};
      }
      case TermOp::Kind::weight:
        make_parameter(where, t.name, {x.channels, t.out}, Init::glorot, t.gain);
        return {x.rank, t.out};
      case TermOp::Kind::linear:
        make_parameter(where, t.name + ".weight", {t.out, x.channels}, Init::linear_weight, 0);
        if (t.bias)
          make_parameter(where, t.name + ".bias", {t.out}, Init::linear_bias,
                         static_cast<double>(x.channels));
        return {x.rank, t.out};
      case TermOp::Kind::initial_residual: {
        auto w = width.find(t.skip);
        if (w == width.end())
          throw ScheduleError(where + ": residual cochain " + t.skip.str() + " has no cochain");
        if (t.skip.rank != x.rank || w->second != x.channels)
          throw ScheduleError(where + ": residual cochain " + t.skip.str() + " of rank " +
                              std::to_string(t.skip.rank) + " and " + std::to_string(w->second) +
                              " channels added to rank " + std::to_string(x.rank) + " and " +
                              std::to_string(x.channels));
        make_parameter(where, t.name + ".weight", {x.channels, x.channels}, Init::linear_weight, 0);
        return x;
      }
      case TermOp::Kind::powers:
        for (const auto& [name, order] : t.filters) {
          const auto [src, dst] = op(name);
          if (src != x.rank || dst != x.rank)
            throw ScheduleError(where + ": filter operator '" + name + "' must map rank " +
                                std::to_string(x.rank) + " to itself");
          if (order < 0)
            throw ScheduleError(where + ": filter order of '" + name + "' is negative");
        }
        return x;
      case TermOp::Kind::batch_norm:
      case TermOp::Kind::layer_norm:
        make_norm(where, t, x.channels);
        return x;
      case TermOp::Kind::dropout:
        if (!(t.p >= 0 && t.p <= 1))
          throw ScheduleError(where + ": a dropout rate must be in [0, 1], got " +
                              std::to_string(t.p));
        return x;
      case TermOp::Kind::act:
      case TermOp::Kind::unit_rows:
        return x;
      case TermOp::Kind::scale:
        return x;
      case TermOp::Kind::head_weights:
        if (t.heads < 1)
          throw ScheduleError(where + ": head weights '" + t.name + "' need at least one head");
        make_parameter(where, t.name, {t.heads, x.channels, t.out}, Init::glorot, t.gain);
        return {x.rank, t.heads * t.out};
      case TermOp::Kind::bias: {
        const auto shape = t.shape.empty() ? std::vector<std::int64_t>{x.channels} : t.shape;
        if (torch::empty(shape).numel() != x.channels)
          throw ScheduleError(where + ": bias '" + t.name + "' of shape " +
                              shape_str(torch::empty(shape)) + " added to " +
                              std::to_string(x.channels) + " channels");
        make_parameter(where, t.name, shape, t.gain > 0 ? Init::glorot : Init::zeros, t.gain);
        return x;
      }
      case TermOp::Kind::learned_scale:
        make_parameter(where, t.name, {1}, Init::constant, t.value, t.trainable);
        return x;
      case TermOp::Kind::pow:
      case TermOp::Kind::normalize:
      case TermOp::Kind::intra_aggregate:
        return x;
      case TermOp::Kind::affine_power:
        if (t.filters.empty()) throw ScheduleError(where + ": an affine power needs an operator");
        if (t.filters[0].second < 0)
          throw ScheduleError(where + ": an affine power's exponent is negative");
        for (const auto& f : t.filters) {
          const auto [src, dst] = op(f.first);
          if (src != x.rank || dst != x.rank)
            throw ScheduleError(where + ": the affine power needs operators from rank " +
                                std::to_string(x.rank) + " to itself, '" + f.first + "' maps " +
                                std::to_string(src) + " -> " + std::to_string(dst));
        }
        return x;
    }
    return x;
  }

  /// attend's shapes: the keys', queries' and messages' widths against the heads and the
  /// parameters (created here); the result has the operator's target rank.
  Shape infer_attend(const std::string& where, const CochainKey& target, const TermOp& t, Shape x,
                     const std::map<CochainKey, std::int64_t>& width) {
    const auto& o = t.attention;
    auto it = schedule_.operators().find(t.name);
    if (it == schedule_.operators().end())
      throw ScheduleError(where + ": unknown operator '" + t.name + "'");
    auto [src, dst] = it->second;
    if (o.transposed()) std::swap(src, dst);
    const auto name = t.name + (o.transposed() ? "ᵀ" : "");
    const auto fail = [&](const std::string& why) {
      return ScheduleError(where + ": attention over '" + name + "' " + why);
    };
    if (src != x.rank)
      throw ScheduleError(where + ": operator '" + name + "' applies to rank " +
                          std::to_string(src) + " cochains, not rank " + std::to_string(x.rank));
    std::int64_t ck = x.channels, cq = 0;
    if (o.keys()) {
      auto w = width.find(*o.keys());
      if (o.keys()->rank != src || w == width.end())
        throw fail("takes its keys from " + o.keys()->str() + ", which needs a cochain of rank " +
                   std::to_string(src) + " before the step");
      ck = w->second;
    }
    if (!o.source_only()) {
      const auto key = o.queries() ? *o.queries() : target;
      auto w = width.find(key);
      if (key.rank != dst || w == width.end())
        throw fail("scores against " + std::string(o.queries() ? "" : "the target ") + key.str() +
                   ", which needs a cochain of rank " + std::to_string(dst) + " before the step");
      cq = w->second;
    }
    const auto H = o.heads();
    if (H < 1 || x.channels % H || ck % H || cq % H)
      throw fail("with " + std::to_string(H) + " heads: the messages (" +
                 std::to_string(x.channels) + "), keys (" + std::to_string(ck) + ") and queries (" +
                 std::to_string(cq) + ") need channels divisible by the heads");
    if (o.v2() && cq != ck)
      throw fail("(GATv2) needs queries as wide as its keys, got " + std::to_string(cq) + " and " +
                 std::to_string(ck));
    const bool split = !o.target_param().empty();
    if (split && (o.v2() || o.source_only()))
      throw fail("has no target part for '" + o.target_param() + "'");
    if (o.dropout() < 0 || o.dropout() > 1) throw fail("needs a dropout rate in [0, 1]");
    const auto P = o.filters();
    if (P < 1 || (P > 1 && (H != 1 || x.channels % P)))
      throw fail("with " + std::to_string(P) + " filters needs one head and messages (" +
                 std::to_string(x.channels) + " channels) of whole filters");
    const auto n = o.source_only() || o.v2() || split ? ck : ck + cq;
    for (const auto& offset : {o.source_offset(), o.target_offset()})
      if (offset && (n == ck || *offset < 0 || *offset >= n))
        throw fail(n == ck ? "has offsets but no target part in its parameter"
                           : "needs offsets in [0, " + std::to_string(n) + "), got " +
                                 std::to_string(*offset));
    auto make = [&](const std::string& path, std::vector<std::int64_t> shape, std::int64_t count) {
      if (shape.empty()) shape = {count};
      if (torch::empty(shape).numel() != count)
        throw fail("needs " + std::to_string(count) + " entries in '" + path + "', its shape " +
                   shape_str(torch::empty(shape)) + " has " +
                   std::to_string(torch::empty(shape).numel()));
      make_parameter(where, path, shape, Init::glorot, o.gain());
    };
    make(o.param(), o.shape(), n);
    if (split) make(o.target_param(), o.target_shape(), cq);
    return {dst, o.concat() && P == 1 ? x.channels : x.channels / (H * P)};
  }

  void validate_and_create() {
    for (const auto& d : schedule_.dropped_operators()) {
      const auto where = "dropped operator '" + d.name + "'";
      auto& sig = schedule_.operators();
      auto it = sig.find(d.source);
      if (it == sig.end()) throw ScheduleError(where + ": unknown operator '" + d.source + "'");
      if (sig.count(d.name)) throw ScheduleError(where + ": the name is already an operator input");
      if (!(d.rate >= 0 && d.rate <= 1))
        throw ScheduleError(where + ": the rate must be in [0, 1], got " + std::to_string(d.rate));
      schedule_.operator_input(d.name, it->second.first, it->second.second);
    }
    std::map<CochainKey, std::int64_t> width;
    std::set<std::string> names;
    for (const auto& in : schedule_.inputs()) {
      if (!names.insert(in.name).second)
        throw ScheduleError("input '" + in.name + "' is declared twice");
      if (in.channels <= 0)
        throw ScheduleError("input '" + in.name + "' needs a positive number of channels");
      width[in.key] = in.channels;
    }
    for (const auto& group : schedule_.groups()) {
      auto next = width;
      std::set<CochainKey> written;
      for (const auto& s : group) {
        const std::string where = s.name + " (into " + s.target.str() + ")";
        if (!written.insert(s.target).second)
          throw ScheduleError(where + ": another step of the same parallel group writes " +
                              s.target.str());
        if (s.terms.empty()) throw ScheduleError(where + ": a step needs at least one term");
        std::int64_t channels = -1, count = 0;
        for (const auto& term : s.terms) {
          auto w = width.find(term.source);
          if (w == width.end())
            throw ScheduleError(where + ": source " + term.source.str() +
                                " has no cochain (no input or earlier step produces it)");
          Shape x{term.source.rank, w->second};
          std::int64_t fanned = 1;
          const auto& list = term.operations();
          for (std::size_t i = 0; i < list.size(); ++i) {
            if (list[i].kind == TermOp::Kind::powers) {
              if (i + 1 != list.size())
                throw ScheduleError(where + ": powers must be a term's last operation");
              fanned = 1;
              for (const auto& f : list[i].filters) fanned += f.second;
            }
            x = infer(where, s.target, list[i], x, width);
          }
          if (x.rank != s.target.rank)
            throw ScheduleError(where + ": the term from " + term.source.str() + " ends on rank " +
                                std::to_string(x.rank) + ", the target is rank " +
                                std::to_string(s.target.rank));
          if (s.mix == OperatorStep::Mix::concat) {  // widths add up
            channels = std::max<std::int64_t>(channels, 0) + x.channels;
          } else {
            if (channels >= 0 && x.channels != channels)
              throw ScheduleError(where + ": the term from " + term.source.str() + " has " +
                                  std::to_string(x.channels) + " channels, the one before has " +
                                  std::to_string(channels));
            channels = x.channels;
          }
          count += fanned;
        }
        Shape y{s.target.rank, channels};
        if (s.mix == OperatorStep::Mix::filter) {
          make_parameter(where, s.filter_path, {channels, s.filter_out, count}, Init::glorot,
                         1.414);
          y.channels = s.filter_out;
        } else if (count != static_cast<std::int64_t>(s.terms.size())) {
          throw ScheduleError(where + ": polynomial filter terms need a filter weight to mix them");
        }
        for (const auto& t : s.operations()) {
          if (t.kind == TermOp::Kind::powers)
            throw ScheduleError(where + ": powers apply to terms, not to a step");
          y = infer(where, s.target, t, y, width);
        }
        next[s.target] = y.channels;
      }
      width = std::move(next);
    }
    for (const auto& o : schedule_.outputs())
      if (!width.count(o.key))
        throw ScheduleError("output '" + o.name + "': no cochain " + o.key.str());
    for (const auto& p : schedule_.parameters())
      make_parameter("parameter '" + p.path + "'", p.path, p.shape, Init::glorot, p.gain);
  }
};
TORCH_MODULE(OperatorNetwork);

}  // namespace topos::nn
