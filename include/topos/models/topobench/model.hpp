// topos/models/topobench/model.hpp
// A model as TopoBench assembles one around a backbone: its feature encoder (per rank GraphNorm,
// Linear to the hidden width, relu, dropout), the backbone, its wrapper's residual
// (x_r <- LayerNorm(backbone's x_r + encoded x_r)), its readout (PropagateSignalDown: per rank i
// from the top down, x_{i-1} <- Linear([LayerNorm(B_i (x_i W_i)) ‖ x_{i-1}]); or none), then for
// graph-level tasks the sum of each graph's node rows and a Linear to the classes (per node for
// node-level tasks). The wrapper and readout are one more schedule ("head"). Batches come from
// topobench/batch.hpp.
//
// The backbone is any `Backbone`: an operator schedule, or any module whose
// forward(x, operators) maps the encoded cochains {"x_r"} and the batch's operators to x_r for
// every rank r < cell_dimensions, with its RankLayout (domain, encoded ranks, cell dimensions,
// operators). The ten backbones of TopoBench's table and TopoTune's GCCN are
// `table_backbone(name)` (topobench/table_models.hpp), kept out of this header so that a user's
// model compiles without them:
//   topobench::Backbone mine = topobench::Backbone::schedule(
//       "GIN2", {topobench::Domain::graph, {0}, 1, {"gcn_adjacency"}},
//       [](const topobench::BackboneContext& c) { return my_schedule(c.hidden, c.n_layers); });
//   topobench::TopoBenchModel m(topobench::TopoBenchModelOptions(mine, {7}, 32, 2));
#pragma once

#include "topos/config.hpp"
#include "topos/models/topobench/batch.hpp"
#include "topos/models/topobench/protocol.hpp"  // RankLayout
#include "topos/nn/cloneable.hpp"
#include "topos/nn/graph_norm.hpp"
#include "topos/nn/operator_schedule.hpp"

#include <torch/torch.h>

#include <functional>
#include <map>
#include <memory>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

namespace topos::models::topobench {

/// Cochains by name ("x_0", "x_1", ...) and a batch's operators by name.
using NamedCochains = std::map<std::string, torch::Tensor>;
using NamedOperators = std::map<std::string, nn::SparseOperator>;

/// What a backbone is built for: the model's hidden width (the backbone's input and output
/// width on every rank) and its TopoBenchModelOptions.
struct BackboneContext {
  std::int64_t hidden = 0;
  int n_layers = 1;
  bool topobench_compatible = true;
};

/// A backbone built for one model: the module that holds its parameters (registered as the
/// model's "backbone"; null when it has none), and its forward.
struct BuiltBackbone {
  std::shared_ptr<torch::nn::Module> module;
  nn::OperatorNetwork network{nullptr};  ///< the same module, when it is an operator schedule
  std::function<NamedCochains(const NamedCochains&, const NamedOperators&)> forward;
};

/// A backbone and its rank layout, as a recipe: TopoBenchModel builds it in its constructor,
/// after the encoder (so that parameters are drawn in TopoBench's order; a clone builds its own).
class Backbone {
 public:
  using Build = std::function<BuiltBackbone(const BackboneContext&)>;
  using Rename = std::function<NamedOperators(const NamedOperators&, const BackboneContext&)>;

  Backbone(std::string name, RankLayout layout, Build build);

  /// An operator network built by `make` (the table's EDGNN re-draws some of its parameters).
  static Backbone network(std::string name, RankLayout layout,
                          std::function<nn::OperatorNetwork(const BackboneContext&)> make);
  /// An operator schedule over "x_r" at the hidden width, giving "x_r" (r < cell_dimensions).
  static Backbone schedule(std::string name, RankLayout layout,
                           std::function<nn::OperatorSchedule(const BackboneContext&)> make) {
    return network(std::move(name), std::move(layout),
                   [make](const BackboneContext& c) { return nn::OperatorNetwork(make(c)); });
  }
  /// Any module: `make(context)` returns a module holder (or shared_ptr) whose
  /// forward(const NamedCochains&, const NamedOperators&) returns NamedCochains.
  template <class Make>
  static Backbone module(std::string name, RankLayout layout, Make make) {
    return Backbone(std::move(name), std::move(layout), [make](const BackboneContext& c) {
      BuiltBackbone b;
      auto p = as_shared(make(c));
      b.module = p;
      b.forward = [p](const NamedCochains& x, const NamedOperators& ops) {
        return p->forward(x, ops);
      };
      return b;
    });
  }

