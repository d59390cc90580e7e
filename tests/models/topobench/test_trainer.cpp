// Tests of TopoBench's pipeline with a backbone of one's own (topos/models/topobench/trainer.hpp,
// report.hpp and model.hpp's Backbone) on a tiny synthetic dataset: early stopping keeps the
// best validation check and the restored model (parameters and BatchNorm's running statistics)
// reproduces that check's validation accuracy exactly; a schedule given as a Backbone is the
// table's own backbone of that schedule; a backbone whose layout the data cannot serve is an
// error naming the rank or operator; the runs folder writes a user's model into its table and
// resumes from its files; run_table runs jobs side by side, a failing cell marked not run; runs
// on two threads at once give what each gives alone.
#include "support/torch_prelude.hpp"

#include "topos/models/graph/gcn.hpp"
#include "topos/models/topobench/report.hpp"
#include "topos/models/topobench/table_models.hpp"
#include "topos/models/topobench/trainer.hpp"
#include "topos/nn/cpu.hpp"

#include <atomic>
#include <filesystem>
#include <random>
#include <set>
#include <stdexcept>
#include <thread>
#include <vector>

using namespace topos;
using namespace topos::models;
using namespace topos::models::topobench;

namespace {

// 40 random graphs of 4-9 nodes, three node features; the class shifts the first feature, so a
// model can learn it but not perfectly.
LiftedDataset synthetic_graphs(Domain domain = Domain::graph,
                               std::set<std::string> operators = {"gcn_adjacency"}) {
  std::mt19937 rng(11);
  std::uniform_real_distribution<float> u(0, 1);
  GraphLiftingOptions lo;
  lo.operators = std::move(operators);
  LiftedDataset d;
  d.num_classes = 2;
  for (int g = 0; g < 40; ++g) {
    const std::int64_t n = 4 + static_cast<std::int64_t>(rng() % 6);
    std::vector<std::array<std::int64_t, 2>> edges;
    for (std::int64_t a = 0; a < n; ++a)
      for (std::int64_t b = a + 1; b < n; ++b)
        if (b == a + 1 || u(rng) < 0.3) edges.push_back({a, b});
    std::vector<float> x;
    for (std::int64_t v = 0; v < n; ++v)
      x.insert(x.end(), {u(rng) + 0.4f * static_cast<float>(g % 2), u(rng), u(rng)});
    d.graphs.push_back(lift_graph(n, edges, x, 3, {}, domain, lo));
    d.graphs.back().label = g % 2;
  }
  return d;
}

// A user's backbone: one linear layer over (x + A x), then BatchNorm (whose running statistics
// are buffers), on the nodes; A the operator `op`.
struct TinyImpl : torch::nn::Module {
  explicit TinyImpl(std::int64_t h, std::string op = "gcn_adjacency")
      : op(std::move(op)),
        lin(register_module("lin", torch::nn::Linear(h, h))),
        bn(register_module("bn", torch::nn::BatchNorm1d(h))) {}
  NamedCochains forward(const NamedCochains& x, const NamedOperators& ops) {
    const auto& h = x.at("x_0");
    return {{"x_0", torch::relu(bn->forward(lin->forward(h + nn::spmm(ops.at(op), h))))}};
  }
  std::string op;
  torch::nn::Linear lin;
  torch::nn::BatchNorm1d bn;
};
TORCH_MODULE(Tiny);

Backbone tiny_backbone(RankLayout layout = {Domain::graph, {0}, 1, {"gcn_adjacency"}}) {
  return Backbone::module("Tiny", std::move(layout),
                          [](const BackboneContext& c) { return Tiny(c.hidden); });
}

RunConfig tiny_config() {
  RunConfig c;
  c.lr = 0.05, c.hidden = 8, c.layers = 1, c.batch_size = 6, c.dropout = 0;
  c.max_epochs = 80, c.min_epochs = 1, c.val_every = 2, c.patience = 3;
  return c;
}

}  // namespace

