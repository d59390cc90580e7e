// topos/nn/functional.hpp
// The functions under the operator schedule's operations, general enough to write new ones:
// update functions, messages weighted by an operator's values (optionally row-normalised),
// polynomial filters (A x, A² x, ... A^K x,
// optionally row-normalised), attention over a target's incoming messages (per-entry scores
// from source and target features, an activation, then a per-target softmax or row
// normalisation; the weighted operator and multi-head messages every attention shares), affine
// powers, readouts, dropout (its mask drawn by a counter-based kernel, several times faster
// than torch 1.13's on the CPU) and weight initialisers. Parameter names and
// layouts are TopoModelX's
// (Conv.weight is in × out, Conv.att_weight has 2·in entries) so its state_dicts load as they are.
#pragma once

#include "topos/nn/activation.hpp"
#include "topos/nn/kernels/attention.hpp"
#include "topos/nn/kernels/dropout.hpp"
#include "topos/nn/sparse_operator.hpp"

#include <ATen/CPUGeneratorImpl.h>
#include <torch/torch.h>

#include <algorithm>
#include <cmath>
#include <mutex>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

namespace topos::nn {

/// How messages reaching one target are combined. `max` only over a batch's neighbourhoods
/// (aggregate.hpp), not over a SparseOperator's pattern.
enum class Aggr { sum, mean, max };

inline const char* aggr_name(Aggr a) {
  return a == Aggr::sum ? "sum" : (a == Aggr::mean ? "mean" : "max");
}

/// Row normalisation by the operator's row sums, 0 where a row sums to 0 (SCCNN's aggr_norm).
inline torch::Tensor divide_by_row_sums(const SparseOperator& A, const torch::Tensor& x) {
  auto inv = A.row_sums().to(x.scalar_type()).reciprocal();
  inv = torch::where(torch::isfinite(inv), inv, torch::zeros_like(inv));
  return x * inv.unsqueeze(1);
}

/// A hypergraph model's node features against its node × hyperedge incidence: a clear error
/// naming the model when the counts differ.
inline void check_node_features(const char* model, const torch::Tensor& x0,
                                const SparseOperator& incidence) {
  if (x0.dim() != 2 || x0.size(0) != incidence.rows)
    throw std::invalid_argument(
        std::string(model) + ": " + std::to_string(x0.dim() == 2 ? x0.size(0) : -1) +
        " node features for an incidence of " + std::to_string(incidence.rows) + " nodes");
}

/// Messages along A's pattern only (its values ignored, as torch_scatter over a matrix's indices):
/// each target row gets the sum, or the mean, of its sources' rows; a target without sources gets
/// zeros (the count is clamped at 1, as scatter_mean does). A two-stage hypergraph message is
/// pattern_aggregate(B, pattern_aggregate(Bᵀ, x_0)) with B the node × hyperedge incidence.
inline torch::Tensor pattern_aggregate(const SparseOperator& A, const torch::Tensor& x,
                                       Aggr aggr = Aggr::sum) {
  if (aggr == Aggr::max)
    throw std::invalid_argument(
        "pattern_aggregate: max over a sparse operator's pattern is not "
        "supported (it is over a batch neighbourhood)");
  A.require_entries("pattern_aggregate");
  auto y = spmm(A.pattern().to(x.scalar_type()), x);
  if (aggr == Aggr::mean) {
    const auto count = torch::diff(A.crow).to(x.scalar_type()).clamp_min(1).to(x.device());
    y = y / count.unsqueeze(1);
  }
  return y;
}

namespace detail {
// Dropout whose mask is drawn again in the backward from its seed (kernels/dropout.hpp): one pass
// each way, nothing stored. The backward is this function again, so it differentiates too.
struct DropoutFunction : public torch::autograd::Function<DropoutFunction> {
  static torch::Tensor forward(torch::autograd::AutogradContext* ctx, const torch::Tensor& x,
                               std::int64_t seed, double p) {
    ctx->saved_data["seed"] = seed, ctx->saved_data["p"] = p;
    return run(x, static_cast<std::uint64_t>(seed), p);
  }
  static torch::autograd::tensor_list backward(torch::autograd::AutogradContext* ctx,
                                               torch::autograd::tensor_list grads) {
    const auto seed = ctx->saved_data["seed"].toInt();
    const auto p = ctx->saved_data["p"].toDouble();
    return {DropoutFunction::apply(grads[0], seed, p), torch::Tensor(), torch::Tensor()};
  }
  static torch::Tensor run(const torch::Tensor& x, std::uint64_t seed, double p) {
    const auto in = x.contiguous();
    auto y = torch::empty_like(in, at::MemoryFormat::Contiguous);
    AT_DISPATCH_FLOATING_TYPES(in.scalar_type(), "topos_dropout", [&] {
      dropout_apply<scalar_t>(in.data_ptr<scalar_t>(), y.data_ptr<scalar_t>(), in.numel(), seed,
                              DropoutRate::of(p), static_cast<scalar_t>(1.0 / (1.0 - p)));
    });
    return y;
  }
};
}  // namespace detail

namespace detail {
/// The calling thread's dropout stream (ScopedDropoutStream), or null.
inline std::uint64_t*& thread_dropout_stream() {
  thread_local std::uint64_t* stream = nullptr;
  return stream;
}
}  // namespace detail

/// While alive, the calling thread's dropout masks (nn::dropout on the CPU) are seeded from a
/// stream of its own, started at `seed`, instead of torch's default generator. torch's generator
/// is one per process: runs trained on several threads at once would otherwise take each other's
/// draws, and their results would depend on how the threads interleave. Scopes nest; the stream
/// is the innermost one's.
class ScopedDropoutStream {
 public:
  explicit ScopedDropoutStream(std::uint64_t seed)
      : state_(seed), outer_(detail::thread_dropout_stream()) {
    detail::thread_dropout_stream() = &state_;
  }
  ~ScopedDropoutStream() { detail::thread_dropout_stream() = outer_; }
  ScopedDropoutStream(const ScopedDropoutStream&) = delete;
  ScopedDropoutStream& operator=(const ScopedDropoutStream&) = delete;

