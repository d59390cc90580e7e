// Tests of the operator schedule's extension point (topos/nn/operator_schedule/operation.hpp):
// operations defined here, outside topos, with their parameters, submodules, cochain reads,
// build-time errors, printed form and a hand-written backward; and of what the network does with
// any step: it runs only the steps an output needs, runs named layers alone, refuses attention
// that would score against a stale target, and prints activations by name.
#include "support/torch_prelude.hpp"

#include "support/operator_schedule.hpp"
#include "topos/nn/operator_schedule.hpp"

#include <atomic>
#include <chrono>
#include <optional>
#include <thread>

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

TEST_CASE("forward runs only the steps an output needs, and run_layer runs a named layer whole",
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
  s.step(into(0).sum(from(0).act(Activation::relu)).act(Activation::leaky_relu));
  const auto text = s.str();
  CHECK_THAT(text, Contains("leaky_relu(sum[relu((0))])"));
  CHECK(text.find("act") == std::string::npos);
}

namespace {

// x ⊙ σ(x W) again, recording the rows of each call; `declared` says it is row-wise.
struct RowGate : Operation {
  std::string path;
  bool declared;
  std::shared_ptr<std::vector<std::int64_t>> rows = std::make_shared<std::vector<std::int64_t>>();
  RowGate(std::string p, bool d) : path(std::move(p)), declared(d) {}
  std::string str(const std::string& x) const override { return "rowgate(" + x + ")"; }
  TermShape infer(BuildContext& ctx, TermShape x) const override {
    ctx.parameter(path, {x.channels, x.channels});
    return x;
  }
  torch::Tensor forward(RunContext& ctx, const torch::Tensor& x) const override {
    rows->push_back(x.size(0));
    return x * torch::sigmoid(x.matmul(ctx.parameter(path)));
  }
  OperationTraits traits() const override {
    OperationTraits t;
    t.row_wise = declared;
    return t;
  }
};

// A batch of one complex: 6 nodes, 4 edges, 2 faces; the nodes-to-edges pairs read nodes 0-2
// only, the nodes-to-faces pairs nodes 1-3: nodes 4 and 5 send nothing.
ComplexBatch small_batch() {
  ComplexView v;
  v.sizes = {6, 4, 2};
  topos::Neighborhood n01;
  n01.name = "N01", n01.source_rank = 0, n01.target_rank = 1;
  n01.source = {0, 1, 1, 2, 2, 0}, n01.target = {0, 0, 1, 1, 2, 3};
  n01.num_source = 6, n01.num_target = 4;
  topos::Neighborhood n02 = n01;
  n02.name = "N02", n02.target_rank = 2;
  n02.source = {1, 2, 3, 3}, n02.target = {0, 0, 1, 0};
  n02.num_target = 2;
  v.neighborhoods = {{"N01", n01}, {"N02", n02}};
  return ComplexBatch::collate({v}, 2);
}

}  // namespace

TEST_CASE("a user operation declared row-wise takes the row-wise fast paths, with the same numbers",
          "[nn][schedule][operation]") {
  const auto batch = small_batch();
  torch::manual_seed(8);
  const auto x = torch::randn({6, 3}, torch::kDouble);
  struct Run {
    torch::Tensor y1, y2, grad;
    std::vector<std::int64_t> rows;  // of each call of the gate
  };
  // compact: the gate writes (0, "h"), which only the aggregations read; else the gate is the
  // prefix of both aggregations' terms.
  const auto run = [&](bool compact, bool declared, bool fast) {
    auto gate = std::make_shared<RowGate>("gate", declared);
    OperatorSchedule s;
    s.input("x", 0, 3).operator_input("N01", 0, 1).operator_input("N02", 0, 2);
    if (compact) {
      s.step(into(0, "h").sum(from(0).apply(gate)));
      s.parallel({into(1).sum(from(0, "h").pattern("N01")),
                  into(2).sum(from(0, "h").pattern("N02", Aggr::mean))});
    } else {
      s.parallel({into(1).sum(from(0).apply(gate).pattern("N01")),
                  into(2).sum(from(0).apply(gate).pattern("N02", Aggr::mean))});
    }
    s.output("y1", 1).output("y2", 2);
    torch::manual_seed(9);
    OperatorNetwork net(s);
    net->to(torch::kDouble);
    net->set_fast_paths(fast);
    const auto out = net->forward({{"x", x}}, batch);
    (out.at("y1").pow(2).sum() + out.at("y2").sum()).backward();
    return Run{out.at("y1").detach(), out.at("y2").detach(), net->parameter("gate").grad().clone(),
               *gate->rows};
  };
  using Rows = std::vector<std::int64_t>;
  for (bool compact : {false, true}) {
    INFO((compact ? "a compact step" : "a row-wise prefix"));
    const auto plain = run(compact, false, false);
    const auto fast = run(compact, true, true);
    // Declared: each aggregation's prefix on the 3 nodes it reads, or the compact step on the 4
    // that some aggregation reads. Undeclared, or without fast paths: every node.
    CHECK(fast.rows == (compact ? Rows{4} : Rows{3, 3}));
    CHECK(plain.rows == (compact ? Rows{6} : Rows{6, 6}));
    CHECK(run(compact, false, true).rows == plain.rows);
    CHECK(run(compact, true, false).rows == plain.rows);
    CHECK(torch::allclose(fast.y1, plain.y1, 1e-12, 1e-12));
    CHECK(torch::allclose(fast.y2, plain.y2, 1e-12, 1e-12));
    CHECK(torch::allclose(fast.grad, plain.grad, 1e-12, 1e-12));
    CHECK(fast.grad.abs().sum().item<double>() > 0);
    // The sums written out: edge 0 hears nodes 0 and 1, face 0 the mean of nodes 1, 2 and 3.
    torch::manual_seed(9);
    OperatorSchedule one;
    one.input("x", 0, 3).output("y", 0);
    one.step(into(0).sum(from(0).apply(RowGate("gate", false))));
    OperatorNetwork net(one);
    net->to(torch::kDouble);
    const auto g = net->forward({{"x", x}}, {}).at("y").detach();
    CHECK(torch::allclose(plain.y1[0], g[0] + g[1], 1e-12, 1e-12));
    CHECK(torch::allclose(plain.y2[0], (g[1] + g[2] + g[3]) / 3, 1e-12, 1e-12));
  }
}

