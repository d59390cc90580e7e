// topos/nn/operator_schedule/plan.hpp
// Plan: what an OperatorNetwork's forward runs, decided before it runs. Building a network checks
// the schedule; planning a forward (per set of operators given, batch or not, and fast paths on)
// picks the steps an output needs and, for each, the route the fast paths give it; the
// interpreter then runs the plan and decides only what depends on the sizes of this forward's
// values. `net->plan(inputs, operators).str()` prints it with each operation's FLOPs and buffer.
#pragma once

#include "topos/nn/operator_schedule/builder.hpp"

#include <cstdint>
#include <set>
#include <string>
#include <utility>
#include <vector>

namespace topos::nn {

/// How a planned step computes its target.
enum class StepRoute {
  keep,               ///< every term applies an optional operator left out: the target stays
  chain,              ///< one term: its operations and the step's as one list (a product
                      ///< ending the term fuses with the step's activation)
  filter,             ///< filter_taps: the taps' shared prefixes once, some weighted first
                      ///< (where a tap is no chain of sparse products: general)
  split_first_layer,  ///< split_first_layer: a concatenation into an mlp, its first Linear
                      ///< layer's blocks applied to the terms before their sums
  general             ///< each term, then the mix, then the step's operations
};

/// A route's name, as Plan::str prints it.
inline const char* route_name(StepRoute r) {
  switch (r) {
    case StepRoute::keep:
      return "keep";
    case StepRoute::chain:
      return "chain";
    case StepRoute::filter:
      return "filter taps";
    case StepRoute::split_first_layer:
      return "split first layer";
    case StepRoute::general:
      return "general";
  }
  return "?";
}

/// A term of a planned step, with what the interpreter would otherwise work out each forward.
struct PlannedTerm {
  const ops::Term* term = nullptr;
  /// Its leading row-wise operations (mlp, linear, activations, ...).
  std::size_t row_wise_prefix = 0;
  /// The neighbourhood of the batch that the operation after that prefix aggregates over, or
  /// empty (the term runs the general way).
  std::string neighborhood;
  /// prefix_cache: the key under which a group shares that prefix (empty: not shared).
  std::string prefix_key;
};

/// One line of a plan's listing: an operation (or a filter's taps) and its FLOPs (-1: not
/// counted); `depth` 0 is a step's term header, 1 an operation.
struct PlanLine {
  int depth = 1;
  std::string what;
  std::int64_t flops = -1;
  /// fuse_products: how many of the next operations run in this one's autograd node (a weight,
  /// the sparse product next to it and a fusable activation after them), where sizes fit.
  int fused_with_next = 0;
  /// The buffer the operation writes, rows × channels in the plain order (-1: none or not known);
  /// an operation that fans out writes `terms` of them (a polynomial filter's powers, the
  /// identity tap included).
  std::int64_t rows = -1, channels = -1, terms = 1;
};

/// A step as the plan runs it.
struct PlannedStep {
  std::size_t group = 0, index = 0;  ///< its place in the schedule's groups
  const OperatorStep* step = nullptr;
  std::string where;  ///< "name (into target)", as errors name it
  bool live = true;   ///< read by a later step or an output (forward runs only those)
  StepRoute route = StepRoute::general;
  std::vector<PlannedTerm> terms;  ///< those that apply no optional operator left out
  /// compact_cochains: the neighbourhoods whose aggregations alone read the target; the step
  /// then runs on the rows they read (else, on every row). Empty: every row.
  std::vector<std::string> compact_readers;
  std::vector<PlanLine> lines;  ///< filled by OperatorNetwork::plan (with the sizes)
};

/// What a forward runs: per group of the schedule, its steps (a group reads one snapshot of the
/// cochains), each with its route. Points into the network's schedule: valid while it lives.
struct Plan {
  std::vector<std::vector<PlannedStep>> groups;
  std::vector<std::pair<std::string, std::size_t>> layers;  ///< each named layer's first group
  FastPaths fast_paths;
  bool over_batch = false;        ///< planned for a ComplexBatch's neighbourhoods
  std::set<std::string> absent;   ///< optional operators left out
  std::int64_t total_flops = -1;  ///< the sum of the lines' FLOPs (-1: planned without sizes)
  /// The values the lines' buffers hold together (-1: planned without sizes): each operation's
  /// output once, in the plain order, over the cells of one sample (leading batch dimensions
  /// multiply it). What a forward under autograd keeps is of this order: the fast paths keep
  /// less; a sum's, mean's or concatenation's own buffer, an mlp's hidden layers, attention's
  /// per-pair scores and dropout's masks come on top; a fan-out's identity term is counted
  /// though it is its input.
  std::int64_t total_values = -1;
  std::int64_t value_bytes = 0;  ///< bytes per value: the inputs' dtype (0: not known)

  /// The plan as text: the fast paths on, then each live step with its route, terms and
  /// operations (FLOPs in the plain order: every dense product on every row, where the fast paths
  /// may compute fewer; the buffer each writes, rows × channels), and the totals.
  std::string str() const;
};

}  // namespace topos::nn
