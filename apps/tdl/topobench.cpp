// tdl topobench: TopoBench's table on topos, from the raw dataset files to the numbers, over the
// library's pipeline. For every (model, dataset, split) asked for: the dataset read and lifted to
// the model's domain and trained as TopoBench's trainer does with its hyperparameters for that
// pair (reproduce-hparams.txt; topos/models/topobench/trainer.hpp, the table's backbones from
// table_models.hpp), tested at the best validation check. Finished runs go to OUT/runs.csv at
// once (topobench/report.hpp: rewritten atomically); a runner started again on the same OUT skips
// them, so a table is completed over several sittings. OUT/summary.csv and OUT/index.html (the
// table, the learning curves, the time per cell) are rewritten after every run. This file picks
// the jobs and the cells too large to run; the library runs them side by side
// (topobench::run_table) with the majority baselines.
#include "commands.hpp"

#include "topos/data/graph_datasets.hpp"
#include "topos/io/atomic_file.hpp"
#include "topos/models/topobench/protocol.hpp"
#include "topos/models/topobench/report.hpp"
#include "topos/models/topobench/table_models.hpp"
#include "topos/models/topobench/trainer.hpp"
#include "topos/nn/cpu.hpp"
#include "topos/nn/kernels/dense_bf16.hpp"
#include "topos/nn/kernels/precision.hpp"

#include <torch/torch.h>

#include <algorithm>
#include <cctype>
#include <deque>
#include <chrono>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <iostream>
#include <memory>
#include <numeric>
#include <random>
#include <limits>
#include <map>
#include <set>
#include <sstream>
#include <tuple>

namespace tdl_cli {

namespace topobench = topos::models::topobench;
namespace fs = std::filesystem;

namespace {

struct TopoBenchOptions {
  std::string data_dir, out, hparams;
  std::vector<std::string> models, datasets;
  std::vector<std::int64_t> splits;  ///< empty: the seeds of the hparams line
  int jobs = 1;
  int threads = 1;     ///< LibTorch intra-op threads per run
  int max_epochs = 0;  ///< > 0: at most this many epochs (quick checks; not the protocol)
  /// Σ_v deg(v)² over a dataset above which its rank-1 pair operators are kept as factors.
  std::int64_t factor_above = 100'000'000;
  bool keep_denormals = false;  ///< IEEE denormals kept (slower; topobench::TrainOptions)
  std::string matmul_precision = "highest";  ///< nn::MatmulPrecision of the runs' products
};

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

  topobench::RunsFolder folder(out, topobench::table_model_names());  // an earlier start's, checked
  // A folder holds runs of one precision: OUT/matmul_precision says which when it is not float32
  // (a folder without it, TopoBench's float32), so a resume cannot mix the two in one table. A
  // folder without runs takes any.
  const auto precision_path = out / "matmul_precision";
  std::string folder_precision = o.matmul_precision;
  if (!folder.runs().empty()) {
    folder_precision =
        fs::exists(precision_path) ? topos::data::read_text_file(precision_path) : "highest";
    while (!folder_precision.empty() &&
           std::isspace(static_cast<unsigned char>(folder_precision.back())))
      folder_precision.pop_back();
  }
  if (folder_precision != o.matmul_precision)
    throw std::invalid_argument(out.string() + " holds runs at --matmul-precision " +
                                folder_precision + ", not " + o.matmul_precision +
                                ": give another --out, or --matmul-precision " + folder_precision +
                                " to add to it");
  if (o.matmul_precision != "highest" && !topos::nn::detail::cpu_has_bf16())
    throw std::invalid_argument(
        "--matmul-precision " + o.matmul_precision +
        ": this CPU has no AVX-512 BF16, so the backbones' own products (their weights and sparse "
        "weights) would stay float32; use --matmul-precision highest");

  std::vector<topobench::TableJob> jobs;
  std::size_t skipped = 0;
  // Cells that cannot run here, with the measured reason (not_run.csv; the table shows them).
  topobench::NotRun not_run;
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
      if (const auto rank1 = topobench::rank1_pair_operators(topobench::rank_layout(*m));
          !rank1.empty()) {
        if (!pairs.count(d->name)) pairs[d->name] = shared_node_pairs(root, *d);
        if (pairs[d->name] > o.factor_above) {
          const auto can = topobench::factorable_operators(
              m->domain, m->domain == topobench::Domain::simplicial && cfg.signed_incidence);
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
        if (folder.done(m->name, d->name, s))
          ++skipped;
        else
          jobs.push_back({m, d, &cfg, s, factored});
      }
    }
  std::cerr << "tdl topobench: " << jobs.size() << " runs to do, " << skipped << " already in "
            << (out / "runs.csv").string() << "\n";
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
  topos::io::write_file_atomic((out / "not_run.csv").string(), not_run_csv());

