// topos/nn/operator_schedule/gnn.hpp
// The schedule's built-in operations for running a graph neural network on the graph an
// operator's pattern draws (PyG's layers on a neighbourhood, as TopoTune's GCCN does): GCNConv's
// normalised propagation and GATConv's attention, over a graph of one rank's cells or over the
// union graph of two ranks that an inter-rank neighbourhood makes (target and source cells as the
// nodes, an edge from each source cell to each of its target cells), and a BatchNorm1d whose
// batch statistics are those of the rows of several cochains together (the union graph's nodes).
// Each is an Operation; the builder's `gcn`, `gat` and `batch_norm(path, union_of, part)` apply
// them.
#pragma once

#include "topos/nn/operator_schedule/operation.hpp"

#include <torch/torch.h>

#include <cmath>
#include <cstdint>
#include <optional>
#include <string>
#include <utility>
#include <vector>

namespace topos::nn {

/// Which part of PyG's GCNConv propagation `gcn` computes, over A's pattern P (target × source,
/// A's values ignored) with the self-loops GCNConv adds (add_remaining_self_loops):
enum class GcnPart {
  /// A square: D^-1/2 (P + I) D^-1/2 x, D = diag((P + I) 1), a diagonal entry of P its self-loop.
  graph,
  /// The union graph [targets; sources], edges source → target: the targets' messages from the
  /// sources D^-1/2 P x, D = diag(1 + P 1) (a source's only incoming edge is its self-loop).
  union_sources,
  /// The same union graph: the targets' self-loops D^-1 x, x on the target cells.
  union_targets
};

/// Which nodes of which graph `gat` computes the outputs of, over A's pattern (target × source, A's
/// values ignored), with the self-loops GATConv adds (remove_self_loops, add_self_loops):
enum class GatPart {
  /// A square: every node, over P's edges without its diagonal, plus one self-loop per node.
  graph,
  /// The union graph [targets; sources], edges source → target: the target nodes, each over its
  /// sources and its self-loop. The operand is the source nodes' features, the targets' are
  /// GatOptions::targets (zero when unset: TopoTune's first layer).
  union_targets,
  /// The same union graph: the source nodes, whose only incoming edge is their self-loop.
  union_sources
};

/// PyG's GATConv after its `lin` (which the term applies before `gat`): per head h of C channels,
/// scores LeakyReLU(a_src,h·x_j + a_dst,h·x_i) over each node's incoming edges, a softmax per node,
/// dropout on the weights (training), Σ_j α_ij x_j, the heads side by side or averaged. The
/// vectors are `path`.att_src and `path`.att_dst (1 × heads × C, PyG's glorot).
struct GatOptions {
  TORCH_ARG(std::int64_t, heads) = 1;
  TORCH_ARG(bool, concat) = true;  ///< the heads side by side, or their mean
  TORCH_ARG(double, negative_slope) = 0.2;
  TORCH_ARG(double, dropout) = 0;  ///< on the attention weights
  TORCH_ARG(GatPart, part) = GatPart::graph;
  /// union_targets: the target nodes' features (a cochain of the target rank, the operand's width).
  TORCH_ARG(std::optional<CochainKey>, targets);
};

namespace builtin {

/// GCNConv's propagation over operator `op` (GcnPart); degrees from the operator at each forward.
class GcnPropagation final : public Operation {
 public:
  GcnPropagation(std::string op, GcnPart part) : op_(std::move(op)), part_(part) {}
  std::string str(const std::string& x) const override {
    const char* p = part_ == GcnPart::graph           ? ""
                    : part_ == GcnPart::union_sources ? ", sources"
                                                      : ", targets";
    return "gcn[" + op_ + p + "](" + x + ")";
  }
  TermShape infer(BuildContext& ctx, TermShape x) const override {
    auto [src, dst] = ctx.operator_ranks(op_);
    if (part_ == GcnPart::graph && src != dst)
      ctx.fail("gcn over '" + op_ + "' (rank " + std::to_string(src) + " to " +
               std::to_string(dst) + "): a graph of one rank needs a square operator");
    const int from = part_ == GcnPart::union_targets ? dst : src;
    if (x.rank != from)
      ctx.fail("gcn over '" + op_ + "' reads rank " + std::to_string(from) +
               " cochains, not rank " + std::to_string(x.rank));
    return {dst, x.channels};
  }
  torch::Tensor forward(RunContext& ctx, const torch::Tensor& x) const override {
    const SparseOperator& a = ctx.op(op_);
    a.require_entries("gcn over '" + op_ + "'");
    if (part_ == GcnPart::graph) {
      if (a.rows != a.cols) ctx.fail("gcn over '" + op_ + "': the operator is not square");
      const SparseOperator p = a.pattern_with_self_loops();
      const auto d = p.row_sums().rsqrt().to(x.dtype());
      return spmm(p.to(x.scalar_type()), x * d.unsqueeze(1)) * d.unsqueeze(1);
    }
    const SparseOperator p = a.pattern();
    const auto degree = (p.row_sums() + 1).to(x.dtype());
    if (part_ == GcnPart::union_targets) return x / degree.unsqueeze(1);
    return spmm(p.to(x.scalar_type()), x) * degree.rsqrt().unsqueeze(1);
  }
  OperationTraits traits() const override {
    OperationTraits t;
    t.reads_cochains = false;
    t.operators = {op_};
    return t;
  }
  /// The product by the pattern (with a self-loop per cell on a graph: at most nnz + cells
  /// entries); the targets' part only scales.
  OperationCost cost(const CostContext& c) const override {
    if (part_ == GcnPart::union_targets) return {};
    return OperationCost::sparse(c.nnz(op_) + (part_ == GcnPart::graph ? c.rows : 0), c.x.channels);
  }