TEST_CASE("The trainer stops early at the best check and restores it, buffers included",
          "[topobench]") {
  const auto data = synthetic_graphs();
  const auto cfg = tiny_config();
  // Every check's validation accuracy and the state then (the model in eval mode).
  std::vector<double> seen;
  std::vector<torch::Tensor> running_mean, weight;
  TrainOptions opt;
  bool flushing = true;  // denormals flushed while the run trains, and only then
  opt.on_check = [&](const Check& c, TopoBenchModelImpl& m) {
    flushing = flushing && topos::nn::ScopedFlushDenormals::active();
    seen.push_back(c.val_accuracy);
    running_mean.push_back(m.named_buffers()["backbone.bn.running_mean"].clone());
    weight.push_back(m.named_parameters()["backbone.lin.weight"].clone());
  };
  auto run = train_run(data, tiny_backbone(), "synthetic", cfg, 3, opt);
  CHECK(flushing);
  CHECK_FALSE(topos::nn::ScopedFlushDenormals::active());

  REQUIRE(run.curve.size() == seen.size());
  REQUIRE(run.curve.size() >= 2);
  for (std::size_t k = 0; k < run.curve.size(); ++k) {
    CHECK(run.curve[k].epoch == 2 * static_cast<int>(k + 1));  // every val_every epochs
    CHECK(run.curve[k].val_accuracy == seen[k]);
    CHECK(std::isfinite(run.curve[k].loss));
  }
  // The best check is the first of the highest validation accuracy (strictly better only).
  const auto best =
      static_cast<std::size_t>(std::max_element(seen.begin(), seen.end()) - seen.begin());
  CHECK(run.result.best_epoch == run.curve[best].epoch);
  CHECK(run.best_val_accuracy == seen[best]);
  // Early stopping: `patience` checks without improvement after the best, then the run ends.
  REQUIRE(run.result.epochs < cfg.max_epochs);
  CHECK(run.curve.size() == best + 1 + static_cast<std::size_t>(cfg.patience));
  CHECK(run.result.epochs == run.curve.back().epoch);

  // The returned model is the best check's: parameters and running statistics, not the last's.
  const auto buffers = run.model->named_buffers();
  const auto params = run.model->named_parameters();
  CHECK(torch::equal(buffers["backbone.bn.running_mean"], running_mean[best]));
  CHECK(torch::equal(params["backbone.lin.weight"], weight[best]));
  CHECK_FALSE(torch::equal(running_mean.back(), running_mean[best]));
  // ... so it reproduces that check's validation accuracy exactly, and the test accuracy.
  const auto split = random_split(data.size(), 3);
  const auto bs = static_cast<std::size_t>(cfg.batch_size);
  CHECK(EvalSet(data, split.val, bs).accuracy(*run.model) == seen[best]);
  CHECK(EvalSet(data, split.test, bs).accuracy(*run.model) == run.result.test_accuracy);
  // Restoring the parameters alone (last check's statistics kept) is another model.
  auto stale = std::dynamic_pointer_cast<TopoBenchModelImpl>(run.model->clone());
  REQUIRE(stale != nullptr);
  {
    torch::NoGradGuard no_grad;
    stale->named_buffers()["backbone.bn.running_mean"].copy_(running_mean.back());
  }
  {
    torch::NoGradGuard no_grad;
    const auto b = collate(data.graphs, split.val);
    stale->eval(), run.model->eval();
    CHECK_FALSE(torch::equal(stale->forward(b), run.model->forward(b)));
  }

  CHECK(run.result.model == "Tiny");
  CHECK(run.result.dataset == "synthetic");
  CHECK(run.result.split_seed == 3);
  // The same run again gives the same numbers (TopoBench's seed 42, the split's shuffle).
  const auto again = train_run(data, tiny_backbone(), "synthetic", cfg, 3);
  CHECK(again.result.test_accuracy == run.result.test_accuracy);
  CHECK(again.result.best_epoch == run.result.best_epoch);
}

TEST_CASE("A schedule given as a Backbone is the table's backbone of that schedule",
          "[topobench]") {
  const auto data = synthetic_graphs();
  const auto b = collate(data.graphs, {0, 1, 2, 3});
  const auto mine =
      Backbone::schedule("MyGCN", rank_layout(model_spec("GCN")), [](const BackboneContext& c) {
        return gcn_schedule(GCNOptions(c.hidden, c.hidden).num_layers(c.n_layers));
      });
  torch::manual_seed(5);
  TopoBenchModel a(TopoBenchModelOptions(mine, {3}, 8, 2).n_layers(2));
  torch::manual_seed(5);
  TopoBenchModel t(TopoBenchModelOptions(table_backbone("GCN"), {3}, 8, 2).n_layers(2));
  const auto pa = a->named_parameters(), pt = t->named_parameters();
  REQUIRE(pa.size() == pt.size());
  for (const auto& p : pt) CHECK(torch::equal(pa[p.key()], p.value()));
  CHECK(pa.contains("backbone.convs.0.lin.weight"));
  a->eval(), t->eval();
  CHECK(torch::equal(a->forward(b), t->forward(b)));
  REQUIRE(a->backbone);
  CHECK(a->options.model() == "MyGCN");
  // A module backbone's clone builds its own module: equal outputs, its own parameters.
  TopoBenchModel m(TopoBenchModelOptions(tiny_backbone(), {3}, 8, 2));
  m->eval();
  CHECK_FALSE(m->backbone);  // not a schedule
  auto copy = std::dynamic_pointer_cast<TopoBenchModelImpl>(m->clone());
  torch::NoGradGuard no_grad;
  const auto y = m->forward(b);
  CHECK(torch::equal(copy->forward(b), y));
  for (auto& p : copy->parameters()) p.add_(1.0);
  CHECK(torch::equal(m->forward(b), y));
}