TEST_CASE("a plan over a batch: compact steps, a split first layer, FLOPs on the pairs",
          "[nn][schedule][plan]") {
  const auto batch = small_batch();  // 6 nodes, 4 edges, 2 faces; N01: 6 pairs, N02: 4
  OperatorSchedule s;
  s.input("x", 0, 3).input("e", 1, 2).operator_input("N01", 0, 1).operator_input("N02", 0, 2);
  s.step(into(0, "h").sum(from(0).linear("lift", 4)).named("lift"));
  s.step(into(1).concat(from(1), from(0, "h").via("N01")).mlp("m", MlpOptions(6, 8, 2)).named("e"));
  s.step(into(2).sum(from(0).linear("g", 2).pattern("N02", Aggr::mean)).named("f"));
  s.output("y1", 1).output("y2", 2);
  torch::manual_seed(3);
  OperatorNetwork net(s);
  net->to(torch::kDouble);
  const std::map<std::string, torch::Tensor> in{{"x", torch::randn({6, 3}, torch::kDouble)},
                                                {"e", torch::randn({4, 2}, torch::kDouble)}};
  const auto p = net->plan(in, batch);
  INFO(p.str());
  CHECK(p.over_batch);
  const auto& lift = p.groups[0][0];
  const auto& e = p.groups[1][0];
  const auto& f = p.groups[2][0];
  // (0, "h") is read by N01's aggregation alone: computed on the nodes N01 reads.
  CHECK(lift.route == StepRoute::chain);
  CHECK(lift.compact_readers == std::vector<std::string>{"N01"});
  CHECK(e.route == StepRoute::split_first_layer);
  CHECK(f.route == StepRoute::general);
  REQUIRE(f.terms.size() == 1);
  CHECK(f.terms[0].neighborhood == "N02");
  CHECK(f.terms[0].row_wise_prefix == 1);
  CHECK_FALSE(f.terms[0].prefix_key.empty());
  CHECK_THAT(p.str(),
             Contains("step lift (into (0, \"h\"), group 0): chain, on the rows that N01 read"));
  CHECK_THAT(p.str(), Contains("sparse 2·6·4  48 FLOPs"));
  // The same FLOPs as the plain plan over operators of the neighbourhoods' patterns.
  std::map<std::string, SparseOperator> ops;
  for (const auto& name : {"N01", "N02"}) {
    const auto& n = batch.neighborhood(name);
    const auto t = n.target.contiguous(), src = n.source.contiguous();
    ops[name] = SparseOperator::from_triplets(
        n.num_target, n.num_source,
        std::vector<std::int64_t>(t.data_ptr<std::int64_t>(),
                                  t.data_ptr<std::int64_t>() + t.numel()),
        std::vector<std::int64_t>(src.data_ptr<std::int64_t>(),
                                  src.data_ptr<std::int64_t>() + src.numel()),
        std::vector<double>(static_cast<std::size_t>(t.numel()), 1.0));
  }
  const auto plain = net->plan(in, ops);
  CHECK(plain.total_flops == p.total_flops);
  CHECK(plain.total_flops > 0);
  CHECK(plain.groups[0][0].compact_readers.empty());
  CHECK(plain.groups[1][0].route == StepRoute::general);
  // Each route gives the plain plan's numbers (all fast paths off).
  const auto fast = net->forward(in, batch);
  net->set_fast_paths(false);
  const auto none = net->plan(in, batch);
  CHECK(none.groups[0][0].compact_readers.empty());
  CHECK(none.groups[1][0].route == StepRoute::general);
  CHECK(none.groups[2][0].terms[0].prefix_key.empty());
  const auto slow = net->forward(in, batch);
  for (const auto& name : {"y1", "y2"})
    CHECK(torch::allclose(fast.at(name), slow.at(name), 1e-12, 1e-12));
}

namespace {

// A · x through RunContext::op; `declared` lists A among its operators.
struct Through : Operation {
  std::string op;
  bool declared;
  Through(std::string o, bool d) : op(std::move(o)), declared(d) {}
  std::string str(const std::string& x) const override { return "through[" + op + "](" + x + ")"; }
  TermShape infer(BuildContext& ctx, TermShape x) const override {
    return {ctx.operator_from(op, x.rank).second, x.channels};
  }
  torch::Tensor forward(RunContext& ctx, const torch::Tensor& x) const override {
    return spmm(ctx.op(op), x);
  }
  OperationTraits traits() const override {
    OperationTraits t;
    if (declared) t.operators = {op};
    return t;
  }
};

// relu, declared as the activation it is (counting the calls the product's kernel spares it).
struct CountedRelu : Operation {
  std::shared_ptr<std::atomic<int>> calls = std::make_shared<std::atomic<int>>(0);
  std::string str(const std::string& x) const override { return "myrelu(" + x + ")"; }
  TermShape infer(BuildContext&, TermShape x) const override { return x; }
  torch::Tensor forward(RunContext&, const torch::Tensor& x) const override {
    ++*calls;
    return torch::relu(x);
  }
  OperationTraits traits() const override {
    OperationTraits t;
    t.row_wise = true;
    t.activation = Activation::relu;
    return t;
  }
};

}  // namespace