 private:
  std::uint64_t state_;
  std::uint64_t* outer_;
};

/// torch::dropout's semantics (in training each element is zeroed with probability p and the
/// others scaled by 1 / (1 - p); the identity otherwise), differentiable in x. On the CPU the mask
/// comes from kernels/dropout.hpp, seeded by one draw of torch's default generator (so
/// torch::manual_seed repeats it), or of the thread's ScopedDropoutStream; elsewhere torch draws
/// it.
inline torch::Tensor dropout(const torch::Tensor& x, double p, bool training) {
  if (!(p >= 0 && p <= 1))
    throw std::invalid_argument("dropout: rate " + std::to_string(p) + " outside [0, 1]");
  if (!training || p == 0) return x;
  const bool floating = x.scalar_type() == torch::kFloat || x.scalar_type() == torch::kDouble;
  if (p == 1 || !x.device().is_cpu() || !floating) return torch::dropout(x, p, training);
  std::uint64_t seed = 0;
  if (std::uint64_t* stream = detail::thread_dropout_stream()) {
    seed = detail::splitmix64(*stream += 0x9E3779B97F4A7C15ull);
  } else {
    auto gen = at::detail::getDefaultCPUGenerator();
    std::lock_guard<std::mutex> lock(gen.mutex());
    seed = at::check_generator<at::CPUGeneratorImpl>(gen)->random64();
  }
  return detail::DropoutFunction::apply(x, static_cast<std::int64_t>(seed), p);
}

/// Each row divided by its L2 norm, the norm a constant for autograd; rows of norm 0 stay 0
/// (UniGNN's use_norm).
inline torch::Tensor unit_rows(const torch::Tensor& x) {
  auto scale = x.detach().norm(2, 1, true).reciprocal();
  return x * torch::where(torch::isinf(scale), torch::zeros_like(scale), scale);
}

/// Polynomial filter terms A x, A² x, ..., A^K x. With `row_norm`, each term is divided by A's
/// row sums (from power `norm_from` on: SCCNN normalises every power, SCNN skips the first).
inline std::vector<torch::Tensor> powers(const SparseOperator& A, torch::Tensor x, int K,
                                         bool row_norm = false, int norm_from = 1) {
  std::vector<torch::Tensor> out;
  for (int k = 1; k <= K; ++k) {
    x = spmm(A, x);
    if (row_norm && k >= norm_from) x = divide_by_row_sums(A, x);
    out.push_back(x);
  }
  return out;
}

/// Per-entry scores from per-cell ones: s_col[col k] + s_row[row k] (a source's and a target's).
inline torch::Tensor entry_scores(const SparseOperator& A, const torch::Tensor& s_col,
                                  const torch::Tensor& s_row) {
  A.require_entries("entry_scores");
  return s_col.index_select(0, A.col.to(s_col.device())) +
         s_row.index_select(0, A.row.to(s_row.device()));
}

/// Per-entry attention scores of A's pattern: score_k = <x_col[col k], a_col> + <x_row[row k],
/// a_row>
/// (a target's row and a source's column; GAT's a·[W h_j || W h_i] split in two halves),
/// computed per cell first so the cost is O(n C + nnz).
inline torch::Tensor pair_scores(const SparseOperator& A, const torch::Tensor& x_col,
                                 const torch::Tensor& a_col, const torch::Tensor& x_row,
                                 const torch::Tensor& a_row) {
  if (x_col.size(1) != a_col.numel() || x_row.size(1) != a_row.numel())
    throw std::invalid_argument("pair_scores: attention vector of " +
                                std::to_string(a_col.numel() + a_row.numel()) +
                                " entries for features of " + std::to_string(x_col.size(1)) +
                                " + " + std::to_string(x_row.size(1)) + " channels");
  return entry_scores(A, x_col.matmul(a_col.reshape({-1})), x_row.matmul(a_row.reshape({-1})));
}

/// How per-entry scores become weights: a per-target softmax, division by the row sum, or as is.
enum class AttentionNorm { softmax, row_sum, none };

inline torch::Tensor attention_weights(const SparseOperator& A, const torch::Tensor& raw,
                                       Activation activation, double negative_slope,
                                       AttentionNorm norm) {
  const auto s = apply_activation(raw, activation, negative_slope);
  if (norm == AttentionNorm::softmax) return row_softmax(A, s);
  if (norm == AttentionNorm::row_sum) return row_normalize(A, s);
  return s;
}

namespace detail {
// head_scores' node: it keeps f and a; its backward is one pass over f's rows
// (kernels/attention.hpp).
struct HeadScoresFunction : public torch::autograd::Function<HeadScoresFunction> {
  static torch::Tensor compute(const torch::Tensor& f, const torch::Tensor& a, std::int64_t H) {
    auto out =
        H == 1 ? torch::empty({f.size(0)}, f.options()) : torch::empty({f.size(0), H}, f.options());
    AT_DISPATCH_FLOATING_TYPES(f.scalar_type(), "topos_head_scores", [&] {
      head_scores_forward<scalar_t>(f.data_ptr<scalar_t>(), a.data_ptr<scalar_t>(),
                                    out.data_ptr<scalar_t>(), f.size(0), H, f.size(1) / H);
    });
    return out;
  }
  static torch::Tensor forward(torch::autograd::AutogradContext* ctx, const torch::Tensor& f,
                               const torch::Tensor& a, std::int64_t H) {
    const auto fc = f.contiguous(), ac = a.contiguous();
    ctx->save_for_backward({fc, ac});
    ctx->saved_data["heads"] = H;
    return compute(fc, ac, H);
  }
  static torch::autograd::tensor_list backward(torch::autograd::AutogradContext* ctx,
                                               torch::autograd::tensor_list grads) {
    const auto s = ctx->get_saved_variables();
    const auto &f = s[0], &a = s[1];
    const auto H = ctx->saved_data["heads"].toInt();
    const auto g = grads[0].contiguous();
    torch::Tensor df, da;
    if (ctx->needs_input_grad(0)) df = torch::empty_like(f);
    if (ctx->needs_input_grad(1)) da = torch::zeros_like(a);
    AT_DISPATCH_FLOATING_TYPES(f.scalar_type(), "topos_head_scores_backward", [&] {
      head_scores_backward<scalar_t>(
          g.data_ptr<scalar_t>(), f.data_ptr<scalar_t>(), a.data_ptr<scalar_t>(),
          df.defined() ? df.data_ptr<scalar_t>() : nullptr,
          da.defined() ? da.data_ptr<scalar_t>() : nullptr, f.size(0), H, f.size(1) / H);
    });
    return {df, da, torch::Tensor()};
  }
};
}  // namespace detail

/// Per cell and head, <f_h, a_h>: f (cells × heads·C) and a (heads·C entries) split head-major.
/// One head: the vector of f's rows' products with a; several: cells × heads. With entry_scores,
/// GAT's raw a_s·k_j + a_t·q_i per head. On the CPU (float, double) one autograd node and one
/// pass over f each way (no second derivative); elsewhere torch's ops.
inline torch::Tensor head_scores(const torch::Tensor& f, const torch::Tensor& a,
                                 std::int64_t heads = 1) {
  const auto av = a.reshape({-1});
  if (heads < 1 || (f.dim() == 2 && (f.size(1) % heads != 0 || av.numel() != f.size(1))))
    throw std::invalid_argument(
        "head_scores: " + std::to_string(f.dim() == 2 ? f.size(1) : -1) + " channels with " +
        std::to_string(av.numel()) + " attention weights in " + std::to_string(heads) +
        " heads; give as many weights as channels, a multiple of the heads");
  const bool fused = f.device().is_cpu() && av.device().is_cpu() && f.dim() == 2 && f.size(1) > 0 &&
                     f.size(1) % heads == 0 && av.numel() == f.size(1) &&
                     (f.scalar_type() == torch::kFloat || f.scalar_type() == torch::kDouble) &&
                     av.scalar_type() == f.scalar_type();
  if (!fused) {
    if (heads == 1) return f.mv(av);
    return (f.reshape({f.size(0), heads, -1}) * a.reshape({1, heads, -1})).sum(-1);
  }
  if (!torch::GradMode::is_enabled() || !(f.requires_grad() || av.requires_grad()))
    return detail::HeadScoresFunction::compute(f.contiguous(), av.contiguous(), heads);
  return detail::HeadScoresFunction::apply(f, av, heads);
}

/// The operator attention applies: A's pattern with values w ⊙ A's values, w the weights from
/// raw per-entry scores (attention_weights: activation, then the per-target norm), entry k taking
/// entry order[k]'s weight when `order` is given (a permutation of A's entries: HMC's mirrored
/// rows, SparseOperator::row_mirror), then dropped out at rate `dropout` in training. The one
/// place every attention (the schedule's `attend`, HMC's, CAN's, SAN's operations) weighs A.
inline SparseOperator attention_operator(const SparseOperator& A, const torch::Tensor& raw,
                                         Activation activation, double negative_slope,
                                         AttentionNorm norm, double dropout = 0,
                                         bool training = false, const torch::Tensor& order = {}) {
  auto w = attention_weights(A, raw, activation, negative_slope, norm);
  if (order.defined()) w = w.index_select(0, order.to(w.device()));
  if (dropout > 0) w = nn::dropout(w, dropout, training);
  return A.with_values(w * A.values.to(w.scalar_type()));
}

/// Multi-head attention's messages: x (A.cols × heads·C) split into heads in column blocks, head
/// h's block multiplied by attention_operator(A, its raw scores) (`raw`: one score per entry for
/// one head, or nnz × heads), the heads side by side (`concat`) or averaged.
inline torch::Tensor multi_head_attention(const SparseOperator& A, const torch::Tensor& raw,
                                          const torch::Tensor& x, bool concat,
                                          Activation activation, double negative_slope,
                                          AttentionNorm norm, double dropout = 0,
                                          bool training = false) {
  const auto H = raw.dim() == 1 ? 1 : raw.size(1);
  if (x.size(1) % H)
    throw std::invalid_argument("multi_head_attention: " + std::to_string(x.size(1)) +
                                " channels for " + std::to_string(H) + " heads");
  std::vector<torch::Tensor> heads;
  const auto x_h = H == 1 ? std::vector<torch::Tensor>{x} : x.split(x.size(1) / H, 1);
  for (std::int64_t i = 0; i < H; ++i) {
    const auto W = attention_operator(A, raw.dim() == 1 ? raw : raw.select(1, i).contiguous(),
                                      activation, negative_slope, norm, dropout, training);
    heads.push_back(spmm(W, x_h[static_cast<std::size_t>(i)].contiguous()));
  }
  if (H == 1) return heads[0];
  return concat ? torch::cat(heads, 1) : torch::stack(heads, 0).mean(0);
}

namespace detail {
// multi_head_attention_from_cells' node: it keeps the normed weights (entries × heads) and what it
// read; its backward is attention_backward's pass over the rows, then over Aᵀ's.
struct CellAttentionFunction : public torch::autograd::Function<CellAttentionFunction> {
  template <class T>
  static AttentionArgs<T> args(const torch::Tensor& source, const torch::Tensor& target,
                               const torch::Tensor& x, const torch::Tensor& values,
                               const torch::Tensor& crow, const torch::Tensor& col,
                               const torch::Tensor& t_crow, const torch::Tensor& t_row,
                               const torch::Tensor& t_perm, const torch::Tensor& weights,
                               std::int64_t how, double slope) {
    AttentionArgs<T> a;
    a.crow = crow.data_ptr<std::int64_t>(), a.col = col.data_ptr<std::int64_t>();
    a.t_crow = t_crow.data_ptr<std::int64_t>(), a.t_row = t_row.data_ptr<std::int64_t>();
    a.t_perm = t_perm.data_ptr<std::int64_t>(), a.values = values.data_ptr<T>();
    a.source = source.data_ptr<T>();  // no target scores: undefined, or autograd's empty stand-in
    a.target = target.defined() && target.numel() > 0 ? target.data_ptr<T>() : nullptr;
    a.x = x.data_ptr<T>(), a.weights = weights.data_ptr<T>();
    a.rows = crow.size(0) - 1, a.cols = x.size(0), a.nnz = col.size(0), a.heads = source.size(1);
    a.channels = x.size(1) / a.heads;
    a.act = static_cast<ScoreActivation>(how & 3), a.norm = static_cast<ScoreNorm>(how >> 2);
    a.slope = static_cast<T>(slope);
    return a;
  }
  /// The output and the normed weights.
  static std::pair<torch::Tensor, torch::Tensor> compute(
      const torch::Tensor& source, const torch::Tensor& target, const torch::Tensor& x,
      const torch::Tensor& values, const torch::Tensor& crow, const torch::Tensor& col,
      const torch::Tensor& t_crow, const torch::Tensor& t_row, const torch::Tensor& t_perm,
      std::int64_t how, double slope) {
    auto w = torch::empty({col.size(0), source.size(1)}, source.options());
    auto y = torch::empty({crow.size(0) - 1, x.size(1)}, x.options());
    AT_DISPATCH_FLOATING_TYPES(x.scalar_type(), "topos_attention", [&] {
      attention_forward(args<scalar_t>(source, target, x, values, crow, col, t_crow, t_row, t_perm,
                                       w, how, slope),
                        y.data_ptr<scalar_t>());
    });
    return {y, w};
  }
  static torch::Tensor forward(torch::autograd::AutogradContext* ctx, const torch::Tensor& source,
                               const torch::Tensor& target, const torch::Tensor& x,
                               const torch::Tensor& values, const torch::Tensor& crow,
                               const torch::Tensor& col, const torch::Tensor& t_crow,
                               const torch::Tensor& t_row, const torch::Tensor& t_perm,
                               std::int64_t how, double slope) {
    auto [y, w] = compute(source, target, x, values, crow, col, t_crow, t_row, t_perm, how, slope);
    ctx->save_for_backward({source, target, x, values, crow, col, t_crow, t_row, t_perm, w});
    ctx->saved_data["how"] = how;
    ctx->saved_data["slope"] = slope;
    return y;
  }
  static torch::autograd::tensor_list backward(torch::autograd::AutogradContext* ctx,
                                               torch::autograd::tensor_list grads) {
    const auto s = ctx->get_saved_variables();
    const auto &source = s[0], &target = s[1], &x = s[2], &w = s[9];
    const auto g = grads[0].contiguous();
    const auto H = source.size(1);
    auto d = torch::empty({s[5].size(0), H}, source.options());
    torch::Tensor d_source, d_target, dx;
    if (ctx->needs_input_grad(0)) d_source = torch::empty({x.size(0), H}, source.options());
    if (ctx->needs_input_grad(1)) d_target = torch::empty({g.size(0), H}, source.options());
    if (ctx->needs_input_grad(2)) dx = torch::empty_like(x);
    const auto ptr = [](torch::Tensor& t, auto* type) {
      return t.defined() ? t.data_ptr<std::remove_pointer_t<decltype(type)>>() : nullptr;
    };
    AT_DISPATCH_FLOATING_TYPES(x.scalar_type(), "topos_attention_backward", [&] {
      const auto a =
          args<scalar_t>(source, target, x, s[3], s[4], s[5], s[6], s[7], s[8], w,
                         ctx->saved_data["how"].toInt(), ctx->saved_data["slope"].toDouble());
      scalar_t* type = nullptr;
      attention_backward(a, g.data_ptr<scalar_t>(), d.data_ptr<scalar_t>(), ptr(d_target, type),
                         ptr(d_source, type), ptr(dx, type));
    });
    return {d_source, d_target, dx, {}, {}, {}, {}, {}, {}, {}, {}};
  }
};
}  // namespace detail

/// Multi-head attention's messages from per-cell scores: entry k of A (target row i, source column
/// j) scores raw[k, h] = source[j, h] + target[i, h] (the source's alone where `target` is
/// undefined), then as multi_head_attention: the activation, the per-target norm, dropout, times
/// A's values, head h's block of x (A.cols × heads·C) weighted, the heads side by side (`concat`)
/// or averaged. `source` and `target` are cells × heads, or vectors for one head. With `fused`, on
/// the CPU, in float or double, with the activation none, relu, leaky_relu or elu, A's values
/// constants and no dropout in training, it is one autograd node (kernels/attention.hpp: a pass
/// over A's rows forward, one over its rows and one over its columns backward) where torch's
/// operations took about ten per head; otherwise entry_scores then multi_head_attention, the same
/// numbers up to rounding.
inline torch::Tensor multi_head_attention_from_cells(
    const SparseOperator& A, const torch::Tensor& source, const torch::Tensor& target,
    const torch::Tensor& x, bool concat, Activation activation, double negative_slope,
    AttentionNorm norm, double dropout = 0, bool training = false, bool fused = true) {
  A.require_entries("multi_head_attention_from_cells");
  const auto H = source.dim() == 1 ? 1 : source.size(1);
  const auto shape = [](const torch::Tensor& t) {
    std::ostringstream o;
    o << t.sizes();
    return o.str();
  };
  if (source.dim() > 2 || source.size(0) != A.cols ||
      (target.defined() && target.size(0) != A.rows) ||
      (target.defined() && (target.dim() == 1 ? 1 : target.size(1)) != H) || x.dim() != 2 ||
      x.size(0) != A.cols || x.size(1) % H != 0)
    throw std::invalid_argument(
        "multi_head_attention_from_cells: the operator is " + std::to_string(A.rows) + " x " +
        std::to_string(A.cols) + "; the source scores " + shape(source) + " and the messages " +
        shape(x) + " need " + std::to_string(A.cols) + " rows" +
        (target.defined() ? ", the target scores " + shape(target) + " " + std::to_string(A.rows)
                          : std::string()) +
        ", one score per head and channels divisible by the heads");
  const auto kind = x.scalar_type();
  const auto cpu_as_x = [&](const torch::Tensor& t) {
    return !t.defined() || (t.device().is_cpu() && t.scalar_type() == kind);
  };
  const bool act_fuses = activation == Activation::none || activation == Activation::relu ||
                         activation == Activation::leaky_relu || activation == Activation::elu;
  if (!fused || !x.device().is_cpu() || (kind != torch::kFloat && kind != torch::kDouble) ||
      !cpu_as_x(source) || !cpu_as_x(target) || !act_fuses || A.values.requires_grad() ||
      (dropout > 0 && training)) {
    const auto raw = target.defined() ? entry_scores(A, source, target)
                                      : source.index_select(0, A.col.to(source.device()));
    return multi_head_attention(A, raw, x, concat, activation, negative_slope, norm, dropout,
                                training);
  }
  using detail::ScoreActivation;
  const auto act = activation == Activation::relu         ? ScoreActivation::relu
                   : activation == Activation::leaky_relu ? ScoreActivation::leaky_relu
                   : activation == Activation::elu        ? ScoreActivation::elu
                                                          : ScoreActivation::none;
  const auto how = static_cast<std::int64_t>(act) | static_cast<std::int64_t>(norm) << 2;
  const auto as_matrix = [&](const torch::Tensor& t) {
    return t.defined() ? t.reshape({t.size(0), H}).contiguous() : t;
  };
  const auto src = as_matrix(source), tgt = as_matrix(target), xc = x.contiguous();
  const auto values = A.values.scalar_type() == kind ? A.values : A.values.to(kind);
  torch::Tensor y;
  if (!torch::GradMode::is_enabled() ||
      !(src.requires_grad() || (tgt.defined() && tgt.requires_grad()) || xc.requires_grad()))
    y = detail::CellAttentionFunction::compute(src, tgt, xc, values, A.crow, A.col, A.t_crow,
                                               A.t_col, A.t_perm, how, negative_slope)
            .first;
  else  // autograd takes no undefined input: no target scores as an empty tensor
    y = detail::CellAttentionFunction::apply(src, tgt.defined() ? tgt : src.new_empty({0}), xc,
                                             values, A.crow, A.col, A.t_crow, A.t_col, A.t_perm,
                                             how, negative_slope);
  return concat || H == 1 ? y : y.view({A.rows, H, -1}).mean(1);
}

/// Glorot initialisation with TopoModelX's gain for a weight of any rank (fan_in = size(1)·rest,
/// fan_out = size(0)·rest, as torch.nn.init computes them).
inline void xavier_uniform(const torch::Tensor& w, double gain = 1.414) {
  torch::NoGradGuard g;
  auto v =
      w.dim() < 2 ? w.view({-1, 1}) : w;  // a vector as a column, like TopoModelX's view(-1, 1)
  torch::nn::init::xavier_uniform_(v, gain);
}

/// A weight tensor for the combination of several filter terms: y = act(base + Σ_k X_k W[:, :, k])
/// (TopoModelX's einsum "nik,iok->no" over stacked terms; base undefined for none), computed
/// without the stack, the activation applied as the product is stored. A term given twice as the
/// same tensor (a schedule naming one term twice, computed once: TopoBench's SCCNN takes L↓x_1
/// twice) is multiplied once, by the sum of its weight slices.
inline torch::Tensor combine_terms(const std::vector<torch::Tensor>& terms,
                                   const torch::Tensor& weight, Epilogue act = Epilogue::none,
                                   const torch::Tensor& base = {}) {
  if (static_cast<std::int64_t>(terms.size()) != weight.size(2))
    throw std::invalid_argument("combine_terms: " + std::to_string(terms.size()) +
                                " terms for a weight with " + std::to_string(weight.size(2)) +
                                " filters");
  std::vector<torch::Tensor> unique;
  std::vector<std::vector<std::int64_t>> slices;  // per unique term, its filters
  for (std::size_t k = 0; k < terms.size(); ++k) {
    std::size_t j = 0;
    while (j < unique.size() && !unique[j].is_same(terms[k])) ++j;
    if (j == unique.size()) unique.push_back(terms[k]), slices.emplace_back();
    slices[j].push_back(static_cast<std::int64_t>(k));
  }
  // One product n × (K·in) by (K·in) × out over the terms side by side, never concatenated
  // (linear_blocks): each term's gradient comes back whole, not as a strided slice.
  if (unique.size() == terms.size())
    return linear_blocks(unique, weight.permute({2, 0, 1}).reshape({-1, weight.size(1)}).t(), act,
                         base);
  std::vector<torch::Tensor> blocks;
  for (const auto& s : slices) {
    auto w = weight.select(2, s[0]);
    for (std::size_t i = 1; i < s.size(); ++i) w = w + weight.select(2, s[i]);
    blocks.push_back(w);
  }
  return linear_blocks(unique, torch::cat(blocks, 0).t(), act, base);
}

namespace detail {
// (a I + b Σ_i A_i)^k is linear in x and the A_i are constants here, so its backward is
// (a I + b Σ_i A_iᵀ)^k applied to the gradient: nothing of the k intermediate products is kept.
struct AffinePowerFunction : public torch::autograd::Function<AffinePowerFunction> {
  static torch::Tensor forward(torch::autograd::AutogradContext* ctx, const torch::Tensor& x,
                               const std::vector<SparseOperator>& terms, std::int64_t k, double a,
                               double b) {
    std::vector<torch::Tensor> crow, col, values, t_crow, t_col, t_perm;
    for (const auto& A : terms) {
      crow.push_back(A.crow), col.push_back(A.col), values.push_back(A.values.to(x.scalar_type()));
      t_crow.push_back(A.t_crow), t_col.push_back(A.t_col), t_perm.push_back(A.t_perm);
    }
    ctx->saved_data["k"] = k, ctx->saved_data["a"] = a, ctx->saved_data["b"] = b;
    ctx->saved_data["t_crow"] = t_crow, ctx->saved_data["t_col"] = t_col;
    ctx->saved_data["t_perm"] = t_perm, ctx->saved_data["values"] = values;
    return run(x, crow, col, values, {}, k, a, b);
  }
  static torch::autograd::tensor_list backward(torch::autograd::AutogradContext* ctx,
                                               torch::autograd::tensor_list grads) {
    auto& d = ctx->saved_data;
    const auto dx = run(grads[0], d["t_crow"].toTensorVector(), d["t_col"].toTensorVector(),
                        d["values"].toTensorVector(), d["t_perm"].toTensorVector(), d["k"].toInt(),
                        d["a"].toDouble(), d["b"].toDouble());
    return {dx, torch::Tensor(), torch::Tensor(), torch::Tensor(), torch::Tensor()};
  }
  static torch::Tensor run(torch::Tensor x, const std::vector<torch::Tensor>& crow,
                           const std::vector<torch::Tensor>& col,
                           const std::vector<torch::Tensor>& values,
                           const std::vector<torch::Tensor>& perm, std::int64_t k, double a,
                           double b) {
    torch::NoGradGuard g;
    const auto rows = x.size(0);
    for (std::int64_t i = 0; i < k; ++i) {
      torch::Tensor y;
      for (std::size_t t = 0; t < crow.size(); ++t) {
        const auto p = perm.empty() ? torch::Tensor() : perm[t];
        const auto z = csr_apply(crow[t], col[t], values[t], p, x, rows);
        y = y.defined() ? y.add_(z) : z;
      }
      x = y.mul_(b).add_(x, a);
    }
    return x;
  }
};
}  // namespace detail

/// (a I + b Σ_i A_i)^k x by k rounds of sparse products, never forming the sum or its power:
/// SAN's harmonic projection (I - ε(L↑ + L↓))^k without the dense n × n power. The A_i must be
/// square and constant (their values are not differentiated); the backward keeps no
/// intermediate product.
inline torch::Tensor apply_affine_power(const std::vector<SparseOperator>& terms,
                                        const torch::Tensor& x, int k, double a, double b) {
  if (terms.empty()) throw std::invalid_argument("apply_affine_power: no operator");
  for (const auto& A : terms)
    if (A.rows != A.cols || x.dim() != 2 || x.size(0) != A.cols)
      throw std::invalid_argument("apply_affine_power: needs square operators of " +
                                  std::to_string(x.size(0)) + " rows, got " +
                                  std::to_string(A.rows) + " x " + std::to_string(A.cols));
  if (k == 0) return x;
  bool plain = !x.device().is_cpu();
  for (const auto& A : terms) plain = plain || A.factored() || A.values.requires_grad();
  if (plain) {
    auto y = x;
    for (int i = 0; i < k; ++i) {
      torch::Tensor s;
      for (const auto& A : terms) s = s.defined() ? s + spmm(A, y) : spmm(A, y);
      y = a * y + b * s;
    }
    return y;
  }
  return detail::AffinePowerFunction::apply(x, terms, static_cast<std::int64_t>(k), a, b);
}

inline torch::Tensor apply_affine_power(const SparseOperator& A, const torch::Tensor& x, int k,
                                        double a, double b) {
  return apply_affine_power(std::vector<SparseOperator>{A}, x, k, a, b);
}

/// Sum of y over the cells of each complex of a batch (`batch[i]` = complex of row i): readout.
inline torch::Tensor readout(const torch::Tensor& y, const torch::Tensor& batch,
                             std::int64_t num_complexes, Aggr aggr = Aggr::sum) {
  if (aggr == Aggr::max)
    return torch::zeros({num_complexes, y.size(1)}, y.options())
        .scatter_reduce(0, batch.unsqueeze(1).expand_as(y), y, "amax", /*include_self=*/false);
  auto out = torch::zeros({num_complexes, y.size(1)}, y.options()).index_add(0, batch, y);
  if (aggr == Aggr::mean) {
    const auto count = torch::zeros({num_complexes}, y.options())
                           .index_add(0, batch, torch::ones({y.size(0)}, y.options()));
    out = out / count.clamp_min(1).unsqueeze(1);
  }
  return out;
}

}  // namespace topos::nn
