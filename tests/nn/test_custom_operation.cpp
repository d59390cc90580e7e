// Tests of the operator schedule's extension point (topos/nn/operator_schedule/operation.hpp):
// operations defined here, outside topos, with their parameters, submodules, cochain reads,
// build-time errors, printed form and a hand-written backward; and of what the network does with
// any step: it runs only the steps an output needs, runs named layers alone, refuses attention
// that would score against a stale target, and prints activations by name.
#include "support/torch_prelude.hpp"

#include "support/operator_schedule.hpp"
#include "topos/nn/operator_schedule.hpp"

#include <atomic>
#include <functional>

using namespace topos::nn;
using namespace topos::nn::ops;
using Catch::Matchers::Contains;
using topos::test::build_error;
using topos::test::random_operator;

namespace {

// x ⊙ σ(x W): the header's own example.
struct Gate : Operation {
  std::string path;
  explicit Gate(std::string p) : path(std::move(p)) {}
  std::string str(const std::string& x) const override { return "gate[" + path + "](" + x + ")"; }
  TermShape infer(BuildContext& ctx, TermShape x) const override {
    ctx.parameter(path, {x.channels, x.channels});
    return x;
  }
  torch::Tensor forward(RunContext& ctx, const torch::Tensor& x) const override {
    return x * torch::sigmoid(x.matmul(ctx.parameter(path)));
  }
};

// Widens to `out` channels with a torch::nn::Linear submodule, and adds a cochain it reads.
struct LinearPlus : Operation {
  std::string path;
  std::int64_t out;
  CochainKey plus;
  LinearPlus(std::string p, std::int64_t o, CochainKey k) : path(std::move(p)), out(o), plus(k) {}
  std::string str(const std::string& x) const override {
    return path + "(" + x + ") + " + plus.str();
  }
  TermShape infer(BuildContext& ctx, TermShape x) const override {
    if (ctx.cochain_width(plus) != out) ctx.fail("linear plus: " + plus.str() + " is not as wide");
    ctx.module(path, torch::nn::Linear(x.channels, out).ptr());
    return {x.rank, out};
  }
  torch::Tensor forward(RunContext& ctx, const torch::Tensor& x) const override {
    return ctx.module<torch::nn::LinearImpl>(path).forward(x) + ctx.cochain(plus);
  }
};

// tanh(x) · s with a hand-written backward (a torch::autograd::Function); counts its calls.
std::atomic<int> backward_calls{0};
struct ScaledTanhFunction : torch::autograd::Function<ScaledTanhFunction> {
  static torch::Tensor forward(torch::autograd::AutogradContext* ctx, torch::Tensor x,
                               torch::Tensor s) {
    const auto t = torch::tanh(x);
    ctx->save_for_backward({t, s});
    return t * s;
  }
  static torch::autograd::variable_list backward(torch::autograd::AutogradContext* ctx,
                                                 torch::autograd::variable_list grad) {
    ++backward_calls;
    const auto saved = ctx->get_saved_variables();
    const auto& t = saved[0];
    const auto& s = saved[1];
    return {grad[0] * s * (1 - t * t), (grad[0] * t).sum().reshape(s.sizes())};
  }
};
struct ScaledTanh : Operation {
  std::string path;
  bool hand_written;
  ScaledTanh(std::string p, bool hand) : path(std::move(p)), hand_written(hand) {}
  std::string str(const std::string& x) const override { return "stanh(" + x + ")"; }
  TermShape infer(BuildContext& ctx, TermShape x) const override {
    ctx.parameter(path, {1}, ParameterInit::constant(0.7));
    return x;
  }
  torch::Tensor forward(RunContext& ctx, const torch::Tensor& x) const override {
    const auto& s = ctx.parameter(path);
    return hand_written ? ScaledTanhFunction::apply(x, s) : torch::tanh(x) * s;
  }
};

// Counts its forwards: shows which steps run.
struct Count : Operation {
  std::shared_ptr<std::atomic<int>> calls = std::make_shared<std::atomic<int>>(0);
  std::string str(const std::string& x) const override { return "count(" + x + ")"; }
  TermShape infer(BuildContext&, TermShape x) const override { return x; }
  torch::Tensor forward(RunContext&, const torch::Tensor& x) const override {
    ++*calls;
    return x;
  }
};

}  // namespace

