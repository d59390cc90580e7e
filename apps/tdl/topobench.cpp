// tdl topobench: TopoBench's table on topos, from the raw dataset files to the numbers. For every
// (model, dataset, split) asked for: the dataset read (topos/data/graph_datasets.hpp), lifted
// to the model's domain (topos/models/topobench/lifting.hpp), split as TopoBench splits it,
// trained with TopoBench's hyperparameters for that pair (reproduce-hparams.txt), Adam with a
// step schedule, validation and early stopping as its trainer does, and tested at the best
// validation check. Finished runs go to OUT/runs.csv at once (rewritten atomically); a runner
// started again on the same OUT skips them, so a table is completed over several sittings.
// OUT/summary.csv and OUT/index.html (the table, the learning curves, the time per cell) are
// rewritten after every run.
#include "commands.hpp"

#include "topos/data/graph_datasets.hpp"
#include "topos/io/atomic_file.hpp"
#include "topos/models/topobench/model.hpp"
#include "topos/models/topobench/protocol.hpp"
#include "topos/nn/cloneable.hpp"
#include "topos/nn/cpu.hpp"
#include "topos/util/progress.hpp"
#include "svg_plot.hpp"

#include <torch/torch.h>

#include <algorithm>
#include <deque>
#include <atomic>
#include <chrono>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <iostream>
#include <memory>
#include <mutex>
#include <numeric>
#include <random>
#include <limits>
#include <map>
#include <set>
#include <sstream>
#include <thread>
#include <tuple>

