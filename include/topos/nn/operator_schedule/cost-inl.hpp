// topos/nn/operator_schedule/cost-inl.hpp
// OperatorNetwork::plan_str: what forward(inputs, operators) will run, step by step, each
// operation with its FLOPs counted on the given complex (a product by a sparse operator
// 2·nnz·width, a dense product 2·m·k·n). Compiled into topos::nn, or inline with
// TOPOS_HEADER_ONLY (topos/config.hpp).
#pragma once

#include "topos/nn/operator_schedule/interpreter-inl.hpp"

#include <cstdint>
#include <algorithm>
#include <map>
#include <set>
#include <sstream>
#include <string>

namespace topos::nn {

namespace detail {

/// FLOPs as a plan prints them: digits grouped by thousands.
TOPOS_INLINE std::string flops_str(std::int64_t v) {
  auto s = std::to_string(v);
  for (auto i = static_cast<std::int64_t>(s.size()) - 3; i > 0; i -= 3)
    s.insert(static_cast<std::size_t>(i), ",");
  return s;
}

/// One operation's line in a plan: what it is, and its FLOPs (-1: not counted).
struct CostLine {
  std::string what;
  std::int64_t flops = -1;
};

}  // namespace detail

// One operation's line: a sparse product 2·nnz·width, a dense one 2·rows·in·out; `x`: its
// operand's (rank, channels), `cells`: each rank's cells.
TOPOS_INLINE detail::CostLine OperatorNetworkImpl::op_cost(
    const TermOp& t, TermShape x, const std::map<int, std::int64_t>& cells,
    const std::map<std::string, SparseOperator>& operators) const {
  const auto rows = [&](int rank) { return cells.count(rank) ? cells.at(rank) : 0; };
  const auto nnz = [&](const std::string& name) {
    auto it = operators.find(name);
    return it == operators.end() ? std::int64_t(0) : it->second.nnz();
  };
  const auto label = detail::ops_str("x", {t});
  const auto shape = shapes_.find(&t);
  const auto out = shape == shapes_.end() ? x : shape->second;
  if (!t.operation) return {label, -1};
  CostContext c;
  c.rows = rows(x.rank), c.x = x, c.y = out;
  c.nnz = nnz;
  const auto cost = t.operation->cost(c);
  return {cost.formula.empty() ? label : label + "  " + cost.formula, cost.flops};
}

TOPOS_INLINE std::string OperatorNetworkImpl::plan_str(
    const std::map<std::string, torch::Tensor>& inputs,
    const std::map<std::string, SparseOperator>& operators) const {
  check_arguments(inputs, operators, nullptr);
  std::map<int, std::int64_t> cells;  // per rank, from the inputs and the operators
  for (const auto& in : schedule_.inputs()) cells[in.key.rank] = inputs.at(in.name).size(0);
  for (const auto& [name, ranks] : schedule_.operators())
    if (auto it = operators.find(name); it != operators.end()) {
      cells[ranks.first] = it->second.cols;
      cells[ranks.second] = it->second.rows;
    }
  const auto rows = [&](int rank) { return cells.count(rank) ? cells.at(rank) : 0; };
  const auto cost = [&](const TermOp& t, TermShape x) { return op_cost(t, x, cells, operators); };
  std::ostringstream o;
  std::int64_t total = 0;
  const auto line = [&](const std::string& indent, const detail::CostLine& c) {
    o << indent << c.what;
    if (c.flops >= 0) o << "  " << detail::flops_str(c.flops) << " FLOPs";
    o << "\n";
    total += std::max<std::int64_t>(c.flops, 0);
  };
  const auto ops_lines = [&](const std::vector<TermOp>& list, TermShape x) {
    for (const auto& t : list) {
      line("      ", cost(t, x));
      if (auto it = shapes_.find(&t); it != shapes_.end()) x = it->second;
    }
  };
  std::set<std::string> absent;
  for (const auto& name : schedule_.optional_operators())
    if (!operators.count(name)) absent.insert(name);
  const auto& groups = schedule_.groups();
  auto layer = schedule_.layers().begin();
  for (std::size_t g = 0; g < groups.size(); ++g) {
    for (; layer != schedule_.layers().end() && layer->second == g; ++layer)
      o << "layer " << layer->first << "\n";
    for (std::size_t i = 0; i < groups[g].size(); ++i) {
      if (!live_[g][i]) continue;
      const auto& s = groups[g][i];
      o << "  step " << s.name << " (into " << s.target.str() << ", group " << g << ")\n";
      for (const auto& term : s.terms) {
        if (detail::applies_absent(term, absent)) continue;
        o << "    term from " << term.source.str() << "\n";
        ops_lines(term.operations(), {term.source.rank, term_width_.at(&term)});
      }
      TermShape y{s.target.rank, mix_width_.at(&s)};
      if (s.mix == OperatorStep::Mix::filter) {
        const auto& W = params_.at(s.filter_path);  // in × out × taps
        line("    ",
             {"filter " + s.filter_path + "  dense 2·" + std::to_string(rows(y.rank)) + "·" +
                  std::to_string(W.size(0) * W.size(2)) + "·" + std::to_string(W.size(1)),
              2 * rows(y.rank) * W.size(0) * W.size(2) * W.size(1)});
        y.channels = W.size(1);
      }
      if (!s.operations().empty()) o << "    step's operations\n";
      ops_lines(s.operations(), y);
    }
  }
  o << "total " << detail::flops_str(total) << " FLOPs\n";
  return o.str();
}

}  // namespace topos::nn