TEST_CASE("A backbone whose layout the data cannot serve is an error naming what is missing",
          "[topobench]") {
  const auto data = synthetic_graphs();
  const auto cfg = tiny_config();
  // Rank 1 on graph-lifted data (nodes only).
  CHECK_THROWS_WITH(train_run(data, tiny_backbone({Domain::graph, {0, 1}, 2, {"gcn_adjacency"}}),
                              "synthetic", cfg, 0),
                    Catch::Matchers::Contains(
                        "Tiny encodes rank 1 but synthetic lifted to graph has ranks 0..0"));
  CHECK_THROWS_WITH(
      train_run(data, tiny_backbone({Domain::graph, {0}, 1, {"gcn_adjacency", "incidence_1"}}),
                "synthetic", cfg, 0),
      Catch::Matchers::Contains("Tiny needs the operator 'incidence_1'"));
  // A backbone that returns fewer ranks than it declares.
  const auto short_of_x1 =
      Backbone::module("Short", {Domain::cell, {0, 1}, 2, {"adjacency_0"}},
                       [](const BackboneContext& c) { return Tiny(c.hidden, "adjacency_0"); });
  const auto cells = synthetic_graphs(Domain::cell, {"adjacency_0"});
  TopoBenchModel m(TopoBenchModelOptions(short_of_x1, cells.graphs[0].widths, 8, 2));
  CHECK_THROWS_WITH(m->forward(collate(cells.graphs, {0, 1})),
                    Catch::Matchers::Contains("Short: the backbone gave no x_1"));
  // Layouts and names that cannot be.
  const auto make = [](const BackboneContext& c) { return Tiny(c.hidden); };
  CHECK_THROWS_WITH(Backbone::module("a,b", {}, make), Catch::Matchers::Contains("without commas"));
  CHECK_THROWS_WITH(Backbone::module("NoX1", {Domain::cell, {0}, 2, {}}, make),
                    Catch::Matchers::Contains("every rank below cell_dimensions"));
}

TEST_CASE("A runs folder tables a user's model beside the table's and resumes", "[topobench]") {
  const auto dir = std::filesystem::temp_directory_path() / "topos_test_runs_folder";
  std::filesystem::remove_all(dir);
  RunResult mine{"Tiny", "MUTAG", 0, 0.75, 4, 10, 1.5}, table{"CWN", "MUTAG", 0, 0.5, 2, 8, 2.0};
  {
    RunsFolder folder(dir, table_model_names());
    CHECK(folder.runs().empty());
    folder.add(mine, {{2, 0.6, 0.5}, {4, 0.4, 0.7}});
    folder.add(table, {{2, 0.7, 0.4}});
  }
  RunsFolder again(dir);
  REQUIRE(again.runs().size() == 2);
  CHECK(again.done("Tiny", "MUTAG", 0));
  CHECK_FALSE(again.done("Tiny", "MUTAG", 3));
  CHECK(again.runs()[0].test_accuracy == 0.75);
  const auto md = data::read_text_file(dir / "table.md");
  // The table's model first, then the user's; with no order, as they first appear.
  CHECK(md ==
        "| model | MUTAG |\n|---|---|\n| CWN | 50.00 ± 0.00 (1 runs) |\n"
        "| Tiny | 75.00 ± 0.00 (1 runs) |\n");
  CHECK(table_markdown(again.runs(), {}) ==
        "| model | MUTAG |\n|---|---|\n| Tiny | 75.00 ± 0.00 (1 runs) |\n"
        "| CWN | 50.00 ± 0.00 (1 runs) |\n");
  CHECK(data::read_text_file(dir / "curves.csv") ==
        std::string(curves_header()) +
            "Tiny,MUTAG,0,2,0.6,0.5\nTiny,MUTAG,0,4,0.4,0.7\n"
            "CWN,MUTAG,0,2,0.7,0.4\n");
  CHECK(data::read_text_file(dir / "index.html").find("<h3 id='Tiny_MUTAG'>") != std::string::npos);
  // A malformed curves.csv is named before anything runs.
  io::write_file_atomic((dir / "curves.csv").string(), std::string(curves_header()) + "x\n");
  CHECK_THROWS_WITH(RunsFolder(dir), Catch::Matchers::Contains("curves.csv:2: malformed row 'x'"));
  std::filesystem::remove_all(dir);
}