  /// The batch's operators under the names the backbone reads (default: as they are).
  Backbone& operators(Rename rename) {
    rename_ = std::move(rename);
    return *this;
  }

  const std::string& name() const { return name_; }
  const RankLayout& layout() const { return layout_; }
  BuiltBackbone build(const BackboneContext& c) const { return build_(c); }
  NamedOperators operators_for(const NamedOperators& batch, const BackboneContext& c) const {
    return rename_ ? rename_(batch, c) : batch;
  }

 private:
  template <class T>
  static std::shared_ptr<T> as_shared(const std::shared_ptr<T>& p) {
    return p;
  }
  template <class T>
  static std::shared_ptr<T> as_shared(const torch::nn::ModuleHolder<T>& m) {
    return m.ptr();
  }

  std::string name_;
  RankLayout layout_;
  Build build_;
  Rename rename_;
};

struct TopoBenchModelOptions {
  TopoBenchModelOptions(Backbone backbone, std::vector<std::int64_t> in_channels,
                        std::int64_t hidden, std::int64_t num_classes)
      : backbone_(std::move(backbone)),
        in_channels_(std::move(in_channels)),
        hidden_(hidden),
        num_classes_(num_classes) {}
  TORCH_ARG(Backbone, backbone);                      ///< table_backbone(name) or a user's
  TORCH_ARG(std::vector<std::int64_t>, in_channels);  ///< feature width of each rank of the data
  TORCH_ARG(std::int64_t, hidden);
  TORCH_ARG(std::int64_t, num_classes);
  TORCH_ARG(int, n_layers) = 2;
  TORCH_ARG(double, dropout) = 0;                  ///< the encoder's (TopoBench's proj_dropout)
  TORCH_ARG(bool, propagate_signal_down) = false;  ///< readout PropagateSignalDown, else none
  TORCH_ARG(bool, graph_level) = true;             ///< pool each graph's nodes (sum)
  /// Reproduce TopoBench's code where it departs from its models' formulas (SCCNN's repeated
  /// filter taps, CCXN's attention targets, UniGCNII's β).
  TORCH_ARG(bool, topobench_compatible) = true;

 public:
  /// The model's name (the backbone's): runs.csv's `model`.
  const std::string& model() const { return backbone_.name(); }
  BackboneContext context() const { return {hidden_, n_layers_, topobench_compatible_}; }
};

/// The wrapper's residual and the readout, as one schedule over "x_r" (the backbone's outputs)
/// and "encoded_r" (the encoder's), giving "x_0".
nn::OperatorSchedule head_schedule(const TopoBenchModelOptions& o);

class TopoBenchModelImpl : public nn::Cloneable<TopoBenchModelImpl> {
 public:
  explicit TopoBenchModelImpl(TopoBenchModelOptions o);

  /// Logits: one row per graph (graph-level) or per node.
  torch::Tensor forward(const Batch& b);

  /// The batch's operators under the names the backbone reads (Backbone::operators).
  NamedOperators backbone_operators(const Batch& b) const {
    return options.backbone().operators_for(b.operators, options.context());
  }

  TopoBenchModelOptions options;
  /// The backbone's operator network; null when the backbone is another module.
  nn::OperatorNetwork backbone{nullptr};
  nn::OperatorNetwork head{nullptr};
  torch::nn::Linear classifier{nullptr};

 private:
  std::vector<nn::GraphNorm> norms_;
  std::vector<torch::nn::Linear> linears_;
  BuiltBackbone built_;
};
TORCH_MODULE(TopoBenchModel);

}  // namespace topos::models::topobench

#ifdef TOPOS_HEADER_ONLY
#include "topos/models/topobench/model-inl.hpp"
#endif