TEST_CASE("a user operation runs in a term like a built-in one", "[nn][schedule][operation]") {
  const auto A = random_operator(6, 6, 1, 0.5);
  torch::manual_seed(2);
  const auto x = torch::randn({6, 4}, torch::kDouble);
  OperatorSchedule s;
  s.input("x", 0, 4).operator_input("A", 0, 0).output("y", 0);
  s.step(into(0).sum(from(0).via("A").apply(Gate("gate")), from(0).apply(Gate("gate"))));
  OperatorNetwork net(s);
  net->to(torch::kDouble);
  REQUIRE(net->named_parameters().size() == 1);  // one path, one shared parameter
  const auto& W = net->parameter("gate");
  CHECK(W.sizes() == torch::IntArrayRef({4, 4}));
  const auto ax = A.to_dense().matmul(x);
  const auto expected = ax * torch::sigmoid(ax.matmul(W)) + x * torch::sigmoid(x.matmul(W));
  const auto y = net->forward({{"x", x}}, {{"A", A}}).at("y");
  CHECK(torch::allclose(y, expected, 1e-12, 1e-12));
  CHECK_THAT(net->schedule().str(), Contains("gate[gate](A·(0))") && Contains("gate[gate]((0))"));
}

TEST_CASE("a user operation makes submodules, reads cochains and names its step in errors",
          "[nn][schedule][operation]") {
  torch::manual_seed(3);
  const auto x = torch::randn({5, 3}, torch::kDouble), z = torch::randn({5, 4}, torch::kDouble);
  OperatorSchedule s;
  s.input("x", 0, 3).input("z", 0, 4, "z").output("y", 0);
  s.step(into(0).sum(from(0).apply(LinearPlus("block.lin", 4, {0, "z"}))).named("widen"));
  OperatorNetwork net(s);
  net->to(torch::kDouble);
  const auto params = net->named_parameters();
  REQUIRE(params.contains("block.lin.weight"));
  REQUIRE(params.contains("block.lin.bias"));
  const auto y = net->forward({{"x", x}, {"z", z}}, {}).at("y");
  CHECK(torch::allclose(
      y, torch::linear(x, params["block.lin.weight"], params["block.lin.bias"]) + z, 1e-12, 1e-12));

  OperatorSchedule bad;
  bad.input("x", 0, 3).input("z", 0, 5, "z").output("y", 0);
  bad.step(into(0).sum(from(0).apply(LinearPlus("lin", 4, {0, "z"}))).named("widen"));
  CHECK_THAT(build_error(bad),
             Contains("widen (into (0)): linear plus: (0, \"z\") is not as wide"));
  OperatorSchedule missing;
  missing.input("x", 0, 3).output("y", 0);
  missing.step(into(0).sum(from(0).apply(LinearPlus("lin", 3, {0, "nowhere"}))));
  CHECK_THAT(build_error(missing),
             Contains("step 0 (into (0)): cochain (0, \"nowhere\") is read, but no input"));
  // One path, two kinds of module: an error naming both.
  struct Other : LinearPlus {
    using LinearPlus::LinearPlus;
    TermShape infer(BuildContext& ctx, TermShape x) const override {
      ctx.module(path, torch::nn::LayerNorm(torch::nn::LayerNormOptions({x.channels})).ptr());
      return x;
    }
  };
  OperatorSchedule clash;
  clash.input("x", 0, 4).input("z", 0, 4, "z").output("y", 0);
  clash.step(into(0).sum(from(0).apply(LinearPlus("m", 4, {0, "z"}))));
  clash.step(into(0).sum(from(0).apply(Other("m", 4, {0, "z"}))));
  CHECK_THAT(build_error(clash), Contains("module 'm' was made torch::nn::Linear"));
  // A module's path is a dotted name, as a parameter's is.
  OperatorSchedule undotted;
  undotted.input("x", 0, 4).input("z", 0, 4, "z").output("y", 0);
  undotted.step(into(0).sum(from(0).apply(LinearPlus("block..lin", 4, {0, "z"}))).named("widen"));
  CHECK_THAT(build_error(undotted),
             Contains("widen (into (0)): module path 'block..lin' is not a dotted name"));
  OperatorSchedule null_op;
  null_op.input("x", 0, 4).output("y", 0);
  null_op.step(into(0).sum(from(0).apply(std::shared_ptr<const Operation>())));
  CHECK_THAT(build_error(null_op), Contains("step 0 (into (0)): a custom operation is null"));
  OperatorSchedule trailing_dot;
  trailing_dot.input("x", 0, 4).output("y", 0);
  trailing_dot.step(into(0).sum(from(0).apply(Gate("gate."))));
  CHECK_THAT(build_error(trailing_dot),
             Contains("step 0 (into (0)): parameter path 'gate.' is not a dotted name"));
}

