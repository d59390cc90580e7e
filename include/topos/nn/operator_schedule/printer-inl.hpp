// topos/nn/operator_schedule/printer-inl.hpp
// OperatorSchedule::str(): one line per step, each term written as the operations it applies.
// Compiled into topos::nn, or inline with TOPOS_HEADER_ONLY (topos/config.hpp).
#pragma once

#include "topos/nn/operator_schedule/builder.hpp"

#include <sstream>

namespace topos::nn {

namespace detail {

TOPOS_INLINE std::string num(double v) {
  std::ostringstream o;
  o << v;
  return o.str();
}

TOPOS_INLINE std::string ops_str(std::string x, const std::vector<TermOp>& ops) {
  for (const auto& t : ops) x = t.operation ? t.operation->str(x) : "null(" + x + ")";
  return x;
}

TOPOS_INLINE std::string step_str(const OperatorStep& s) {
  std::string mixed = s.mix == OperatorStep::Mix::filter   ? "filter " + s.filter_path + "["
                      : s.mix == OperatorStep::Mix::mean   ? "mean["
                      : s.mix == OperatorStep::Mix::concat ? "cat["
                                                           : "sum[";
  for (std::size_t i = 0; i < s.terms.size(); ++i)
    mixed += (i ? ", " : "") + ops_str(s.terms[i].source.str(), s.terms[i].operations());
  mixed += "]";
  return s.name + ": " + s.target.str() + " = " + ops_str(mixed, s.operations()) +
         (s.guard_rank >= 0 ? " where rank " + std::to_string(s.guard_rank) + " is nonempty" : "");
}

}  // namespace detail

TOPOS_INLINE std::string OperatorSchedule::str() const {
  std::ostringstream o;
  for (const auto& in : inputs_) o << "input " << in.name << " -> " << in.key.str() << "\n";
  auto layer = layers_.begin();
  for (std::size_t i = 0; i < groups_.size(); ++i) {
    const auto& g = groups_[i];
    for (; layer != layers_.end() && layer->second == i; ++layer)
      o << "layer " << layer->first << ":\n";
    if (g.size() > 1) o << "parallel {\n";
    for (const auto& s : g) o << (g.size() > 1 ? "  " : "") << detail::step_str(s) << "\n";
    if (g.size() > 1) o << "}\n";
  }
  for (const auto& out : outputs_) o << "output " << out.key.str() << " -> " << out.name << "\n";
  for (const auto& p : parameters_) o << "parameter " << p.path << "\n";
  return o.str();
}

}  // namespace topos::nn