TEST_CASE("run_table runs a table's jobs side by side into a runs folder, a failing cell not run",
          "[topobench]") {
  const auto dir = std::filesystem::temp_directory_path() / "topos_test_run_table";
  std::filesystem::remove_all(dir);
  const auto data = synthetic_graphs();
  const auto cfg = tiny_config();
  const ModelSpec good{"Tiny", "graph/tiny", Domain::graph, {0}, 1, {"gcn_adjacency"}};
  const ModelSpec bad{"Broken", "graph/broken", Domain::graph, {0}, 1, {"gcn_adjacency"}};
  const DatasetName synthetic{"synthetic", "synthetic", false};
  std::vector<TableJob> jobs;
  for (std::int64_t s : {0, 3}) jobs.push_back({&good, &synthetic, &cfg, s});
  for (std::int64_t s : {5, 7}) jobs.push_back({&bad, &synthetic, &cfg, s});
  std::atomic<int> lifts{0}, reported{0};
  TableRunOptions o;
  o.jobs = 2;
  o.max_epochs = 4;
  o.lift = [&](const TableJob&) {
    ++lifts;
    return data;
  };
  o.backbone = [](const ModelSpec& m) {
    if (std::string(m.name) == "Broken") throw std::runtime_error("no backbone here\nbacktrace");
    return tiny_backbone();
  };
  o.on_not_run = [&](const NotRun&) { ++reported; };
  NotRun not_run;
  {
    RunsFolder folder(dir);
    const auto failed = run_table("unused", jobs, folder, not_run, o);
    CHECK(failed == std::set<std::pair<std::string, std::string>>{{"Broken", "synthetic"}});
    CHECK(lifts == 1);  // both models read the same lifting
    REQUIRE(folder.runs().size() == 2);
    CHECK(folder.done("Tiny", "synthetic", 0));
    CHECK(folder.done("Tiny", "synthetic", 3));
    for (const auto& r : folder.runs()) CHECK(r.epochs == 4);
    // The failed split or both (the second may have started before the first failed).
    REQUIRE(!not_run.empty());
    CHECK(static_cast<std::size_t>(reported) == not_run.size());
    for (const auto& n : not_run) {
      CHECK(n[0] == "Broken");
      CHECK_THAT(n[2], Catch::Matchers::EndsWith(" failed: no backbone here"));
    }
  }
  // The majority baselines of the splits that ran, read back from baselines.csv.
  RunsFolder again(dir);
  REQUIRE(again.baselines().size() == 2);
  for (std::int64_t s : {0, 3})
    CHECK(again.baselines().at({"synthetic", s}) ==
          Approx(majority_accuracy(data, s)).margin(1e-6));
  io::write_file_atomic((dir / "baselines.csv").string(),
                        "dataset,split_seed,majority_test_accuracy\nsynthetic,x,0.5\n");
  CHECK_THROWS_WITH(RunsFolder(dir), Catch::Matchers::Contains("baselines.csv:2: expected "
                                                               "dataset,split_seed,"));
  // Anything but a std::exception stops the runner and is rethrown.
  o.backbone = [](const ModelSpec&) -> Backbone { throw 7; };
  std::filesystem::remove_all(dir);
  RunsFolder folder(dir);
  CHECK_THROWS_AS(run_table("unused", {jobs[0]}, folder, not_run, o), int);
  CHECK(folder.runs().empty());
  std::filesystem::remove_all(dir);
}

TEST_CASE("Runs trained on two threads at once give what each gives alone", "[topobench]") {
  // torch's generator is one per process: before each run drew its dropout masks from a stream
  // of its own, two runs at once took each other's draws (tdl topobench --jobs 2 gave other
  // numbers than --jobs 1).
  const auto data = synthetic_graphs();
  auto cfg = tiny_config();
  cfg.dropout = 0.5;  // the encoder's dropout, drawn at every step
  TrainOptions o;
  o.max_epochs = 12;
  const auto backbone = tiny_backbone();
  const auto outcome = [&](std::int64_t seed) {
    const auto run = train_run(data, backbone, "synthetic", cfg, seed, o);
    std::vector<double> v{run.result.test_accuracy, run.best_val_accuracy};
    for (const auto& c : run.curve) v.push_back(c.loss);
    for (const auto& p : run.model->parameters()) v.push_back(p.sum().item<double>());
    return v;
  };
  const auto alone0 = outcome(0), alone3 = outcome(3);
  REQUIRE(alone0 != alone3);
  for (int round = 0; round < 3; ++round) {
    std::vector<double> together0, together3;
    std::thread a([&] { together0 = outcome(0); });
    std::thread b([&] { together3 = outcome(3); });
    a.join(), b.join();
    CHECK(together0 == alone0);
    CHECK(together3 == alone3);
  }
}