TEST_CASE("a user operation's declared operators and activation: skipped terms, fused kernels",
          "[nn][schedule][operation]") {
  const auto A = random_operator(5, 5, 3, 0.5);
  torch::manual_seed(4);
  const auto x = torch::randn({5, 2}, torch::kDouble);
  // An optional operator left out skips the term whose operation declares it.
  for (bool declared : {true, false}) {
    OperatorSchedule s;
    s.input("x", 0, 2).optional_operator("A", 0, 0).output("y", 0);
    s.step(into(0).sum(from(0), from(0).apply(Through("A", declared))).named("skip"));
    OperatorNetwork net(s);
    CHECK(torch::allclose(net->forward({{"x", x}}, {{"A", A}}).at("y"), x + A.to_dense().matmul(x),
                          1e-12, 1e-12));
    if (declared)
      CHECK(torch::equal(net->forward({{"x", x}}, {}).at("y"), x));
    else
      CHECK_THROWS_WITH(net->forward({{"x", x}}, {}),
                        Contains("skip (into (0))") && Contains("operator 'A' was not given"));
  }
  // A declared optional operator in a concatenation cannot be skipped: refused when built.
  OperatorSchedule cat;
  cat.input("x", 0, 2).optional_operator("A", 0, 0).output("y", 0);
  cat.step(into(0).concat(from(0), from(0).apply(Through("A", true))));
  CHECK_THAT(build_error(cat), Contains("applies the optional operator 'A'"));
  // A product followed by an operation that declares itself relu applies it in its kernel.
  CountedRelu relu;
  OperatorSchedule fused;
  fused.input("x", 0, 2).operator_input("A", 0, 0).output("y", 0);
  fused.step(into(0).sum(from(0).via("A").apply(relu)));
  OperatorNetwork net(fused);
  const auto y = net->forward({{"x", x}}, {{"A", A}}).at("y");
  CHECK(torch::allclose(y, torch::relu(A.to_dense().matmul(x)), 1e-12, 1e-12));
  CHECK(*relu.calls == 0);
  // Not after an operation with no kernel of its own (a transposed row-normalised product).
  OperatorSchedule unfused;
  unfused.input("x", 0, 2).operator_input("A", 0, 0).output("y", 0);
  unfused.step(into(0).sum(from(0).via_t("A", true).apply(relu)));
  OperatorNetwork net2(unfused);
  net2->forward({{"x", x}}, {{"A", A}});
  CHECK(*relu.calls == 1);
}

namespace {

// Returns what its infer did not promise: another width, dtype or row count; or fails in
// LibTorch (a parameter made with the wrong shape).
struct Liar : Operation {
  enum class Lie { channels, dtype, rows, torch_error } lie;
  explicit Liar(Lie l) : lie(l) {}
  std::string str(const std::string& x) const override { return "liar(" + x + ")"; }
  TermShape infer(BuildContext& ctx, TermShape x) const override {
    ctx.parameter("w", {x.channels + 1, x.channels});
    return x;
  }
  torch::Tensor forward(RunContext& ctx, const torch::Tensor& x) const override {
    switch (lie) {
      case Lie::channels:
        return torch::cat({x, x}, 1);
      case Lie::dtype:
        return x.to(torch::kDouble);
      case Lie::rows:
        return x.narrow(0, 0, x.size(0) - 1);
      case Lie::torch_error:
        break;
    }
    return x.matmul(ctx.parameter("w"));
  }
};

}  // namespace

TEST_CASE("what a step's operations return is checked, and errors in a step name it and the term",
          "[nn][schedule][operation]") {
  const auto x = torch::randn({6, 4});
  const auto error = [&](Liar::Lie lie) {
    OperatorSchedule s;
    s.input("x", 0, 4).output("y", 0);
    s.step(into(0).sum(from(0), from(0).apply(Liar(lie))).named("lying"));
    OperatorNetwork net(s);
    try {
      net->forward({{"x", x}}, {});
    } catch (const ScheduleError& e) {
      return std::string(e.what());
    }
    return std::string();
  };
  CHECK_THAT(error(Liar::Lie::channels),
             Contains("lying (into (0)): operation liar(x) returned 8 channels, but its infer "
                      "said 4: return TermShape{0, 8} from infer, or 4 columns from forward"));
  CHECK_THAT(error(Liar::Lie::dtype),
             Contains("lying (into (0)): operation liar(x) returned Double, but it was given "
                      "Float: return the operand's dtype"));
  CHECK_THAT(error(Liar::Lie::rows),
             Contains("lying (into (0)): operation liar(x) returned 5 rows, but rank 0 has 6 "
                      "cells here"));
  // A LibTorch error inside a term: rethrown naming the step and the term.
  CHECK_THAT(error(Liar::Lie::torch_error), Contains("lying (into (0)): the term liar((0)): ") &&
                                                Contains("cannot be multiplied"));
  // Two operators disagreeing on the edges' count: forward's argument check names them before
  // any step runs (run_layer, which skips that check, meets the step's own row check:
  // test_operator_schedule.cpp, "LibTorch's errors inside a step ...").
  OperatorSchedule s;
  s.input("x", 0, 4).operator_input("B", 0, 1).operator_input("C", 0, 1).output("y", 1);
  s.step(into(1).sum(from(0).via("B"), from(0).via("C")).named("edges"));
  OperatorNetwork net(s);
  const auto B = random_operator(3, 6, 1), C = random_operator(4, 6, 2);
  CHECK_THROWS_WITH(net->forward({{"x", x}}, {{"B", B}, {"C", C}}),
                    Contains("operator 'C' is 4 × 6 and maps rank 0 cochains to rank 1") &&
                        Contains("but operator 'B' has 3 rows: give a 3 × 6 operator"));
}

