// Tests of the operator schedule (topos/nn/operator_schedule.hpp): its steps against dense
// products written out by hand, parameters created at TopoModelX's paths with inferred shapes,
// parallel groups reading one snapshot, and every error of a bad schedule named by its step when
// the network is built (and bad operators when it runs).
#include "support/torch_prelude.hpp"

#include "topos/models/zoo.hpp"
#include "topos/nn/operator_schedule.hpp"

#include <set>

using namespace topos;
using namespace topos::nn;
using namespace topos::nn::ops;
using Catch::Matchers::Contains;

namespace {

SparseOperator dense_operator(std::int64_t rows, std::int64_t cols, int seed) {
  torch::manual_seed(seed);
  auto d = torch::randn({rows, cols}, torch::kDouble) *
           (torch::rand({rows, cols}, torch::kDouble) < 0.4).to(torch::kDouble);
  return SparseOperator::from_dense(d);
}

std::set<std::string> parameter_names(const torch::nn::Module& m) {
  std::set<std::string> out;
  for (const auto& p : m.named_parameters()) out.insert(p.key());
  return out;
}

// The error message of building `s`, or "" when it builds.
std::string build_error(const OperatorSchedule& s) {
  try {
    OperatorNetwork net(s);
  } catch (const ScheduleError& e) {
    return e.what();
  }
  return "";
}

}  // namespace

TEST_CASE("an operator schedule computes its terms, mix and tail as written", "[nn][schedule]") {
  // Nodes (5, 3 channels), edges (7, 2 channels); B: nodes × edges, L: nodes × nodes.
  const auto B = dense_operator(5, 7, 1), L = dense_operator(5, 5, 2);
  torch::manual_seed(3);
  const auto x0 = torch::randn({5, 3}, torch::kDouble), x1 = torch::randn({7, 2}, torch::kDouble);
  OperatorSchedule s;
  s.input("x_0", 0, 3).input("x_1", 1, 2).operator_input("B", 1, 0).operator_input("L", 0, 0);
  s.step(into(0)
             .sum(from(0).conv("layer.a", 4).via("L").act(Update::relu),
                  from(1).via("B").linear("layer.b", 4))
             .weight("layer.c", 2, 1.0)
             .act(Update::tanh)
             .named("mix"));
  s.step(into(1).filter("layer.filter", 3, from(0).via_t("B").powers({{"S", 0}}),
                        from(1).powers({{"T", 2}})));
  s.operator_input("S", 1, 1).operator_input("T", 1, 1);
  s.output("y_0", 0).output("y_1", 1);
  OperatorNetwork net(s);
  net->to(torch::kDouble);
  CHECK(parameter_names(*net) == std::set<std::string>{"layer.a.weight", "layer.b.weight",
                                                       "layer.b.bias", "layer.c", "layer.filter"});
  CHECK(net->parameter("layer.a.weight").sizes() == torch::IntArrayRef({3, 4}));
  CHECK(net->parameter("layer.b.weight").sizes() == torch::IntArrayRef({4, 2}));
  CHECK(net->parameter("layer.filter").sizes() == torch::IntArrayRef({2, 3, 1 + 3}));
  const auto T = dense_operator(7, 7, 4);
  auto out = net->forward({{"x_0", x0}, {"x_1", x1}}, {{"B", B}, {"L", L}, {"S", T}, {"T", T}});

  // By hand with dense matrices.
  const auto Bd = B.to_dense(), Ld = L.to_dense(), Td = T.to_dense();
  const auto& W = [&](const char* n) { return net->parameter(n); };
  auto y0 = torch::relu(Ld.mm(x0.mm(W("layer.a.weight")))) +
            torch::linear(Bd.mm(x1), W("layer.b.weight"), W("layer.b.bias"));
  y0 = torch::tanh(y0.mm(W("layer.c")));
  CHECK(torch::allclose(out.at("y_0"), y0, 1e-12, 1e-12));
  const auto F = W("layer.filter");
  const auto t0 = Bd.t().mm(y0);
  const auto y1 = t0.mm(F.select(2, 0)) + x1.mm(F.select(2, 1)) + Td.mm(x1).mm(F.select(2, 2)) +
                  Td.mm(Td.mm(x1)).mm(F.select(2, 3));
  CHECK(torch::allclose(out.at("y_1"), y1, 1e-12, 1e-12));
  CHECK_THAT(s.str(), Contains("mix: (0) = "));
}

