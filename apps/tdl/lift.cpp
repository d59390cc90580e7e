// apps/tdl/lift.cpp
// `tdl lift --data-dir DIR --dataset NAME --lifting clique|cycle|khop`: lifts every graph of a
// TopoBench dataset (topos/data/graph_datasets.hpp) with TopoBench's lifting
// (topos/core/domain_lifting.hpp: clique_lifting, cycle_lifting, khop_lifting) and prints one
// JSON object on stdout: the dataset, the lifting and its options, the number of graphs, the
// total cells per rank ("cells": nodes, edges, ...; k-hop: nodes, hyperedges) and the seconds
// spent reading and lifting. A progress bar goes to stderr. LibTorch-free.
#include "commands.hpp"

#include "topos/core/domain_lifting.hpp"
#include "topos/data/graph_datasets.hpp"
#include "topos/util/progress.hpp"

#include <nlohmann/json.hpp>

#include <chrono>
#include <cstdio>
#include <filesystem>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

namespace tdl_cli {

namespace {

struct LiftArgs {
  std::string data_dir, dataset, lifting;
  int complex_dim = 3, max_cell_length = 10, k = 1;
};

using Edges = std::vector<std::array<std::int64_t, 2>>;

// Adds one graph's lifted cell counts to `cells` (grown as ranks appear).
void lift_graph(const LiftArgs& a, std::int64_t num_nodes, const Edges& edges,
                std::vector<std::int64_t>& cells) {
  std::vector<std::int64_t> shape;
  if (a.lifting == "clique") {
    shape = topos::clique_lifting(num_nodes, edges, a.complex_dim).shape();
  } else if (a.lifting == "cycle") {
    shape = topos::cycle_lifting(num_nodes, edges, a.max_cell_length).shape();
  } else {
    shape = topos::khop_lifting(num_nodes, edges, a.k).shape();
  }
  if (shape.size() > cells.size()) cells.resize(shape.size(), 0);
  for (std::size_t r = 0; r < shape.size(); ++r) cells[r] += shape[r];
}

bool is_node_dataset(std::string name) {
  for (auto& c : name) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  if (name.rfind("cocitation_", 0) == 0) name = name.substr(11);
  return name == "cora" || name == "citeseer" || name == "pubmed";
}

int run_lift(const LiftArgs& a) {
  using clock = std::chrono::steady_clock;
  const auto seconds = [](clock::time_point t0) {
    return std::chrono::duration<double>(clock::now() - t0).count();
  };
  if (a.complex_dim < 0) throw std::invalid_argument("--complex-dim must be >= 0");
  if (a.k < 0) throw std::invalid_argument("--k must be >= 0");

  // Every rank the lifting can produce is reported, even when no graph has a cell of it.
  std::vector<std::int64_t> cells(a.lifting == "clique"
                                      ? static_cast<std::size_t>(std::max(a.complex_dim, 1)) + 1
                                  : a.lifting == "cycle" ? 3
                                                         : 2,
                                  0);
  std::int64_t graphs = 0;
  double load_s = 0, lift_s = 0;
  auto t0 = clock::now();
  if (is_node_dataset(a.dataset)) {
    const auto ds = topos::data::load_topobench_node_dataset(a.data_dir, a.dataset);
    load_s = seconds(t0);
    t0 = clock::now();
    lift_graph(a, ds.num_nodes, ds.edges, cells);
    lift_s = seconds(t0);
    graphs = 1;
  } else {
    topos::data::GraphClassificationDataset ds;
    try {
      ds = topos::data::load_topobench_graph_dataset(a.data_dir, a.dataset);
    } catch (const std::invalid_argument& e) {  // an unknown name: list the node sets too
      throw std::invalid_argument(std::string(e.what()) +
                                  "; node-level: cocitation_cora, cocitation_citeseer");
    }
    load_s = seconds(t0);
    t0 = clock::now();
    topos::ProgressBar bar("lift " + ds.name + " (" + a.lifting + ")",
                           static_cast<std::int64_t>(ds.graphs.size()), "graphs");
    for (const auto& g : ds.graphs) {
      lift_graph(a, g.num_nodes, g.edges, cells);
      bar.update();
    }
    bar.finish();
    lift_s = seconds(t0);
    graphs = static_cast<std::int64_t>(ds.graphs.size());
  }

  nlohmann::ordered_json out;
  out["dataset"] = a.dataset;
  out["lifting"] = a.lifting;
  if (a.lifting == "clique") out["complex_dim"] = a.complex_dim;
  if (a.lifting == "cycle") out["max_cell_length"] = a.max_cell_length;
  if (a.lifting == "khop") out["k"] = a.k;
  out["graphs"] = graphs;
  out["cells"] = cells;
  out["seconds"] = lift_s;
  out["load_seconds"] = load_s;
  std::printf("%s\n", out.dump().c_str());
  return 0;
}

}  // namespace

void register_lift(CLI::App& app, Run& run) {
  auto args = std::make_shared<LiftArgs>();
  CLI::App* c = app.add_subcommand(
      "lift",
      "lift every graph of a TopoBench dataset (TopoBench's clique, cycle or k-hop lifting); "
      "print the total cells per rank and the time as one JSON object");
  c->add_option("--data-dir", args->data_dir,
                "the raw datasets (../shared/datasets: tu/, dgcnn/, planetoid/)")
      ->required()
      ->check(CLI::ExistingDirectory);
  c->add_option("--dataset", args->dataset,
                "MUTAG, PROTEINS, NCI1, NCI109, IMDB-BINARY, IMDB-MULTI, REDDIT-BINARY, "
                "cocitation_cora, cocitation_citeseer")
      ->required();
  c->add_option("--lifting", args->lifting,
                "clique (graph -> simplicial), cycle (graph -> cell), khop (graph -> hypergraph)")
      ->required()
      ->check(CLI::IsMember({"clique", "cycle", "khop"}));
  c->add_option("--complex-dim", args->complex_dim,
                "clique: highest simplex rank (TopoBench's complex_dim)")
      ->capture_default_str();
  c->add_option("--max-cell-length", args->max_cell_length,
                "cycle: longest basis cycle kept as a 2-cell (negative: no limit)")
      ->capture_default_str();
  c->add_option("--k", args->k, "khop: hops (TopoBench's k_value)")->capture_default_str();
  c->callback([args, &run] { run = [args] { return run_lift(*args); }; });
}

}  // namespace tdl_cli
