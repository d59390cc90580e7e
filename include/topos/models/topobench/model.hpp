// topos/models/topobench/model.hpp
// The ten models of TopoBench's table, and TopoTune's GCCN, as TopoBench assembles them: its
// feature encoder (per rank GraphNorm, Linear to the hidden width, relu, dropout), a backbone (an
// operator schedule of the zoo: GCN, AllSetTransformer, EDGNN, UniGNN2 = UniGCNII, CWN, CCCN,
// CCXN, SCN = SCN2, SCCN, SCCNN = TopoBench's SCCNNCustom, GCCN), its wrapper's residual
// (x_r <- LayerNorm(backbone's x_r + encoded x_r)), its readout (PropagateSignalDown: per rank i
// from the top down, x_{i-1} <- Linear([LayerNorm(B_i (x_i W_i)) ‖ x_{i-1}]); or none), then for
// graph-level tasks the sum of each graph's node rows and a Linear to the classes (per node for
// node-level tasks). The wrapper and readout are one more schedule ("head"). Batches come from
// topobench/batch.hpp.
#pragma once

#include "topos/models/cell/cccn.hpp"
#include "topos/models/cell/ccxn.hpp"
#include "topos/models/cell/cwn.hpp"
#include "topos/models/combinatorial/gccn.hpp"
#include "topos/models/graph/gcn.hpp"
#include "topos/models/hypergraph/allset_transformer.hpp"
#include "topos/models/hypergraph/edgnn.hpp"
#include "topos/models/hypergraph/unigcnii.hpp"
#include "topos/models/simplicial/sccn.hpp"
#include "topos/models/simplicial/sccnn_custom.hpp"
#include "topos/models/simplicial/scn2.hpp"
#include "topos/models/topobench/batch.hpp"
#include "topos/models/topobench/protocol.hpp"  // model_spec
#include "topos/nn/graph_norm.hpp"
#include "topos/nn/cloneable.hpp"

#include <torch/torch.h>

#include <map>
#include <stdexcept>
#include <string>
#include <vector>

namespace topos::models::topobench {

struct TopoBenchModelOptions {
  TopoBenchModelOptions(std::string model, std::vector<std::int64_t> in_channels,
                        std::int64_t hidden, std::int64_t num_classes)
      : model_(std::move(model)),
        in_channels_(std::move(in_channels)),
        hidden_(hidden),
        num_classes_(num_classes) {}
  TORCH_ARG(std::string, model);                      ///< a name of model_specs()
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
};

/// The backbone's schedule; its inputs are x_r at the hidden width, its outputs x_r.
inline nn::OperatorSchedule backbone_schedule(const TopoBenchModelOptions& o) {
  const std::string& m = o.model();
  const auto h = o.hidden();
  const int L = o.n_layers();
  if (m == "GCN") return gcn_schedule(GCNOptions(h, h).num_layers(L));
  if (m == "AllSetTransformer")
    return allset_transformer_schedule(AllSetTransformerOptions(h, h)
                                           .n_layers(L)
                                           .heads(4)
                                           .dropout(0)
                                           .mlp_num_layers(1)
                                           .mlp_dropout(0));
  if (m == "EDGNN") return edgnn_schedule(EDGNNOptions(h).n_layers(L));
  if (m == "UniGNN2")
    return unigcnii_schedule(
        UniGCNIIOptions(h, h).n_layers(L).input_drop(0).layer_drop(0).topomodelx_compatible(
            o.topobench_compatible()));
  if (m == "CWN") return cwn_schedule(CWNOptions(h, h, h, h, L));
  if (m == "CCCN") return cccn_schedule(CCCNOptions(h).n_layers(L));
  if (m == "CCXN")
    return ccxn_schedule(
        CCXNOptions(h, h, h).n_layers(L).att(true).topomodelx_compatible(o.topobench_compatible()));
  if (m == "SCN") return scn2_schedule(SCN2Options(h, h, h).n_layers(L));
  if (m == "SCCN")
    return sccn_schedule(SCCNOptions(h, 2).n_layers(L).update_func(nn::Update::sigmoid));
  if (m == "SCCNN")
    return sccnn_custom_schedule(
        SCCNNCustomOptions(h).n_layers(L).topobench_compatible(o.topobench_compatible()));
  if (m == "GCCN") return gccn_schedule(GCCNOptions(h, topotune_cell_neighborhoods()).n_layers(L));
  model_spec(m);  // throws, listing the names
  return {};
}

/// The wrapper's residual and the readout, as one schedule over "x_r" (the backbone's outputs)
/// and "encoded_r" (the encoder's), giving "x_0".
inline nn::OperatorSchedule head_schedule(const TopoBenchModelOptions& o) {
  using namespace nn::ops;
  const auto& spec = model_spec(o.model());
  const auto h = o.hidden();
  nn::OperatorSchedule s;
  for (int r = 0; r < spec.cell_dimensions; ++r) {
    const auto R = std::to_string(r);
    s.input("x_" + R, r, h).input("encoded_" + R, r, h, "encoded");
    s.step(into(r).sum(from(r), from(r, "encoded")).layer_norm("wrapper.ln_" + R));
  }
  if (o.propagate_signal_down())
    for (int i = spec.cell_dimensions - 1; i >= 1; --i) {
      const auto I = std::to_string(i), p = "readout.stage_" + I + ".";
      s.operator_input("incidence_" + I, i, i - 1);
      s.step(into(i - 1)
                 .concat(from(i).conv(p + "conv", h).via("incidence_" + I).layer_norm(p + "ln"),
                         from(i - 1))
                 .linear(p + "linear", h));
    }
  s.output("x_0", 0);
  return s;
}

class TopoBenchModelImpl : public nn::Cloneable<TopoBenchModelImpl> {
 public:
  explicit TopoBenchModelImpl(TopoBenchModelOptions o) : options(std::move(o)) {
    const auto& spec = model_spec(options.model());
    if (options.hidden() < 1 || options.num_classes() < 2 || options.n_layers() < 1)
      throw std::invalid_argument(options.model() +
                                  ": hidden and n_layers must be positive, classes at least 2");
    for (int r : spec.encoded_ranks) {
      if (static_cast<std::size_t>(r) >= options.in_channels().size())
        throw std::invalid_argument(options.model() + " encodes rank " + std::to_string(r) +
                                    " but the data has " +
                                    std::to_string(options.in_channels().size()) + " ranks");
      const auto R = std::to_string(r);
      const auto f = options.in_channels()[static_cast<std::size_t>(r)];
      norms_.push_back(register_module("encoder_norm_" + R, nn::GraphNorm(f)));
      linears_.push_back(
          register_module("encoder_linear_" + R, torch::nn::Linear(f, options.hidden())));
    }
    backbone = register_module("backbone", nn::OperatorNetwork(backbone_schedule(options)));
    if (options.model() == "EDGNN") reset_edgnn_parameters(*backbone, options.hidden());
    head = register_module("head", nn::OperatorNetwork(head_schedule(options)));
    classifier =
        register_module("classifier", torch::nn::Linear(options.hidden(), options.num_classes()));
  }