TEST_CASE("the built-in elementwise operations are Operations with declared traits",
          "[nn][schedule][operation]") {
  torch::manual_seed(12);
  const auto x = torch::randn({5, 4}, torch::kDouble);
  // Applied as Operations, they compute and print what the builder's calls do.
  OperatorSchedule by_builder, by_hand;
  by_builder.input("x", 0, 4).output("y", 0);
  by_hand.input("x", 0, 4).output("y", 0);
  by_builder.step(into(0).sum(from(0)
                                  .act(Activation::elu)
                                  .scale(0.5)
                                  .pow(2)
                                  .bias("b")
                                  .head_weights("h", 2, 3)
                                  .unit_rows()));
  by_hand.step(into(0).sum(from(0)
                               .apply(builtin::Activate(Activation::elu))
                               .apply(builtin::Scale(0.5))
                               .apply(builtin::Pow(2))
                               .apply(builtin::Bias("b", {}, 0))
                               .apply(builtin::HeadWeights("h", 2, 3, 1.414))
                               .apply(builtin::UnitRows())));
  CHECK(by_builder.str() == by_hand.str());
  CHECK_THAT(by_builder.str(), Contains("unit_rows((0.5·elu((0)))^2 + b·h[×2])"));
  torch::manual_seed(13);
  OperatorNetwork a(by_builder);
  torch::manual_seed(13);
  OperatorNetwork b(by_hand);
  a->to(torch::kDouble), b->to(torch::kDouble);
  const auto ya = a->forward({{"x", x}}, {}).at("y"), yb = b->forward({{"x", x}}, {}).at("y");
  CHECK(ya.sizes() == torch::IntArrayRef({5, 6}));
  CHECK(torch::allclose(ya, yb, 0, 0));
  // The expected values written out (b starts at zero).
  const auto& H = a->parameter("h");
  const auto z = torch::cat(
      {(0.5 * torch::elu(x)).pow(2).matmul(H[0]), (0.5 * torch::elu(x)).pow(2).matmul(H[1])}, 1);
  CHECK(torch::allclose(ya, z / z.norm(2, 1, true), 1e-12, 1e-12));
  // Their traits: what the fast paths may assume.
  CHECK(builtin::Activate(Activation::relu).traits().activation == Activation::relu);
  // The enum's deprecated earlier names still compile and mean the same.
  static_assert(std::is_same_v<Update, Activation>);
  CHECK(update_from_string("elu") == Activation::elu);
  CHECK(update_name(Activation::gelu) == activation_name(Activation::gelu));
  CHECK(builtin::Activate(Activation::relu).traits().row_wise);
  CHECK_FALSE(builtin::Dropout(0.5).traits().row_wise);  // a fresh mask per entry
  CHECK_FALSE(builtin::Dropout(0.5).traits().reads_cochains);
  CHECK(builtin::Normalize(true).traits().row_wise);
  CHECK_FALSE(builtin::Normalize(false).traits().row_wise);  // the whole matrix's norm
  CHECK(builtin::Scale(2).traits().identity != builtin::Scale(2.0000001).traits().identity);
  CHECK(builtin::LearnedScale("s", 0, true, 1).traits().row_wise);
}

TEST_CASE("the built-in learned maps and norms are Operations with declared traits",
          "[nn][schedule][operation]") {
  torch::manual_seed(14);
  const auto x = torch::randn({5, 4}, torch::kDouble);
  OperatorSchedule by_builder, by_hand;
  by_builder.input("x", 0, 4).output("y", 0);
  by_hand.input("x", 0, 4).output("y", 0);
  const auto mlp = MlpOptions(3, 8, 2).layers(3);
  by_builder.step(into(0).sum(
      from(0).weight("w", 3).linear("l", 3).layer_norm("n").batch_norm("b").mlp("m", mlp)));
  by_hand.step(into(0).sum(from(0)
                               .apply(builtin::Weight("w", 3, 1.414))
                               .apply(builtin::Linear("l", 3, true, LinearInit::torch))
                               .apply(builtin::ChannelNorm("n", false))
                               .apply(builtin::ChannelNorm("b", true))
                               .apply(builtin::MlpBlock("m", mlp))));
  CHECK(by_builder.str() == by_hand.str());
  CHECK_THAT(by_builder.str(), Contains("m(b(n(l((0)·w))))"));
  torch::manual_seed(15);
  OperatorNetwork a(by_builder);
  torch::manual_seed(15);
  OperatorNetwork b(by_hand);
  a->to(torch::kDouble), b->to(torch::kDouble);
  const auto ya = a->forward({{"x", x}}, {}).at("y"), yb = b->forward({{"x", x}}, {}).at("y");
  CHECK(torch::allclose(ya, yb, 0, 0));
  // Written out with LibTorch's modules at the same paths (the state_dict names are torch's).
  auto named = a->named_parameters();
  for (const char* p : {"w", "l.weight", "l.bias", "n.weight", "b.weight", "m.0.weight",
                        "m.4.weight", "m.6.weight"})
    CHECK(named.contains(p));
  CHECK(a->named_buffers().contains("b.running_mean"));
  auto h = torch::linear(x.matmul(named["w"]), named["l.weight"], named["l.bias"]);
  h = torch::layer_norm(h, {3}, named["n.weight"], named["n.bias"]);
  h = torch::batch_norm(h, named["b.weight"], named["b.bias"], {}, {}, true, 0.1, 1e-5, false);
  CHECK(torch::allclose(ya, a->mlp("m")->forward(h), 1e-12, 1e-12));
  // A path shared with other options, or another width, is refused when built.
  OperatorSchedule clash;
  clash.input("x", 0, 4).output("y", 0);
  clash.step(into(0).sum(from(0).mlp("m", MlpOptions(4, 8, 4)),
                         from(0).mlp("m", MlpOptions(4, 8, 4).layers(3))));
  CHECK_THAT(build_error(clash), Contains("mlp 'm' is used again with other options"));
  OperatorSchedule widths;
  widths.input("x", 0, 4).output("y", 0);
  widths.step(into(0).sum(from(0).layer_norm("n").weight("w", 2).layer_norm("n").weight("v", 4)));
  CHECK_THAT(build_error(widths), Contains("normalisation 'n' of 4 channels applied to 2"));
  OperatorSchedule taken;
  taken.input("x", 0, 4).output("y", 0);
  taken.step(into(0).sum(from(0).linear("p", 4).batch_norm("p")));
  CHECK_THAT(build_error(taken), Contains("'p' already holds the parameter 'p."));
  // Their traits.
  CHECK(builtin::Weight("w", 3, 1).traits().right_factor == "w");
  CHECK(builtin::Weight("w", 3, 1).traits().row_wise);
  CHECK(builtin::Linear("l", 3, true, LinearInit::torch).traits().fuses_activation);
  CHECK(builtin::MlpBlock("m", mlp).traits().leading_linear);
  CHECK(builtin::ChannelNorm("n", false).traits().row_wise);
  CHECK_FALSE(builtin::ChannelNorm("b", true).traits().row_wise);  // batch statistics
  CostContext c;
  c.rows = 10, c.x = {0, 3}, c.y = {0, 2};
  CHECK(builtin::MlpBlock("m", mlp).cost(c).flops == 2 * 10 * (3 * 8 + 8 * 8 + 8 * 2));
  // The formulas a user's cost() can return, as the built-ins do.
  const auto d = OperationCost::dense(10, 3, 2), sp = OperationCost::sparse(7, 3);
  CHECK(d.flops == 120);
  CHECK(d.formula == "dense 2·10·3·2");
  CHECK(builtin::Weight("w", 2, 1).cost(c).formula == d.formula);
  CHECK(sp.flops == 42);
  CHECK(sp.formula == "sparse 2·7·3");
}

