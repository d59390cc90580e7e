// Overhead of the schedule DSL against the same computation written directly in LibTorch, on a
// HOPNet-sized complex (two meshes of ~180 nodes and ~520 edges, 26 faces in contact, 13 contact
// cells, 128 channels): the HOPNet collision block (faces <- nodes, edges; contacts <- faces by
// role; faces <- contacts by role) and the node/object exchange. Forward, and forward+backward.
#include <benchmark/benchmark.h>

#include <torch/torch.h>

#include "topos/core/mesh_lifting.hpp"
#include "topos/mesh/primitives.hpp"
#include "topos/nn/schedule.hpp"

using namespace topos;
using namespace topos::nn;
using namespace topos::nn::dsl;

namespace {
constexpr int D = 128;

struct Fixture {
  ComplexBatch batch;
  std::map<std::string, torch::Tensor> inputs;
  ScheduleNetwork net{nullptr};

  Fixture() {
    at::set_num_threads(1);
    auto lifted = lift_meshes({uv_sphere(8, 20), cylinder_mesh(30, 3), box_mesh(3)},
                              LiftOptions().with_faces(false).with_object_rank(4));
    auto& cc = lifted.complex;
    // 13 contacts between faces of object 0 and object 1 (26 distinct faces).
    for (int c = 0; c < 13; ++c) {
      const auto fa = lifted.faces.row(c), fb = lifted.faces.row(lifted.face_offset[1] + c);
      const auto a = cc.add_cell({fa(0), fa(1), fa(2)}, 2).first,
                 b = cc.add_cell({fb(0), fb(1), fb(2)}, 2).first;
      cc.add_cell({fa(0), fa(1), fa(2), fb(0), fb(1), fb(2)}, 3,
                  {{2, a, -1.0, -1}, {2, b, 1.0, 1}});
    }
    ComplexView v;
    v.sizes = cc.shape();
    for (auto [name, s, t] : std::vector<std::tuple<std::string, int, int>>{{"B02", 0, 2},
                                                                            {"B12", 1, 2},
                                                                            {"B42", 4, 2},
                                                                            {"B23", 2, 3},
                                                                            {"B32", 3, 2},
                                                                            {"B24", 2, 4},
                                                                            {"B04", 0, 4},
                                                                            {"B40", 4, 0}})
      v.neighborhoods[name] = incidence_neighborhood(cc, s, t);
    batch = ComplexBatch::collate({v}, 4);
    ScheduleSignature sig;
    for (auto& [n, tn] : batch.neighborhoods())
      sig.neighborhoods[n] = {tn.source_rank, tn.target_rank};
    sig.inputs = {{"x0", 16}, {"x1", 8}, {"x2", 3}, {"x3", 28}, {"x4", 13}};
    Schedule s;
    s.encode(0, "", "x0", "E0")
        .encode(1, "", "x1", "E1")
        .encode(2, "", "x2", "E2")
        .encode(4, "", "x4", "E4")
        .encode(3, "minus", "x3", "E3")
        .encode(3, "plus", "x3", "E3", {}, {0, 1, 2});
    s.step(into(2)
               .msg(from(0).via("B02").map("P02"))
               .msg(from(1).via("B12").map("P12"))
               .msg(from(4).via("B42").map("P42"))
               .update_with("P2"));
    s.parallel(
        {into(3, "plus").msg(from(2).via("B23").map("P23").by_role({-1, 1})).update_with("P3"),
         into(3, "minus").msg(from(2).via("B23").map("P23").by_role({1, -1})).update_with("P3")});
    s.step(into(2)
               .msg(from(3, "plus").via("B32").only(1))
               .msg(from(3, "minus").via("B32").only(-1))
               .combine_with(Combine::sum_self)
               .update_with("P2p"));
    s.step(into(4).msg(from(2).via("B24").map("P24").reduce(Reduce::mean)).update_with("P4"));
    s.parallel(
        {into(0).msg(from(4).via("B40").map("P40")).update_with("P0"),
         into(4).msg(from(0).via("B04").map("P04").reduce(Reduce::mean)).update_with("P4p")});
    s.decode(0, "", "D0", "a0").decode(4, "", "D4", "a4");
    auto m = [](std::int64_t in, std::int64_t out = D) { return MlpOptions(in, D, out); };
    const std::map<std::string, MlpOptions> modules{
        {"E0", m(16)},
        {"E1", m(8)},
        {"E2", m(3)},
        {"E3", m(28)},
        {"E4", m(13)},
        {"P02", m(D)},
        {"P12", m(D)},
        {"P42", m(D)},
        {"P2", m(4 * D)},
        {"P23", m(D)},
        {"P3", m(3 * D)},
        {"P2p", m(D)},
        {"P24", m(D)},
        {"P4", m(2 * D)},
        {"P40", m(D)},
        {"P0", m(2 * D)},
        {"P04", m(D)},
        {"P4p", m(2 * D)},
        {"D0", m(D, 3).final_activation(false).layer_norm(false)},
        {"D4", m(D, 3).final_activation(false).layer_norm(false)}};
    net = ScheduleNetwork(s, modules, sig);
    torch::manual_seed(0);
    inputs = {{"x0", torch::randn({batch.size(0), 16})},
              {"x1", torch::randn({batch.size(1), 8})},
              {"x2", torch::randn({batch.size(2), 3})},
              {"x3", torch::randn({batch.size(3), 28})},
              {"x4", torch::randn({batch.size(4), 13})}};
  }

