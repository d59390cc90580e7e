// TopoBench's training epoch on topos, beside TopoModelX's (shared/reference/tdl-bench's
// bench_topomodelx_epoch.py): the train half of MUTAG and PROTEINS (data seed 0), in TopoBench's
// batches, each batch one disjoint union lifted beforehand (clique complex to rank 2 for SCN,
// the cycle basis up to length 10 for CWN, closed 1-hop neighbourhoods for UniGNN2), with
// TopoBench's width and layer count, one thread, freed memory kept in the heap and denormals
// flushed to zero as `tdl topobench` runs (nn::keep_freed_memory, nn::ScopedFlushDenormals).
// Also AllSetTransformer's and SCCNN's REDDIT-BINARY settings, the table's costliest cells.
//   BM_backbone_epoch  forward + backward of the backbone alone over every batch, the work the
//                      Python script times (counter x_topomodelx: the speed-up over its figure),
//                      after one untimed epoch
//   BM_epoch           topos's whole epoch: shuffle, batches (a Collator, as train_run), encoder,
//                      backbone, readout, loss, Adam step
//   BM_collate         one epoch's shuffled batches: collate, or a Collator prepared once
//   BM_lift            lifting a whole dataset (features and operators included)
//   BM_encoder         TopoBench's encoder (GraphNorm then Linear, 64 wide) forward + backward
//                      over every rank of Cora's or Citeseer's clique complex: the two modules
//                      (arg 0) or nn::graph_norm_linear over the features' nonzeros (arg 1)
//   BM_epoch_options   SCCN's whole epoch on IMDB-BINARY's clique complexes to rank 3 (1.7M
//                      tetrahedra: dense products and allocations dominate), with the
//                      interpreter's fast paths off or on (arg 1) and freed memory kept in
//                      the heap (nn::keep_freed_memory) or given back to the kernel (arg 2)
//   BM_rank1_laplacian SCN's normalised Hodge Laplacian of rank 1 on REDDIT-BINARY's first eight
//                      training batches of 16 (data seed 0), spmm forward + backward over 32
//                      channels: formed (arg 0) or kept as its factors (arg 1, what `tdl
//                      topobench` does there); counter entries: the operator's stored entries
//   BM_dropout         dropout (p = 0.5, training) of a 4000 × 128 float tensor, forward: torch's
//                      (arg 0) or nn::dropout (arg 1); every TopoBench encoder and several
//                      backbones drop out at every step (no data needed)
// BM_backbone_epoch without one fast path: TOPOS_FAST_PATH_OFF=<FastPaths name> (e.g.
// fuse_products), to compare in one binary; BM_backbone_epoch and the epochs with denormals kept:
// TOPOS_KEEP_DENORMALS=1. Needs TOPOS_DATASETS_DIR (but for BM_dropout). Run with
//   OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 ./build/bench/bench_topobench
#include "topos/data/graph_datasets.hpp"
#include "topos/models/topobench/table_models.hpp"
#include "topos/models/topobench/trainer.hpp"
#include "topos/nn/cpu.hpp"
#include "topos/util/malloc.hpp"

#include <benchmark/benchmark.h>

#include <cstdlib>
#include <iostream>
#include <map>
#include <memory>
#include <random>

using namespace topos;
using namespace topos::models::topobench;