namespace {

// x · P with P at `path`, declaring it as its right factor; counts its forwards.
struct RightWeight : Operation {
  std::string path;
  std::shared_ptr<std::atomic<int>> calls = std::make_shared<std::atomic<int>>(0);
  explicit RightWeight(std::string p) : path(std::move(p)) {}
  std::string str(const std::string& x) const override { return x + "·my[" + path + "]"; }
  TermShape infer(BuildContext& ctx, TermShape x) const override {
    ctx.parameter(path, {x.channels, 8});
    return {x.rank, 8};
  }
  torch::Tensor forward(RunContext& ctx, const torch::Tensor& x) const override {
    ++*calls;
    return x.matmul(ctx.parameter(path));
  }
  OperationTraits traits() const override {
    OperationTraits t;
    t.row_wise = true;
    t.reads_cochains = false;
    t.right_factor = path;
    return t;
  }
  OperationCost cost(const CostContext& c) const override {
    return {2 * c.rows * c.x.channels * c.y.channels, "mine"};
  }
};

// x Wᵀ + b through a torch::nn::Linear at `path`, with a fused kernel for a following activation
// (counting which of its forwards ran).
struct FusingLinear : Operation {
  std::string path;
  std::shared_ptr<std::atomic<int>> plain = std::make_shared<std::atomic<int>>(0),
                                    fused = std::make_shared<std::atomic<int>>(0);
  explicit FusingLinear(std::string p) : path(std::move(p)) {}
  std::string str(const std::string& x) const override { return "fl(" + x + ")"; }
  TermShape infer(BuildContext& ctx, TermShape x) const override {
    ctx.module(path, torch::nn::Linear(x.channels, 3).ptr());
    return {x.rank, 3};
  }
  torch::Tensor forward(RunContext& ctx, const torch::Tensor& x) const override {
    ++*plain;
    return ctx.module<torch::nn::LinearImpl>(path).forward(x);
  }
  torch::Tensor forward_activated(RunContext& ctx, const torch::Tensor& x, Activation activation,
                                  double) const override {
    ++*fused;
    CHECK(activation == Activation::elu);
    return torch::elu(ctx.module<torch::nn::LinearImpl>(path).forward(x));
  }
  OperationTraits traits() const override {
    OperationTraits t;
    t.row_wise = true;
    t.reads_cochains = false;
    t.fuses_activation = true;
    return t;
  }
};

// tanh(x W₁ᵀ + b₁) W₂ᵀ: a two-layer map declaring its leading Linear layer (path.first).
struct TwoLayer : Operation {
  std::string path;
  std::shared_ptr<std::atomic<int>> whole = std::make_shared<std::atomic<int>>(0),
                                    after_first = std::make_shared<std::atomic<int>>(0);
  explicit TwoLayer(std::string p) : path(std::move(p)) {}
  std::string str(const std::string& x) const override { return "two(" + x + ")"; }
  TermShape infer(BuildContext& ctx, TermShape x) const override {
    ctx.module(path + ".first", torch::nn::Linear(x.channels, 5).ptr());
    ctx.parameter(path + ".second", {2, 5});
    return {x.rank, 2};
  }
  torch::Tensor rest(RunContext& ctx, const torch::Tensor& z) const {
    return torch::tanh(z).matmul(ctx.parameter(path + ".second").t());
  }
  torch::Tensor forward(RunContext& ctx, const torch::Tensor& x) const override {
    ++*whole;
    return rest(ctx, first_linear(ctx)->forward(x));
  }
  std::shared_ptr<torch::nn::LinearImpl> first_linear(RunContext& ctx) const override {
    return std::dynamic_pointer_cast<torch::nn::LinearImpl>(
        ctx.module<torch::nn::LinearImpl>(path + ".first").shared_from_this());
  }
  torch::Tensor forward_after_first(RunContext& ctx, const torch::Tensor& z) const override {
    ++*after_first;
    return rest(ctx, z);
  }
  OperationTraits traits() const override {
    OperationTraits t;
    t.row_wise = true;
    t.reads_cochains = false;
    t.leading_linear = true;
    return t;
  }
};

}  // namespace