namespace tdl_cli {

namespace tb = topos::models::topobench;
namespace topobench = topos::models::topobench;
namespace fs = std::filesystem;

namespace {

struct TopoBenchOptions {
  std::string data_dir, out, hparams;
  std::vector<std::string> models, datasets;
  std::vector<std::int64_t> splits;  ///< empty: the seeds of the hparams line
  int jobs = 1;
  int max_epochs = 0;  ///< > 0: at most this many epochs (quick checks; not the protocol)
  /// Σ_v deg(v)² over a dataset above which its rank-1 pair operators are kept as factors.
  std::int64_t factor_above = 100'000'000;
};

/// A dataset lifted for one domain: its graphs (one for a node-level set) and classes.
struct LiftedDataset {
  std::vector<tb::LiftedGraph> graphs;
  std::vector<std::int64_t> node_labels;  ///< node-level sets: every node's class
  std::int64_t num_classes = 0;
  bool node_level = false;
  double seconds = 0;
};

/// The operators of `model` that pair edges through a shared node (Σ_v deg(v)² entries).
std::set<std::string> rank1_pair_operators(const topobench::ModelSpec& model) {
  std::set<std::string> out;
  for (const auto& op : model.operators)
    if (op == "down_laplacian_1" || op == "down_laplacian_1_gcn" || op == "hodge_laplacian_1" ||
        op == "hodge_laplacian_1_norm")
      out.insert(op);
  return out;
}

/// `factored`: keep the model's rank-1 pair operators as factors (tb::LiftingOptions::factored).
LiftedDataset lift_dataset(const fs::path& root, const topobench::DatasetName& d,
                           const topobench::ModelSpec& model, const topobench::RunConfig& cfg,
                           bool factored) {
  const auto start = std::chrono::steady_clock::now();
  const tb::Domain domain = model.domain;
  tb::LiftingOptions lo;
  lo.operators = model.operators;
  lo.signed_incidence = domain == tb::Domain::simplicial ? cfg.signed_incidence : false;
  if (factored) lo.factored = rank1_pair_operators(model);
  if (cfg.max_cell_length > 0) lo.max_cell_length = cfg.max_cell_length;
  LiftedDataset out;
  out.node_level = d.node_level;
  if (d.node_level) {
    const auto ds = topos::data::load_topobench_node_dataset(root, d.name);
    out.num_classes = ds.num_classes;
    out.node_labels = ds.labels;
    out.graphs.push_back(
        tb::lift_graph(ds.num_nodes, ds.edges, ds.x, ds.num_node_features, {}, domain, lo));
  } else {
    const auto ds = topos::data::load_topobench_graph_dataset(root, d.name);
    out.num_classes = ds.num_classes;
    // TopoBench keeps MUTAG's bond types as the edges' features when it lifts to cells or
    // simplices (preserve_edge_attr_if_lifted); elsewhere x_1 is the projection of x_0.
    if (std::string(d.name) == "MUTAG" &&
        (domain == tb::Domain::cell || domain == tb::Domain::simplicial)) {
      lo.edge_features = true;
      for (const auto& g : ds.graphs)
        for (auto l : g.edge_labels) lo.num_edge_labels = std::max(lo.num_edge_labels, l + 1);
    }
    topos::ProgressBar bar(std::string("lift ") + d.name + " (" + tb::domain_name(domain) + ")",
                           static_cast<std::int64_t>(ds.graphs.size()), "graph");
    for (const auto& g : ds.graphs) {
      out.graphs.push_back(tb::lift_graph(g.num_nodes, g.edges, g.x, ds.num_node_features,
                                          g.edge_labels, domain, lo));
      out.graphs.back().label = g.label;
      bar.update(1);
    }
    bar.finish();
  }
  out.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return out;
}

/// The majority classifier's test accuracy: the most frequent class of the training split (the
/// lowest on a tie) predicted for every test graph or node. A trained model must beat it.
double majority_accuracy(const LiftedDataset& data, std::int64_t seed) {
  const auto label = [&](std::size_t i) {
    return data.node_level ? data.node_labels[i] : data.graphs[i].label;
  };
  const std::int64_t n = data.node_level ? static_cast<std::int64_t>(data.node_labels.size())
                                         : static_cast<std::int64_t>(data.graphs.size());
  const auto split = topobench::random_split(n, seed);
  std::vector<std::int64_t> count(static_cast<std::size_t>(data.num_classes), 0);
  for (auto i : split.train) ++count[static_cast<std::size_t>(label(i))];
  const auto majority = std::max_element(count.begin(), count.end()) - count.begin();
  std::int64_t hits = 0;
  for (auto i : split.test) hits += label(i) == majority;
  return split.test.empty() ? 0
                            : static_cast<double>(hits) / static_cast<double>(split.test.size());
}

/// One validation check of a run: its epoch, the mean training loss and the validation accuracy.
struct Check {
  int epoch;
  double loss, val_accuracy;
};

double accuracy(const torch::Tensor& logits, const torch::Tensor& labels) {
  if (labels.numel() == 0) return 0;
  return logits.argmax(1).eq(labels).to(torch::kDouble).mean().item<double>();
}

/// Trains one (model, dataset, split) as TopoBench's trainer does and returns its result.
topobench::RunResult train_run(const LiftedDataset& data, const topobench::ModelSpec& model,
                               const topobench::DatasetName& dataset,
                               const topobench::RunConfig& cfg, std::int64_t seed,
                               int max_epochs_cap, std::vector<Check>& curve, bool progress) {
  const auto start = std::chrono::steady_clock::now();
  torch::manual_seed(42);  // TopoBench seeds every run with 42
  const auto& g0 = data.graphs.front();
  tb::TopoBenchModel net(
      tb::TopoBenchModelOptions(model.name, g0.widths, cfg.hidden, data.num_classes)
          .n_layers(static_cast<int>(cfg.layers))
          .dropout(cfg.dropout)
          .propagate_signal_down(cfg.readout == "PropagateSignalDown")
          .graph_level(!data.node_level));
  torch::optim::Adam opt(net->parameters(), torch::optim::AdamOptions(cfg.lr));
  const int max_epochs =
      max_epochs_cap > 0 ? std::min(cfg.max_epochs, max_epochs_cap) : cfg.max_epochs;
  const int min_epochs = std::min(cfg.min_epochs, max_epochs);

  const std::int64_t n = data.node_level ? static_cast<std::int64_t>(data.node_labels.size())
                                         : static_cast<std::int64_t>(data.graphs.size());
  const topobench::Split split = topobench::random_split(n, seed);
  const auto index_tensor = [](const std::vector<std::size_t>& v) {
    std::vector<std::int64_t> w(v.begin(), v.end());
    return torch::tensor(w, torch::kLong);
  };
  // Validation and test graphs go in batches of the training batch size, in the split's order,
  // as TopoBench's loaders give them: CCXN's TopoModelX-compatible attention scores 2-cell i of a
  // batch with edge i of the same batch, so its predictions depend on the batching (the other
  // models' do not). The batches are collated once.
  tb::Batch whole;
  std::vector<tb::Batch> val_batches, test_batches;
  torch::Tensor node_labels, train_idx, val_idx, test_idx;
  if (data.node_level) {
    whole = tb::collate(data.graphs, {0});
    node_labels = torch::tensor(data.node_labels, torch::kLong);
    train_idx = index_tensor(split.train), val_idx = index_tensor(split.val),
    test_idx = index_tensor(split.test);
  } else {
    const auto bs = static_cast<std::size_t>(cfg.batch_size);
    for (const auto& which : tb::batches_of(split.val, bs))
      val_batches.push_back(tb::collate(data.graphs, which));
    for (const auto& which : tb::batches_of(split.test, bs))
      test_batches.push_back(tb::collate(data.graphs, which));
  }
  const auto evaluate = [&](bool test) {
    torch::NoGradGuard no_grad;
    net->eval();
    if (data.node_level) {
      const auto& idx = test ? test_idx : val_idx;
      return accuracy(net->forward(whole).index_select(0, idx), node_labels.index_select(0, idx));
    }
    std::int64_t correct = 0, total = 0;
    for (const auto& b : test ? test_batches : val_batches) {
      correct += net->forward(b).argmax(1).eq(b.labels).sum().item<std::int64_t>();
      total += b.num_graphs;
    }
    return total ? static_cast<double>(correct) / static_cast<double>(total) : 0.0;
  };

  std::mt19937_64 shuffle(static_cast<std::uint64_t>(seed) * 1000003u + 42u);
  std::vector<std::size_t> order = split.train;
  double best = -1;
  int best_epoch = 0, wait = 0, epoch = 0;
  bool stop = false;
  topos::nn::StateSnapshot best_state;  // parameters and buffers (BatchNorm's running statistics)
  // A bar per run when runs go one at a time (side by side, the table's bar alone).
  std::unique_ptr<topos::ProgressBar> bar;
  if (progress)
    bar = std::make_unique<topos::ProgressBar>(
        std::string(model.name) + " " + dataset.name + " split " + std::to_string(seed), max_epochs,
        "epoch");
  for (epoch = 1; epoch <= max_epochs; ++epoch) {
    // StepLR(step_size 50, gamma 0.5), stepped once per epoch.
    const double lr = cfg.lr * std::pow(0.5, (epoch - 1) / 50);
    for (auto& group : opt.param_groups())
      static_cast<torch::optim::AdamOptions&>(group.options()).lr(lr);
    net->train();
    double loss_sum = 0;
    std::int64_t steps = 0;
    if (data.node_level) {
      const auto logits = net->forward(whole).index_select(0, train_idx);
      const auto loss =
          torch::nn::functional::cross_entropy(logits, node_labels.index_select(0, train_idx));
      opt.zero_grad();
      loss.backward();
      opt.step();
      loss_sum += loss.item<double>(), ++steps;
    } else {
      std::shuffle(order.begin(), order.end(), shuffle);
      const auto bs = static_cast<std::size_t>(cfg.batch_size);
      for (const auto& which : tb::batches_of(order, bs)) {
        const auto b = tb::collate(data.graphs, which);
        const auto loss = torch::nn::functional::cross_entropy(net->forward(b), b.labels);
        opt.zero_grad();
        loss.backward();
        opt.step();
        loss_sum += loss.item<double>(), ++steps;
      }
    }
    if (epoch % cfg.val_every == 0) {
      const double v = evaluate(false);
      curve.push_back({epoch, loss_sum / std::max<std::int64_t>(steps, 1), v});
      if (v > best) {  // strictly better (Lightning's ModelCheckpoint and EarlyStopping)
        best = v, best_epoch = epoch, wait = 0;
        best_state = topos::nn::StateSnapshot(*net);
      } else if (++wait >= cfg.patience) {
        stop = true;
      }
    }
    if (bar) {
      std::ostringstream status;
      status << std::fixed << std::setprecision(3) << "best val " << std::max(best, 0.0) << " at "
             << best_epoch;
      bar->update(1, status.str());
    }
    if (stop && epoch >= min_epochs) break;
  }
  const int epochs = std::min(epoch, max_epochs);
  if (!best_state.empty()) best_state.restore(*net);
  topobench::RunResult r;
  r.model = model.name, r.dataset = dataset.name, r.split_seed = seed;
  r.test_accuracy = evaluate(true);
  r.best_epoch = best_epoch, r.epochs = epochs;
  r.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return r;
}

// Every run's validation curve, one file: model,dataset,split_seed,epoch,loss,val_accuracy.
constexpr const char* kCurvesHeader = "model,dataset,split_seed,epoch,loss,val_accuracy\n";

// Per (model, dataset, split seed): the checks' epochs and validation accuracies.
std::map<std::tuple<std::string, std::string, std::int64_t>,
         std::pair<std::vector<int>, std::vector<double>>>
read_curves(const fs::path& file) {
  std::map<std::tuple<std::string, std::string, std::int64_t>,
           std::pair<std::vector<int>, std::vector<double>>>
      out;
  std::ifstream in(file);
  std::string line;
  std::getline(in, line);  // header, checked when the runner starts
  for (int n = 2; std::getline(in, line); ++n) {
    std::istringstream f(line);
    std::string m, d, s, e, l, a;
    if (std::getline(f, m, ',') && std::getline(f, d, ',') && std::getline(f, s, ',') &&
        std::getline(f, e, ',') && std::getline(f, l, ',') && std::getline(f, a, ',')) {
      try {
        auto& c = out[{m, d, std::stoll(s)}];
        c.first.push_back(std::stoi(e));
        c.second.push_back(std::stod(a));
        continue;
      } catch (const std::exception&) {  // std::stoi's own message names no file
      }
    }
    throw std::runtime_error(file.string() + ":" + std::to_string(n) + ": malformed row '" + line +
                             "'");
  }
  return out;
}

std::string html_escape(const std::string& s) {
  std::string o;
  for (char c : s)
    o += c == '<' ? "&lt;" : c == '>' ? "&gt;" : c == '&' ? "&amp;" : std::string(1, c);
  return o;
}

/// OUT/table.md: the table in Markdown (models as rows, datasets as columns, mean ± std and the
/// number of runs where fewer than five), for docs/topobench.md.
using NotRun = std::vector<std::array<std::string, 3>>;  // model, dataset, reason

std::string table_markdown(const std::vector<topobench::RunResult>& runs, const NotRun& not_run) {
  const auto cells = topobench::summarize(runs);
  std::ostringstream o;
  o << "| model |";
  std::vector<std::string> datasets;
  for (const auto& d : topobench::table_datasets())
    if (std::any_of(cells.begin(), cells.end(),
                    [&](const auto& c) { return c.dataset == d.name; }) ||
        std::any_of(not_run.begin(), not_run.end(), [&](const auto& n) { return n[1] == d.name; }))
      datasets.push_back(d.name), o << " " << d.name << " |";
  o << "\n|---|";
  for (std::size_t i = 0; i < datasets.size(); ++i) o << "---|";
  o << "\n";
  for (const auto& m : topobench::model_specs()) {
    if (std::none_of(cells.begin(), cells.end(),
                     [&](const auto& c) { return c.model == m.name; }) &&
        std::none_of(not_run.begin(), not_run.end(), [&](const auto& n) { return n[0] == m.name; }))
      continue;
    o << "| " << m.name << " |";
    for (const auto& d : datasets) {
      const auto it = std::find_if(cells.begin(), cells.end(), [&](const auto& c) {
        return c.model == m.name && c.dataset == d;
      });
      if (it == cells.end()) {
        const auto n = std::find_if(not_run.begin(), not_run.end(),
                                    [&](const auto& x) { return x[0] == m.name && x[1] == d; });
        o << (n == not_run.end()                            ? " - |"
              : (*n)[2].find("failed") != std::string::npos ? " failed |"
                                                            : " not run (memory) |");
        continue;
      }
      o << " " << std::fixed << std::setprecision(2) << it->mean << " ± " << it->std;
      if (it->runs < 5) o << " (" << it->runs << " runs)";
      o << " |";
    }
    o << "\n";
  }
  return o.str();
}

/// OUT/index.html: the table (mean ± std over the splits, runs, time per cell) and, per cell,
/// the validation accuracy of every split against the epoch.
std::string report_html(const fs::path& out, const std::vector<topobench::RunResult>& runs,
                        const NotRun& not_run) {
  const auto cells = topobench::summarize(runs);
  std::vector<std::string> models, datasets;
  for (const auto& m : topobench::model_specs())
    if (std::any_of(cells.begin(), cells.end(), [&](const auto& c) { return c.model == m.name; }) ||
        std::any_of(not_run.begin(), not_run.end(), [&](const auto& n) { return n[0] == m.name; }))
      models.push_back(m.name);
  for (const auto& d : topobench::table_datasets())
    if (std::any_of(cells.begin(), cells.end(),
                    [&](const auto& c) { return c.dataset == d.name; }) ||
        std::any_of(not_run.begin(), not_run.end(), [&](const auto& n) { return n[1] == d.name; }))
      datasets.push_back(d.name);
  double total = 0;
  for (const auto& r : runs) total += r.seconds;
  std::ostringstream h;
  h << "<!doctype html><html><head><meta charset='utf-8'><title>TopoBench on topos</title>"
       "<style>body{font-family:sans-serif;margin:2em}table{border-collapse:collapse}"
       "td,th{border:1px solid #ccc;padding:4px 8px;text-align:center}small{color:#666}"
       "</style></head><body><h1>TopoBench on topos</h1>\n<p>Test accuracy (%), mean ± std over "
       "the splits (numpy's std); below each, the runs and their training time (summed). "
    << runs.size() << " runs, " << std::fixed << std::setprecision(1)
    << (total < 3600 ? total / 60 : total / 3600) << (total < 3600 ? " min" : " h")
    << " of training in all.</p>\n<table><tr><th>model</th>";
  for (const auto& d : datasets) h << "<th>" << d << "</th>";
  h << "</tr>\n";
  for (const auto& m : models) {
    h << "<tr><th>" << m << "</th>";
    for (const auto& d : datasets) {
      const auto it = std::find_if(cells.begin(), cells.end(),
                                   [&](const auto& c) { return c.model == m && c.dataset == d; });
      if (it == cells.end()) {
        const auto n = std::find_if(not_run.begin(), not_run.end(),
                                    [&](const auto& x) { return x[0] == m && x[1] == d; });
        if (n != not_run.end())
          h << "<td title='" << html_escape((*n)[2]) << "'>not run<br><small>"
            << ((*n)[2].find("failed") != std::string::npos ? "failed" : "memory")
            << "</small></td>";
        else
          h << "<td>-</td>";
        continue;
      }
      h << "<td><a href='#" << m << "_" << d << "'>" << std::setprecision(2) << it->mean << " ± "
        << it->std << "</a><br><small>" << it->runs << " runs, " << std::setprecision(0)
        << it->seconds << " s</small></td>";
    }
    h << "</tr>\n";
  }
  h << "</table>\n<h2>Validation accuracy per split</h2>\n";
  const auto curves = read_curves(out / "curves.csv");
  for (const auto& c : cells) {
    std::vector<std::pair<std::string, std::vector<double>>> series;
    int every = 1;
    for (const auto& r : runs) {
      if (r.model != c.model || r.dataset != c.dataset) continue;
      const auto it = curves.find({r.model, r.dataset, r.split_seed});
      if (it == curves.end()) continue;  // a run without its curve: none to draw
      const auto& [epochs, v] = it->second;
      if (epochs.size() >= 2) every = epochs[1] - epochs[0];
      series.emplace_back("split " + std::to_string(r.split_seed), v);
    }
    topos::SvgPlotOptions plot;
    plot.xlabel = "validation check (every " + std::to_string(every) + " epochs)";
    plot.ylabel = "val accuracy";
    plot.ymax = 1;
    plot.x0 = 1;
    h << "<h3 id='" << c.model << "_" << c.dataset << "'>" << html_escape(c.model) << " on "
      << html_escape(c.dataset) << "</h3>\n"
      << topos::svg_line_plot(series, plot) << "\n";
  }
  h << "</body></html>\n";
  return h.str();
}

std::string operator_names(const topobench::ModelSpec& m) {
  std::string s;
  for (const auto& op : m.operators) s += (s.empty() ? "" : ",") + op;
  return s;
}

/// Entries of the rank-1 operators that pair edges through a shared node (the down Laplacian,
/// and the Hodge Laplacian that contains it): Σ_v deg(v)² over every graph of a dataset.
std::int64_t shared_node_pairs(const fs::path& root, const topobench::DatasetName& d) {
  std::int64_t total = 0;
  const auto count = [&](std::int64_t n, const std::vector<std::array<std::int64_t, 2>>& edges) {
    std::vector<std::int64_t> deg(static_cast<std::size_t>(n), 0);
    for (const auto& e : edges)
      ++deg[static_cast<std::size_t>(e[0])], ++deg[static_cast<std::size_t>(e[1])];
    for (auto k : deg) total += k * k;
  };
  if (d.node_level) {
    const auto ds = topos::data::load_topobench_node_dataset(root, d.name);
    count(ds.num_nodes, ds.edges);
  } else {
    for (const auto& g : topos::data::load_topobench_graph_dataset(root, d.name).graphs)
      count(g.num_nodes, g.edges);
  }
  return total;
}

int run_topobench(const TopoBenchOptions& o) {
  const fs::path root(o.data_dir), out(o.out);
  const fs::path hparams_path =
      o.hparams.empty() ? root / "topobench" / "reproduce-hparams.txt" : fs::path(o.hparams);
  const auto configs = topobench::read_hparams(hparams_path);
  std::vector<const topobench::ModelSpec*> models;
  std::vector<const topobench::DatasetName*> datasets;
  for (const auto& m : o.models) models.push_back(&topobench::model_spec(m));
  for (const auto& d : o.datasets) datasets.push_back(&topobench::dataset_name(d));
  // Every pair's hyperparameters are checked before anything runs.
  for (auto* d : datasets)
    for (auto* m : models) topobench::find_config(configs, *m, *d);

  fs::create_directories(out);
  std::string curves_csv = kCurvesHeader;
  if (std::ifstream in(out / "curves.csv"); in) {
    std::ostringstream all;
    all << in.rdbuf();
    if (all.str().rfind(kCurvesHeader, 0) != 0)
      throw std::runtime_error(
          (out / "curves.csv").string() + ": expected the header " +
          std::string(kCurvesHeader).substr(0, std::string(kCurvesHeader).size() - 1));
    curves_csv = all.str();
    read_curves(out / "curves.csv");  // a malformed row is named before anything runs
  }
  const fs::path runs_path = out / "runs.csv";
  std::vector<topobench::RunResult> runs;
  if (fs::exists(runs_path))
    runs = topobench::parse_runs(topos::data::read_text_file(runs_path), runs_path.string());
  const auto done = [&](const std::string& m, const std::string& d, std::int64_t s) {
    return std::any_of(runs.begin(), runs.end(), [&](const topobench::RunResult& r) {
      return r.model == m && r.dataset == d && r.split_seed == s;
    });
  };

  struct Job {
    const topobench::ModelSpec* model;
    const topobench::DatasetName* dataset;
    const topobench::RunConfig* cfg;
    std::int64_t seed;
    bool factored;  ///< rank-1 pair operators kept as factors
  };
  std::vector<Job> jobs;
  std::size_t skipped = 0;
  // Cells that cannot run here, with the measured reason (not_run.csv; the table shows them).
  std::vector<std::array<std::string, 3>> not_run;
  // Cells an earlier start found not runnable stay listed unless this start evaluates them again.
  if (const auto path = out / "not_run.csv"; fs::exists(path)) {
    std::istringstream in(topos::data::read_text_file(path));
    std::string line;
    for (int n = 1; std::getline(in, line); ++n) {
      if (n == 1 || line.empty()) continue;
      const auto a = line.find(','), b = line.find(',', a == std::string::npos ? a : a + 1);
      if (a == std::string::npos || b == std::string::npos || line.size() < b + 3 ||
          line[b + 1] != '"' || line.back() != '"')
        throw topos::data::DataError(path.string() + ":" + std::to_string(n) +
                                     ": expected model,dataset,\"reason\"");
      std::string reason = line.substr(b + 2, line.size() - b - 3);
      for (std::size_t at = 0; (at = reason.find("\"\"", at)) != std::string::npos; ++at)
        reason.erase(at, 1);
      const std::string m = line.substr(0, a), d = line.substr(a + 1, b - a - 1);
      const bool again =
          std::any_of(models.begin(), models.end(), [&](const auto* x) { return m == x->name; }) &&
          std::any_of(datasets.begin(), datasets.end(),
                      [&](const auto* x) { return d == x->name; });
      if (!again) not_run.push_back({m, d, reason});
    }
  }
  std::map<std::string, std::int64_t> pairs;      // per dataset, computed when a model needs it
  std::deque<topobench::RunConfig> cell_configs;  // the jobs point here (find_config may build one)
  for (auto* d : datasets)
    for (auto* m : models) {
      const auto& cfg = cell_configs.emplace_back(topobench::find_config(configs, *m, *d));
      if (o.splits.empty() && cfg.data_seeds.empty())
        throw std::invalid_argument(cfg.source +
                                    ": no dataset.split_params.data_seed (give --splits)");
      bool factored = false;
      if (const auto rank1 = rank1_pair_operators(*m); !rank1.empty()) {
        if (!pairs.count(d->name)) pairs[d->name] = shared_node_pairs(root, *d);
        if (pairs[d->name] > o.factor_above) {
          const auto can = tb::factorable_operators(
              m->domain, m->domain == tb::Domain::simplicial && cfg.signed_incidence);
          factored = std::all_of(rank1.begin(), rank1.end(),
                                 [&](const std::string& op) { return can.count(op) > 0; });
          std::ostringstream why;
          why << "its rank-1 down Laplacian (edges sharing a node) has " << pairs[d->name]
              << " entries over the dataset (sum of squared degrees), above the " << o.factor_above
              << " of --factor-above";
          if (!factored) {
            why << ", and its operators cannot be kept as factors";
            not_run.push_back({m->name, d->name, why.str()});
            std::cerr << "not run: " << m->name << " on " << d->name << ": " << why.str() << "\n";
            continue;
          }
          std::cerr << m->name << " on " << d->name << ": " << why.str()
                    << "; they are applied as products of incidences\n";
        }
      }
      for (auto s : o.splits.empty() ? cfg.data_seeds : o.splits) {
        if (done(m->name, d->name, s))
          ++skipped;
        else
          jobs.push_back({m, d, &cfg, s, factored});
      }
    }
  std::cerr << "tdl topobench: " << jobs.size() << " runs to do, " << skipped << " already in "
            << runs_path.string() << "\n";
  const auto not_run_csv = [&] {
    std::ostringstream csv;
    csv << "model,dataset,reason\n";
    for (const auto& [m, d, why] : not_run) {
      std::string quoted = why;  // CSV: double the quotes inside
      for (std::size_t at = 0; (at = quoted.find('"', at)) != std::string::npos; at += 2)
        quoted.insert(at, 1, '"');
      csv << m << "," << d << ",\"" << quoted << "\"\n";
    }
    return csv.str();
  };
  topos::write_file_atomic((out / "not_run.csv").string(), not_run_csv());
  std::set<std::pair<std::string, std::string>> failed_cells;

  // Threads: one intra-op thread and one BLAS thread per run; `--jobs` runs side by side are the
  // parallelism. TopoBench's batches are small: with two OpenMP threads per run, 83 % of a MUTAG
  // run's time went to libgomp's spin-waits on a busy two-core machine.
  const int workers = std::max(1, std::min<int>(o.jobs, static_cast<int>(jobs.size())));
  topos::nn::set_cpu_threads(1, 1);
  // Freed memory kept in the heap: glibc hands every block over 32 MB back to the kernel, and an
  // IMDB batch's rank-3 cochains (200k tetrahedra × 128 channels) were faulted in afresh at every
  // operation (docs/benchmarks.md: BM_epoch_options).
  topos::nn::keep_freed_memory();

  // The majority classifier per (dataset, split), beside the runs (baselines.csv).
  std::map<std::pair<std::string, std::int64_t>, double> baselines;
  const auto baselines_csv = [&] {
    std::ostringstream o;
    o << "dataset,split_seed,majority_test_accuracy\n" << std::fixed << std::setprecision(6);
    for (const auto& [k, v] : baselines) o << k.first << "," << k.second << "," << v << "\n";
    return o.str();
  };
  if (const auto path = out / "baselines.csv"; fs::exists(path)) {
    std::istringstream in(topos::data::read_text_file(path));
    std::string line;
    for (int n = 1; std::getline(in, line); ++n) {
      if (n == 1 || line.empty()) continue;
      std::istringstream f(line);
      std::string d, seed, v;
      std::size_t a = 0, b = 0;
      try {
        if (!std::getline(f, d, ',') || !std::getline(f, seed, ',') || !std::getline(f, v))
          throw std::invalid_argument("fields");
        baselines[{d, std::stoll(seed, &a)}] = std::stod(v, &b);
        if (a != seed.size() || b != v.size()) throw std::invalid_argument("trailing");
      } catch (const std::exception&) {
        throw topos::data::DataError(path.string() + ":" + std::to_string(n) +
                                     ": expected dataset,split_seed,majority_test_accuracy");
      }
    }
  }

  std::mutex mutex;  // guards runs, the lifted cache, the files and the bar
  // Each dataset is lifted once per domain and kept while runs that need it remain.
  const auto lifting_key = [](const Job& j) {
    return std::string(j.dataset->name) + "/" + tb::domain_name(j.model->domain) + "/" +
           (j.cfg->signed_incidence ? "signed" : "unsigned") + "/" +
           std::to_string(j.cfg->max_cell_length) + "/" + operator_names(*j.model) +
           (j.factored ? "/factored" : "");
  };
  std::map<std::string, std::shared_ptr<const LiftedDataset>> lifted;
  std::map<std::string, std::shared_ptr<std::mutex>> lifting;
  std::map<std::string, std::size_t> remaining;  // runs not yet started, per lifting
  for (const auto& j : jobs) ++remaining[lifting_key(j)];
  const auto get_lifted = [&](const Job& j) {
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
        lift_dataset(root, *j.dataset, *j.model, *j.cfg, j.factored));
    std::lock_guard<std::mutex> lock(mutex);
    std::cerr << "lifted " << key << " in " << std::fixed << std::setprecision(2) << d->seconds
              << " s\n";
    lifted[key] = d;
    return std::shared_ptr<const LiftedDataset>(d);
  };

