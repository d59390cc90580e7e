// topos/nn/schedule.hpp
// The schedule DSL: a message-passing network over a combinatorial complex written as data.
//
//   using namespace topos::nn;
//   using namespace topos::nn::dsl;
//   Schedule s;
//   s.encode(0, "", "x0", "enc0")                               // (rank, state) <- module(input)
//       .encode(2, "", "x2", "enc2");
//   s.step(into(2).msg(from(0).via("B02").map("phi02"))         // messages, mapped then reduced
//                 .combine_with(Combine::cat_self)              // [self, m] -> update module
//                 .update_with("psi2")
//                 .when_nonempty(2));                           // per-complex guard
//   s.parallel({into(0).msg(from(2).via("B20")).update_with("psi0"),  // one snapshot
//               into(2).msg(from(0).via("B02")).update_with("psi2b")});
//   s.decode(0, "", "dec0", "y0");
//   ScheduleSignature sig{{{"B02", {0, 2}}, {"B20", {2, 0}}}, {{"x0", 3}, {"x2", 3}}};
//   std::map<std::string, MlpOptions> modules{
//       {"enc0", MlpOptions(3, 8, 8)},   {"enc2", MlpOptions(3, 8, 8)},
//       {"phi02", MlpOptions(8, 8, 8)},  {"psi2", MlpOptions(16, 8, 8)},
//       {"psi0", MlpOptions(16, 8, 8)},  {"psi2b", MlpOptions(16, 8, 8)},
//       {"dec0", MlpOptions(8, 8, 3)}};
//   ScheduleNetwork net(s, modules, sig);                       // validated here
//   auto y = net->forward({{"x0", x0}, {"x2", x2}}, batch).at("y0");
//
// Messages come from a (rank, state) through a named, directed neighbourhood of the batch,
// optionally mapped by a module, then reduced (sum/mean/max, weighted or restricted to a role)
// or concatenated by role in a fixed order. A step combines them with the target's own state
// (concatenation or sum) and updates it with a module. Steps run in sequence; a parallel group
// reads one snapshot. Modules are shared between steps by name and registered as
// "modules.<name>", so checkpoints are read and written by readable, stable names.
#pragma once

#include "topos/config.hpp"
#include "topos/nn/aggregate.hpp"
#include "topos/nn/cochains.hpp"
#include "topos/nn/complex_batch.hpp"
#include "topos/nn/mlp.hpp"
#include "topos/nn/schedule_error.hpp"

#include <torch/torch.h>

#include <cstdio>
#include <fstream>
#include <map>
#include <optional>
#include <set>
#include <sstream>
#include <string>
#include <vector>

namespace topos::nn {

enum class Combine { cat_self, sum_self };

struct Message {
  CochainKey source;
  std::string via;
  std::string map;  ///< module applied to source rows ("" = identity)
  AggregateOptions agg;
  std::vector<int> by_role;  ///< non-empty: concatenate per-role sums in this order
  bool accumulate = false;   ///< added to the previous message instead of concatenated
  Message& with_via(std::string n) {
    via = std::move(n);
    return *this;
  }
};

namespace dsl {
struct From {
  Message m;
  From& via(std::string n) {
    m.via = std::move(n);
    return *this;
  }
  From& map(std::string module) {
    m.map = std::move(module);
    return *this;
  }
  From& weighted() {
    m.agg.weighted = true;
    return *this;
  }
  From& only(int role) {
    m.agg.role = role;
    return *this;
  }
  From& reduce(Reduce r) {
    m.agg.reduce = r;
    return *this;
  }
  From& by_role(std::vector<int> order) {
    m.by_role = std::move(order);
    return *this;
  }
};
inline From from(int rank, std::string state = "") {
  From f;
  f.m.source = {rank, std::move(state)};
  return f;
}
}  // namespace dsl

struct Step {
  CochainKey target;
  std::vector<Message> messages;
  Combine combine = Combine::cat_self;
  std::string update;   ///< module producing the new target state
  int guard_rank = -1;  ///< >= 0: only complexes with at least one cell of this rank
  std::string name;     ///< for errors and printing (default "step <i>")