TEST_CASE(
    "a user operation declaring a right factor, a fused activation or a leading Linear "
    "layer takes those fast paths, with the same numbers",
    "[nn][schedule][operation]") {
  torch::manual_seed(16);
  // A right factor: B maps 40 nodes to 2 cells, so (B x) P is far cheaper than B (x P).
  torch::Tensor dense = torch::zeros({2, 40}, torch::kDouble);
  dense.index_put_({0, torch::indexing::Slice(0, 20)}, 1.0);
  dense.index_put_({1, torch::indexing::Slice(20, 40)}, 0.5);
  const auto B = SparseOperator::from_dense(dense);
  const auto x = torch::randn({40, 8}, torch::kDouble);
  struct Out {
    torch::Tensor y, grad;
    int calls;
  };
  const auto reorder = [&](bool fast) {
    RightWeight w("p");
    OperatorSchedule s;
    s.input("x", 0, 8).operator_input("B", 0, 1).output("y", 1);
    s.step(into(1).sum(from(0).apply(w).via("B")));
    torch::manual_seed(17);
    OperatorNetwork net(s);
    net->to(torch::kDouble);
    net->set_fast_paths(fast);
    const auto y = net->forward({{"x", x}}, {{"B", B}}).at("y");
    y.pow(2).sum().backward();
    if (fast) CHECK_THAT(net->plan_str({{"x", x}}, {{"B", B}}), Contains("mine  5,120 FLOPs"));
    return Out{y.detach(), net->parameter("p").grad().clone(), *w.calls};
  };
  const auto plain = reorder(false), fast = reorder(true);
  CHECK(plain.calls == 1);
  CHECK(fast.calls == 0);  // the network multiplied (B x) by P itself
  CHECK(torch::allclose(fast.y, plain.y, 1e-12, 1e-12));
  CHECK(torch::allclose(fast.grad, plain.grad, 1e-12, 1e-12));

  // A fused activation: forward_activated instead of forward and the activation.
  for (bool fast_on : {true, false}) {
    FusingLinear fl("fl");
    OperatorSchedule s;
    s.input("x", 0, 8).output("y", 0);
    s.step(into(0).sum(from(0).apply(fl).act(Activation::elu)));
    torch::manual_seed(18);
    OperatorNetwork net(s);
    net->to(torch::kDouble);
    net->set_fast_paths(fast_on);
    const auto y = net->forward({{"x", x}}, {}).at("y");
    auto& lin = *net->named_modules()["fl"]->as<torch::nn::LinearImpl>();
    CHECK(torch::allclose(y, torch::elu(lin.forward(x)), 1e-12, 1e-12));
    CHECK(*fl.fused == (fast_on ? 1 : 0));
    CHECK(*fl.plain == (fast_on ? 0 : 1));
  }

  // A leading Linear layer: an object's message concatenated into it is multiplied by its block
  // of W on the 2 objects before it reaches the 6 nodes.
  ComplexView v;
  v.sizes = {6, 1, 2};
  topos::Neighborhood n20;
  n20.name = "N20", n20.source_rank = 2, n20.target_rank = 0;
  n20.source = {0, 0, 0, 1, 1, 1}, n20.target = {0, 1, 2, 3, 4, 5};
  n20.num_source = 2, n20.num_target = 6;
  v.neighborhoods = {{"N20", n20}};
  const auto batch = ComplexBatch::collate({v}, 2);
  const auto nodes = torch::randn({6, 3}, torch::kDouble),
             objects = torch::randn({2, 4}, torch::kDouble);
  const auto split = [&](bool fast_on) {
    TwoLayer two("u");
    OperatorSchedule s;
    s.input("n", 0, 3).input("o", 2, 4).operator_input("N20", 2, 0).output("y", 0);
    s.step(into(0).concat(from(0), from(2).pattern("N20")).apply(two));
    torch::manual_seed(19);
    OperatorNetwork net(s);
    net->to(torch::kDouble);
    net->set_fast_paths(fast_on);
    const auto y = net->forward({{"n", nodes}, {"o", objects}}, batch).at("y");
    y.pow(2).sum().backward();
    CHECK(*two.after_first == (fast_on ? 1 : 0));
    CHECK(*two.whole == (fast_on ? 0 : 1));
    return Out{y.detach(), net->parameter("u.second").grad().clone(), 0};
  };
  const auto whole = split(false), parts = split(true);
  CHECK(torch::allclose(parts.y, whole.y, 1e-12, 1e-12));
  CHECK(torch::allclose(parts.grad, whole.grad, 1e-12, 1e-12));
  CHECK(whole.grad.abs().sum().item<double>() > 0);
}

namespace {
// Two steps that must run at once: each arrives, then waits (10 s at most) for the other.
std::atomic<bool> must_meet{false};
std::atomic<int> arrived{0};
void meet() {
  ++arrived;
  const auto until = std::chrono::steady_clock::now() + std::chrono::seconds(10);
  while (arrived.load() < 2 && std::chrono::steady_clock::now() < until)
    std::this_thread::sleep_for(std::chrono::microseconds(100));
}

// x · 2; records the thread it ran on and the packed weights' scope that thread is in, meets the
// other meeting step when asked to, and fails on a thread other than `caller` when one is given.
struct Slow : Operation {
  bool meets;
  std::thread::id* ran_on;
  std::optional<std::thread::id> caller;  // set: fail on any other thread
  std::uint64_t* scope = nullptr;
  Slow(bool m, std::thread::id* on, std::optional<std::thread::id> c = {},
       std::uint64_t* packed_scope = nullptr)
      : meets(m), ran_on(on), caller(c), scope(packed_scope) {}
  std::string str(const std::string& x) const override { return "slow(" + x + ")"; }
  TermShape infer(BuildContext&, TermShape x) const override { return x; }
  torch::Tensor forward(RunContext& ctx, const torch::Tensor& x) const override {
    if (meets && must_meet) meet();
    *ran_on = std::this_thread::get_id();
    if (scope) *scope = topos::nn::detail::packed_weights_scope();
    if (caller && *caller != *ran_on) ctx.fail("slow failed on a helper thread");
    return x * 2;
  }
};
}  // namespace