 private:
  std::string op_;
  GcnPart part_;
};

/// GATConv's attention over operator `op` (GatOptions); parameters at `path`.att_src, .att_dst.
class GatAttention final : public Operation {
 public:
  GatAttention(std::string op, std::string path, GatOptions o)
      : op_(std::move(op)), path_(std::move(path)), o_(std::move(o)) {}
  std::string str(const std::string& x) const override {
    const char* p = o_.part() == GatPart::graph           ? ""
                    : o_.part() == GatPart::union_targets ? ", targets"
                                                          : ", sources";
    return "gat[" + op_ + p + "](" + x + ")";
  }
  TermShape infer(BuildContext& ctx, TermShape x) const override {
    auto [src, dst] = ctx.operator_ranks(op_);
    const std::string what = "gat over '" + op_ + "'";
    if (o_.part() == GatPart::graph && src != dst)
      ctx.fail(what + " (rank " + std::to_string(src) + " to " + std::to_string(dst) +
               "): a graph of one rank needs a square operator");
    if (x.rank != src)
      ctx.fail(what + " reads rank " + std::to_string(src) + " cochains, not rank " +
               std::to_string(x.rank));
    const auto H = o_.heads();
    if (H < 1 || x.channels % H)
      ctx.fail(what + ": " + std::to_string(x.channels) + " channels do not split into " +
               std::to_string(H) + " heads");
    if (!(o_.dropout() >= 0 && o_.dropout() < 1)) ctx.fail(what + ": dropout must be in [0, 1)");
    if (o_.targets()) {
      if (o_.part() != GatPart::union_targets)
        ctx.fail(what + ": target features are read by the union_targets part alone");
      const auto& t = *o_.targets();
      if (t.rank != dst || ctx.cochain_width(t) != x.channels)
        ctx.fail(what + ": the targets " + t.str() + " must be a rank " + std::to_string(dst) +
                 " cochain of " + std::to_string(x.channels) + " channels");
    }
    const auto C = x.channels / H;
    const auto bound = std::sqrt(6.0 / static_cast<double>(H + C));  // PyG's glorot on 1 × H × C
    ctx.parameter(path_ + ".att_src", {1, H, C}, ParameterInit::uniform(bound));
    ctx.parameter(path_ + ".att_dst", {1, H, C}, ParameterInit::uniform(bound));
    return {o_.part() == GatPart::union_sources ? src : dst, o_.concat() ? x.channels : C};
  }
  torch::Tensor forward(RunContext& ctx, const torch::Tensor& x) const override {
    const SparseOperator& a = ctx.op(op_);
    a.require_entries("gat over '" + op_ + "'");
    if (x.size(0) != a.cols)
      ctx.fail("gat over '" + op_ + "': " + std::to_string(x.size(0)) +
               " rows for an operator of " + std::to_string(a.cols) + " columns");
    // The graph U whose rows are the nodes computed, its columns the nodes read (features X),
    // and the features Q of U's rows.
    SparseOperator u;
    torch::Tensor X = x, Q = x;
    switch (o_.part()) {
      case GatPart::graph:
        if (a.rows != a.cols) ctx.fail("gat over '" + op_ + "': the operator is not square");
        u = a.pattern_with_self_loops();
        break;
      case GatPart::union_sources:
        u = SparseOperator::identity(a.cols, x.scalar_type());
        break;
      case GatPart::union_targets: {
        Q = o_.targets() ? ctx.cochain(*o_.targets())
                         : torch::zeros({a.rows, x.size(1)}, x.options());
        // [I | P]: each target reads itself (column i) and its sources (column rows + j).
        const auto crow = index_vector(a.crow), col = index_vector(a.col);
        std::vector<std::int64_t> r, c;
        for (std::int64_t i = 0; i < a.rows; ++i) {
          r.push_back(i), c.push_back(i);
          for (auto k = crow[static_cast<std::size_t>(i)];
               k < crow[static_cast<std::size_t>(i) + 1]; ++k)
            r.push_back(i), c.push_back(a.rows + col[static_cast<std::size_t>(k)]);
        }
        u = SparseOperator::from_sorted(
            a.rows, a.rows + a.cols, r, c,
            torch::ones({static_cast<std::int64_t>(r.size())}, x.scalar_type()));
        X = torch::cat({Q, x});
        break;
      }
    }
    const auto H = o_.heads();
    return multi_head_attention_from_cells(u, head_scores(X, ctx.parameter(path_ + ".att_src"), H),
                                           head_scores(Q, ctx.parameter(path_ + ".att_dst"), H), X,
                                           o_.concat(), Activation::leaky_relu, o_.negative_slope(),
                                           AttentionNorm::softmax, o_.dropout(), ctx.is_training(),
                                           ctx.fast_paths().fuse_attention());
  }
  OperationTraits traits() const override {
    OperationTraits t;
    t.reads_cochains = o_.targets().has_value();
    t.operators = {op_};
    return t;
  }
  /// The weighted sum over the attention's entries: the operator's and a self-loop per cell on
  /// a graph (at most nnz + cells), each cell itself for the sources' part, each target and its
  /// sources for the targets' part.
  OperationCost cost(const CostContext& c) const override {
    const auto entries = o_.part() == GatPart::graph           ? c.nnz(op_) + c.rows
                         : o_.part() == GatPart::union_sources ? c.rows
                                                               : c.nnz(op_) + c.y_rows;
    return OperationCost::sparse(entries, c.x.channels);
  }

