// Overhead of the operator schedule against the same computation written directly in LibTorch, on a
// HOPNet-sized complex (two meshes of ~180 nodes and ~520 edges, 26 faces in contact, 13 contact
// cells, 128 channels): the HOPNet collision block (faces <- nodes, edges; contacts <- faces by
// role; faces <- contacts by role) and the node/object exchange. Forward, and forward+backward.
// BM_CwnLayer: CWN's layer (16 channels) on an n × n grid of triangles, the case that
// bench/bench_python_schedule.py runs from Python (the same schedule, complex and thread count).
#include <benchmark/benchmark.h>

#include <torch/torch.h>

#include "topos/core/mesh_lifting.hpp"
#include "topos/core/simplicial_complex.hpp"
#include "topos/mesh/primitives.hpp"
#include "topos/nn/operator_schedule.hpp"

using namespace topos;
using namespace topos::nn;
using namespace topos::nn::ops;

namespace {
constexpr int D = 128;

/// The contact cells' second view: the direction (columns 0..2) negated.
struct NegateDirection : Operation {
  std::string str(const std::string& x) const override { return "negate_direction(" + x + ")"; }
  TermShape infer(BuildContext&, TermShape x) const override { return x; }
  torch::Tensor forward(RunContext&, const torch::Tensor& x) const override {
    auto sign = torch::ones({x.size(1)}, x.options());
    sign.slice(0, 0, 3).fill_(-1);
    return x * sign;
  }
};

struct Fixture {
  ComplexBatch batch;
  std::map<std::string, torch::Tensor> inputs;
  OperatorNetwork net{nullptr};

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
    auto m = [](std::int64_t in, std::int64_t out = D) { return MlpOptions(in, D, out); };
    const auto decoder = m(D, 3).final_activation(false).layer_norm(false);
    OperatorSchedule s;
    for (auto& [n, tn] : batch.neighborhoods()) s.operator_input(n, tn.source_rank, tn.target_rank);
    for (auto [name, rank, width] : std::vector<std::tuple<std::string, int, int>>{
             {"x0", 0, 16}, {"x1", 1, 8}, {"x2", 2, 3}, {"x3", 3, 28}, {"x4", 4, 13}})
      s.input(name, rank, width, "x");
    s.parallel(
        {into(0).sum(from(0, "x").mlp("E0", m(16))), into(1).sum(from(1, "x").mlp("E1", m(8))),
         into(2).sum(from(2, "x").mlp("E2", m(3))), into(4).sum(from(4, "x").mlp("E4", m(13))),
         into(3, "minus").sum(from(3, "x").mlp("E3", m(28))),
         into(3, "plus").sum(from(3, "x").apply(NegateDirection()).mlp("E3", m(28)))});
    s.step(into(2)
               .concat(from(2), from(0).mlp("P02", m(D)).pattern("B02"),
                       from(1).mlp("P12", m(D)).pattern("B12"),
                       from(4).mlp("P42", m(D)).pattern("B42"))
               .mlp("P2", m(4 * D)));
    const auto role = [&](int r) { return from(2).mlp("P23", m(D)).pattern("B23").only(r); };
    s.parallel({into(3, "plus").concat(from(3, "plus"), role(-1), role(1)).mlp("P3", m(3 * D)),
                into(3, "minus").concat(from(3, "minus"), role(1), role(-1)).mlp("P3", m(3 * D))});
    s.step(into(2)
               .sum(from(2), from(3, "plus").pattern("B32").only(1),
                    from(3, "minus").pattern("B32").only(-1))
               .mlp("P2p", m(D)));
    s.step(into(4)
               .concat(from(4), from(2).mlp("P24", m(D)).pattern("B24", Aggr::mean))
               .mlp("P4", m(2 * D)));
    s.parallel(
        {into(0).concat(from(0), from(4).mlp("P40", m(D)).pattern("B40")).mlp("P0", m(2 * D)),
         into(4)
             .concat(from(4), from(0).mlp("P04", m(D)).pattern("B04", Aggr::mean))
             .mlp("P4p", m(2 * D))});
    s.step(into(0, "a0").sum(from(0).mlp("D0", decoder)));
    s.step(into(4, "a4").sum(from(4).mlp("D4", decoder)));
    s.output("a0", 0, "a0").output("a4", 4, "a4");
    net = OperatorNetwork(s);
    torch::manual_seed(0);
    inputs = {{"x0", torch::randn({batch.size(0), 16})},
              {"x1", torch::randn({batch.size(1), 8})},
              {"x2", torch::randn({batch.size(2), 3})},
              {"x3", torch::randn({batch.size(3), 28})},
              {"x4", torch::randn({batch.size(4), 13})}};
  }