TEST_CASE(
    "a parallel group's steps run on the helper threads, with the one-thread values and "
    "errors",
    "[nn][schedule][operation][threads]") {
  torch::manual_seed(5);
  const auto x = torch::randn({6, 4}, torch::kDouble).requires_grad_();
  const auto A = random_operator(6, 6, 3, 0.5);
  const auto me = std::this_thread::get_id();
  std::thread::id on[3];
  std::uint64_t scope_on[2] = {};
  // Two steps that meet (so each of two threads takes one of them), and a quick third.
  const auto schedule = [&](std::optional<std::thread::id> fail_off) {
    OperatorSchedule s;
    s.input("x", 0, 4).operator_input("A", 0, 0).output("y", 0).output("z", 0, "z");
    s.output("w", 0, "w");
    s.parallel({into(0)
                    .sum(from(0).apply(Slow(true, &on[0], fail_off, &scope_on[0])).via("A"))
                    .named("first"),
                into(0, "z")
                    .sum(from(0).apply(Gate("g")).apply(Slow(true, &on[1], fail_off, &scope_on[1])))
                    .named("second"),
                into(0, "w").sum(from(0).via("A").apply(Slow(false, &on[2]))).named("third")});
    return s;
  };
  OperatorNetwork net(schedule({}));
  net->to(torch::kDouble);
  CHECK(net->step_threads() == 1);
  const auto run = [&] {
    const auto out = net->forward({{"x", x}}, {{"A", A}});
    const auto loss = out.at("y").sum() + out.at("z").pow(2).sum() + out.at("w").sin().sum();
    auto g = torch::autograd::grad({loss}, {x, net->parameter("g")});
    return std::vector<torch::Tensor>{out.at("y"), out.at("z"), out.at("w"), g[0], g[1]};
  };
  const auto one = run();
  CHECK((on[0] == me && on[1] == me && on[2] == me));
  CHECK(net->split_groups() == 0);
  net->eval();
  net->step_threads(2);
  CHECK(net->step_threads() == 2);
  must_meet = true, arrived = 0;
  const auto two = run();
  must_meet = false;
  CHECK(on[0] != on[1]);
  CHECK((on[0] == me || on[1] == me));
  CHECK(net->split_groups() == 1);
  // The helper keeps bfloat16 weights' packed pairs within the caller's PackedWeightsScope (a
  // rollout's helpers pack each weight once), and outside one packs afresh as the caller does.
  CHECK((scope_on[0] == 0 && scope_on[1] == 0));
  {
    const PackedWeightsScope packed;
    const auto id = topos::nn::detail::packed_weights_scope();
    CHECK(id != 0);
    for (int round = 0; round < 2; ++round) {
      must_meet = true, arrived = 0;
      run();
      must_meet = false;
      CHECK(on[0] != on[1]);
      CHECK((scope_on[0] == id && scope_on[1] == id));
    }
  }
  must_meet = true, arrived = 0;
  run();
  must_meet = false;
  CHECK((scope_on[0] == 0 && scope_on[1] == 0));
  CHECK(net->split_groups() == 4);
  // The outputs bit for bit; the gradients up to the order of autograd's sums (test::
  // check_step_threads says why).
  for (std::size_t k = 0; k < 3; ++k) CHECK(torch::equal(one[k], two[k]));
  for (std::size_t k = 3; k < one.size(); ++k) CHECK(torch::allclose(one[k], two[k], 1e-13, 1e-14));
  // A training forward keeps one thread (its random draws keep their order).
  net->train();
  const auto trained = run();
  CHECK((on[0] == me && on[1] == me && on[2] == me));
  CHECK(net->split_groups() == 4);
  for (std::size_t k = 0; k < one.size(); ++k) CHECK(torch::equal(one[k], trained[k]));

  // An error on a helper thread reaches the caller, naming its step; the network runs again.
  OperatorNetwork failing(schedule(me));
  failing->to(torch::kDouble);
  failing->eval();
  failing->step_threads(3);
  torch::NoGradGuard no_grad;
  for (int round = 0; round < 2; ++round) {
    must_meet = true, arrived = 0;
    CHECK_THROWS_WITH(failing->forward({{"x", x}}, {{"A", A}}),
                      (Contains("first (into (0)): ") || Contains("second (into (0, \"z\")): ")) &&
                          Contains("slow failed on a helper thread"));
  }
  must_meet = false;
  failing->step_threads(1);
  CHECK_NOTHROW(failing->forward({{"x", x}}, {{"A", A}}));
  CHECK_THROWS_WITH(failing->step_threads(0),
                    Contains("OperatorNetwork::step_threads: 0 threads; give 1 (the calling "
                             "thread alone) or more"));
  CHECK(failing->step_threads() == 1);
}

namespace {
// x · 2, declared row-wise: the row-wise prefix of a term that aggregates over a batch's
// neighbourhood, which its step may evaluate at once with its other terms (step_threads).
// Records its thread, meets the other meeting term when asked to, and fails (naming `label`)
// on a thread other than `caller` when one is given.
struct RowWiseSlow : Operation {
  bool meets;
  std::thread::id* ran_on;
  std::optional<std::thread::id> caller;
  std::string label;
  RowWiseSlow(bool m, std::thread::id* on, std::optional<std::thread::id> c, std::string l)
      : meets(m), ran_on(on), caller(c), label(std::move(l)) {}
  std::string str(const std::string& x) const override { return "slow(" + x + ")"; }
  TermShape infer(BuildContext&, TermShape x) const override { return x; }
  torch::Tensor forward(RunContext& ctx, const torch::Tensor& x) const override {
    if (meets && must_meet) meet();
    *ran_on = std::this_thread::get_id();
    if (caller && *caller != *ran_on) ctx.fail(label + " failed off the calling thread");
    return x * 2;
  }
  OperationTraits traits() const override {
    OperationTraits t;
    t.row_wise = true;
    return t;
  }
};

// 40 nodes and 40 edges into 10 faces, each face reading four of each (N02, N12); N02half
// reads nodes 0-19 only.
ComplexBatch faces_batch() {
  ComplexView v;
  v.sizes = {40, 40, 10};
  topos::Neighborhood n02;
  n02.name = "N02", n02.source_rank = 0, n02.target_rank = 2;
  for (std::int64_t i = 0; i < 40; ++i) n02.source.push_back(i), n02.target.push_back(i / 4);
  n02.num_source = 40, n02.num_target = 10;
  auto n12 = n02, half = n02;
  n12.name = "N12", n12.source_rank = 1;
  half.name = "N02half", half.source.resize(20), half.target.resize(20);
  v.neighborhoods = {{"N02", n02}, {"N12", n12}, {"N02half", half}};
  return ComplexBatch::collate({v}, 2);
}
}  // namespace

