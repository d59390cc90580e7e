// topos/nn/operator_schedule/gnn.hpp
// The schedule's built-in operations for running a graph neural network on the graph an
// operator's pattern draws (PyG's layers on a neighbourhood, as TopoTune's GCCN does): GCNConv's
// normalised propagation, over a graph of one rank's cells or over the union graph of two ranks
// that an inter-rank neighbourhood makes (target and source cells as the nodes, an edge from each
// source cell to each of its target cells), and a BatchNorm1d whose batch statistics are those
// of the rows of several cochains together (the union graph's nodes). Each is an Operation; the
// builder's `gcn` and `batch_norm(path, union_of, part)` apply them.
#pragma once

#include "topos/nn/operator_schedule/operation.hpp"

#include <torch/torch.h>

#include <cstdint>
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

 private:
  std::string op_;
  GcnPart part_;
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