  topos::ProgressBar bar("topobench", static_cast<std::int64_t>(jobs.size()), "run");
  std::atomic<std::size_t> next{0};
  std::exception_ptr failure;
  const auto worker = [&] {
    for (;;) {
      const std::size_t k = next++;
      if (k >= jobs.size()) return;
      const Job& j = jobs[k];
      {
        std::lock_guard<std::mutex> lock(mutex);
        if (failed_cells.count({j.model->name, j.dataset->name})) {  // its cell failed already
          bar.update(1);
          continue;
        }
      }
      try {
        const auto data = get_lifted(j);
        std::vector<Check> curve;
        const auto r = train_run(*data, *j.model, *j.dataset, *j.cfg, j.seed, o.max_epochs, curve,
                                 workers == 1);
        std::ostringstream c;
        for (const auto& ch : curve)
          c << r.model << "," << r.dataset << "," << r.split_seed << "," << ch.epoch << ","
            << ch.loss << "," << ch.val_accuracy << "\n";
        const double majority = majority_accuracy(*data, j.seed);
        std::lock_guard<std::mutex> lock(mutex);
        baselines[{j.dataset->name, j.seed}] = majority;
        topos::write_file_atomic((out / "baselines.csv").string(), baselines_csv());
        curves_csv += c.str();
        topos::write_file_atomic((out / "curves.csv").string(), curves_csv);
        runs.push_back(r);
        topos::write_file_atomic(runs_path.string(), topobench::format_runs(runs));
        topos::write_file_atomic((out / "summary.csv").string(),
                                 topobench::format_summary(topobench::summarize(runs)));
        topos::write_file_atomic((out / "index.html").string(), report_html(out, runs, not_run));
        topos::write_file_atomic((out / "table.md").string(), table_markdown(runs, not_run));
        std::ostringstream status;
        status << r.model << " " << r.dataset << " split " << r.split_seed << ": " << std::fixed
               << std::setprecision(1) << 100 * r.test_accuracy << "% (" << r.epochs << " epochs, "
               << std::setprecision(0) << r.seconds << " s)";
        bar.update(1, status.str());
      } catch (const std::exception& e) {
        // A run that fails (e.g. out of memory) marks its cell not run, with the error, and the
        // table goes on; the runner then exits with status 1, naming the failed cells.
        std::lock_guard<std::mutex> lock(mutex);
        failed_cells.insert({j.model->name, j.dataset->name});
        std::string what = e.what();  // LibTorch's errors carry a backtrace after the first line
        what = what.substr(0, what.find('\n'));
        not_run.push_back({j.model->name, j.dataset->name,
                           "split " + std::to_string(j.seed) + " failed: " + what});
        topos::write_file_atomic((out / "not_run.csv").string(), not_run_csv());
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
  if (!failed_cells.empty()) {
    std::cerr << "tdl topobench: " << failed_cells.size() << " cell(s) failed; see not_run.csv:";
    for (const auto& [m, d] : failed_cells) std::cerr << " " << m << "/" << d;
    std::cerr << "\n";
  }
  if (!runs.empty()) {
    topos::write_file_atomic((out / "summary.csv").string(),
                             topobench::format_summary(topobench::summarize(runs)));
    topos::write_file_atomic((out / "index.html").string(), report_html(out, runs, not_run));
    topos::write_file_atomic((out / "table.md").string(), table_markdown(runs, not_run));
  }
  std::cout << topobench::format_summary(topobench::summarize(runs));
  std::cerr << "wrote " << (out / "runs.csv").string() << ", summary.csv, index.html\n";
  return failed_cells.empty() ? 0 : 1;
}

std::vector<std::string> split_list(const std::string& s) {
  std::vector<std::string> v;
  std::istringstream in(s);
  std::string x;
  while (std::getline(in, x, ','))
    if (!x.empty()) v.push_back(x);
  return v;
}

}  // namespace

void register_topobench(CLI::App& app, Run& run) {
  auto o = std::make_shared<TopoBenchOptions>();
  auto models = std::make_shared<std::string>(), datasets = std::make_shared<std::string>(),
       splits = std::make_shared<std::string>();
  auto* cmd = app.add_subcommand(
      "topobench",
      "TopoBench's table: raw datasets lifted, trained and tested with TopoBench's "
      "hyperparameters and protocol; resumable (OUT/runs.csv)");
  cmd->add_option("--data-dir", o->data_dir, "the raw datasets (../shared/datasets)")->required();
  cmd->add_option("--out", o->out, "output folder: runs.csv, summary.csv, index.html, curves.csv")
      ->required();
  cmd->add_option("--models", *models,
                  "comma-separated: GCN, AllSetTransformer, EDGNN, UniGNN2, "
                  "CWN, CCCN, CCXN, SCN, SCCN, SCCNN, GCCN (TopoTune)")
      ->required();
  cmd->add_option("--datasets", *datasets,
                  "comma-separated: MUTAG, PROTEINS, NCI1, NCI109, "
                  "IMDB-BINARY, IMDB-MULTI, REDDIT-BINARY, Cora, Citeseer")
      ->required();
  cmd->add_option("--splits", *splits, "data seeds (default: the hparams line's, 0,3,5,7,9)");
  cmd->add_option("--jobs", o->jobs, "runs side by side (threads shared out, no oversubscription)")
      ->check(CLI::Range(1, 64))
      ->capture_default_str();
  cmd->add_option("--hparams", o->hparams,
                  "TopoBench's hyperparameters (default DATA_DIR/topobench/reproduce-hparams.txt)");
  cmd->add_option("--max-epochs", o->max_epochs,
                  "cap the epochs (quick checks; the protocol's own limits when 0)")
      ->check(CLI::Range(0, 100000))
      ->capture_default_str();
  // Formed for a whole dataset as float32 triplets, 100 million entries take 2 GB per operator,
  // then as much again for a batch's CSR and its transpose.
  cmd->add_option("--factor-above", o->factor_above,
                  "keep the rank-1 Laplacians (edges sharing a node) as products of incidences "
                  "where a dataset's sum of squared degrees exceeds this (REDDIT-BINARY: 372 M)")
      ->check(CLI::Range(std::int64_t{0}, std::numeric_limits<std::int64_t>::max()))
      ->capture_default_str();
  cmd->callback([o, models, datasets, splits, &run] {
    o->models = split_list(*models);
    o->datasets = split_list(*datasets);
    for (const auto& s : split_list(*splits)) {
      std::size_t used = 0;
      long long v = 0;
      try {
        v = std::stoll(s, &used);
      } catch (const std::exception&) {
        used = 0;
      }
      if (used != s.size() || v < 0)
        throw CLI::ValidationError("--splits", "'" + s + "' is not a non-negative integer");
      o->splits.push_back(v);
    }
    run = [o] { return run_topobench(*o); };
  });
}

}  // namespace tdl_cli