TEST_CASE("a step's terms run at once on the helper threads, with the one-thread values and errors",
          "[nn][schedule][operation][threads]") {
  const auto batch = faces_batch();
  torch::manual_seed(6);
  const auto x0 = torch::randn({40, 3}, torch::kDouble).requires_grad_();
  const auto x1 = torch::randn({40, 3}, torch::kDouble).requires_grad_();
  const auto f = torch::randn({10, 2}, torch::kDouble);
  const auto me = std::this_thread::get_id();
  std::thread::id on[4];
  // One step (a group of its own) whose node and edge terms meet: only a split of its terms
  // passes. The third term shares the node term's prefix (one operation object, so one cache
  // key: the same job, a cache hit there) over a neighbourhood that reads half the nodes; the
  // fourth, a job of its own, runs its prefix on the 20 nodes that neighbourhood reads. The
  // fifth reads a compact cochain (the step "h" before, computed on the 20 nodes N02half reads
  // alone), so its job maps the neighbourhood's sources to the cochain's rows.
  const auto schedule = [&](std::optional<std::thread::id> fail_off) {
    const auto nodes = std::make_shared<RowWiseSlow>(true, &on[0], fail_off, "the nodes' slow");
    OperatorSchedule s;
    s.input("x0", 0, 3).input("x1", 1, 3).input("f", 2, 2).output("y", 2);
    s.operator_input("N02", 0, 2).operator_input("N12", 1, 2).operator_input("N02half", 0, 2);
    s.step(into(0, "h").sum(from(0).linear("lift", 3)).named("h"));
    s.step(into(2)
               .concat(from(2), from(0).apply(nodes).linear("a", 4).pattern("N02"),
                       from(1)
                           .apply(RowWiseSlow(true, &on[1], fail_off, "the edges' slow"))
                           .linear("b", 4)
                           .pattern("N12"),
                       from(0).apply(nodes).linear("a", 4).pattern("N02half", Aggr::mean),
                       from(0)
                           .apply(RowWiseSlow(false, &on[2], fail_off, "the half's slow"))
                           .linear("c", 4)
                           .pattern("N02half"),
                       from(0, "h")
                           .apply(RowWiseSlow(false, &on[3], fail_off, "the compact slow"))
                           .linear("d", 4)
                           .pattern("N02half", Aggr::max))
               .mlp("m",
                    MlpOptions(22, 8, 2).layer_norm(false))  // (a norm over 2 outputs: no gradient)
               .named("faces"));
    return s;
  };
  OperatorNetwork net(schedule({}));
  net->to(torch::kDouble);
  const std::map<std::string, torch::Tensor> inputs{{"x0", x0}, {"x1", x1}, {"f", f}};
  const auto plan = net->plan(inputs, batch);
  INFO(plan.str());
  REQUIRE(plan.groups.size() == 2);
  CHECK(plan.groups[0][0].compact_readers == std::vector<std::string>{"N02half"});
  const auto run = [&] {
    const auto y = net->forward(inputs, batch).at("y");
    const auto g = torch::autograd::grad(
        {y.sin().sum()}, {x0, x1, net->parameter("a.weight"), net->parameter("lift.weight")});
    return std::vector<torch::Tensor>{y, g[0], g[1], g[2], g[3]};
  };
  net->eval();
  const auto one = run();
  CHECK((on[0] == me && on[1] == me && on[3] == me));
  net->step_threads(2);
  must_meet = true, arrived = 0;
  const auto two = run();
  must_meet = false;
  CHECK(on[0] != on[1]);
  CHECK((on[0] == me || on[1] == me));
  CHECK((net->split_groups() == 1 && net->split_steps() == 1));
  CHECK(torch::equal(one[0], two[0]));
  for (std::size_t k = 1; k < one.size(); ++k) CHECK(torch::allclose(one[k], two[k], 1e-13, 1e-14));
  CHECK(one[3].abs().sum().item<double>() > 0);
  CHECK(one[4].abs().sum().item<double>() > 0);  // the compact term reaches the loss
  // The plain plan (every fast path off: "h" on all 40 nodes, no split, no cache) agrees.
  net->set_fast_paths(false);
  net->step_threads(1);
  CHECK(net->plan(inputs, batch).groups[0][0].compact_readers.empty());
  const auto plain = run();
  net->set_fast_paths(true);
  net->step_threads(2);
  for (std::size_t k = 0; k < one.size(); ++k)
    CHECK(torch::allclose(plain[k], two[k], 1e-12, 1e-13));
  net->train();  // one thread
  const auto trained = run();
  CHECK((on[0] == me && on[1] == me));
  CHECK(torch::equal(one[0], trained[0]));
  CHECK((net->split_groups() == 1 && net->split_steps() == 1));

  // A term failing on the helper: the step and the term's error, then one thread runs it.
  torch::NoGradGuard no_grad;
  const auto forward = [&](OperatorNetwork& n) {
    return n->forward({{"x0", x0}, {"x1", x1}, {"f", f}}, batch);
  };
  OperatorNetwork failing(schedule(me));
  failing->to(torch::kDouble);
  failing->eval();
  failing->step_threads(2);
  for (int round = 0; round < 2; ++round) {
    must_meet = true, arrived = 0;
    CHECK_THROWS_WITH(forward(failing), Contains("faces (into (2)): ") &&
                                            Contains("slow failed off the calling thread"));
  }
  // Both failing at once: the first in the step's order is the one thrown.
  OperatorNetwork both(schedule(std::thread::id()));  // no thread's id: fails everywhere
  both->to(torch::kDouble);
  both->eval();
  both->step_threads(2);
  must_meet = true, arrived = 0;
  CHECK_THROWS_WITH(forward(both), Contains("the nodes' slow failed"));
  CHECK(arrived.load() == 2);  // the edges' term ran too, on the other thread
  must_meet = false;
  failing->step_threads(1);
  CHECK_NOTHROW(forward(failing));
}