TEST_CASE("a parallel group reads one snapshot; a path used twice is one parameter",
          "[nn][schedule]") {
  const auto A = dense_operator(4, 4, 5);
  torch::manual_seed(6);
  const auto x = torch::randn({4, 2}, torch::kDouble), y = torch::randn({4, 2}, torch::kDouble);
  OperatorSchedule s;
  s.input("x", 0, 2).input("y", 0, 2, "other").operator_input("A", 0, 0);
  s.parallel({into(0).sum(from(0, "other").conv("shared", 2).via("A")),
              into(0, "other").sum(from(0).conv("shared", 2).via("A"))});
  s.output("x", 0).output("y", 0, "other");
  OperatorNetwork net(s);
  net->to(torch::kDouble);
  CHECK(parameter_names(*net) == std::set<std::string>{"shared.weight"});
  const auto W = net->parameter("shared.weight");
  const auto out = net->forward({{"x", x}, {"y", y}}, {{"A", A}});
  CHECK(torch::allclose(out.at("x"), A.to_dense().mm(y.mm(W)), 1e-12, 1e-12));
  CHECK(torch::allclose(out.at("y"), A.to_dense().mm(x.mm(W)), 1e-12, 1e-12));
}

TEST_CASE("attention in a schedule: TopoModelX's Conv with att, and a per-target softmax",
          "[nn][schedule][attention]") {
  const auto A = dense_operator(5, 7, 7);  // edges (7) -> nodes (5)
  torch::manual_seed(8);
  const auto x0 = torch::randn({5, 4}, torch::kDouble), x1 = torch::randn({7, 4}, torch::kDouble);
  OperatorSchedule s;
  s.input("x_0", 0, 4).input("x_1", 1, 4).input("x_0_soft", 0, 4, "soft");
  s.operator_input("A", 1, 0);
  s.step(into(0).sum(from(1).attend("A", "conv.att_weight").conv("conv", 3)));
  s.step(into(0, "soft").sum(
      from(1).attend("A", "att", Update::leaky_relu, AttentionNorm::softmax, 0.2)));
  s.output("y", 0).output("soft", 0, "soft");
  OperatorNetwork net(s);
  net->to(torch::kDouble);
  Conv conv(ConvOptions(4, 3).att(true));
  conv->to(torch::kDouble);
  {
    torch::NoGradGuard g;
    conv->weight.copy_(net->parameter("conv.weight"));
    conv->att_weight.copy_(net->parameter("conv.att_weight"));
  }
  const auto out = net->forward({{"x_0", x0}, {"x_1", x1}, {"x_0_soft", x0}}, {{"A", A}});
  CHECK(torch::allclose(out.at("y"), conv->forward(x1, A, x0), 1e-10, 1e-12));
  // Softmax over each node's incoming entries of leaky_relu(a_s·x_j + a_t·x0_i), by hand.
  const auto a = net->parameter("att");
  const auto D = A.to_dense();
  const auto scores = torch::leaky_relu(
      x1.matmul(a.narrow(0, 0, 4)).unsqueeze(0) + x0.matmul(a.narrow(0, 4, 4)).unsqueeze(1), 0.2);
  const auto masked = torch::where(D != 0, scores, torch::full_like(scores, -INFINITY));
  auto weights = torch::softmax(masked, 1);
  weights = torch::where(torch::isnan(weights), torch::zeros_like(weights), weights);
  CHECK(torch::allclose(out.at("soft"), (weights * D).mm(x1), 1e-10, 1e-12));
}

