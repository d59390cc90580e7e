// topos/nn/operator_schedule/builder-inl.hpp
// The schedule builder's container code: the special members of operations, steps and
// schedules, and the members that grow their vectors. Compiled into topos::nn, or inline with
// TOPOS_HEADER_ONLY (topos/config.hpp).
#pragma once

#include "topos/nn/operator_schedule/builder.hpp"

namespace topos::nn {

TOPOS_INLINE TermOp::TermOp() = default;
TOPOS_INLINE TermOp::TermOp(const TermOp&) = default;
TOPOS_INLINE TermOp::TermOp(TermOp&&) noexcept = default;
TOPOS_INLINE TermOp& TermOp::operator=(const TermOp&) = default;
TOPOS_INLINE TermOp& TermOp::operator=(TermOp&&) noexcept = default;
TOPOS_INLINE TermOp::~TermOp() = default;

namespace detail {
TOPOS_INLINE OperationList::OperationList() = default;
TOPOS_INLINE OperationList::OperationList(const OperationList&) = default;
TOPOS_INLINE OperationList::OperationList(OperationList&&) noexcept = default;
TOPOS_INLINE OperationList& OperationList::operator=(const OperationList&) = default;
TOPOS_INLINE OperationList& OperationList::operator=(OperationList&&) noexcept = default;
TOPOS_INLINE OperationList::~OperationList() = default;
TOPOS_INLINE void OperationList::push(TermOp t) {
  ops_.push_back(std::move(t));
}
TOPOS_INLINE void OperationList::push_operation(std::shared_ptr<const Operation> op) {
  TermOp t;  // a null operation is refused when the network is built, naming the step
  if (op) t.traits = op->traits();
  t.operation = std::move(op);
  ops_.push_back(std::move(t));
}
}  // namespace detail

TOPOS_INLINE OperatorStep::OperatorStep(CochainKey target) : target(std::move(target)) {}
TOPOS_INLINE OperatorStep::OperatorStep(const OperatorStep&) = default;
TOPOS_INLINE OperatorStep::OperatorStep(OperatorStep&&) noexcept = default;
TOPOS_INLINE OperatorStep& OperatorStep::operator=(const OperatorStep&) = default;
TOPOS_INLINE OperatorStep& OperatorStep::operator=(OperatorStep&&) noexcept = default;
TOPOS_INLINE OperatorStep::~OperatorStep() = default;

TOPOS_INLINE void OperatorStep::add_term(ops::Term t) {
  terms.push_back(std::move(t));
}

TOPOS_INLINE OperatorStep& OperatorStep::sum(std::vector<ops::Term> t) & {
  mix = Mix::sum;
  terms.insert(terms.end(), std::make_move_iterator(t.begin()), std::make_move_iterator(t.end()));
  return *this;
}

TOPOS_INLINE OperatorStep& OperatorStep::concat(std::vector<ops::Term> t) & {
  sum(std::move(t));
  mix = Mix::concat;
  return *this;
}

TOPOS_INLINE OperatorSchedule::OperatorSchedule() = default;
TOPOS_INLINE OperatorSchedule::OperatorSchedule(const OperatorSchedule&) = default;
TOPOS_INLINE OperatorSchedule::OperatorSchedule(OperatorSchedule&&) noexcept = default;
TOPOS_INLINE OperatorSchedule& OperatorSchedule::operator=(const OperatorSchedule&) = default;
TOPOS_INLINE OperatorSchedule& OperatorSchedule::operator=(OperatorSchedule&&) noexcept = default;
TOPOS_INLINE OperatorSchedule::~OperatorSchedule() = default;

TOPOS_INLINE OperatorSchedule& OperatorSchedule::input(std::string name, int rank,
                                                       std::int64_t channels, std::string state) {
  inputs_.push_back({std::move(name), {rank, std::move(state)}, channels});
  return *this;
}

TOPOS_INLINE OperatorSchedule& OperatorSchedule::operator_input(std::string name, int source_rank,
                                                                int target_rank) {
  operators_[std::move(name)] = {source_rank, target_rank};
  return *this;
}

TOPOS_INLINE OperatorSchedule& OperatorSchedule::optional_operator(std::string name,
                                                                   int source_rank,
                                                                   int target_rank) {
  optional_.insert(name);
  return operator_input(std::move(name), source_rank, target_rank);
}

TOPOS_INLINE OperatorSchedule& OperatorSchedule::step(OperatorStep s) {
  name_step(s);
  groups_.emplace_back();
  groups_.back().push_back(std::move(s));
  return *this;
}

TOPOS_INLINE OperatorSchedule& OperatorSchedule::parallel(std::vector<OperatorStep> steps) {
  for (auto& s : steps) name_step(s);
  groups_.push_back(std::move(steps));
  return *this;
}

TOPOS_INLINE OperatorSchedule& OperatorSchedule::layer(std::string name) {
  layers_.emplace_back(std::move(name), groups_.size());
  return *this;
}

TOPOS_INLINE OperatorSchedule& OperatorSchedule::output(std::string name, int rank,
                                                        std::string state) {
  outputs_.push_back({std::move(name), {rank, std::move(state)}, 0});
  return *this;
}

TOPOS_INLINE OperatorSchedule& OperatorSchedule::parameter(std::string path,
                                                           std::vector<std::int64_t> shape,
                                                           double gain) {
  parameters_.push_back({std::move(path), std::move(shape), gain});
  return *this;
}

TOPOS_INLINE void OperatorSchedule::name_step(OperatorStep& s) {
  if (s.name.empty()) s.name = "step " + std::to_string(num_steps_);
  ++num_steps_;
}

}  // namespace topos::nn
