// topos/models/topobench/trainer.hpp
// TopoBench's trainer for any backbone (topobench/model.hpp): a dataset of the table read and
// lifted to the backbone's domain with the operators its layout names (lift_dataset), then one
// run per split as TopoBench trains (train_run): its random split, batches of the training split
// shuffled every epoch, Adam with StepLR (step 50, gamma 0.5), a validation check every
// `val_every` epochs, early stopping after `patience` checks without a strictly better
// validation accuracy (not before `min_epochs`), the best check's parameters and buffers put
// back, and the test accuracy there. topobench/report.hpp writes the runs' files.
//   const auto data = lift_dataset(root, dataset_name("MUTAG"), mine.layout(), cfg);
//   const auto run = train_run(data, mine, "MUTAG", cfg, /*split seed*/ 0);
#pragma once

#include "topos/data/graph_datasets.hpp"
#include "topos/models/topobench/batch.hpp"
#include "topos/models/topobench/model.hpp"
#include "topos/models/topobench/protocol.hpp"
#include "topos/nn/cloneable.hpp"  // StateSnapshot
#include "topos/util/progress.hpp"

#include <torch/torch.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <functional>
#include <iomanip>
#include <memory>
#include <random>
#include <set>
#include <sstream>
#include <string>
#include <vector>

namespace topos::models::topobench {

/// A dataset lifted for one domain: its graphs (one for a node-level set) and classes.
struct LiftedDataset {
  std::vector<LiftedGraph> graphs;
  std::vector<std::int64_t> node_labels;  ///< node-level sets: every node's class
  std::int64_t num_classes = 0;
  bool node_level = false;
  double seconds = 0;
  /// Graphs (graph-level) or nodes (node-level): what the split divides.
  std::int64_t size() const {
    return static_cast<std::int64_t>(node_level ? node_labels.size() : graphs.size());
  }
};

/// The operators of `layout` that pair edges through a shared node (Σ_v deg(v)² entries).
inline std::set<std::string> rank1_pair_operators(const RankLayout& layout) {
  std::set<std::string> out;
  for (const auto& op : layout.operators)
    if (op == "down_laplacian_1" || op == "down_laplacian_1_gcn" || op == "hodge_laplacian_1" ||
        op == "hodge_laplacian_1_norm")
      out.insert(op);
  return out;
}

/// Reads dataset `d` from `root` (TOPOS_DATASETS_DIR's layout) and lifts it as TopoBench does
/// for `layout`'s domain, building its operators. `cfg` gives the lifting's settings
/// (signed_incidence, max_cell_length); `factored` keeps the rank-1 pair operators as factors
/// (LiftingOptions::factored).
inline LiftedDataset lift_dataset(const std::filesystem::path& root, const DatasetName& d,
                                  const RankLayout& layout, const RunConfig& cfg,
                                  bool factored = false, bool progress = true) {
  const auto start = std::chrono::steady_clock::now();
  const Domain domain = layout.domain;
  LiftingOptions lo;
  lo.operators = layout.operators;
  lo.signed_incidence = domain == Domain::simplicial ? cfg.signed_incidence : false;
  if (factored) lo.factored = rank1_pair_operators(layout);
  if (cfg.max_cell_length > 0) lo.max_cell_length = cfg.max_cell_length;
  LiftedDataset out;
  out.node_level = d.node_level;
  if (d.node_level) {
    const auto ds = data::load_topobench_node_dataset(root, d.name);
    out.num_classes = ds.num_classes;
    out.node_labels = ds.labels;
    out.graphs.push_back(
        lift_graph(ds.num_nodes, ds.edges, ds.x, ds.num_node_features, {}, domain, lo));
  } else {
    const auto ds = data::load_topobench_graph_dataset(root, d.name);
    out.num_classes = ds.num_classes;
    // TopoBench keeps MUTAG's bond types as the edges' features when it lifts to cells or
    // simplices (preserve_edge_attr_if_lifted); elsewhere x_1 is the projection of x_0.
    if (std::string(d.name) == "MUTAG" &&
        (domain == Domain::cell || domain == Domain::simplicial)) {
      lo.edge_features = true;
      for (const auto& g : ds.graphs)
        for (auto l : g.edge_labels) lo.num_edge_labels = std::max(lo.num_edge_labels, l + 1);
    }
    std::unique_ptr<ProgressBar> bar;
    if (progress)
      bar = std::make_unique<ProgressBar>(
          std::string("lift ") + d.name + " (" + domain_name(domain) + ")",
          static_cast<std::int64_t>(ds.graphs.size()), "graph");
    for (const auto& g : ds.graphs) {
      out.graphs.push_back(
          lift_graph(g.num_nodes, g.edges, g.x, ds.num_node_features, g.edge_labels, domain, lo));
      out.graphs.back().label = g.label;
      if (bar) bar->update(1);
    }
    if (bar) bar->finish();
  }
  out.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return out;
}

/// The majority classifier's test accuracy: the most frequent class of the training split (the
/// lowest on a tie) predicted for every test graph or node. A trained model must beat it.
inline double majority_accuracy(const LiftedDataset& data, std::int64_t seed) {
  const auto label = [&](std::size_t i) {
    return data.node_level ? data.node_labels[i] : data.graphs[i].label;
  };
  const auto split = random_split(data.size(), seed);
  std::vector<std::int64_t> count(static_cast<std::size_t>(data.num_classes), 0);
  for (auto i : split.train) ++count[static_cast<std::size_t>(label(i))];
  const auto majority = std::max_element(count.begin(), count.end()) - count.begin();
  std::int64_t hits = 0;
  for (auto i : split.test) hits += label(i) == majority;
  return split.test.empty() ? 0
                            : static_cast<double>(hits) / static_cast<double>(split.test.size());
}

/// One part of a split (validation or test), batched once as TopoBench's loaders give it: graphs
/// in batches of the training batch size in the split's order (CCXN's TopoModelX-compatible
/// attention scores 2-cell i of a batch with edge i of the same batch, so its predictions depend
/// on the batching), or the nodes of the whole graph.
class EvalSet {
 public:
  EvalSet(const LiftedDataset& data, const std::vector<std::size_t>& part, std::size_t batch_size,
          std::shared_ptr<const Batch> whole = nullptr)
      : node_level_(data.node_level) {
    if (node_level_) {
      whole_ = whole ? std::move(whole) : std::make_shared<const Batch>(collate(data.graphs, {0}));
      std::vector<std::int64_t> idx(part.begin(), part.end()), labels;
      for (auto i : part) labels.push_back(data.node_labels.at(i));
      index_ = torch::tensor(idx, torch::kLong);
      labels_ = torch::tensor(labels, torch::kLong);
    } else {
      for (const auto& which : batches_of(part, batch_size))
        batches_.push_back(collate(data.graphs, which));
    }
  }