  // Threads: one intra-op thread and one BLAS thread per run by default; `--jobs` runs side by
  // side are the parallelism. TopoBench's batches are small: with two OpenMP threads per run, 83 %
  // of a MUTAG run's time went to libgomp's spin-waits on a busy two-core machine. `--threads`
  // suits one large run alone (REDDIT-BINARY's batches of 110 k cells).
  if (o.jobs * o.threads > topos::nn::available_cores())
    std::cerr << "tdl topobench: warning: --jobs " << o.jobs << " × --threads " << o.threads
              << " is more threads than this machine's " << topos::nn::available_cores()
              << " cores; each run will wait on the others\n";
  topos::nn::set_cpu_threads(o.threads, 1);
  topos::nn::set_float32_matmul_precision(
      topos::nn::matmul_precision_from_string(o.matmul_precision));
  // Freed memory kept in the heap: glibc hands every block over 32 MB back to the kernel, and an
  // IMDB batch's rank-3 cochains (200k tetrahedra × 128 channels) were faulted in afresh at every
  // operation (docs/benchmarks.md: BM_epoch_options).
  topos::nn::keep_freed_memory();

  // Marked once nothing is left to refuse the start.
  if (o.matmul_precision != "highest")
    topos::io::write_file_atomic(precision_path.string(), o.matmul_precision);
  else if (fs::exists(precision_path))
    fs::remove(precision_path);  // a folder without runs, taken at float32

  topobench::TableRunOptions run;
  run.jobs = o.jobs;
  run.max_epochs = o.max_epochs;
  run.flush_denormals = !o.keep_denormals;
  run.backbone = [](const topobench::ModelSpec& m) { return topobench::table_backbone(m.name); };
  run.on_not_run = [&](const topobench::NotRun&) {
    topos::io::write_file_atomic((out / "not_run.csv").string(), not_run_csv());
  };
  const auto failed_cells = topobench::run_table(root, jobs, folder, not_run, run);
  if (!failed_cells.empty()) {
    std::cerr << "tdl topobench: " << failed_cells.size() << " cell(s) failed; see not_run.csv:";
    for (const auto& [m, d] : failed_cells) std::cerr << " " << m << "/" << d;
    std::cerr << "\n";
  }
  if (!folder.runs().empty()) folder.write_reports(not_run);
  std::cout << topobench::format_summary(topobench::summarize(folder.runs()));
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
  std::string model_names;  // the table's registry (table_models.hpp)
  for (const auto& m : topobench::table_model_names())
    model_names += (model_names.empty() ? "" : ", ") + m;
  cmd->add_option("--models", *models, "comma-separated: " + model_names)->required();
  cmd->add_option("--datasets", *datasets,
                  "comma-separated: MUTAG, PROTEINS, NCI1, NCI109, "
                  "IMDB-BINARY, IMDB-MULTI, REDDIT-BINARY, Cora, Citeseer")
      ->required();
  cmd->add_option("--splits", *splits, "data seeds (default: the hparams line's, 0,3,5,7,9)");
  cmd->add_option("--jobs", o->jobs, "runs side by side (threads shared out, no oversubscription)")
      ->check(CLI::Range(1, 64))
      ->capture_default_str();
  cmd->add_option("--threads", o->threads,
                  "LibTorch intra-op threads per run (1 unless one large run has the machine)")
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
  cmd->add_option("--matmul-precision", o->matmul_precision,
                  "highest: float32 products, as TopoBench; medium: bfloat16 inputs with float32 "
                  "sums (faster where the CPU has AVX-512 BF16; recorded in OUT/matmul_precision)")
      ->check(CLI::IsMember({"highest", "medium"}))
      ->capture_default_str();
  cmd->add_flag("--keep-denormals", o->keep_denormals,
                "keep denormal floats (by default they are flushed to zero while a run trains: "
                "the same results but below 1.2e-38, and SCCNN about 2x faster)");
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
