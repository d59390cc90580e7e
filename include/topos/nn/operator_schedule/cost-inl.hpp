// topos/nn/operator_schedule/cost-inl.hpp
// OperatorNetwork::plan: the plan a forward runs (plan-inl.hpp) with each operation's FLOPs
// counted on the given complex (a product by a sparse operator 2·nnz·width, a dense product
// 2·m·k·n) and the buffer it writes (rows × channels). Compiled into topos::nn, or inline with
// TOPOS_HEADER_ONLY (topos/config.hpp).
#pragma once

#include "topos/nn/operator_schedule/plan-inl.hpp"

#include <algorithm>
#include <cstdint>
#include <map>
#include <string>
#include <vector>

namespace topos::nn {

namespace detail {
/// A rank's cells in a plan's sizes, or `unknown` where the plan has none for it.
TOPOS_INLINE std::int64_t cells_or(const std::map<int, std::int64_t>& cells, int rank,
                                   std::int64_t unknown) {
  const auto it = cells.find(rank);
  return it == cells.end() ? unknown : it->second;
}
}  // namespace detail

// One operation's line: a sparse product 2·nnz·width, a dense one 2·rows·in·out; `x`: its
// operand's (rank, channels), `cells`: each rank's cells.
TOPOS_INLINE PlanLine
OperatorNetworkImpl::op_cost(const TermOp& t, TermShape x, const std::map<int, std::int64_t>& cells,
                             const std::function<std::int64_t(const std::string&)>& nnz) const {
  const auto label = detail::ops_str("x", {t});
  const auto shape = shapes_.find(&t);
  const auto out = shape == shapes_.end() ? x : shape->second;
  if (!t.operation) return {1, label, -1};
  CostContext c;
  c.rows = detail::cells_or(cells, x.rank, 0), c.x = x, c.y = out;
  c.y_rows = detail::cells_or(cells, out.rank, 0);
  c.nnz = nnz;
  const auto cost = t.operation->cost(c);
  PlanLine line{1, cost.formula.empty() ? label : label + "  " + cost.formula, cost.flops};
  line.rows = detail::cells_or(cells, out.rank, -1);
  line.channels = line.rows >= 0 ? out.channels : -1;
  if (t.traits.fans_out) line.terms = t.traits.terms;
  return line;
}

TOPOS_INLINE Plan OperatorNetworkImpl::plan_with_costs(
    const Operators& ops, const std::map<int, std::int64_t>& cells,
    const std::function<std::int64_t(const std::string&)>& nnz) const {
  auto plan = make_plan(ops);
  plan.total_flops = 0, plan.total_values = 0;
  for (auto& group : plan.groups)
    for (auto& p : group) {
      // A kept step runs nothing: its target stays (its terms were left out already).
      if (!p.live || p.route == StepRoute::keep) continue;
      const auto& s = *p.step;
      const auto line = [&](PlanLine l) {
        plan.total_flops += std::max<std::int64_t>(l.flops, 0);
        if (l.rows >= 0) plan.total_values += l.rows * l.channels * l.terms;
        p.lines.push_back(std::move(l));
      };
      // fuse_products: per operation, how many after it run in its node, found as the
      // interpreter finds them (a chain's term and step operations are one list; the filter
      // route's taps run their own way).
      const auto fused = [&](const detail::OperationSeq& seq) {
        std::vector<int> n(seq.size(), 0);
        if (!fast_.fuse_products() || p.route == StepRoute::filter) return n;
        for (std::size_t i = 0; i < seq.size(); ++i) {
          const auto w = detail::weight_next_to_product(
              seq, i, [&](const std::string& name) { return ops.neighborhood(name) != nullptr; });
          if (w.product == nullptr || w.product->row_norm) continue;
          n[i] = w.activation ? 2 : 1;
          i += static_cast<std::size_t>(n[i]);
        }
        return n;
      };
      const auto ops_lines = [&](const std::vector<TermOp>& list, TermShape x,
                                 const std::vector<int>& marks, std::size_t offset) {
        for (std::size_t i = 0; i < list.size(); ++i) {
          auto l = op_cost(list[i], x, cells, nnz);
          l.fused_with_next = marks[offset + i];
          line(std::move(l));
          if (auto it = shapes_.find(&list[i]); it != shapes_.end()) x = it->second;
        }
      };
      const bool chain = p.route == StepRoute::chain;
      std::vector<int> step_marks = fused(s.operations());
      for (const auto& term : p.terms) {
        line({0, "term from " + term.term->source.str(), -1});
        const auto& list = term.term->operations();
        const auto marks = chain ? fused(detail::OperationSeq(list, &s.operations())) : fused(list);
        if (chain)
          step_marks.assign(marks.begin() + static_cast<std::ptrdiff_t>(list.size()), marks.end());
        ops_lines(list, {term.term->source.rank, term_width_.at(term.term)}, marks, 0);
      }
      // split_first_layer applies the step's first operation in its mix: no node starts there.
      if (p.route == StepRoute::split_first_layer && !step_marks.empty()) step_marks[0] = 0;
      TermShape y{s.target.rank, mix_width_.at(&s)};
      if (s.mix == OperatorStep::Mix::filter) {
        const auto& W = params_.at(s.filter_path);  // in × out × taps
        // The filter route applies an activation after it as its product is stored.
        const bool act = p.route == StepRoute::filter &&
                         fusable_activation_at(detail::OperationSeq(s.operations()), 0) != nullptr;
        const auto n = detail::cells_or(cells, y.rank, -1);
        line({0,
              "filter " + s.filter_path + "  dense 2·" +
                  std::to_string(std::max<std::int64_t>(n, 0)) + "·" +
                  std::to_string(W.size(0) * W.size(2)) + "·" + std::to_string(W.size(1)),
              2 * std::max<std::int64_t>(n, 0) * W.size(0) * W.size(2) * W.size(1), act ? 1 : 0, n,
              n >= 0 ? W.size(1) : -1});
        y.channels = W.size(1);
      }
      if (!s.operations().empty()) line({0, "step's operations", -1});
      ops_lines(s.operations(), y, step_marks, 0);
    }
  return plan;
}

TOPOS_INLINE Plan OperatorNetworkImpl::plan_over(
    const std::map<std::string, torch::Tensor>& inputs,
    const std::map<std::string, SparseOperator>& operators, const ComplexBatch* batch) const {
  check_arguments(inputs, operators, batch);
  input_cochains(inputs);  // each input's shape
  Operators ops{&operators, batch, {}, absent_operators(operators, batch), {}, false, {},
                0,          false, {}};
  std::map<int, std::int64_t> cells;  // per rank, from the inputs, operators and neighbourhoods
  for (const auto& in : schedule_.inputs()) cells[in.key.rank] = inputs.at(in.name).size(-2);
  for (const auto& [name, ranks] : schedule_.operators())
    if (auto it = operators.find(name); it != operators.end()) {
      cells[ranks.first] = it->second.cols;
      cells[ranks.second] = it->second.rows;
    } else if (const auto* n = ops.neighborhood(name)) {
      cells[ranks.first] = n->num_source;
      cells[ranks.second] = n->num_target;
    }
  // A neighbourhood's pairs count as its nonzeros.
  auto plan = plan_with_costs(ops, cells, [&](const std::string& name) -> std::int64_t {
    if (auto it = operators.find(name); it != operators.end()) return it->second.nnz();
    const auto* n = ops.neighborhood(name);
    return n == nullptr ? 0 : n->source.size(0);
  });
  if (!inputs.empty()) plan.value_bytes = inputs.begin()->second.element_size();
  return plan;
}

}  // namespace topos::nn