  /// Logits: one row per graph (graph-level) or per node.
  torch::Tensor forward(const Batch& b) {
    const auto& spec = model_spec(options.model());
    std::map<std::string, torch::Tensor> encoded;
    for (std::size_t k = 0; k < spec.encoded_ranks.size(); ++k) {
      const auto r = static_cast<std::size_t>(spec.encoded_ranks[k]);
      auto e = torch::relu(
          nn::graph_norm_linear(norms_[k], linears_[k], b.x.at(r), b.batch.at(r), b.num_graphs));
      if (options.dropout() > 0) e = nn::dropout(e, options.dropout(), is_training());
      encoded["x_" + std::to_string(r)] = e;
    }
    std::map<std::string, torch::Tensor> in;
    for (const auto& port : backbone->schedule().inputs()) {
      auto it = encoded.find(port.name);
      if (it == encoded.end())
        throw std::invalid_argument(options.model() + ": the backbone reads '" + port.name +
                                    "', which the encoder does not give");
      in[port.name] = it->second;
    }
    const auto out = backbone->forward(in, backbone->declared_operators(backbone_operators(b)));
    std::map<std::string, torch::Tensor> head_in;
    for (int r = 0; r < spec.cell_dimensions; ++r) {
      const auto R = std::to_string(r);
      head_in["x_" + R] = out.at("x_" + R);
      head_in["encoded_" + R] = encoded.at("x_" + R);
    }
    auto x0 = head->forward(head_in, head->declared_operators(b.operators)).at("x_0");
    if (options.graph_level()) x0 = nn::segment_sum(x0, b.batch.at(0), b.num_graphs);
    return classifier->forward(x0);
  }

  /// The batch's operators under the names the backbone's schedule reads (TopoBench's wrappers
  /// hand SCN the normalised Hodge Laplacians, SCCN the plain ones as its same-rank operators),
  /// plus what a backbone derives at batch level: CCXN's attention targets (TopoModelX scores
  /// 2-cell i with edge i of the whole batch in compatible mode).
  std::map<std::string, nn::SparseOperator> backbone_operators(const Batch& b) const {
    const std::string& m = options.model();
    if (m != "CCXN" && m != "SCN" && m != "SCCN") return b.operators;
    auto ops = b.operators;
    for (int r = 0; r < 3 && m != "CCXN"; ++r) {
      const auto R = std::to_string(r);
      if (m == "SCN") ops["laplacian_" + R] = ops.at("hodge_laplacian_" + R + "_norm");
      if (m == "SCCN") ops["adjacency_" + R] = ops.at("hodge_laplacian_" + R);
    }
    if (m == "CCXN") {
      const auto& bt = ops.at("incidence_2_t");
      ops["incidence_2_t_target"] =
          options.topobench_compatible()
              ? nn::SparseOperator::selection(torch::arange(bt.rows), bt.cols, torch::kFloat)
              : bt;
    }
    return ops;
  }

  TopoBenchModelOptions options;
  nn::OperatorNetwork backbone{nullptr}, head{nullptr};
  torch::nn::Linear classifier{nullptr};

 private:
  std::vector<nn::GraphNorm> norms_;
  std::vector<torch::nn::Linear> linears_;
};
TORCH_MODULE(TopoBenchModel);

}  // namespace topos::models::topobench