TEST_CASE("a bad operator schedule is an error naming its step", "[nn][schedule]") {
  auto base = [] {
    OperatorSchedule s;
    s.input("x_0", 0, 3).input("x_1", 1, 2).operator_input("B", 1, 0).operator_input("L", 0, 0);
    return s;
  };
  {
    auto s = base();
    s.step(into(0).sum(from(0).via("M")).named("layer 3"));
    CHECK_THAT(build_error(s), Contains("layer 3") && Contains("unknown operator 'M'"));
  }
  {
    auto s = base();
    s.step(into(0).sum(from(0).via("B")));
    CHECK_THAT(build_error(s), Contains("step 0") && Contains("operator 'B' applies to rank 1"));
  }
  {
    auto s = base();
    s.step(into(0).sum(from(0).conv("a", 4), from(1).via("B")).named("mix"));
    CHECK_THAT(build_error(s), Contains("mix") && Contains("has 2 channels, the one before has 4"));
  }
  {
    auto s = base();
    s.step(into(0).sum(from(1)));
    CHECK_THAT(build_error(s), Contains("ends on rank 1, the target is rank 0"));
  }
  {
    auto s = base();
    s.step(into(0).sum(from(0).conv("a", 4)));
    s.step(into(0).sum(from(0).conv("a", 4)).named("again"));
    CHECK_THAT(build_error(s), Contains("again") && Contains("parameter 'a.weight'"));
  }
  {
    auto s = base();
    s.step(into(0).sum(from(0, "missing")));
    CHECK_THAT(build_error(s), Contains("source (0, \"missing\") has no cochain"));
  }
  {
    auto s = base();
    s.step(into(0).sum(from(0).powers({{"L", 2}})));
    CHECK_THAT(build_error(s), Contains("need a filter weight"));
  }
  {
    auto s = base();
    s.step(into(0).filter("w", 3, from(0).powers({{"B", 2}})));
    CHECK_THAT(build_error(s), Contains("filter operator 'B' must map rank 0 to itself"));
  }
  {
    auto s = base();
    s.parallel({into(0).sum(from(0)), into(0).sum(from(1).via("B"))});
    CHECK_THAT(build_error(s), Contains("another step of the same parallel group writes (0)"));
  }
  {
    auto s = base();
    s.step(into(0).sum(from(0)).initial_residual({1, ""}, 0.1, 0.5, "lin"));
    CHECK_THAT(build_error(s), Contains("residual cochain (1)"));
  }
  {
    auto s = base();
    s.step(into(0, "new").sum(from(1).attend("B", "att")));
    CHECK_THAT(build_error(s), Contains("scores against the target (0, \"new\")"));
  }
  {
    auto s = base();
    s.output("y", 2);
    CHECK_THAT(build_error(s), Contains("output 'y': no cochain (2)"));
  }
  // At run time: a missing input or operator, an operator of the wrong size.
  auto s = base();
  s.step(into(0).sum(from(1).via("B")).named("gather"));
  s.output("y", 0);
  OperatorNetwork net(s);
  const auto x0 = torch::randn({5, 3}), x1 = torch::randn({7, 2});
  const auto B = SparseOperator::from_dense(torch::ones({5, 7}));
  CHECK_THROWS_WITH(net->forward({{"x_0", x0}}, {{"B", B}}), Contains("input 'x_1'"));
  CHECK_THROWS_WITH(net->forward({{"x_0", x0}, {"x_1", x1}}, {}),
                    Contains("gather") && Contains("operator 'B' was not given"));
  CHECK_THROWS_WITH(net->forward({{"x_0", x0}, {"x_1", x1.narrow(0, 0, 6)}}, {{"B", B}}),
                    Contains("gather") && Contains("'B' has 7 columns") && Contains("6 rows"));
  CHECK_THROWS_WITH(net->forward({{"x_0", x0}, {"x_1", torch::randn({7, 3})}}, {{"B", B}}),
                    Contains("input 'x_1' must be (cells × 2)"));
}

TEST_CASE("the zoo's schedules create TopoModelX's parameter names and shapes",
          "[nn][schedule][models]") {
  models::SCN2 scn2(models::SCN2Options(3, 4, 5).n_layers(2));
  std::set<std::string> expected;
  for (int l = 0; l < 2; ++l)
    for (int r = 0; r < 3; ++r)
      expected.insert("layers." + std::to_string(l) + ".conv_" + std::to_string(r) + "_to_" +
                      std::to_string(r) + ".weight");
  CHECK(parameter_names(*scn2) == expected);
  CHECK(scn2->parameter("layers.1.conv_2_to_2.weight").sizes() == torch::IntArrayRef({5, 5}));

  models::CWN cwn(models::CWNOptions(3, 4, 5, 8, 1));
  CHECK(parameter_names(*cwn) ==
        std::set<std::string>{
            "proj_0.weight", "proj_0.bias", "proj_1.weight", "proj_1.bias", "proj_2.weight",
            "proj_2.bias", "layers.0.conv_1_to_1.conv_1_to_1.weight",
            "layers.0.conv_1_to_1.conv_2_to_1.weight", "layers.0.conv_0_to_1.conv_0_to_1.weight",
            "layers.0.update_fn.transform.weight", "layers.0.update_fn.transform.bias"});

  // SCCNN: 2 + 2K, 3 + 4K and (sc_order 3) 2 + 3K filter terms per rank.
  models::SCCNN sccnn(models::SCCNNOptions({3, 4, 5}, {6, 6, 6}, 2, 3).n_layers(1));
  CHECK(sccnn->parameter("layers.0.weight_0").sizes() == torch::IntArrayRef({6, 6, 6}));
  CHECK(sccnn->parameter("layers.0.weight_1").sizes() == torch::IntArrayRef({6, 6, 11}));
  CHECK(sccnn->parameter("layers.0.weight_2").sizes() == torch::IntArrayRef({6, 6, 8}));
  CHECK_THAT(sccnn->schedule().str(), Contains("parallel {"));
}
