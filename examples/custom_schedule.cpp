// A message-passing network that is not HOPNet, written as a topos operator schedule: on the built-
// in meshes (randomly scaled and rotated), learn the area of every face from its nodes' positions
// and its edges' vectors, with one round of face <- (nodes, edges) and face <- faces messages.
// Trains for a few seconds and prints the loss as it falls.
#include <torch/torch.h>

#include "topos/core/mesh_lifting.hpp"
#include "topos/mesh/primitives.hpp"
#include "topos/mesh/rigid.hpp"
#include "topos/nn/operator_schedule.hpp"

#include <chrono>
#include <iostream>
#include <random>

using namespace topos;
using namespace topos::nn;
using namespace topos::nn::ops;

struct Sample {
  ComplexView view;
  std::map<std::string, torch::Tensor> inputs;
  torch::Tensor target;  // face areas
};

Sample make_sample(std::mt19937& rng) {
  std::uniform_real_distribution<double> u(-1, 1);
  const char* shapes[] = {"sphere", "cube", "cylinder"};
  TriangleMesh m = builtin_shape(shapes[rng() % 3]);
  m.vertices = pose_vertices(m.vertices * (1.0 + 0.5 * u(rng)), Eigen::Vector3d::Zero(),
                             Eigen::Vector4d(u(rng), u(rng), u(rng), u(rng)));
  auto lifted = lift_meshes({m}, LiftOptions().with_object_rank(0));
  const auto& cc = lifted.complex;
  Sample s;
  s.view.sizes = cc.shape();
  s.view.neighborhoods["B02"] = incidence_neighborhood(cc, 0, 2);
  s.view.neighborhoods["B12"] = incidence_neighborhood(cc, 1, 2);
  s.view.neighborhoods["A21"] = adjacency_neighborhood(cc, 2, 1);  // faces sharing an edge
  auto x0 = torch::from_blob(m.vertices.data(), {m.num_vertices(), 3}, torch::kDouble)
                .to(torch::kFloat)
                .clone();
  std::vector<float> e, area;
  for (const auto& [a, b] : lifted.edges) {
    const Eigen::Vector3d d = m.vertices.row(a) - m.vertices.row(b);
    e.insert(e.end(), {float(d.x()), float(d.y()), float(d.z()), float(d.norm())});
  }
  for (Eigen::Index f = 0; f < m.faces.rows(); ++f)
    area.push_back(
        float(0.5 * (m.vertices.row(m.faces(f, 1)) - m.vertices.row(m.faces(f, 0)))
                        .cross(m.vertices.row(m.faces(f, 2)) - m.vertices.row(m.faces(f, 0)))
                        .norm()));
  s.inputs = {
      {"x0", x0}, {"x1", torch::tensor(e).view({-1, 4})}, {"x2", torch::ones({m.num_faces(), 1})}};
  s.target = torch::tensor(area).view({-1, 1}) * 10;  // areas of order 1
  return s;
}

int main() {
  at::set_num_threads(1);
  torch::manual_seed(0);
  const int D = 32;
  auto mlp = [&](std::int64_t in, std::int64_t out) { return MlpOptions(in, D, out); };
  OperatorSchedule s;
  s.input("x0", 0, 3, "x").input("x1", 1, 4, "x").input("x2", 2, 1, "x");  // (rank, "x")
  s.operator_input("B02", 0, 2).operator_input("B12", 1, 2).operator_input("A21", 2, 2);
  s.parallel({into(0).sum(from(0, "x").mlp("enc0", mlp(3, D))),  // encoders: (r) from (r, "x")
              into(1).sum(from(1, "x").mlp("enc1", mlp(4, D))),
              into(2).sum(from(2, "x").mlp("enc2", mlp(1, D)))});
  s.step(into(2)  // [h2, Σ_B02 phi02(h0), Σ_B12 phi12(h1)] -> face_update
             .concat(from(2), from(0).mlp("phi02", mlp(D, D)).pattern("B02"),
                     from(1).mlp("phi12", mlp(D, D)).pattern("B12"))
             .mlp("face_update", mlp(3 * D, D)));
  s.step(into(2)  // [h2, mean over the faces sharing an edge] -> face_smooth
             .concat(from(2), from(2).pattern("A21", Aggr::mean))
             .mlp("face_smooth", mlp(2 * D, D)));
  s.step(into(2, "area").sum(
      from(2).mlp("area", mlp(D, 1).final_activation(false).layer_norm(false))));
  s.output("area", 2, "area");
  OperatorNetwork net(s);  // checked here: ranks, widths, every mlp's input
  std::cout << s.str();
  std::mt19937 rng(1);
  torch::optim::Adam opt(net->parameters(), torch::optim::AdamOptions(3e-3));
  const auto t0 = std::chrono::steady_clock::now();
  double seconds = 0, smoothed = -1;
  for (int it = 1; seconds < 8.0; ++it) {
    std::vector<Sample> samples;
    for (int k = 0; k < 8; ++k) samples.push_back(make_sample(rng));
    std::vector<ComplexView> views;
    std::map<std::string, std::vector<torch::Tensor>> cols;
    std::vector<torch::Tensor> targets;
    for (auto& smp : samples) {
      views.push_back(smp.view);
      for (auto& [k, v] : smp.inputs) cols[k].push_back(v);
      targets.push_back(smp.target);
    }
    const auto batch = ComplexBatch::collate(views, 2);
    std::map<std::string, torch::Tensor> inputs;
    for (auto& [k, v] : cols) inputs[k] = torch::cat(v);
    const auto loss = torch::mse_loss(net->forward(inputs, batch).at("area"), torch::cat(targets));
    opt.zero_grad();
    loss.backward();
    opt.step();
    smoothed = smoothed < 0 ? loss.item<double>() : 0.9 * smoothed + 0.1 * loss.item<double>();
    seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    if (it % 25 == 0)
      std::cout << "iteration " << it << "  loss " << smoothed << "  (" << seconds << " s)\n";
  }
  std::cout << "final loss " << smoothed << "\n";
  return 0;
}