  Step& msg(const dsl::From& f) {
    messages.push_back(f.m);
    return *this;
  }
  /// A message summed into the previous one (same width), e.g. r = Σ_role+ h3p + Σ_role- h3m.
  Step& add(const dsl::From& f) {
    messages.push_back(f.m);
    messages.back().accumulate = true;
    return *this;
  }
  Step& combine_with(Combine c) {
    combine = c;
    return *this;
  }
  Step& update_with(std::string module) {
    update = std::move(module);
    return *this;
  }
  Step& when_nonempty(int rank) {
    guard_rank = rank;
    return *this;
  }
  Step& named(std::string n) {
    name = std::move(n);
    return *this;
  }
};

namespace dsl {
inline Step into(int rank, std::string state = "") {
  Step s;
  s.target = {rank, std::move(state)};
  return s;
}
}  // namespace dsl

struct Encoder {
  CochainKey key;
  std::string input;                  ///< name of the input feature tensor
  std::vector<std::int64_t> columns;  ///< empty: all, else this column order
  std::vector<std::int64_t> negate;   ///< columns (of the input, before selection) negated
  std::string module;
};
struct Decoder {
  CochainKey key;
  std::string module;
  std::string output;
};

class Schedule {
 public:
  /// Encodes input tensor `input` into cochain (rank, state) with `module` (after column
  /// negation, then selection).
  Schedule& encode(int rank, std::string state, std::string input, std::string module,
                   std::vector<std::int64_t> columns = {}, std::vector<std::int64_t> negate = {}) {
    encoders_.push_back({{rank, std::move(state)},
                         std::move(input),
                         std::move(columns),
                         std::move(negate),
                         std::move(module)});
    return *this;
  }
  Schedule& step(Step s) {
    if (s.name.empty()) s.name = "step " + std::to_string(num_steps_);
    ++num_steps_;
    groups_.push_back({std::move(s)});
    return *this;
  }
  Schedule& parallel(std::vector<Step> steps) {
    for (auto& s : steps) {
      if (s.name.empty()) s.name = "step " + std::to_string(num_steps_);
      ++num_steps_;
    }
    groups_.push_back(std::move(steps));
    return *this;
  }
  Schedule& decode(int rank, std::string state, std::string module, std::string output) {
    decoders_.push_back({{rank, std::move(state)}, std::move(module), std::move(output)});
    return *this;
  }
  /// Appends `other`'s steps (encoders and decoders too) `times` times.
  Schedule& repeat(const Schedule& other, int times = 1) {
    for (int t = 0; t < times; ++t)
      for (const auto& g : other.groups_) g.size() == 1 ? step(g[0]) : parallel(g);
    return *this;
  }

  const std::vector<Encoder>& encoders() const { return encoders_; }
  const std::vector<std::vector<Step>>& groups() const { return groups_; }
  const std::vector<Decoder>& decoders() const { return decoders_; }

  std::string str() const;

 private:
  std::vector<Encoder> encoders_;
  std::vector<std::vector<Step>> groups_;
  std::vector<Decoder> decoders_;
  int num_steps_ = 0;
};

/// What the network knows of the batches it will see: neighbourhood directions and input widths.
struct ScheduleSignature {
  std::map<std::string, std::pair<int, int>> neighborhoods;  ///< name -> (source rank, target rank)
  std::map<std::string, std::int64_t> inputs;                ///< input tensor name -> columns
};

/// Runs a Schedule with named Mlp modules. Validated at construction: unknown modules,
/// neighbourhoods, ranks or states, and channel mismatches throw ScheduleError naming the step.
class ScheduleNetworkImpl : public torch::nn::Module {
 public:
  ScheduleNetworkImpl(Schedule schedule, const std::map<std::string, MlpOptions>& modules,
                      ScheduleSignature sig);

  /// Runs the schedule: inputs by name -> outputs by name.
  std::map<std::string, torch::Tensor> forward(const std::map<std::string, torch::Tensor>& inputs,
                                               const ComplexBatch& batch);

  /// Encodes the inputs. Given the batch, a cochain that is only ever read by messages (never
  /// updated or decoded) is encoded on the rows those messages read, and nowhere else: HOPNet's
  /// edges reach the network only through the faces in contact, a third of them.
  Cochains encode(const std::map<std::string, torch::Tensor>& inputs,
                  const ComplexBatch* batch = nullptr);

  void process(Cochains& h, const ComplexBatch& batch);

  std::map<std::string, torch::Tensor> decode(const Cochains& h);

  Mlp module(const std::string& name) const;
  const Schedule& schedule() const { return schedule_; }

  /// Off: every module maps every row and every concatenation is built, which is slower and
  /// gives the same numbers (up to float rounding); for checking the fast paths.
  void set_fast_paths(bool on) { fast_ = on; }

 private:
  Schedule schedule_;
  ScheduleSignature sig_;
  std::map<std::string, Mlp> modules_;

  bool fast_ = true;
  std::map<CochainKey, std::vector<std::string>>
      read_only_;  ///< encoded cochains only messages read -> their neighbourhoods

  using MapCache = std::map<std::pair<CochainKey, std::string>, torch::Tensor>;

  /// For a sorted set of `used` rows out of `rows`: each row's position in `used`, or -1.
  static torch::Tensor compact_rows(const torch::Tensor& used, std::int64_t rows);
  void find_read_only();
  torch::Tensor run_step(const Step& s, const Cochains& h, const ComplexBatch& batch,
                         MapCache& cache);
  // Channel inference: widths of every (rank, state) after each group, checked step by step.
  void validate();
};
TORCH_MODULE(ScheduleNetwork);

}  // namespace topos::nn

#ifdef TOPOS_HEADER_ONLY
#include "topos/nn/schedule-inl.hpp"
#endif