TEST_CASE("a user operation whose output disagrees with its infer is an error naming the step",
          "[nn][schedule][operation][checks]") {
  // Infers (rank 0, same channels) but returns what `make` makes of x.
  struct Liar : Operation {
    std::function<torch::Tensor(const torch::Tensor&)> make;
    explicit Liar(std::function<torch::Tensor(const torch::Tensor&)> f) : make(std::move(f)) {}
    std::string str(const std::string& x) const override { return "liar(" + x + ")"; }
    TermShape infer(BuildContext&, TermShape x) const override { return x; }
    torch::Tensor forward(RunContext&, const torch::Tensor& x) const override { return make(x); }
  };
  const auto error = [](std::function<torch::Tensor(const torch::Tensor&)> f) {
    OperatorSchedule s;
    s.input("x", 0, 3).output("y", 0);
    s.step(into(0).sum(from(0).apply(Liar(std::move(f)))).named("lie"));
    OperatorNetwork net(s);
    try {
      net->forward({{"x", torch::randn({5, 3})}}, {});
    } catch (const ScheduleError& e) {
      return std::string(e.what());
    }
    return std::string();
  };
  CHECK(error([](const torch::Tensor& x) { return x * 2; }).empty());
  const std::string fix =
      "make forward return that, or infer return the rank and channels forward makes";
  CHECK_THAT(error([](const torch::Tensor& x) { return x.narrow(1, 0, 2); }),
             Contains("lie (into (0)): operation liar(x) returns [5, 2] float32, but its infer "
                      "said rank 0 with 3 channels, so [5, 3] float32: " +
                      fix));
  CHECK_THAT(error([](const torch::Tensor& x) { return x.narrow(0, 0, 4); }),
             Contains("returns [4, 3] float32") && Contains("so [5, 3] float32"));
  CHECK_THAT(error([](const torch::Tensor& x) { return x.to(torch::kDouble); }),
             Contains("returns [5, 3] float64") && Contains("so [5, 3] float32"));
}

TEST_CASE("a user operation's hand-written backward gives autograd's gradients",
          "[nn][schedule][operation]") {
  const auto A = random_operator(7, 7, 4, 0.5);
  torch::manual_seed(5);
  const auto x = torch::randn({7, 3}, torch::kDouble);
  std::vector<torch::Tensor> grads;
  for (bool hand : {false, true}) {
    torch::manual_seed(6);
    OperatorSchedule s;
    s.input("x", 0, 3).operator_input("A", 0, 0).output("y", 0);
    s.step(into(0).sum(from(0).via("A").weight("w", 3).apply(ScaledTanh("s", hand))));
    OperatorNetwork net(s);
    net->to(torch::kDouble);
    const int before = backward_calls;
    net->forward({{"x", x}}, {{"A", A}}).at("y").pow(2).sum().backward();
    CHECK(backward_calls - before == (hand ? 1 : 0));
    grads.push_back(net->parameter("w").grad().clone());
    grads.push_back(net->parameter("s").grad().clone());
  }
  CHECK(torch::allclose(grads[0], grads[2], 1e-12, 1e-12));
  CHECK(torch::allclose(grads[1], grads[3], 1e-12, 1e-12));
  CHECK(grads[1].abs().item<double>() > 0);
}