  /// The model's accuracy on this part, in eval mode without gradients (0 when it is empty).
  double accuracy(TopoBenchModelImpl& net) const {
    torch::NoGradGuard no_grad;
    net.eval();
    if (node_level_) {
      if (labels_.numel() == 0) return 0;
      return net.forward(*whole_)
          .index_select(0, index_)
          .argmax(1)
          .eq(labels_)
          .to(torch::kDouble)
          .mean()
          .item<double>();
    }
    std::int64_t correct = 0, total = 0;
    for (const auto& b : batches_) {
      correct += net.forward(b).argmax(1).eq(b.labels).sum().item<std::int64_t>();
      total += b.num_graphs;
    }
    return total ? static_cast<double>(correct) / static_cast<double>(total) : 0.0;
  }

 private:
  bool node_level_;
  std::shared_ptr<const Batch> whole_;
  torch::Tensor index_, labels_;
  std::vector<Batch> batches_;
};

struct TrainOptions {
  int max_epochs = 0;     ///< > 0: at most this many epochs (quick checks; not the protocol)
  bool progress = false;  ///< a progress bar for the run
  /// Called after every validation check (with the model as it is then, in eval mode).
  std::function<void(const Check&, TopoBenchModelImpl&)> on_check;
};

/// A finished run: its row of runs.csv, its validation checks, and the model at its best check.
struct TrainedRun {
  RunResult result;
  std::vector<Check> curve;
  double best_val_accuracy = 0;
  TopoBenchModel model{nullptr};
};

/// Trains `backbone` (in TopoBenchModel) on `data` split by `seed` as TopoBench's trainer does:
/// cfg's hidden, layers, dropout, readout, lr, batch size, epochs, val_every and patience.
inline TrainedRun train_run(const LiftedDataset& data, const Backbone& backbone,
                            const std::string& dataset, const RunConfig& cfg, std::int64_t seed,
                            const TrainOptions& options = {}) {
  const auto start = std::chrono::steady_clock::now();
  if (data.graphs.empty()) throw std::invalid_argument("train_run: " + dataset + " has no graphs");
  const auto& g0 = data.graphs.front();
  const auto& layout = backbone.layout();
  for (int r : layout.encoded_ranks)
    if (r < 0 || static_cast<std::size_t>(r) >= g0.widths.size())
      throw std::invalid_argument(backbone.name() + " encodes rank " + std::to_string(r) + " but " +
                                  dataset + " lifted to " + domain_name(layout.domain) +
                                  " has ranks 0.." + std::to_string(g0.widths.size() - 1));
  for (const auto& op : layout.operators)
    if (!g0.operators.count(op) && !g0.factored.count(op))
      throw std::invalid_argument(backbone.name() + " needs the operator '" + op + "', which " +
                                  dataset + " lifted to " + domain_name(layout.domain) +
                                  " does not have");
  torch::manual_seed(42);  // TopoBench seeds every run with 42
  TrainedRun run;
  TopoBenchModel net(TopoBenchModelOptions(backbone, g0.widths, cfg.hidden, data.num_classes)
                         .n_layers(static_cast<int>(cfg.layers))
                         .dropout(cfg.dropout)
                         .propagate_signal_down(cfg.readout == "PropagateSignalDown")
                         .graph_level(!data.node_level));
  torch::optim::Adam opt(net->parameters(), torch::optim::AdamOptions(cfg.lr));
  const int max_epochs =
      options.max_epochs > 0 ? std::min(cfg.max_epochs, options.max_epochs) : cfg.max_epochs;
  const int min_epochs = std::min(cfg.min_epochs, max_epochs);

  const Split split = random_split(data.size(), seed);
  const auto bs = static_cast<std::size_t>(cfg.batch_size);
  std::shared_ptr<const Batch> whole;
  torch::Tensor node_labels, train_idx;
  if (data.node_level) {
    whole = std::make_shared<const Batch>(collate(data.graphs, {0}));
    node_labels = torch::tensor(data.node_labels, torch::kLong);
    train_idx = torch::tensor(std::vector<std::int64_t>(split.train.begin(), split.train.end()),
                              torch::kLong);
  }
  const EvalSet val(data, split.val, bs, whole), test(data, split.test, bs, whole);

  std::mt19937_64 shuffle(static_cast<std::uint64_t>(seed) * 1000003u + 42u);
  std::vector<std::size_t> order = split.train;
  double best = -1;
  int best_epoch = 0, wait = 0, epoch = 0;
  bool stop = false;
  nn::StateSnapshot best_state;  // parameters and buffers (BatchNorm's running statistics)
  std::unique_ptr<ProgressBar> bar;
  if (options.progress)
    bar = std::make_unique<ProgressBar>(
        backbone.name() + " " + dataset + " split " + std::to_string(seed), max_epochs, "epoch");
  for (epoch = 1; epoch <= max_epochs; ++epoch) {
    // StepLR(step_size 50, gamma 0.5), stepped once per epoch.
    const double lr = cfg.lr * std::pow(0.5, (epoch - 1) / 50);
    for (auto& group : opt.param_groups())
      static_cast<torch::optim::AdamOptions&>(group.options()).lr(lr);
    net->train();
    double loss_sum = 0;
    std::int64_t steps = 0;
    const auto step = [&](const torch::Tensor& logits, const torch::Tensor& labels) {
      const auto loss = torch::nn::functional::cross_entropy(logits, labels);
      opt.zero_grad();
      loss.backward();
      opt.step();
      loss_sum += loss.item<double>(), ++steps;
    };
    if (data.node_level) {
      step(net->forward(*whole).index_select(0, train_idx), node_labels.index_select(0, train_idx));
    } else {
      std::shuffle(order.begin(), order.end(), shuffle);
      for (const auto& which : batches_of(order, bs)) {
        const auto b = collate(data.graphs, which);
        step(net->forward(b), b.labels);
      }
    }
    if (epoch % cfg.val_every == 0) {
      const double v = val.accuracy(*net);
      run.curve.push_back({epoch, loss_sum / std::max<std::int64_t>(steps, 1), v});
      if (v > best) {  // strictly better (Lightning's ModelCheckpoint and EarlyStopping)
        best = v, best_epoch = epoch, wait = 0;
        best_state = nn::StateSnapshot(*net);
      } else if (++wait >= cfg.patience) {
        stop = true;
      }
      if (options.on_check) options.on_check(run.curve.back(), *net);
    }
    if (bar) {
      std::ostringstream status;
      status << std::fixed << std::setprecision(3) << "best val " << std::max(best, 0.0) << " at "
             << best_epoch;
      bar->update(1, status.str());
    }
    if (stop && epoch >= min_epochs) break;
  }
  if (!best_state.empty()) best_state.restore(*net);
  RunResult& r = run.result;
  r.model = backbone.name(), r.dataset = dataset, r.split_seed = seed;
  r.test_accuracy = test.accuracy(*net);
  r.best_epoch = best_epoch, r.epochs = std::min(epoch, max_epochs);
  r.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  run.best_val_accuracy = std::max(best, 0.0);
  run.model = net;
  return run;
}

}  // namespace topos::models::topobench
