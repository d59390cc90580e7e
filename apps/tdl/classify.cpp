// tdl classify: graph-level classification of many lifted complexes, batched with ComplexBatch.
// Point clouds sampled from three planar shapes that differ in their holes (a disk, an annulus, a
// disk with two holes), each randomly scaled, rotated and jittered, are lifted to the clique
// complex (ranks 0-2) of their radius graph. The network is an operator schedule: per layer, edges
// take their low-pass Hodge-filtered neighbours, their nodes and their triangles; nodes and
// triangles do the same; each rank is decoded, averaged over each complex, and a linear head gives
// the class. Accuracy per epoch to OUT/accuracy.csv and OUT/accuracy.svg, the figures to
// OUT/summary.json.
#include "commands.hpp"
#include "tasks.hpp"

#include "topos/core/domain_lifting.hpp"
#include "topos/core/neighborhood.hpp"
#include "topos/nn/operator_schedule.hpp"
#include "topos/util/progress.hpp"

#include <nlohmann/json.hpp>

#include <torch/torch.h>

#include <Eigen/Geometry>

#include <cmath>
#include <filesystem>
#include <iomanip>
#include <iostream>
#include <random>
#include <sstream>

namespace tdl_cli {

namespace {

struct ClassifyOptions {
  std::string out;
  int samples = 150;  ///< point clouds in all, a third per class
  int points = 64;    ///< per cloud
  double radius = 0.3;
  int epochs = 30, batch = 8, layers = 2;
  std::int64_t hidden = 32;
  double lr = 1e-3, test_fraction = 0.25;  // 3e-3 and more stall at chance for many epochs
  std::uint64_t seed = 0;
};

const char* const kClasses[] = {"disk", "annulus", "two holes"};

/// A uniform point of class k's shape (rejection sampling in [-1, 1]^2).
Eigen::Vector2d sample_point(int k, std::mt19937_64& rng) {
  std::uniform_real_distribution<double> u(-1, 1);
  for (;;) {
    const Eigen::Vector2d p(u(rng), u(rng));
    const double r = p.norm();
    if (r > 1) continue;
    if (k == 1 && r < 0.55) continue;
    if (k == 2 && ((p - Eigen::Vector2d(-0.45, 0)).norm() < 0.3 ||
                   (p - Eigen::Vector2d(0.45, 0)).norm() < 0.3))
      continue;
    return p;
  }
}

struct Sample {
  topos::nn::ComplexView view;
  std::map<std::string, torch::Tensor> inputs;
  int label = 0;
};

/// One point cloud of class k, lifted: node features (distance to the centroid), edge lengths,
/// triangle areas, all invariant to the cloud's rotation and scale; the low-pass filters of the
/// Hodge Laplacians and the incidences (both directions) as named neighbourhoods.
Sample make_sample(int k, const ClassifyOptions& o, std::mt19937_64& rng) {
  using namespace topos;
  std::uniform_real_distribution<double> angle(0, 2 * M_PI), scale(0.8, 1.2);
  std::normal_distribution<double> jitter(0, 0.02);
  const double a = angle(rng), s = scale(rng);
  const Eigen::Matrix2d rot = Eigen::Rotation2Dd(a).toRotationMatrix() * s;
  std::vector<Eigen::Vector2d> p(static_cast<std::size_t>(o.points));
  for (auto& q : p) q = rot * sample_point(k, rng) + Eigen::Vector2d(jitter(rng), jitter(rng));
  Eigen::Vector2d centroid = Eigen::Vector2d::Zero();
  for (const auto& q : p) centroid += q / static_cast<double>(p.size());
  std::vector<std::array<std::int64_t, 2>> edges;
  const double r = o.radius * s;
  for (std::int64_t i = 0; i < o.points; ++i)
    for (std::int64_t j = i + 1; j < o.points; ++j)
      if ((p[static_cast<std::size_t>(i)] - p[static_cast<std::size_t>(j)]).norm() < r)
        edges.push_back({i, j});
  const auto sc = clique_complex(o.points, edges, 2);
  if (sc.dim() < 2)
    throw std::invalid_argument(
        "tdl classify: a point cloud of class '" + std::string(kClasses[k]) +
        "' has no triangles at --radius " + std::to_string(o.radius) + " with --points " +
        std::to_string(o.points) + "; the network needs ranks 0..2 (raise either)");
  Sample smp;
  smp.label = k;
  smp.view.sizes = {sc.num_cells(0), sc.num_cells(1), sc.num_cells(2)};
  auto& nb = smp.view.neighborhoods;
  for (int rank = 0; rank <= 2; ++rank) {
    const std::string name = "L" + std::to_string(rank);
    nb[name] = neighborhood_from_matrix(low_pass_filter(sc.hodge_laplacian_matrix(rank)), rank,
                                        rank, name);
  }
  for (int rank = 1; rank <= 2; ++rank) {
    const SparseMatrix b = sparse::abs(sc.incidence_matrix(rank));  // (rank-1) x rank
    const std::string down = "B" + std::to_string(rank) + std::to_string(rank - 1),
                      up = "B" + std::to_string(rank - 1) + std::to_string(rank);
    nb[down] = neighborhood_from_matrix(b, rank, rank - 1, down);
    nb[up] = neighborhood_from_matrix(sparse::transpose(b), rank - 1, rank, up);
  }
  std::vector<float> x0, x1, x2;
  for (const auto& q : p) x0.push_back(float((q - centroid).norm() / s));
  for (const auto& e : sc.skeleton(1))
    x1.push_back(
        float((p[static_cast<std::size_t>(e[0])] - p[static_cast<std::size_t>(e[1])]).norm() / r));
  for (const auto& t : sc.skeleton(2)) {
    const Eigen::Vector2d u = p[static_cast<std::size_t>(t[1])] - p[static_cast<std::size_t>(t[0])],
                          v = p[static_cast<std::size_t>(t[2])] - p[static_cast<std::size_t>(t[0])];
    x2.push_back(float(0.5 * std::abs(u.x() * v.y() - u.y() * v.x()) / (r * r)));
  }
  smp.inputs = {{"x0", torch::tensor(x0).view({-1, 1})},
                {"x1", torch::tensor(x1).view({-1, 1})},
                {"x2", torch::tensor(x2).view({-1, 1})}};
  return smp;
}

/// The network: encoders, `layers` rounds of edge, node and triangle updates, decoders.
topos::nn::OperatorNetwork make_network(const ClassifyOptions& o) {
  using namespace topos::nn;
  using namespace topos::nn::ops;
  const auto D = o.hidden;
  OperatorSchedule s;
  for (int r = 0; r <= 2; ++r) s.input("x" + std::to_string(r), r, 1, "x");
  for (const auto& [name, ranks] : std::map<std::string, std::pair<int, int>>{{"L0", {0, 0}},
                                                                              {"L1", {1, 1}},
                                                                              {"L2", {2, 2}},
                                                                              {"B10", {1, 0}},
                                                                              {"B01", {0, 1}},
                                                                              {"B21", {2, 1}},
                                                                              {"B12", {1, 2}}})
    s.operator_input(name, ranks.first, ranks.second);
  s.parallel({into(0).sum(from(0, "x").mlp("enc0", MlpOptions(1, D, D))),
              into(1).sum(from(1, "x").mlp("enc1", MlpOptions(1, D, D))),
              into(2).sum(from(2, "x").mlp("enc2", MlpOptions(1, D, D)))});
  for (int l = 0; l < o.layers; ++l) {
    const std::string i = std::to_string(l);
    s.step(into(1)
               .concat(from(1), from(1).via("L1"), from(0).pattern("B01", Aggr::mean),
                       from(2).pattern("B21", Aggr::mean))
               .mlp("edge" + i, MlpOptions(4 * D, D, D)));
    s.step(into(0)
               .concat(from(0), from(0).via("L0"), from(1).pattern("B10", Aggr::mean))
               .mlp("node" + i, MlpOptions(3 * D, D, D)));
    s.step(into(2)
               .concat(from(2), from(2).via("L2"), from(1).pattern("B12", Aggr::mean))
               .mlp("triangle" + i, MlpOptions(3 * D, D, D)));
  }
  for (int r = 0; r <= 2; ++r) {
    const auto R = std::to_string(r);
    s.step(into(r, "y").sum(
        from(r).mlp("dec" + R, MlpOptions(D, D, D).final_activation(false).layer_norm(false))));
    s.output("y" + R, r, "y");
  }
  return OperatorNetwork(s);
}

/// Per complex, the mean of each rank's decoded rows, ranks side by side: B x 3D.
torch::Tensor readout(const std::map<std::string, torch::Tensor>& y,
                      const topos::nn::ComplexBatch& batch) {
  std::vector<torch::Tensor> parts;
  for (int r = 0; r <= 2; ++r) {
    const auto& h = y.at("y" + std::to_string(r));
    const auto counts = torch::tensor(batch.counts(r), torch::kLong).to(h.scalar_type());
    parts.push_back(torch::zeros({batch.num_complexes(), h.size(1)}, h.options())
                        .index_add(0, batch.batch(r), h) /
                    counts.clamp_min(1).unsqueeze(1));
  }
  return torch::cat(parts, 1);
}

struct Batch {
  topos::nn::ComplexBatch complex;
  std::map<std::string, torch::Tensor> inputs;
  torch::Tensor labels;
};

Batch collate(const std::vector<Sample>& samples, const std::vector<std::size_t>& which) {
  std::vector<topos::nn::ComplexView> views;
  std::map<std::string, std::vector<torch::Tensor>> cols;
  std::vector<std::int64_t> labels;
  for (auto i : which) {
    views.push_back(samples[i].view);
    for (const auto& [k, v] : samples[i].inputs) cols[k].push_back(v);
    labels.push_back(samples[i].label);
  }
  Batch b;
  b.complex = topos::nn::ComplexBatch::collate(views, 2);
  for (auto& [k, v] : cols) b.inputs[k] = torch::cat(v);
  b.labels = torch::tensor(labels, torch::kLong);
  return b;
}

int run_classify(const ClassifyOptions& o) {
  if (o.samples < 6)
    throw std::invalid_argument("tdl classify: --samples " + std::to_string(o.samples) +
                                " leaves a class without training or test clouds (at least 6)");
  torch::manual_seed(o.seed);
  std::mt19937_64 rng(o.seed);
  // Lift every cloud once; a stratified split (the same share of each class held out).
  std::vector<Sample> samples;
  std::vector<std::size_t> train, test;
  topos::ProgressBar lift("lift", o.samples, "complex");
  for (int i = 0; i < o.samples; ++i) {
    samples.push_back(make_sample(i % 3, o, rng));
    lift.update(1);
  }
  lift.finish();
  for (std::size_t i = 0; i < samples.size(); ++i)
    (static_cast<int>(i / 3) < std::lround((1 - o.test_fraction) * (o.samples / 3)) ? train : test)
        .push_back(i);
  std::int64_t cells[3] = {0, 0, 0};
  for (const auto& s : samples)
    for (int r = 0; r <= 2; ++r) cells[r] += s.view.sizes[static_cast<std::size_t>(r)];
  std::cout << "point clouds: " << samples.size() << " (" << train.size() << " training, "
            << test.size() << " test), " << cells[0] << " nodes, " << cells[1] << " edges, "
            << cells[2] << " triangles\n";

  auto net = make_network(o);
  torch::nn::Linear head(3 * o.hidden, 3);
  auto params = net->parameters();
  for (auto& p : head->parameters()) params.push_back(p);
  torch::optim::Adam opt(params, torch::optim::AdamOptions(o.lr));
  std::cout << net->schedule().str();
  const auto test_batch = collate(samples, test);
  const auto accuracy = [&](const Batch& b) {
    torch::NoGradGuard no_grad;
    net->eval(), head->eval();
    return head->forward(readout(net->forward(b.inputs, b.complex), b.complex))
        .argmax(1)
        .eq(b.labels)
        .to(torch::kDouble)
        .mean()
        .item<double>();
  };
  std::ostringstream csv;
  csv << "epoch,loss,train_accuracy,test_accuracy\n";
  std::vector<double> test_curve, train_curve;
  double loss_sum = 0, train_acc = 0;
  topos::ProgressBar bar("classify", o.epochs, "epoch");
  for (int e = 1; e <= o.epochs; ++e) {
    std::shuffle(train.begin(), train.end(), rng);
    loss_sum = 0;
    std::int64_t correct = 0;
    net->train(), head->train();
    for (std::size_t at = 0; at < train.size(); at += static_cast<std::size_t>(o.batch)) {
      const std::vector<std::size_t> which(
          train.begin() + static_cast<std::ptrdiff_t>(at),
          train.begin() + static_cast<std::ptrdiff_t>(
                              std::min(train.size(), at + static_cast<std::size_t>(o.batch))));
      const auto b = collate(samples, which);
      const auto logits = head->forward(readout(net->forward(b.inputs, b.complex), b.complex));
      const auto loss = torch::nn::functional::cross_entropy(logits, b.labels);
      opt.zero_grad();
      loss.backward();
      opt.step();
      loss_sum += loss.item<double>() * static_cast<double>(which.size());
      correct += logits.argmax(1).eq(b.labels).sum().item<std::int64_t>();
    }
    train_acc = static_cast<double>(correct) / static_cast<double>(train.size());
    test_curve.push_back(accuracy(test_batch));
    train_curve.push_back(train_acc);
    const double loss = loss_sum / static_cast<double>(train.size());
    log_epoch(csv, bar, "", e, loss, train_acc, test_curve.back());
  }
  bar.finish();
  const nlohmann::json summary{{"classes", {kClasses[0], kClasses[1], kClasses[2]}},
                               {"train_complexes", train.size()},
                               {"test_complexes", test.size()},
                               {"loss", loss_sum / static_cast<double>(train.size())},
                               {"train_accuracy", train_acc},
                               {"test_accuracy", test_curve.back()}};
  write_task_results(o.out, csv.str(), {{"train", train_curve}, {"test", test_curve}}, "accuracy",
                     summary.dump(2) + "\n");
  return 0;
}

}  // namespace

void register_classify(CLI::App& app, Run& run) {
  auto o = std::make_shared<ClassifyOptions>();
  auto* cmd = app.add_subcommand(
      "classify",
      "classify point clouds by their holes (disk, annulus, two holes): clique complexes of "
      "their radius graphs, batched with ComplexBatch, through a schedule");
  cmd->add_option("--out", o->out, "output folder: accuracy.csv, accuracy.svg, summary.json")
      ->required();
  cmd->add_option("--samples", o->samples, "point clouds in all (a third per class)")
      ->check(CLI::Range(6, 1000000))
      ->capture_default_str();
  cmd->add_option("--points", o->points, "points per cloud")
      ->check(CLI::Range(3, 100000))
      ->capture_default_str();
  cmd->add_option("--radius", o->radius, "radius of the graph (shape radius 1)")
      ->check(CLI::PositiveNumber)
      ->capture_default_str();
  cmd->add_option("--epochs", o->epochs, "training epochs")
      ->check(CLI::Range(1, 100000))
      ->capture_default_str();
  cmd->add_option("--batch", o->batch, "complexes per optimizer step")
      ->check(CLI::Range(1, 100000))
      ->capture_default_str();
  cmd->add_option("--layers", o->layers, "message-passing rounds")
      ->check(CLI::Range(1, 64))
      ->capture_default_str();
  cmd->add_option("--hidden", o->hidden, "hidden channels")
      ->check(CLI::Range(1, 4096))
      ->capture_default_str();
  cmd->add_option("--lr", o->lr, "Adam learning rate")
      ->check(CLI::PositiveNumber)
      ->capture_default_str();
  cmd->add_option("--test-fraction", o->test_fraction, "share of each class held out")
      ->check(CLI::Range(0.05, 0.95))
      ->capture_default_str();
  cmd->add_option("--seed", o->seed, "seed of the clouds, the split and the initial weights")
      ->capture_default_str();
  cmd->callback([o, &run] { run = [o] { return run_classify(*o); }; });
}

}  // namespace tdl_cli
