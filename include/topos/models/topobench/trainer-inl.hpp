// topos/models/topobench/trainer-inl.hpp
// The trainer's implementation (topos/models/topobench/trainer.hpp declares it), compiled once
// into topos::topobench (src/topobench.cpp), or inline with TOPOS_HEADER_ONLY (topos/config.hpp).
#pragma once

#include "topos/data/graph_datasets.hpp"
#include "topos/models/topobench/trainer.hpp"
#include "topos/nn/cloneable.hpp"   // StateSnapshot
#include "topos/nn/cpu.hpp"         // ScopedFlushDenormals
#include "topos/nn/functional.hpp"  // ScopedDropoutStream
#include "topos/util/progress.hpp"

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <exception>
#include <iomanip>
#include <iostream>
#include <limits>
#include <map>
#include <mutex>
#include <random>
#include <sstream>
#include <thread>

namespace topos::models::topobench {

TOPOS_INLINE LiftedDataset lift_dataset(const std::filesystem::path& root, const DatasetName& d,
                                        const RankLayout& layout, const RunConfig& cfg,
                                        bool factored, bool progress) {
  const auto start = std::chrono::steady_clock::now();
  const Domain domain = layout.domain;
  GraphLiftingOptions lo;
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

TOPOS_INLINE double majority_accuracy(const LiftedDataset& data, std::int64_t seed) {
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

TOPOS_INLINE EvalSet::EvalSet(const LiftedDataset& data, const std::vector<std::size_t>& part,
                              std::size_t batch_size, std::shared_ptr<const Batch> whole)
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

TOPOS_INLINE double EvalSet::accuracy(TopoBenchModelImpl& net) const {
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

TOPOS_INLINE TrainedRun train_run(const LiftedDataset& data, const Backbone& backbone,
                                  const std::string& dataset, const RunConfig& cfg,
                                  std::int64_t seed, const TrainOptions& options) {
  const auto start = std::chrono::steady_clock::now();
  const nn::ScopedFlushDenormals flush(options.flush_denormals);
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
  // torch's generator is one per process. So that runs on several threads (run_table's jobs)
  // draw what they would draw alone, a run seeds it and builds its model under one lock, takes
  // one more draw to start its own dropout stream, and draws nothing from it afterwards.
  static std::mutex torch_generator;
  std::unique_lock<std::mutex> seeding(torch_generator);
  torch::manual_seed(42);  // TopoBench seeds every run with 42
  TrainedRun run;
  TopoBenchModel net(TopoBenchModelOptions(backbone, g0.widths, cfg.hidden, data.num_classes)
                         .n_layers(static_cast<int>(cfg.layers))
                         .dropout(cfg.dropout)
                         .propagate_signal_down(cfg.readout == "PropagateSignalDown")
                         .graph_level(!data.node_level));
  const nn::ScopedDropoutStream dropout_stream(static_cast<std::uint64_t>(
      torch::randint(std::numeric_limits<std::int64_t>::max(), {1}, torch::kLong)
          .item<std::int64_t>()));
  seeding.unlock();
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

  // The training graphs' operators in CSR form once: each epoch's shuffled batches are then
  // concatenations of them (Collator), not sorted and transposed anew.
  std::unique_ptr<const Collator> train_batches;
  if (!data.node_level) train_batches = std::make_unique<const Collator>(data.graphs, split.train);
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
        const auto b = (*train_batches)(which);
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

TOPOS_INLINE std::set<std::pair<std::string, std::string>> run_table(
    const std::filesystem::path& root, const std::vector<TableJob>& jobs, RunsFolder& folder,
    NotRun& not_run, const TableRunOptions& options) {
  if (!options.backbone) throw std::invalid_argument("run_table: no TableRunOptions::backbone");
  for (const auto& j : jobs)
    if (!j.model || !j.dataset || !j.cfg)
      throw std::invalid_argument("run_table: a job without its model, dataset or config");
  const int workers = std::max(1, std::min<int>(options.jobs, static_cast<int>(jobs.size())));
  std::set<std::pair<std::string, std::string>> failed_cells;
  std::mutex mutex;  // guards the lifted cache, the folder, not_run and the bar
  // Each dataset is lifted once per domain, settings and operators, and kept while runs need it.
  const auto lifting_key = [](const TableJob& j) {
    std::string ops;
    for (const auto& op : j.model->operators) ops += (ops.empty() ? "" : ",") + op;
    return std::string(j.dataset->name) + "/" + domain_name(j.model->domain) + "/" +
           (j.cfg->signed_incidence ? "signed" : "unsigned") + "/" +
           std::to_string(j.cfg->max_cell_length) + "/" + ops + (j.factored ? "/factored" : "");
  };
  std::map<std::string, std::shared_ptr<const LiftedDataset>> lifted;
  std::map<std::string, std::shared_ptr<std::mutex>> lifting;
  std::map<std::string, std::size_t> remaining;  // runs not yet started, per lifting
  for (const auto& j : jobs) ++remaining[lifting_key(j)];
  const auto get_lifted = [&](const TableJob& j) {
    const std::string key = lifting_key(j);
    std::shared_ptr<std::mutex> m;
    {
      std::lock_guard<std::mutex> lock(mutex);
      --remaining[key];
      for (auto it = lifted.begin(); it != lifted.end();)  // running runs hold their own
        it = remaining[it->first] == 0 && it->first != key ? lifted.erase(it) : std::next(it);
      if (auto it = lifted.find(key); it != lifted.end()) return it->second;
      auto& slot = lifting[key];
      if (!slot) slot = std::make_shared<std::mutex>();
      m = slot;
    }
    std::lock_guard<std::mutex> one(*m);  // one thread lifts, the others wait for it
    {
      std::lock_guard<std::mutex> lock(mutex);
      if (auto it = lifted.find(key); it != lifted.end()) return it->second;
    }
    auto d = std::make_shared<const LiftedDataset>(
        options.lift ? options.lift(j)
                     : lift_dataset(root, *j.dataset, rank_layout(*j.model), *j.cfg, j.factored));
    std::lock_guard<std::mutex> lock(mutex);
    std::cerr << "lifted " << key << " in " << std::fixed << std::setprecision(2) << d->seconds
              << " s\n";
    lifted[key] = d;
    return std::shared_ptr<const LiftedDataset>(d);
  };

  ProgressBar bar("topobench", static_cast<std::int64_t>(jobs.size()), "run");
  std::atomic<std::size_t> next{0};
  std::exception_ptr failure;
  const auto worker = [&] {
    for (;;) {
      const std::size_t k = next++;
      if (k >= jobs.size()) return;
      const TableJob& j = jobs[k];
      {
        std::lock_guard<std::mutex> lock(mutex);
        if (failed_cells.count({j.model->name, j.dataset->name})) {  // its cell failed already
          bar.update(1);
          continue;
        }
      }
      try {
        const auto data = get_lifted(j);
        TrainOptions train;
        train.max_epochs = options.max_epochs;
        train.flush_denormals = options.flush_denormals;
        train.progress = workers == 1;
        const auto run =
            train_run(*data, options.backbone(*j.model), j.dataset->name, *j.cfg, j.seed, train);
        const auto& r = run.result;
        const double majority = majority_accuracy(*data, j.seed);
        std::lock_guard<std::mutex> lock(mutex);
        folder.add_baseline(j.dataset->name, j.seed, majority);
        folder.add(r, run.curve, not_run);
        std::ostringstream status;
        status << r.model << " " << r.dataset << " split " << r.split_seed << ": " << std::fixed
               << std::setprecision(1) << 100 * r.test_accuracy << "% (" << r.epochs << " epochs, "
               << std::setprecision(0) << r.seconds << " s)";
        bar.update(1, status.str());
      } catch (const std::exception& e) {
        // A run that fails (e.g. out of memory) marks its cell not run, with the error, and the
        // table goes on.
        std::lock_guard<std::mutex> lock(mutex);
        failed_cells.insert({j.model->name, j.dataset->name});
        std::string what = e.what();  // LibTorch's errors carry a backtrace after the first line
        what = what.substr(0, what.find('\n'));
        not_run.push_back({j.model->name, j.dataset->name,
                           "split " + std::to_string(j.seed) + " failed: " + what});
        if (options.on_not_run) options.on_not_run(not_run);
        std::cerr << "\nfailed: " << j.model->name << " on " << j.dataset->name << " split "
                  << j.seed << ": " << what << "\n";
        bar.update(1);
      } catch (...) {
        std::lock_guard<std::mutex> lock(mutex);
        if (!failure) failure = std::current_exception();
        next = jobs.size();  // stop handing out work; finished runs are saved
        return;
      }
    }
  };
  std::vector<std::thread> threads;
  for (int w = 1; w < workers; ++w) threads.emplace_back(worker);
  worker();
  for (auto& t : threads) t.join();
  bar.finish();
  if (failure) std::rethrow_exception(failure);
  return failed_cells;
}

}  // namespace topos::models::topobench
