// A backbone of one's own through TopoBench's pipeline: GIN over the nodes (x + A x through an
// MLP with BatchNorm, A the graph's normalised adjacency), written as an operator schedule, not
// one of the table's ten, trained on MUTAG as TopoBench trains its table (the library's
// encoder, wrapper, readout and classifier, TopoBench's split, Adam with StepLR, early stopping
// at the best validation check, its parameters and BatchNorm statistics restored), the runs
// written to OUT as `tdl topobench` writes them (runs.csv, curves.csv, summary.csv, index.html).
// It includes the pipeline's headers only (model.hpp, trainer.hpp, report.hpp), not the ten
// backbones.
//
//   custom_backbone --data-dir ../shared/datasets --out runs [--epochs 20] [--splits 0,3]
// With no --data-dir, the data come from TOPOS_DATASETS_DIR (skipped, with a message, if unset).
#include <torch/torch.h>

#include "topos/models/topobench/model.hpp"
#include "topos/models/topobench/report.hpp"
#include "topos/models/topobench/trainer.hpp"
#include "topos/nn/operator_schedule.hpp"

#include <cstdio>
#include <cstdlib>
#include <iostream>
#include <sstream>
#include <string>

namespace topobench = topos::models::topobench;

// The backbone, GIN (Xu et al. 2019) on the nodes as an operator schedule: layer l is
// h <- Linear(relu(BatchNorm(Linear(h + A h)))), relu between layers, A the GCN-normalised
// adjacency; x_0 at the hidden width in, x_0 out. (Any LibTorch module whose
// forward(NamedCochains, NamedOperators) returns x_r is a backbone too: Backbone::module.)
topos::nn::OperatorSchedule gin_schedule(std::int64_t hidden, int layers) {
  using namespace topos::nn::ops;
  topos::nn::OperatorSchedule s;
  s.input("x_0", 0, hidden).operator_input("gcn_adjacency", 0, 0).output("x_0", 0);
  for (int l = 0; l < layers; ++l) {
    const std::string p = "layers." + std::to_string(l) + ".";
    auto step = into(0).sum(from(0), from(0).via("gcn_adjacency"));
    step.linear(p + "lin_0", hidden)
        .batch_norm(p + "norm")
        .act(topos::nn::Activation::relu)
        .linear(p + "lin_1", hidden);
    if (l + 1 < layers) step.act(topos::nn::Activation::relu);
    s.step(std::move(step));
  }
  return s;
}

int run(int argc, char** argv) {
  std::string data_dir, out = "custom_backbone_runs", splits = "0";
  int epochs = 20;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    if (i + 1 >= argc) throw std::invalid_argument("'" + a + "' needs a value (or unknown)");
    const std::string v = argv[++i];
    if (a == "--data-dir")
      data_dir = v;
    else if (a == "--out")
      out = v;
    else if (a == "--splits")
      splits = v;
    else if (a == "--epochs") {
      std::size_t used = 0;
      try {
        epochs = std::stoi(v, &used);
      } catch (const std::exception&) {
        used = 0;
      }
      if (used != v.size() || epochs < 1 || epochs > 100000)
        throw std::invalid_argument("--epochs expects a number in [1, 100000], got '" + v + "'");
    } else
      throw std::invalid_argument("unknown option '" + a + "'");
  }
  if (data_dir.empty()) {
    const char* env = std::getenv("TOPOS_DATASETS_DIR");
    if (!env || !*env) {
      std::cout << "SKIPPED: give --data-dir or set TOPOS_DATASETS_DIR to ../shared/datasets "
                   "(the example trains on MUTAG from it)\n";
      return 0;
    }
    data_dir = env;
  }
  torch::set_num_threads(1);

  // The backbone and its rank layout: graph domain, encodes and returns rank 0, reads the
  // GCN-normalised adjacency (which the lifting then builds).
  const topobench::Backbone gin = topobench::Backbone::schedule(
      "GIN", {topobench::Domain::graph, {0}, 1, {"gcn_adjacency"}},
      [](const topobench::BackboneContext& c) { return gin_schedule(c.hidden, c.n_layers); });

  // TopoBench's settings for GCN on MUTAG (reproduce-hparams.txt), with fewer epochs and a
  // validation check after every one.
  topobench::RunConfig cfg;
  cfg.lr = 0.001, cfg.hidden = 128, cfg.layers = 3, cfg.batch_size = 32, cfg.dropout = 0.5;
  cfg.max_epochs = epochs, cfg.min_epochs = 1, cfg.val_every = 1, cfg.patience = 10;
  const auto data =
      topobench::lift_dataset(data_dir, topobench::dataset_name("MUTAG"), gin.layout(), cfg);

  topobench::RunsFolder folder(out);
  std::istringstream list(splits);
  for (std::string s; std::getline(list, s, ',');) {
    const std::int64_t seed = std::stoll(s);
    if (folder.done(gin.name(), "MUTAG", seed)) continue;  // resumable, as tdl topobench
    const auto trained = topobench::train_run(data, gin, "MUTAG", cfg, seed);
    folder.add(trained.result, trained.curve);
    std::printf(
        "GIN on MUTAG, split %lld: test accuracy %.1f %% (best check: epoch %d, "
        "validation %.1f %%; majority class %.1f %%)\n",
        static_cast<long long>(seed), 100 * trained.result.test_accuracy, trained.result.best_epoch,
        100 * trained.best_val_accuracy, 100 * topobench::majority_accuracy(data, seed));
  }
  std::cout << topobench::format_summary(topobench::summarize(folder.runs()));
  std::cerr << "wrote " << (folder.path() / "runs.csv").string()
            << ", curves.csv, summary.csv, index.html\n";
  return 0;
}

int main(int argc, char** argv) {
  try {
    return run(argc, argv);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "custom_backbone: %s\n", e.what());
    return 1;
  }
}