  // The same computation written directly with the same modules.
  std::map<std::string, torch::Tensor> direct() {
    auto M = [&](const char* n, const torch::Tensor& x) { return net->mlp(n)->forward(x); };
    auto agg = [&](const torch::Tensor& x, const char* n, Aggr r = Aggr::sum, int role = 0) {
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
    auto np = torch::cat({agg(m23, "B23", Aggr::sum, -1), agg(m23, "B23", Aggr::sum, 1)}, 1);
    auto nm = torch::cat({agg(m23, "B23", Aggr::sum, 1), agg(m23, "B23", Aggr::sum, -1)}, 1);
    auto h3p2 = M("P3", torch::cat({h3p, np}, 1)), h3m2 = M("P3", torch::cat({h3m, nm}, 1));
    h2 = M("P2p", h2 + agg(h3p2, "B32", Aggr::sum, 1) + agg(h3m2, "B32", Aggr::sum, -1));
    h4 = M("P4", torch::cat({h4, agg(M("P24", h2), "B24", Aggr::mean)}, 1));
    auto h0n = M("P0", torch::cat({h0, agg(M("P40", h4), "B40")}, 1));
    auto h4n = M("P4p", torch::cat({h4, agg(M("P04", h0), "B04", Aggr::mean)}, 1));
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
/// CWN's layer on the n × n grid of triangles, with grad enabled (as a Python forward runs).
struct CwnGrid {
  OperatorNetwork net{nullptr};
  std::map<std::string, torch::Tensor> inputs;
  std::map<std::string, SparseOperator> operators;

  explicit CwnGrid(std::int64_t n) {
    at::set_num_threads(1);
    std::vector<std::vector<std::int64_t>> t;
    for (std::int64_t i = 0; i < n; ++i)
      for (std::int64_t j = 0; j < n; ++j) {
        const std::int64_t a = i * (n + 1) + j;
        t.push_back({a, a + 1, a + n + 2});
        t.push_back({a, a + n + 2, a + n + 1});
      }
    const auto sc = SimplicialComplex::from_simplices(t);
    operators = {{"adjacency_1", SparseOperator::from_eigen(sc.adjacency_matrix(1))},
                 {"incidence_2", SparseOperator::from_eigen(sc.incidence_matrix(2))},
                 {"incidence_1", SparseOperator::from_eigen(sc.incidence_matrix(1))}};
    constexpr std::int64_t C = 16;
    OperatorSchedule s;
    s.input("x_0", 0, C).input("x_1", 1, C).input("x_2", 2, C);
    s.operator_input("adjacency_1", 1, 1)
        .operator_input("incidence_2", 2, 1)
        .operator_input("incidence_1", 1, 0);
    s.step(into(1)
               .sum(from(1).conv("conv_1_to_1", C).via("adjacency_1").act(Activation::elu),
                    from(2).conv("conv_2_to_1", C).via("incidence_2").act(Activation::elu),
                    from(0).conv("conv_0_to_1", C).via_t("incidence_1").act(Activation::elu))
               .linear("update_fn.transform", C)
               .act(Activation::elu));
    s.output("x_1", 1);
    net = OperatorNetwork(s);
    for (int r = 0; r < 3; ++r)
      inputs["x_" + std::to_string(r)] = torch::randn({sc.num_cells(r), C});
  }
};

static void BM_CwnLayer_Forward(benchmark::State& state) {
  CwnGrid f(state.range(0));
  for (auto _ : state)
    benchmark::DoNotOptimize(f.net->forward(f.inputs, f.operators).at("x_1").data_ptr());
}
static void BM_CwnLayer_ForwardBackward(benchmark::State& state) {
  CwnGrid f(state.range(0));
  for (auto _ : state) f.net->forward(f.inputs, f.operators).at("x_1").square().sum().backward();
}
BENCHMARK(BM_CwnLayer_Forward)->Arg(2)->Arg(60)->Unit(benchmark::kMicrosecond)->MinTime(1);
BENCHMARK(BM_CwnLayer_ForwardBackward)->Arg(2)->Arg(60)->Unit(benchmark::kMicrosecond)->MinTime(1);
BENCHMARK(BM_Forward_DSL)->Unit(benchmark::kMicrosecond)->MinTime(2);
BENCHMARK(BM_Forward_Direct)->Unit(benchmark::kMicrosecond)->MinTime(2);
BENCHMARK(BM_ForwardBackward_DSL)->Unit(benchmark::kMicrosecond)->MinTime(2);
BENCHMARK(BM_ForwardBackward_Direct)->Unit(benchmark::kMicrosecond)->MinTime(2);
BENCHMARK_MAIN();