 private:
  std::string op_, path_;
  GatOptions o_;
};

/// torch.nn.BatchNorm1d at `path` over the rows of the cochains `union_of` stacked in order, x
/// being part `part` of them (the others are read): each part gets its own rows of the result. In
/// training the part-0 call updates the running statistics (each part's call computes the same
/// batch statistics; apply it to every part, part 0 included); in evaluation each part is
/// normalised with the running statistics alone.
class UnionBatchNorm final : public Operation {
 public:
  UnionBatchNorm(std::string path, std::vector<CochainKey> union_of, std::size_t part)
      : path_(std::move(path)), union_of_(std::move(union_of)), part_(part) {}
  std::string str(const std::string& x) const override {
    std::string parts;
    for (std::size_t k = 0; k < union_of_.size(); ++k)
      parts += (k ? ", " : "") + (k == part_ ? x : union_of_[k].str());
    return "batch_norm[" + path_ + "](" + parts + ")";
  }
  TermShape infer(BuildContext& ctx, TermShape x) const override {
    if (part_ >= union_of_.size())
      ctx.fail("batch_norm '" + path_ + "': part " + std::to_string(part_) + " of a union of " +
               std::to_string(union_of_.size()) + " cochains");
    if (union_of_[part_].rank != x.rank)
      ctx.fail("batch_norm '" + path_ + "': part " + std::to_string(part_) + " is " +
               union_of_[part_].str() + " but the operand has rank " + std::to_string(x.rank));
    for (std::size_t k = 0; k < union_of_.size(); ++k)
      if (k != part_ && ctx.cochain_width(union_of_[k]) != x.channels)
        ctx.fail("batch_norm '" + path_ + "': " + union_of_[k].str() + " has " +
                 std::to_string(ctx.cochain_width(union_of_[k])) + " channels, the operand " +
                 std::to_string(x.channels));
    ctx.module(path_, std::make_shared<torch::nn::BatchNorm1dImpl>(x.channels));
    return x;
  }
  torch::Tensor forward(RunContext& ctx, const torch::Tensor& x) const override {
    auto& bn = ctx.module<torch::nn::BatchNorm1dImpl>(path_);
    if (!ctx.is_training()) return bn.forward(x);
    std::vector<torch::Tensor> rows;
    std::int64_t begin = 0;
    for (std::size_t k = 0; k < union_of_.size(); ++k) {
      rows.push_back(k == part_ ? x : ctx.cochain(union_of_[k]));
      if (k < part_) begin += rows.back().size(0);
    }
    const auto all = torch::cat(rows);
    const auto& o = bn.options;
    const auto y = part_ == 0 ? bn.forward(all)
                              : torch::batch_norm(all, bn.weight, bn.bias, {}, {}, true,
                                                  o.momentum().value_or(0.1), o.eps(), false);
    return y.narrow(0, begin, x.size(0));
  }

 private:
  std::string path_;
  std::vector<CochainKey> union_of_;
  std::size_t part_;
};

}  // namespace builtin
}  // namespace topos::nn
