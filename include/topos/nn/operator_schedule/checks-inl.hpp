// topos/nn/operator_schedule/checks-inl.hpp
// The checks at OperatorNetwork's boundaries, each error naming the argument or the step and
// saying what to write instead: a forward's inputs and operators against the schedule's
// declarations (names, dtype and device, each rank's cells), a user operation's output against
// its infer, and LibTorch's errors inside a step rethrown with the step named.
// Compiled into topos::nn, or inline with TOPOS_HEADER_ONLY (topos/config.hpp).
#pragma once

#include "topos/nn/operator_schedule/network.hpp"
#include "topos/nn/operator_schedule/parameters-inl.hpp"  // detail::shape_str
#include "topos/nn/operator_schedule/printer-inl.hpp"     // detail::ops_str

#include <algorithm>
#include <map>
#include <set>
#include <string>
#include <tuple>
#include <vector>

namespace topos::nn {

namespace detail {

/// A dtype as a message names it, and the constant that converts to it.
TOPOS_INLINE std::string dtype_str(torch::ScalarType t) {
  switch (t) {
    case torch::kFloat:
      return "float32";
    case torch::kDouble:
      return "float64";
    case torch::kHalf:
      return "float16";
    case torch::kBFloat16:
      return "bfloat16";
    default:
      return c10::toString(t);
  }
}
TOPOS_INLINE std::string dtype_constant(torch::ScalarType t) {
  switch (t) {
    case torch::kFloat:
      return "torch::kFloat32";
    case torch::kDouble:
      return "torch::kFloat64";
    default:
      return std::string("torch::k") + c10::toString(t);
  }
}

/// Names, quoted and separated by commas ("none" when there are none).
template <class Range, class Name>
std::string quoted(const Range& r, Name name) {
  std::string s;
  for (const auto& x : r) s += (s.empty() ? "'" : ", '") + name(x) + "'";
  return s.empty() ? "none" : s;
}

/// A term as errors name it: "the term conv·A·(1)".
inline std::string term_str(const ops::Term& t) {
  return "the term " + ops_str(t.source.str(), t.operations());
}

/// The cochains a step reads, with their shapes: what a LibTorch error outside any one term
/// (a compact step's rows, the guard) is described by.
struct StepReads {
  const OperatorStep& s;
  const Cochains& h;
};

inline std::string describe(const char* what) {
  return what;
}
inline std::string describe(const ops::Term* term) {
  return term_str(*term);
}
inline std::string describe(const StepReads& r) {
  std::string reads;
  for (const auto& term : r.s.terms) {
    if (!r.h.has(term.source.rank, term.source.state)) continue;
    const auto piece =
        term.source.str() + " " + shape_str(r.h.at(term.source.rank, term.source.state));
    if (reads.find(piece) == std::string::npos) reads += (reads.empty() ? "" : ", ") + piece;
  }
  return "the step, reading " + reads +
         " (each operator it applies needs its target rank's cells as rows and its source "
         "rank's as columns, each weight the channels it is given)";
}

/// `f()`, a LibTorch error in it (the first line of its message, without the stack) rethrown as
/// a ScheduleError naming the step (`where`) and `what` (a term, the mix, the step: describe),
/// described only then.
template <class What, class F>
auto naming(const std::string& where, const What& what, F&& f) -> decltype(f()) {
  try {
    return f();
  } catch (const c10::Error& e) {
    std::string message = e.what_without_backtrace();
    message = message.substr(0, message.find('\n'));
    throw ScheduleError(where + ": " + describe(what) + ": " + message);
  }
}

}  // namespace detail

TOPOS_INLINE void OperatorNetworkImpl::check_arguments(
    const std::map<std::string, torch::Tensor>& inputs,
    const std::map<std::string, SparseOperator>& operators, const ComplexBatch* batch) const {
  check_names(inputs, operators, batch);
  check_dtypes(inputs, operators);
  check_cells(inputs, operators, batch);
}

TOPOS_INLINE void OperatorNetworkImpl::check_names(
    const std::map<std::string, torch::Tensor>& inputs,
    const std::map<std::string, SparseOperator>& operators, const ComplexBatch* batch) const {
  const auto& ports = schedule_.inputs();
  const auto& declared = schedule_.operators();
  // A name the schedule does not declare is ignored: an error where a declared optional operator
  // is missing (the name is likely it, misspelt, and its terms would be dropped), else a warning
  // (once per name and network: a caller may hold a larger dictionary, see declared_operators).
  const auto is_input = [&](const std::string& name) {
    return std::any_of(ports.begin(), ports.end(), [&](const auto& p) { return p.name == name; });
  };
  std::vector<std::string> absent;  // declared optional operators this forward lacks
  for (const auto& name : schedule_.optional_operators())
    if (!operators.count(name) && !(batch != nullptr && batch->has_neighborhood(name)))
      absent.push_back(name);
  const auto known_ports = [&] {
    return detail::quoted(ports, [](const auto& p) { return p.name; });
  };
  const auto known_ops = [&] {
    return detail::quoted(declared, [](const auto& d) { return d.first; });
  };
  for (const auto& given : operators) {
    const auto& name = given.first;
    if (declared.count(name)) continue;
    if (!absent.empty())
      throw ScheduleError(
          "operator '" + name + "' is not one the schedule declares (" + known_ops() +
          ") and the optional operator " + detail::quoted(absent, [](const auto& n) { return n; }) +
          " was not given, so its terms would be dropped: give it under its "
          "declared name, or declare '" +
          name + "' with operator_input(\"" + name + "\", source_rank, target_rank)");
    if (warned_.insert("operator " + name).second)
      TORCH_WARN("OperatorNetwork: operator '", name, "' is not one the schedule declares (",
                 known_ops(),
                 ") and is ignored: give only the declared ones "
                 "(net->declared_operators(all))");
  }
  for (const auto& given : inputs) {
    const auto& name = given.first;
    if (!is_input(name) && warned_.insert("input " + name).second)
      TORCH_WARN("OperatorNetwork: input '", name, "' is not one the schedule declares (",
                 known_ports(),
                 ") and is ignored: give only the declared ones, or declare it "
                 "with input(\"",
                 name, "\", rank, channels)");
  }
}

TOPOS_INLINE torch::Tensor OperatorNetworkImpl::first_submodule_parameter() const {
  for (const auto& child : children())
    for (const auto& p : child->parameters())  // one submodule's, not the whole tree's
      if (p.is_floating_point()) return p;
  return {};
}

// One dtype and device: the parameters' (or, without any, the first input's).
TOPOS_INLINE void OperatorNetworkImpl::check_dtypes(
    const std::map<std::string, torch::Tensor>& inputs,
    const std::map<std::string, SparseOperator>& operators) const {
  const auto& ports = schedule_.inputs();
  const auto& declared = schedule_.operators();
  const torch::Tensor* reference = nullptr;
  std::string reference_name = "the network's parameters";
  for (const auto& [path, p] : params_)
    if (p.is_floating_point()) {
      reference = &p;
      break;
    }
  if (reference == nullptr && dtype_reference_.defined())  // a submodule's (an mlp, a norm)
    reference = &dtype_reference_;
  for (const auto& port : ports) {
    auto it = inputs.find(port.name);
    if (it == inputs.end()) continue;  // input_cochains says so
    const auto& x = it->second;
    if (reference == nullptr) {
      reference = &x;
      reference_name = "input '" + port.name + "'";
      continue;
    }
    if (x.scalar_type() != reference->scalar_type())
      throw ScheduleError("input '" + port.name + "' is " + detail::dtype_str(x.scalar_type()) +
                          ", " + reference_name + " " +
                          detail::dtype_str(reference->scalar_type()) + ": write x.to(" +
                          detail::dtype_constant(reference->scalar_type()) +
                          "), or convert the network with net->to(" +
                          detail::dtype_constant(x.scalar_type()) + ")");
    if (x.device() != reference->device())
      throw ScheduleError("input '" + port.name + "' is on " + x.device().str() + ", " +
                          reference_name + " on " + reference->device().str() +
                          ": write x.to(torch::Device(\"" + reference->device().str() + "\"))");
  }
  for (const auto& [name, A] : operators) {  // (their values' dtype: spmm converts them)
    if (reference == nullptr || !A.values.defined() || !declared.count(name)) continue;
    if (A.values.device() != reference->device())
      throw ScheduleError("operator '" + name + "' is on " + A.values.device().str() + ", " +
                          reference_name + " on " + reference->device().str() +
                          ": move it with A.to(torch::Device(\"" + reference->device().str() +
                          "\"))");
  }
}

// Each rank's cells, as the batch, the inputs' rows and the operators' rows (target rank) and
// columns (source rank) give them: all must agree.
TOPOS_INLINE void OperatorNetworkImpl::check_cells(
    const std::map<std::string, torch::Tensor>& inputs,
    const std::map<std::string, SparseOperator>& operators, const ComplexBatch* batch) const {
  const auto& ports = schedule_.inputs();
  const auto& declared = schedule_.operators();
  struct Count {
    std::int64_t cells;
    const char* kind;  // "batch", "input", "operator rows", "operator columns"
    const std::string* name;
  };
  std::map<int, Count> cells;
  const auto said = [](int rank, const Count& c) {
    const auto n = std::to_string(c.cells);
    const std::string k = c.kind;
    if (k == "batch") return "the batch has " + n + " cells of rank " + std::to_string(rank);
    if (k == "input") return "input '" + *c.name + "' has " + n + " rows";
    return "operator '" + *c.name + "' has " + n + (k == "operator rows" ? " rows" : " columns");
  };
  if (batch != nullptr)
    for (int r = 0; r <= batch->max_rank(); ++r) cells[r] = {batch->size(r), "batch", nullptr};
  for (const auto& port : ports) {
    auto it = inputs.find(port.name);
    if (it == inputs.end() || it->second.dim() < 2) continue;  // input_cochains says why
    const Count c{it->second.size(-2), "input", &port.name};
    const auto [at, fresh] = cells.emplace(port.key.rank, c);
    if (!fresh && at->second.cells != c.cells)
      throw ScheduleError("input '" + port.name + "' has " + std::to_string(c.cells) +
                          " rows, but " + said(port.key.rank, at->second) +
                          ": give one row per cell of rank " + std::to_string(port.key.rank));
  }
  for (const auto& [name, ranks] : declared) {
    const auto [source, target] = ranks;
    std::int64_t rows = 0, cols = 0;
    if (auto it = operators.find(name); it != operators.end()) {
      rows = it->second.rows;
      cols = it->second.cols;
    } else if (batch != nullptr && batch->has_neighborhood(name)) {
      const auto& n = batch->neighborhood(name);
      if (n.source_rank != source || n.target_rank != target)
        throw ScheduleError(
            "neighbourhood '" + name + "' of the batch maps rank " + std::to_string(n.source_rank) +
            " to rank " + std::to_string(n.target_rank) + ", the schedule declares it from rank " +
            std::to_string(source) + " to rank " + std::to_string(target) +
            ": declare operator_input(\"" + name + "\", " + std::to_string(n.source_rank) + ", " +
            std::to_string(n.target_rank) + ")");
      rows = n.num_target;
      cols = n.num_source;
    } else {
      continue;  // not given: optional, or the step that applies it says so
    }
    for (const auto& [rank, count, kind] :
         {std::tuple<int, std::int64_t, const char*>{target, rows, "operator rows"},
          std::tuple<int, std::int64_t, const char*>{source, cols, "operator columns"}}) {
      const Count c{count, kind, &name};
      const auto [at, fresh] = cells.emplace(rank, c);
      if (fresh || at->second.cells == count) continue;
      const auto want = [&](int r) {
        auto w = cells.find(r);
        return w == cells.end() ? std::string("?") : std::to_string(w->second.cells);
      };
      throw ScheduleError("operator '" + name + "' is " + std::to_string(rows) + " × " +
                          std::to_string(cols) + " and maps rank " + std::to_string(source) +
                          " cochains to rank " + std::to_string(target) + " (rows: rank " +
                          std::to_string(target) + "'s cells, columns: rank " +
                          std::to_string(source) + "'s), but " + said(rank, at->second) +
                          ": give a " + want(target) + " × " + want(source) +
                          " operator, or declare the ranks it maps with operator_input(\"" + name +
                          "\", source_rank, target_rank)");
    }
  }
}

TOPOS_INLINE std::map<std::string, SparseOperator> OperatorNetworkImpl::declared_operators(
    const std::map<std::string, SparseOperator>& all) const {
  std::map<std::string, SparseOperator> out;
  for (const auto& [name, A] : all)
    if (schedule_.operators().count(name)) out.emplace(name, A);
  return out;
}

}  // namespace topos::nn