TEST_CASE("forward runs only the steps an output needs; run_layer runs a named layer whole",
          "[nn][schedule]") {
  Count live, dead, query;
  OperatorSchedule s;
  s.input("x", 0, 2).operator_input("A", 0, 0).output("y", 0);
  s.layer("first").step(into(0, "unused").sum(from(0).apply(dead)));
  s.step(into(0, "q").sum(from(0).apply(query)));  // read only as attention queries below
  s.layer("second").step(into(0).sum(
      from(0).apply(live).attend("A", AttendOptions("att").queries(CochainKey{0, "q"}))));
  OperatorNetwork net(s);
  const auto A = SparseOperator::from_dense(torch::ones({3, 3}));
  const auto x = torch::randn({3, 2});
  net->forward({{"x", x}}, {{"A", A}});
  CHECK(*live.calls == 1);
  CHECK(*query.calls == 1);  // kept: a live step reads its result
  CHECK(*dead.calls == 0);   // nothing reads (0, "unused")
  auto h = net->input_cochains({{"x", x}});
  net->run_layer(h, {{"A", A}}, "first");  // a layer runs whole: what it leaves is the caller's
  CHECK(*dead.calls == 1);
  CHECK(*query.calls == 2);
  CHECK(*live.calls == 1);
  CHECK(h.has(0, "unused"));
  CHECK_THROWS_WITH(net->run_layer(h, {{"A", A}}, "third"),
                    Contains("no layer 'third'") && Contains("first, second"));
  const auto text = net->schedule().str();
  CHECK_THAT(text, Contains("layer first:\n") && Contains("layer second:\n"));
  OperatorSchedule twice;
  twice.input("x", 0, 2).output("y", 0);
  twice.layer("a").step(into(0).sum(from(0))).layer("a").step(into(0).sum(from(0)));
  CHECK_THAT(build_error(twice), Contains("layer 'a' is declared twice"));
}

TEST_CASE("attention that would score against a stale target is an error when built",
          "[nn][schedule]") {
  // Each layer writes (0, "msg") from edge messages scored against the target's default
  // queries: in the first layer there is no (0, "msg"); in the second it would be the first
  // layer's leftover. Both are errors, the second naming the fix.
  OperatorSchedule s;
  s.input("x_0", 0, 2).input("x_1", 1, 2).operator_input("B", 1, 0).output("y", 0);
  s.step(into(0, "msg").sum(from(0)));
  s.step(into(0, "msg").sum(from(1).attend("B", AttendOptions("att"))));
  CHECK_THAT(build_error(s), Contains("step 1 (into (0, \"msg\")): attention over 'B' scores "
                                      "against the target (0, \"msg\") as it was before the "
                                      "step, but no term of the step reads it") &&
                                 Contains("AttendOptions::queries"));
  // Reading the target (an update in place) or naming the queries is fine.
  OperatorSchedule in_place;
  in_place.input("x_0", 0, 2).input("x_1", 1, 2).operator_input("B", 1, 0).output("y", 0);
  in_place.step(into(0).sum(from(0), from(1).attend("B", AttendOptions("att"))));
  CHECK(build_error(in_place).empty());
  OperatorSchedule named;
  named.input("x_0", 0, 2).input("x_1", 1, 2).operator_input("B", 1, 0).output("y", 0, "msg");
  named.step(
      into(0, "msg").sum(from(1).attend("B", AttendOptions("att").queries(CochainKey{0, ""}))));
  CHECK(build_error(named).empty());
}

TEST_CASE("a schedule prints activations by name", "[nn][schedule]") {
  OperatorSchedule s;
  s.input("x", 0, 2).output("y", 0);
  s.step(into(0).sum(from(0).act(Update::relu)).act(Update::leaky_relu));
  const auto text = s.str();
  CHECK_THAT(text, Contains("leaky_relu(sum[relu((0))])"));
  CHECK(text.find("act") == std::string::npos);
}