namespace {

std::string datasets_dir() {
  const char* d = std::getenv("TOPOS_DATASETS_DIR");
  return d ? d : "";
}

const data::GraphClassificationDataset& dataset(const std::string& name) {
  static std::map<std::string, data::GraphClassificationDataset> cache;
  auto it = cache.find(name);
  if (it == cache.end())
    it = cache.emplace(name, data::load_topobench_graph_dataset(datasets_dir(), name)).first;
  return it->second;
}

// The operators the model reads, as the table lifts them; `factored` keeps its rank-1 pair
// operators as products of incidences (`tdl topobench --factor-above`: REDDIT-BINARY's would not
// fit in memory).
std::vector<LiftedGraph> lift(const data::GraphClassificationDataset& ds, const ModelSpec& m,
                              int rank, bool factored) {
  const auto layout = rank_layout(m);
  GraphLiftingOptions o;
  o.complex_dim = rank;  // the Python script lifts cliques to rank 2
  o.operators = layout.operators;
  if (factored) o.factored = rank1_pair_operators(layout);
  std::vector<LiftedGraph> out;
  for (const auto& g : ds.graphs) {
    out.push_back(lift_graph(g.num_nodes, g.edges, g.x, ds.num_node_features, {}, m.domain, o));
    out.back().label = g.label;
  }
  return out;
}

struct Setting {
  const char* model;
  const char* dataset;
  std::int64_t hidden;
  int layers;
  std::size_t batch;
  double topomodelx_ms;   ///< tdl-bench README, the lowest figure
  int complex_dim = 2;    ///< the clique lifting's top rank
  bool factored = false;  ///< rank-1 pair operators as factors, as the table runs REDDIT-BINARY
};
// TopoBench's (hidden, layers, batch size) as the Python script has them, and its times.
const Setting kSettings[] = {
    {"SCN", "MUTAG", 32, 3, 64, 2.7},
    {"SCN", "PROTEINS", 32, 2, 128, 80},
    {"CWN", "MUTAG", 128, 2, 32, 20},
    {"CWN", "PROTEINS", 64, 3, 256, 277},
    {"UniGNN2", "MUTAG", 128, 3, 64, 370},
    {"UniGNN2", "PROTEINS", 64, 3, 128, 78500},
    // The table's two costliest cells (TopoBench's REDDIT-BINARY settings; not in the Python
    // script).
    {"AllSetTransformer", "MUTAG", 64, 3, 32, 0},
    {"AllSetTransformer", "REDDIT-BINARY", 64, 4, 256, 0},
    {"SCCNN", "REDDIT-BINARY", 64, 3, 16, 0, 3, true}};

struct Prepared {
  std::vector<LiftedGraph> graphs;
  std::vector<std::size_t> train;
  std::vector<Batch> batches;
};

const Prepared& prepared(const Setting& s) {
  static std::map<std::string, std::unique_ptr<Prepared>> cache;
  const std::string key = std::string(s.model) + s.dataset + std::to_string(s.complex_dim) +
                          (s.factored ? "/factored" : "");
  auto& p = cache[key];
  if (!p) {
    p = std::make_unique<Prepared>();
    const auto& ds = dataset(s.dataset);
    p->graphs = lift(ds, model_spec(s.model), s.complex_dim, s.factored);
    p->train = random_split(static_cast<std::int64_t>(ds.graphs.size()), 0).train;
    for (const auto& which : batches_of(p->train, s.batch))
      p->batches.push_back(collate(p->graphs, which));
  }
  return *p;
}

bool skip_without_data(benchmark::State& state) {
  if (!datasets_dir().empty()) return false;
  state.SkipWithError("set TOPOS_DATASETS_DIR to ../shared/datasets");
  return true;
}

// Denormals flushed as `tdl topobench` trains (TOPOS_KEEP_DENORMALS=1 keeps them: the same
// binary side by side).
bool flush_denormals() {
  return std::getenv("TOPOS_KEEP_DENORMALS") == nullptr;
}

void BM_backbone_epoch(benchmark::State& state, Setting s) {
  if (skip_without_data(state)) return;
  nn::set_cpu_threads(1, 1);
  nn::keep_freed_memory();  // as `tdl topobench` runs (registered after BM_epoch_options)
  const nn::ScopedFlushDenormals flush(flush_denormals());
  const auto& p = prepared(s);
  torch::manual_seed(0);
  TopoBenchModel model(
      TopoBenchModelOptions(table_backbone(s.model), p.graphs[0].widths, s.hidden, 2)
          .n_layers(s.layers));
  auto& backbone = model->backbone;
  // TOPOS_FAST_PATH_OFF=name (a FastPaths name) times the backbone without that fast path: the
  // same binary, side by side.
  if (const char* off = std::getenv("TOPOS_FAST_PATH_OFF")) backbone->fast_paths().set(off, false);
  // TOPOS_MATMUL_PRECISION=medium times it with bfloat16 products (nn::MatmulPrecision): the same
  // binary, side by side.
  struct Restore {
    ~Restore() { nn::set_float32_matmul_precision(nn::MatmulPrecision::highest); }
  } restore;
  if (const char* p = std::getenv("TOPOS_MATMUL_PRECISION"))
    nn::set_float32_matmul_precision(nn::matmul_precision_from_string(p));
  // Hidden-width features per rank and each output summed for the backward.
  std::vector<std::map<std::string, torch::Tensor>> inputs;
  for (const auto& b : p.batches) {
    std::map<std::string, torch::Tensor> in;
    for (const auto& port : backbone->schedule().inputs())
      in[port.name] =
          torch::randn({b.x.at(static_cast<std::size_t>(port.key.rank)).size(0), s.hidden});
    inputs.push_back(in);
  }
  const auto epoch = [&] {
    for (std::size_t i = 0; i < p.batches.size(); ++i) {
      backbone->zero_grad();
      const auto out = backbone->forward(inputs[i], model->backbone_operators(p.batches[i]));
      torch::Tensor loss = torch::zeros({});
      for (const auto& [name, y] : out) loss = loss + y.sum();
      loss.backward();
    }
  };
  // One epoch untimed: the heap's first growth. On a VM each first touch of a page costs 4-15 us:
  // REDDIT-BINARY's first AllSetTransformer epoch took 9.9-13.5 s, the next ones 3.5-4.3 s. A run
  // of the table pays it once per process, not per epoch.
  epoch();
  for (auto _ : state) epoch();
  state.counters["batches"] = static_cast<double>(p.batches.size());
  // The epoch's FLOPs as the backbone's plan counts them (the plain order), the backward counted
  // as twice the forward; TOPOS_PRINT_PLAN=1 prints the first batch's plan on stderr.
  double flops = 0;
  for (std::size_t i = 0; i < p.batches.size(); ++i) {
    const auto plan = backbone->plan(
        inputs[i], backbone->declared_operators(model->backbone_operators(p.batches[i])));
    if (i == 0 && std::getenv("TOPOS_PRINT_PLAN") != nullptr) std::cerr << plan.str();
    flops += 3.0 * static_cast<double>(plan.total_flops);
  }
  state.counters["MFLOP"] = flops / 1e6;
  state.counters["GFLOP/s"] = benchmark::Counter(
      flops * static_cast<double>(state.iterations()) / 1e9, benchmark::Counter::kIsRate);
  // TopoModelX's epoch over topos's: a rate of (its seconds per iteration) per second spent.
  if (s.topomodelx_ms > 0)
    state.counters["x_topomodelx"] =
        benchmark::Counter(s.topomodelx_ms / 1e3 * static_cast<double>(state.iterations()),
                           benchmark::Counter::kIsRate);
}

// Epochs of Adam on the train split; `warm_up` untimed ones first (the heap's growth, paid once).
// The setting's model (seed 0, the encoder's dropout 0.25), on one thread.
TopoBenchModel make_model(const Setting& s) {
  nn::set_cpu_threads(1, 1);
  const auto& p = prepared(s);
  torch::manual_seed(0);
  return TopoBenchModel(TopoBenchModelOptions(table_backbone(s.model), p.graphs[0].widths, s.hidden,
                                              dataset(s.dataset).num_classes)
                            .n_layers(s.layers)
                            .dropout(0.25)
                            .propagate_signal_down(model_spec(s.model).cell_dimensions > 1));
}

void run_epochs(benchmark::State& state, const Setting& s, bool fast_paths, int warm_up = 0) {
  const nn::ScopedFlushDenormals flush(flush_denormals());
  const auto& p = prepared(s);
  auto model = make_model(s);
  model->backbone->set_fast_paths(fast_paths);
  torch::optim::Adam opt(model->parameters(), torch::optim::AdamOptions(1e-3));
  std::mt19937_64 rng(0);
  auto order = p.train;
  const Collator collator(p.graphs, p.train);  // as train_run: the split's operators once
  model->train();
  const auto epoch = [&] {
    std::shuffle(order.begin(), order.end(), rng);
    for (const auto& which : batches_of(order, s.batch)) {
      const auto b = collator(which);
      const auto loss = torch::nn::functional::cross_entropy(model->forward(b), b.labels);
      opt.zero_grad();
      loss.backward();
      opt.step();
    }
  };
  for (int i = 0; i < warm_up; ++i) epoch();
  for (auto _ : state) epoch();
}

void BM_epoch(benchmark::State& state, Setting s) {
  if (skip_without_data(state)) return;
  nn::keep_freed_memory();  // as `tdl topobench` runs
  run_epochs(state, s, true);
}

// One epoch's batches of the shuffled train split: collate (arg 0) or a Collator prepared once
// (arg 1, what train_run uses).
void BM_collate(benchmark::State& state, Setting s) {
  if (skip_without_data(state)) return;
  nn::set_cpu_threads(1, 1);
  nn::keep_freed_memory();
  const auto& p = prepared(s);
  const Collator collator(p.graphs, p.train);
  std::mt19937_64 rng(0);
  auto order = p.train;
  for (auto _ : state) {
    std::shuffle(order.begin(), order.end(), rng);
    for (const auto& which : batches_of(order, s.batch))
      benchmark::DoNotOptimize(state.range(0) ? collator(which) : collate(p.graphs, which));
  }
}

// One Adam step over the model's parameters (random gradients): the part of a training step
// that does not depend on the batch. Counter tensors: how many parameter tensors it updates.
void BM_adam_step(benchmark::State& state, Setting s) {
  if (skip_without_data(state)) return;
  auto model = make_model(s);
  torch::optim::Adam opt(model->parameters(), torch::optim::AdamOptions(1e-3));
  for (auto& t : model->parameters()) t.mutable_grad() = torch::randn_like(t);
  for (auto _ : state) opt.step();
  state.counters["tensors"] = static_cast<double>(model->parameters().size());
}

void BM_epoch_options(benchmark::State& state, Setting s) {
  if (skip_without_data(state)) return;
  // glibc's own heap (blocks over its mmap threshold, at most 32 MB, go back to the kernel at
  // free) cannot be restored once keep_freed_memory has run: heap:0 runs first in the process.
  static bool kept = false;
  if (state.range(1) != 0) {
    nn::keep_freed_memory();
    kept = true;
  } else if (kept) {
    state.SkipWithError("heap:0 must run before heap:1 in one process");
    return;
  }
  run_epochs(state, s, state.range(0) != 0, /*warm_up=*/1);
}

void BM_lift(benchmark::State& state, const char* name, Domain d) {
  if (skip_without_data(state)) return;
  const auto& ds = dataset(name);
  std::int64_t cells = 0;
  for (auto _ : state) {
    GraphLiftingOptions o;  // TopoBench's: cliques up to 4 nodes, cycles up to 10
    cells = 0;
    for (const auto& g : ds.graphs) {
      const auto l = lift_graph(g.num_nodes, g.edges, g.x, ds.num_node_features, {}, d, o);
      for (auto n : l.sizes) cells += n;
    }
  }
  state.counters["cells"] = static_cast<double>(cells);
  state.counters["graphs"] = static_cast<double>(ds.graphs.size());
}

void BM_rank1_laplacian(benchmark::State& state) {
  if (skip_without_data(state)) return;
  nn::set_cpu_threads(1, 1);
  const bool factored = state.range(0) != 0;
  const auto& ds = dataset("REDDIT-BINARY");
  const auto train = random_split(static_cast<std::int64_t>(ds.graphs.size()), 0).train;
  const auto batches = batches_of(train, 16);
  GraphLiftingOptions o;
  o.operators = {"hodge_laplacian_1_norm"};
  if (factored) o.factored = o.operators;
  std::vector<nn::SparseOperator> ops;
  std::int64_t entries = 0;
  for (std::size_t k = 0; k < 8; ++k) {
    std::vector<LiftedGraph> graphs;
    for (auto i : batches[k]) {
      const auto& g = ds.graphs[i];
      graphs.push_back(
          lift_graph(g.num_nodes, g.edges, g.x, ds.num_node_features, {}, Domain::simplicial, o));
    }
    std::vector<std::size_t> all(graphs.size());
    for (std::size_t i = 0; i < all.size(); ++i) all[i] = i;
    ops.push_back(collate(graphs, all).operators.at("hodge_laplacian_1_norm"));
    entries += ops.back().nnz();
  }
  torch::manual_seed(0);
  std::vector<torch::Tensor> xs;
  for (const auto& A : ops) xs.push_back(torch::randn({A.cols, 32}).requires_grad_(true));
  for (auto _ : state)
    for (std::size_t k = 0; k < ops.size(); ++k) nn::spmm(ops[k], xs[k]).sum().backward();
  state.counters["entries"] = static_cast<double>(entries);
}

void BM_dropout(benchmark::State& state) {
  nn::set_cpu_threads(1, 1);
  nn::keep_freed_memory();  // as `tdl topobench` runs (registered after BM_epoch_options)
  torch::manual_seed(0);
  const auto x = torch::randn({4000, 128});
  for (auto _ : state)
    benchmark::DoNotOptimize(state.range(0) ? nn::dropout(x, 0.5, true)
                                            : torch::dropout(x, 0.5, true));
}

// x Wᵀ + b forward, or forward and backward (x and W need gradients), rows × width by width ×
// width (64, 128): torch's linear (OpenBLAS) against nn::linear_act (topos's register-blocked
// kernel; 128 wide in panels of 64). AllSetTransformer's REDDIT-BINARY batches have about 110 k
// rows. `threads`: LibTorch's intra-op threads (BLAS keeps one), which topos's kernels share.
void BM_linear(benchmark::State& state) {
  nn::set_cpu_threads(static_cast<int>(state.range(4)), 1);
  nn::keep_freed_memory();  // as `tdl topobench` runs (registered after BM_epoch_options)
  torch::manual_seed(0);
  const std::int64_t width = state.range(3);
  const auto x = torch::randn({state.range(1), width}).requires_grad_();
  const auto W = torch::randn({width, width}).requires_grad_();
  const auto b = torch::randn({width}).requires_grad_();
  const bool backward = state.range(2) != 0;
  torch::AutoGradMode grad(backward);
  for (auto _ : state) {
    const auto y = state.range(0) ? nn::linear_act(x, W, b) : torch::linear(x, W, b);
    if (backward) y.sum().backward();
  }
  state.counters["GFLOP/s"] =
      benchmark::Counter((backward ? 6.0 : 2.0) * static_cast<double>(width * width) *
                             static_cast<double>(state.range(1)),
                         benchmark::Counter::kIsIterationInvariantRate);
}

void BM_encoder(benchmark::State& state, const char* name) {
  if (skip_without_data(state)) return;
  nn::set_cpu_threads(1, 1);
  // As `tdl topobench` runs; registered last, so BM_epoch_options's heap:0 runs before this.
  nn::keep_freed_memory();
  const bool sparse = state.range(0) != 0;
  static std::map<std::string, LiftedGraph> cache;
  auto it = cache.find(name);
  if (it == cache.end()) {
    const auto ds = data::load_topobench_node_dataset(datasets_dir(), name);
    GraphLiftingOptions o;
    o.complex_dim = 3;
    it = cache
             .emplace(name, lift_graph(ds.num_nodes, ds.edges, ds.x, ds.num_node_features, {},
                                       Domain::simplicial, o))
             .first;
  }
  const Batch b = collate({it->second}, {0});
  torch::manual_seed(0);
  std::vector<nn::GraphNorm> norms;
  std::vector<torch::nn::Linear> linears;
  std::int64_t entries = 0;
  for (const auto& x : b.x) {
    norms.emplace_back(x.size(1)), linears.emplace_back(x.size(1), 64);
    entries += x.numel();
  }
  for (auto _ : state) {
    torch::Tensor loss = torch::zeros({});
    for (std::size_t r = 0; r < b.x.size(); ++r) {
      const auto y = sparse ? nn::graph_norm_linear(norms[r], linears[r], b.x[r], b.batch[r], 1)
                            : linears[r]->forward(norms[r]->forward(b.x[r], b.batch[r], 1));
      loss = loss + torch::relu(y).sum();
    }
    loss.backward();
  }
  state.counters["feature_entries"] = static_cast<double>(entries);
}

const int registered = [] {
  // OpenBLAS's kernels decide torch's products' speed (OPENBLAS_CORETYPE may pin them).
  benchmark::AddCustomContext("openblas_kernels",
                              nn::blas_kernels().empty() ? "not OpenBLAS" : nn::blas_kernels());
  // tdl's malloc (topos::tcmalloc): with it, the heap:1 settings (glibc's) change nothing.
  benchmark::AddCustomContext("malloc", topos::malloc_name());
  // First: its heap:0 runs must come before anything keeps freed memory in the process.
  // TopoBench's SCCN on IMDB-BINARY: width 128, 4 layers, batches of 128, cliques to rank 3.
  benchmark::RegisterBenchmark("BM_epoch_options/SCCN/IMDB-BINARY", BM_epoch_options,
                               Setting{"SCCN", "IMDB-BINARY", 128, 4, 128, 0, 3})
      ->ArgNames({"fast", "heap"})
      ->Args({0, 0})
      ->Args({1, 0})
      ->Args({0, 1})
      ->Args({1, 1})
      ->Unit(benchmark::kMillisecond)
      ->Iterations(2);
  for (const auto& s : kSettings) {
    const std::string tag = std::string(s.model) + "/" + s.dataset;
    benchmark::RegisterBenchmark(("BM_backbone_epoch/" + tag).c_str(), BM_backbone_epoch, s)
        ->Unit(benchmark::kMillisecond)
        ->MinTime(1.0);
    benchmark::RegisterBenchmark(("BM_epoch/" + tag).c_str(), BM_epoch, s)
        ->Unit(benchmark::kMillisecond)
        ->MinTime(1.0);
    benchmark::RegisterBenchmark(("BM_collate/" + tag).c_str(), BM_collate, s)
        ->ArgName("collator")
        ->Arg(0)
        ->Arg(1)
        ->Unit(benchmark::kMicrosecond)
        ->MinTime(0.5);
    benchmark::RegisterBenchmark(("BM_adam_step/" + tag).c_str(), BM_adam_step, s)
        ->Unit(benchmark::kMicrosecond)
        ->MinTime(0.5);
  }
  benchmark::RegisterBenchmark("BM_lift/clique/REDDIT-BINARY", BM_lift, "REDDIT-BINARY",
                               Domain::simplicial)
      ->Unit(benchmark::kMillisecond)
      ->Iterations(1);
  benchmark::RegisterBenchmark("BM_rank1_laplacian/SCN/REDDIT-BINARY", BM_rank1_laplacian)
      ->ArgName("factored")
      ->Arg(0)
      ->Arg(1)
      ->Unit(benchmark::kMillisecond)
      ->MinTime(1.0);
  benchmark::RegisterBenchmark("BM_linear", BM_linear)
      ->ArgNames({"topos", "rows", "backward", "width", "threads"})
      ->ArgsProduct({{0, 1}, {2000, 20000, 110000}, {0, 1}, {64, 128}, {1, 2}})
      ->Unit(benchmark::kMicrosecond)
      ->MinTime(0.5);
  benchmark::RegisterBenchmark("BM_dropout", BM_dropout)
      ->ArgName("topos")
      ->Arg(0)
      ->Arg(1)
      ->Unit(benchmark::kMicrosecond)
      ->MinTime(0.5);
  benchmark::RegisterBenchmark("BM_lift/clique/IMDB-BINARY", BM_lift, "IMDB-BINARY",
                               Domain::simplicial)
      ->Unit(benchmark::kMillisecond)
      ->Iterations(1);
  benchmark::RegisterBenchmark("BM_lift/cycle/NCI1", BM_lift, "NCI1", Domain::cell)
      ->Unit(benchmark::kMillisecond)
      ->Iterations(1);
  for (const char* name : {"Cora", "Citeseer"})
    benchmark::RegisterBenchmark((std::string("BM_encoder/") + name).c_str(), BM_encoder, name)
        ->ArgName("sparse")
        ->Arg(0)
        ->Arg(1)
        ->Unit(benchmark::kMillisecond)
        ->MinTime(1.0);
  return 0;
}();

}  // namespace

BENCHMARK_MAIN();