  // The same computation written directly with the same modules.
  std::map<std::string, torch::Tensor> direct() {
    auto M = [&](const char* n, const torch::Tensor& x) { return net->module(n)->forward(x); };
    auto agg = [&](const torch::Tensor& x, const char* n, Reduce r = Reduce::sum, int role = 0) {
      return aggregate(x, batch.neighborhood(n), AggregateOptions().with_reduce(r).with_role(role));
    };
    auto h0 = M("E0", inputs["x0"]), h1 = M("E1", inputs["x1"]), h2 = M("E2", inputs["x2"]),
         h4 = M("E4", inputs["x4"]);
    auto x3 = inputs["x3"];
    auto sign = torch::ones({28});
    sign.slice(0, 0, 3).fill_(-1);
    auto h3m = M("E3", x3), h3p = M("E3", x3 * sign);
    h2 = M("P2", torch::cat({h2, agg(M("P02", h0), "B02"), agg(M("P12", h1), "B12"),
                             agg(M("P42", h4), "B42")},
                            1));
    auto m23 = M("P23", h2);
    auto np = torch::cat({agg(m23, "B23", Reduce::sum, -1), agg(m23, "B23", Reduce::sum, 1)}, 1);
    auto nm = torch::cat({agg(m23, "B23", Reduce::sum, 1), agg(m23, "B23", Reduce::sum, -1)}, 1);
    auto h3p2 = M("P3", torch::cat({h3p, np}, 1)), h3m2 = M("P3", torch::cat({h3m, nm}, 1));
    h2 = M("P2p", h2 + agg(h3p2, "B32", Reduce::sum, 1) + agg(h3m2, "B32", Reduce::sum, -1));
    h4 = M("P4", torch::cat({h4, agg(M("P24", h2), "B24", Reduce::mean)}, 1));
    auto h0n = M("P0", torch::cat({h0, agg(M("P40", h4), "B40")}, 1));
    auto h4n = M("P4p", torch::cat({h4, agg(M("P04", h0), "B04", Reduce::mean)}, 1));
    return {{"a0", M("D0", h0n)}, {"a4", M("D4", h4n)}};
  }
};

Fixture& fixture() {
  static Fixture f;
  return f;
}
}  // namespace

static void BM_Forward_DSL(benchmark::State& state) {
  auto& f = fixture();
  torch::NoGradGuard g;
  for (auto _ : state)
    benchmark::DoNotOptimize(f.net->forward(f.inputs, f.batch).at("a0").data_ptr());
}
static void BM_Forward_Direct(benchmark::State& state) {
  auto& f = fixture();
  torch::NoGradGuard g;
  for (auto _ : state) benchmark::DoNotOptimize(f.direct().at("a0").data_ptr());
}
static void BM_ForwardBackward_DSL(benchmark::State& state) {
  auto& f = fixture();
  for (auto _ : state) {
    auto out = f.net->forward(f.inputs, f.batch);
    (out.at("a0").sum() + out.at("a4").sum()).backward();
  }
}
static void BM_ForwardBackward_Direct(benchmark::State& state) {
  auto& f = fixture();
  for (auto _ : state) {
    auto out = f.direct();
    (out.at("a0").sum() + out.at("a4").sum()).backward();
  }
}
BENCHMARK(BM_Forward_DSL)->Unit(benchmark::kMicrosecond)->MinTime(2);
BENCHMARK(BM_Forward_Direct)->Unit(benchmark::kMicrosecond)->MinTime(2);
BENCHMARK(BM_ForwardBackward_DSL)->Unit(benchmark::kMicrosecond)->MinTime(2);
BENCHMARK(BM_ForwardBackward_Direct)->Unit(benchmark::kMicrosecond)->MinTime(2);
BENCHMARK_MAIN();
