// tdl train: node classification on Zachary's karate club (apps/tdl/data/karate_club.txt),
// lifted to its clique complex (SCN2, SCCNN) and to its neighbourhood hypergraph (UniGCNII),
// each model followed by a linear layer to the classes (the two factions). One-hot node
// features (edges and triangles get a constant feature), a stratified train/test split, Adam on
// the cross-entropy of the training nodes; accuracy per epoch to OUT/accuracy.csv and
// OUT/accuracy.svg, the final figures to OUT/summary.json.
#include "tasks.hpp"
#include "karate.hpp"
#include "zoo_commands.hpp"

#include "topos/core/domain_lifting.hpp"
#include "topos/models/hypergraph/unigcnii.hpp"
#include "topos/models/simplicial/sccnn.hpp"
#include "topos/models/simplicial/scn2.hpp"
#include "topos/util/progress.hpp"

#include <nlohmann/json.hpp>

#include <iomanip>
#include <iostream>
#include <random>
#include <sstream>

namespace tdl_cli {

namespace {

struct TrainOptions {
  std::string data = TOPOS_TDL_DATA_DIR "/karate_club.txt";
  std::string out;
  std::vector<std::string> models{"scn2", "sccnn", "unigcnii"};
  int epochs = 100;
  std::int64_t hidden = 16;
  double lr = 0.01, weight_decay = 5e-4, train_fraction = 0.3;
  std::uint64_t seed = 0;
};

/// A model on the lifted karate club, with its classification head; logits() gives one row per
/// node.
struct Classifier {
  std::string name;
  std::shared_ptr<torch::nn::Module> net;  ///< the model and the head
  std::function<torch::Tensor()> logits;
};

torch::Tensor one_hot_nodes(std::int64_t n) {
  return torch::eye(n);
}

Classifier make_classifier(const std::string& name, const Graph& g, const TrainOptions& o) {
  using namespace topos;
  const auto n = g.num_nodes;
  auto root = std::make_shared<torch::nn::Module>();
  Classifier c;
  c.name = name;
  c.net = root;
  const auto x0 = one_hot_nodes(n);
  const std::int64_t classes = *std::max_element(g.label.begin(), g.label.end()) + 1;
  if (name == "scn2" || name == "sccnn") {
    const auto sc = clique_complex(n, g.edges, 2);
    if (sc.dim() < 2)
      throw std::invalid_argument("tdl train: the graph has no triangles, " + name +
                                  " needs ranks 0..2");
    const auto x1 = torch::ones({sc.num_cells(1), 1}), x2 = torch::ones({sc.num_cells(2), 1});
    auto op = [](const SparseMatrix& m) { return nn::SparseOperator::from_eigen(m); };
    if (name == "scn2") {
      // SCN2 keeps each rank's width: the one-hot features go through, then a linear head.
      auto model = root->register_module("model", models::SCN2(models::SCN2Options(n, 1, 1)));
      auto head = root->register_module("head", torch::nn::Linear(n, classes));
      const std::array<nn::SparseOperator, 3> L{op(low_pass_filter(sc.hodge_laplacian_matrix(0))),
                                                op(low_pass_filter(sc.hodge_laplacian_matrix(1))),
                                                op(low_pass_filter(sc.hodge_laplacian_matrix(2)))};
      c.logits = [=]() mutable { return head->forward(model->forward({x0, x1, x2}, L)[0]); };
    } else {
      auto model = root->register_module(
          "model",
          // No aggr_norm: the filters are normalised already, and dividing by row sums would
          // blow up the signed edge filters' rows that sum to nearly zero.
          models::SCCNN(models::SCCNNOptions({n, 1, 1}, {o.hidden, o.hidden, o.hidden}, 1, 2)
                            .update_func(nn::Activation::relu)));
      auto head = root->register_module("head", torch::nn::Linear(o.hidden, classes));
      const std::vector<nn::SparseOperator> L{op(low_pass_filter(sc.hodge_laplacian_matrix(0))),
                                              op(low_pass_filter(sc.down_laplacian_matrix(1))),
                                              op(low_pass_filter(sc.up_laplacian_matrix(1))),
                                              op(low_pass_filter(sc.hodge_laplacian_matrix(2)))};
      const std::vector<nn::SparseOperator> B{op(sc.incidence_matrix(1)),
                                              op(sc.incidence_matrix(2))};
      c.logits = [=]() mutable { return head->forward(model->forward({x0, x1, x2}, L, B)[0]); };
    }
  } else if (name == "unigcnii") {
    const auto h = neighborhood_hypergraph(n, g.edges);
    auto model = root->register_module(
        "model", models::UniGCNII(models::UniGCNIIOptions(n, o.hidden).n_layers(2)));
    auto head = root->register_module("head", torch::nn::Linear(o.hidden, classes));
    const auto B = nn::SparseOperator::from_eigen(h.incidence_matrix(0, 1));
    c.logits = [=]() mutable { return head->forward(model->forward(x0, B)[0]); };
  } else {
    throw std::invalid_argument("tdl train: unknown model '" + name + "' (scn2, sccnn, unigcnii)");
  }
  return c;
}

/// A stratified split: round(fraction · class size) training nodes of every class (at least one).
std::pair<torch::Tensor, torch::Tensor> split(const Graph& g, double fraction, std::uint64_t seed) {
  std::mt19937_64 rng(seed);
  const int classes = *std::max_element(g.label.begin(), g.label.end()) + 1;
  std::vector<std::int64_t> train, test;
  for (int k = 0; k < classes; ++k) {
    std::vector<std::int64_t> members;
    for (std::int64_t v = 0; v < g.num_nodes; ++v)
      if (g.label[static_cast<std::size_t>(v)] == k) members.push_back(v);
    std::shuffle(members.begin(), members.end(), rng);
    const auto m = static_cast<std::size_t>(
        std::clamp<double>(std::round(fraction * static_cast<double>(members.size())), 1.0,
                           static_cast<double>(members.size())));
    train.insert(train.end(), members.begin(), members.begin() + static_cast<std::ptrdiff_t>(m));
    test.insert(test.end(), members.begin() + static_cast<std::ptrdiff_t>(m), members.end());
  }
  return {torch::tensor(train, torch::kLong), torch::tensor(test, torch::kLong)};
}

double accuracy(const torch::Tensor& logits, const torch::Tensor& y, const torch::Tensor& idx) {
  if (idx.numel() == 0) return NAN;
  return logits.index_select(0, idx)
      .argmax(1)
      .eq(y.index_select(0, idx))
      .to(torch::kDouble)
      .mean()
      .item<double>();
}

int run_train(const TrainOptions& o) {
  const auto g = read_labelled_graph(o.data);
  const auto [train_idx, test_idx] = split(g, o.train_fraction, o.seed);
  if (test_idx.numel() == 0)
    throw std::invalid_argument("tdl train: --train-fraction " + std::to_string(o.train_fraction) +
                                " leaves no test nodes");
  const auto y =
      torch::tensor(std::vector<std::int64_t>(g.label.begin(), g.label.end()), torch::kLong);
  std::cout << "karate club: " << g.num_nodes << " nodes, " << g.edges.size() << " edges; "
            << train_idx.numel() << " training and " << test_idx.numel() << " test nodes\n";
  std::vector<std::pair<std::string, std::vector<double>>> test_curves;
  std::ostringstream csv;
  csv << "model,epoch,loss,train_accuracy,test_accuracy\n";
  nlohmann::json summary{{"train_nodes", train_idx.numel()},
                         {"test_nodes", test_idx.numel()},
                         {"models", nlohmann::json::object()}};
  for (std::size_t m = 0; m < o.models.size(); ++m) {
    torch::manual_seed(o.seed);
    auto c = make_classifier(o.models[m], g, o);
    torch::optim::Adam opt(c.net->parameters(),
                           torch::optim::AdamOptions(o.lr).weight_decay(o.weight_decay));
    std::vector<double> test_acc;
    double train_acc = 0, loss_value = 0;
    topos::ProgressBar bar(c.name, o.epochs, "epoch");
    for (int e = 1; e <= o.epochs; ++e) {
      c.net->train();
      opt.zero_grad();
      const auto loss = torch::nn::functional::cross_entropy(c.logits().index_select(0, train_idx),
                                                             y.index_select(0, train_idx));
      loss.backward();
      opt.step();
      loss_value = loss.item<double>();
      c.net->eval();
      torch::NoGradGuard no_grad;
      const auto logits = c.logits();
      train_acc = accuracy(logits, y, train_idx);
      test_acc.push_back(accuracy(logits, y, test_idx));
      log_epoch(csv, bar, c.name + ",", e, loss_value, train_acc, test_acc.back());
    }
    bar.finish();
    summary["models"][c.name] = {
        {"loss", loss_value}, {"train_accuracy", train_acc}, {"test_accuracy", test_acc.back()}};
    test_curves.push_back({c.name, test_acc});
  }
  write_task_results(o.out, csv.str(), test_curves, "test accuracy", summary.dump(2) + "\n");
  return 0;
}

}  // namespace

void register_train(CLI::App& app, Run& run) {
  auto o = std::make_shared<TrainOptions>();
  auto* cmd = app.add_subcommand("train",
                                 "node classification on Zachary's karate club with SCN2, SCCNN "
                                 "(clique complex) and UniGCNII (hypergraph)");
  cmd->add_option("--data", o->data, "labelled graph: 'node <id> <class>' and 'edge <u> <v>' lines")
      ->capture_default_str();
  cmd->add_option("--out", o->out, "output folder: accuracy.csv, accuracy.svg, summary.json")
      ->required();
  cmd->add_option("--models", o->models, "models to train (scn2, sccnn, unigcnii)")
      ->delimiter(',')
      ->capture_default_str();
  cmd->add_option("--epochs", o->epochs, "training epochs")
      ->check(CLI::Range(1, 100000))
      ->capture_default_str();
  cmd->add_option("--hidden", o->hidden, "hidden channels (SCCNN, UniGCNII)")
      ->check(CLI::Range(1, 4096))
      ->capture_default_str();
  cmd->add_option("--lr", o->lr, "Adam learning rate")
      ->check(CLI::PositiveNumber)
      ->capture_default_str();
  cmd->add_option("--weight-decay", o->weight_decay, "Adam weight decay")
      ->check(CLI::NonNegativeNumber)
      ->capture_default_str();
  cmd->add_option("--train-fraction", o->train_fraction, "share of each class used for training")
      ->check(CLI::Range(0.0, 1.0))
      ->capture_default_str();
  cmd->add_option("--seed", o->seed, "seed of the split and the initial weights")
      ->capture_default_str();
  cmd->callback([o, &run] { run = [o] { return run_train(*o); }; });
}

}  // namespace tdl_cli
