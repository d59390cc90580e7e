// topos/models/topobench/trainer.hpp
// TopoBench's trainer for any backbone (topobench/model.hpp): a dataset of the table read and
// lifted to the backbone's domain with the operators its layout names (lift_dataset), then one
// run per split as TopoBench trains (train_run): its random split, batches of the training split
// shuffled every epoch, Adam with StepLR (step 50, gamma 0.5), a validation check every
// `val_every` epochs, early stopping after `patience` checks without a strictly better
// validation accuracy (not before `min_epochs`), the best check's parameters and buffers put
// back, and the test accuracy there. topobench/report.hpp writes the runs' files; run_table runs
// many (model, dataset, split) jobs side by side into a runs folder (tdl topobench).
//   const auto data = lift_dataset(root, dataset_name("MUTAG"), mine.layout(), cfg);
//   const auto run = train_run(data, mine, "MUTAG", cfg, /*split seed*/ 0);
#pragma once

#include "topos/config.hpp"
#include "topos/models/topobench/batch.hpp"
#include "topos/models/topobench/model.hpp"
#include "topos/models/topobench/protocol.hpp"
#include "topos/models/topobench/report.hpp"

#include <torch/torch.h>

#include <filesystem>
#include <functional>
#include <memory>
#include <set>
#include <string>
#include <utility>
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
/// (GraphLiftingOptions::factored).
LiftedDataset lift_dataset(const std::filesystem::path& root, const DatasetName& d,
                           const RankLayout& layout, const RunConfig& cfg, bool factored = false,
                           bool progress = true);
/// The majority classifier's test accuracy: the most frequent class of the training split (the
/// lowest on a tie) predicted for every test graph or node. A trained model must beat it.
double majority_accuracy(const LiftedDataset& data, std::int64_t seed);
/// One part of a split (validation or test), batched once as TopoBench's loaders give it: graphs
/// in batches of the training batch size in the split's order (CCXN's TopoModelX-compatible
/// attention scores 2-cell i of a batch with edge i of the same batch, so its predictions depend
/// on the batching), or the nodes of the whole graph.
class EvalSet {
 public:
  EvalSet(const LiftedDataset& data, const std::vector<std::size_t>& part, std::size_t batch_size,
          std::shared_ptr<const Batch> whole = nullptr);

  /// The model's accuracy on this part, in eval mode without gradients (0 when it is empty).
  double accuracy(TopoBenchModelImpl& net) const;

 private:
  bool node_level_;
  std::shared_ptr<const Batch> whole_;
  torch::Tensor index_, labels_;
  std::vector<Batch> batches_;
};

struct TrainOptions {
  int max_epochs = 0;     ///< > 0: at most this many epochs (quick checks; not the protocol)
  bool progress = false;  ///< a progress bar for the run
  /// Denormal floats flushed to zero while the run trains and tests (nn::ScopedFlushDenormals):
  /// the same results but for values below 1.2e-38, and SCCNN's REDDIT-BINARY epochs about 2x
  /// shorter.
  bool flush_denormals = true;
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
TrainedRun train_run(const LiftedDataset& data, const Backbone& backbone,
                     const std::string& dataset, const RunConfig& cfg, std::int64_t seed,
                     const TrainOptions& options = {});

/// One run of a table: `model` on split `seed` of `dataset` with the hyperparameters `cfg`
/// (find_config), its rank-1 pair operators kept as factors where `factored` (lift_dataset).
struct TableJob {
  const ModelSpec* model = nullptr;
  const DatasetName* dataset = nullptr;
  const RunConfig* cfg = nullptr;
  std::int64_t seed = 0;
  bool factored = false;
};

struct TableRunOptions {
  /// Runs side by side, one thread each (the caller sets the intra-op threads: one per run where
  /// the runs fill the cores, nn::set_cpu_threads).
  int jobs = 1;
  int max_epochs = 0;           ///< TrainOptions::max_epochs
  bool flush_denormals = true;  ///< TrainOptions::flush_denormals
  /// The backbone a job's model trains (required; tdl topobench: table_backbone(model.name)).
  std::function<Backbone(const ModelSpec&)> backbone;
  /// A job's dataset, lifted (default: lift_dataset from run_table's `root` with the model's
  /// layout). Each lifting is made once and dropped when no job left needs it.
  std::function<LiftedDataset(const TableJob&)> lift;
  /// Called when a run failed and its cell joined `not_run` (tdl: not_run.csv rewritten).
  std::function<void(const NotRun&)> on_not_run;
};

/// Runs `jobs` over `options.jobs` threads: each job's dataset lifted (shared by the jobs of the
/// same lifting), its backbone trained (train_run, a progress bar per run when one thread runs),
/// the run added to `folder` (its reports written with `not_run`) and the majority baseline of its
/// split to the folder's baselines.csv; a progress bar over the jobs on stderr. A run that throws
/// a std::exception puts its cell in `not_run` with the error ("split S failed: ...") and the
/// cell's remaining jobs are skipped; anything else stops handing out jobs, lets the running ones
/// finish, and is rethrown. Returns the cells (model, dataset) that failed.
std::set<std::pair<std::string, std::string>> run_table(const std::filesystem::path& root,
                                                        const std::vector<TableJob>& jobs,
                                                        RunsFolder& folder, NotRun& not_run,
                                                        const TableRunOptions& options);
}  // namespace topos::models::topobench

#ifdef TOPOS_HEADER_ONLY
#include "topos/models/topobench/trainer-inl.hpp"
#endif
