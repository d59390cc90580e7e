// Tests of the operator schedule (topos/nn/operator_schedule.hpp): its steps against dense
// products written out by hand, parameters created at TopoModelX's paths with inferred shapes,
// parallel groups reading one snapshot, and every error of a bad schedule named by its step when
// the network is built (and bad operators when it runs).
#include "support/torch_prelude.hpp"

#include "support/operator_schedule.hpp"
#include "topos/models/zoo.hpp"
#include "topos/nn/operator_schedule.hpp"
#include "topos/testing/conv.hpp"

#include <set>
#include <tuple>
#include <type_traits>
#include <utility>

using namespace topos;
using namespace topos::nn;
using namespace topos::nn::ops;
using Catch::Matchers::Contains;
using Catch::Matchers::EndsWith;
using Catch::Matchers::StartsWith;
using topos::test::build_error;
using topos::test::random_operator;

// A chain on a temporary stays an rvalue, so it moves into sum, step or a return without
// std::move, braced arguments included; on a named term or step it is that object.
static_assert(std::is_same_v<decltype(from(0).via("A").act(Activation::relu)), Term&&>);
static_assert(std::is_same_v<decltype(from(0).bias("b", {1, 4})), Term&&>);
static_assert(std::is_same_v<decltype(into(0).sum(from(0)).named("s")), OperatorStep&&>);
static_assert(std::is_same_v<decltype(std::declval<Term&>().via("A")), Term&>);
static_assert(
    std::is_same_v<decltype(std::declval<OperatorStep&>().act(Activation::relu)), OperatorStep&>);

namespace {

std::set<std::string> parameter_names(const torch::nn::Module& m) {
  std::set<std::string> out;
  for (const auto& p : m.named_parameters()) out.insert(p.key());
  return out;
}

// Softmax over each row's entries where D != 0, empty rows zeros (row_softmax, densely).
torch::Tensor masked_softmax(const torch::Tensor& scores, const torch::Tensor& D) {
  const auto w =
      torch::softmax(torch::where(D != 0, scores, torch::full_like(scores, -INFINITY)), 1);
  return torch::where(torch::isnan(w), torch::zeros_like(w), w);
}

}  // namespace

TEST_CASE("an operator schedule computes its terms, mix and tail as written", "[nn][schedule]") {
  // Nodes (5, 3 channels), edges (7, 2 channels); B: nodes × edges, L: nodes × nodes.
  const auto B = random_operator(5, 7, 1), L = random_operator(5, 5, 2);
  torch::manual_seed(3);
  const auto x0 = torch::randn({5, 3}, torch::kDouble), x1 = torch::randn({7, 2}, torch::kDouble);
  OperatorSchedule s;
  s.input("x_0", 0, 3).input("x_1", 1, 2).operator_input("B", 1, 0).operator_input("L", 0, 0);
  s.step(into(0)
             .sum(from(0).conv("layer.a", 4).via("L").act(Activation::relu),
                  from(1).via("B").linear("layer.b", 4))
             .weight("layer.c", 2, 1.0)
             .act(Activation::tanh)
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
  const auto T = random_operator(7, 7, 4);
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

TEST_CASE("a parallel group reads one snapshot, and a path used twice is one parameter",
          "[nn][schedule]") {
  const auto A = random_operator(4, 4, 5);
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
  const auto A = random_operator(5, 7, 7);  // edges (7) -> nodes (5)
  torch::manual_seed(8);
  const auto x0 = torch::randn({5, 4}, torch::kDouble), x1 = torch::randn({7, 4}, torch::kDouble);
  OperatorSchedule s;
  s.input("x_0", 0, 4).input("x_1", 1, 4).input("x_0_soft", 0, 4, "soft");
  s.operator_input("A", 1, 0);
  s.step(into(0).sum(from(1).attend("A", "conv.att_weight").conv("conv", 3)));
  s.step(into(0, "soft").sum(
      from(1).attend("A", "att", Activation::leaky_relu, AttentionNorm::softmax, 0.2)));
  s.output("y", 0).output("soft", 0, "soft");
  OperatorNetwork net(s);
  net->to(torch::kDouble);
  testing::Conv conv(testing::ConvOptions(4, 3).att(true));
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

TEST_CASE("multi-head attention: per-head GAT scores, concatenated or averaged heads, dropout",
          "[nn][schedule][attention]") {
  const auto A = random_operator(6, 6, 21);
  torch::manual_seed(22);
  const auto x = torch::randn({6, 4}, torch::kDouble);
  // CAN's attention: a_src and a_dst as parameters of their own, 1 × heads × channels per head.
  auto gat = [](const std::string& path, bool concat, double dropout = 0) {
    models::CanAttention a("A", path, CochainKey{0, ""}, 2);
    a.concat = concat;
    a.dropout = dropout;
    a.activation = Activation::leaky_relu;
    a.negative_slope = 0.2;
    return a;
  };
  OperatorSchedule s;
  s.input("x", 0, 4).operator_input("A", 0, 0);
  s.parallel({into(0, "cat").sum(from(0).apply(gat("att", true))),
              into(0, "mean").sum(from(0).apply(gat("att", false))),
              into(0, "drop").sum(from(0).apply(gat("att", true, 1.0))),
              // The schedule's own attend: one vector [a_s | a_t], each part heads-major.
              into(0, "one").sum(from(0).attend("A", AttendOptions("one")
                                                         .heads(2)
                                                         .queries(CochainKey{0, ""})
                                                         .activation(Activation::leaky_relu)
                                                         .negative_slope(0.2)
                                                         .norm(AttentionNorm::softmax)))});
  s.output("cat", 0, "cat").output("mean", 0, "mean").output("drop", 0, "drop");
  s.output("one", 0, "one");
  OperatorNetwork net(s);
  net->to(torch::kDouble);
  CHECK(parameter_names(*net) ==
        std::set<std::string>{"att.att_weight_src", "att.att_weight_dst", "one"});
  CHECK(net->parameter("att.att_weight_dst").sizes() == torch::IntArrayRef({1, 2, 2}));
  CHECK(net->parameter("one").sizes() == torch::IntArrayRef({8}));
  CHECK_THAT(s.str(), Contains("can_attend[att ×2]A·(0)") && Contains("att[one ×2]A·(0)"));
  net->eval();
  const auto out = net->forward({{"x", x}}, {{"A", A}});
  // Head h: softmax over i's entries of leaky_relu(a_s,h·x_h[j] + a_t,h·x_h[i]), messages x_h.
  const auto D = A.to_dense();
  std::vector<torch::Tensor> heads, one;
  for (int h = 0; h < 2; ++h) {
    const auto xh = x.narrow(1, 2 * h, 2);
    const auto a_s = net->parameter("att.att_weight_src")[0][h],
               a_t = net->parameter("att.att_weight_dst")[0][h];
    const auto scores =
        torch::leaky_relu(xh.matmul(a_s).unsqueeze(0) + xh.matmul(a_t).unsqueeze(1), 0.2);
    heads.push_back((masked_softmax(scores, D) * D).mm(xh));
    const auto& a = net->parameter("one");
    const auto s1 = torch::leaky_relu(xh.matmul(a.narrow(0, 2 * h, 2)).unsqueeze(0) +
                                          xh.matmul(a.narrow(0, 4 + 2 * h, 2)).unsqueeze(1),
                                      0.2);
    one.push_back((masked_softmax(s1, D) * D).mm(xh));
  }
  CHECK(torch::allclose(out.at("cat"), torch::cat(heads, 1), 1e-10, 1e-12));
  CHECK(torch::allclose(out.at("mean"), (heads[0] + heads[1]) / 2, 1e-10, 1e-12));
  CHECK(torch::allclose(out.at("one"), torch::cat(one, 1), 1e-10, 1e-12));
  CHECK(torch::equal(out.at("drop"), out.at("cat")));  // dropout on the weights: training only
  net->train();
  CHECK(torch::equal(net->forward({{"x", x}}, {{"A", A}}).at("drop"),
                     torch::zeros({6, 4}, torch::kDouble)));
}

TEST_CASE("the attention kernels equal torch's operations in float, heads a vector wide or not",
          "[nn][attention][kernels]") {
  // The kernels sum each head's channels in vectors of 8 or 16 floats with a scalar tail, so the
  // heads here are 16 and 32 channels wide (whole vectors), 20 (vectors and a tail) and 3; the
  // unfused path (fused = false) is torch's operations on the same scores.
  const auto A = random_operator(40, 50, 31, 0.3);
  const std::vector<std::pair<std::int64_t, std::int64_t>> shapes{
      {4, 16}, {2, 32}, {3, 20}, {1, 3}};
  for (const auto& [H, C] : shapes)
    for (const auto act :
         {Activation::none, Activation::relu, Activation::leaky_relu, Activation::elu})
      for (const auto norm : {AttentionNorm::softmax, AttentionNorm::row_sum, AttentionNorm::none})
        for (const bool with_target : {true, false}) {
          INFO(H << " heads of " << C << ", activation " << static_cast<int>(act) << ", norm "
                 << static_cast<int>(norm) << (with_target ? ", target scores" : ""));
          torch::manual_seed(32);
          // Row sums need positive scores (a sum near 0 divides by it); the others cross 0.
          const auto draw = [&](std::int64_t n) {
            return norm == AttentionNorm::row_sum ? torch::rand({n, H}) + 0.1
                                                  : torch::randn({n, H});
          };
          const auto source = draw(50).requires_grad_(),
                     target = with_target ? draw(40).requires_grad_() : torch::Tensor(),
                     x = torch::randn({50, H * C}).requires_grad_(), g = torch::randn({40, H * C});
          const auto run = [&](bool fused) {
            for (const auto& t : {source, target, x})
              if (t.defined()) t.mutable_grad() = torch::Tensor();
            const auto y = multi_head_attention_from_cells(A, source, target, x, true, act, 0.2,
                                                           norm, 0, false, fused);
            (y * g).sum().backward();
            std::vector<torch::Tensor> out{y.detach(), source.grad(), x.grad()};
            if (with_target) out.push_back(target.grad());
            return out;
          };
          const auto kernel = run(true), ops = run(false);
          for (std::size_t i = 0; i < kernel.size(); ++i) {
            INFO("tensor " << i << " (y, d source, dx, d target)");
            CHECK(torch::allclose(kernel[i], ops[i], 1e-4, 1e-5));
          }
        }
}

TEST_CASE("GATv2 attention (CAN's): one vector after the activation of keys plus queries",
          "[nn][schedule][attention]") {
  const auto A = random_operator(5, 5, 23);
  torch::manual_seed(24);
  const auto x = torch::randn({5, 4}, torch::kDouble), d = torch::randn({5, 4}, torch::kDouble);
  OperatorSchedule s;
  s.input("x", 0, 4).input("d", 0, 4, "dst").operator_input("A", 0, 0);
  models::CanAttention v2("A", "att", CochainKey{0, "dst"}, 2);
  v2.v2 = true;
  v2.activation = Activation::leaky_relu;
  v2.negative_slope = 0.2;
  s.step(into(0, "y").sum(from(0).apply(v2)));
  s.output("y", 0, "y");
  OperatorNetwork net(s);
  net->to(torch::kDouble);
  CHECK(net->parameter("att.att_weight").sizes() == torch::IntArrayRef({1, 2, 2}));
  const auto out = net->forward({{"x", x}, {"d", d}}, {{"A", A}}).at("y");
  // Entry (i, j) of head h: a_h · leaky_relu(x_j + d_i) over the head's channels.
  const auto D = A.to_dense();
  const auto a = net->parameter("att.att_weight").reshape({2, 2});
  const auto e = torch::leaky_relu(x.unsqueeze(0) + d.unsqueeze(1), 0.2);  // [i][j] = x_j + d_i
  std::vector<torch::Tensor> heads;
  for (int h = 0; h < 2; ++h) {
    const auto scores = e.narrow(2, 2 * h, 2).matmul(a[h]);
    heads.push_back((masked_softmax(scores, D) * D).mm(x.narrow(1, 2 * h, 2)));
  }
  CHECK(torch::allclose(out, torch::cat(heads, 1), 1e-10, 1e-12));
}

TEST_CASE(
    "attention with keys and queries from other cochains, source-only scores, activated keys "
    "and a transposed operator",
    "[nn][schedule][attention]") {
  const auto B = random_operator(5, 7, 25);  // edges (7) -> nodes (5)
  torch::manual_seed(26);
  const auto x0 = torch::randn({5, 4}, torch::kDouble), x1 = torch::randn({7, 4}, torch::kDouble);
  const auto keys = torch::randn({7, 3}, torch::kDouble),
             queries = torch::randn({5, 2}, torch::kDouble);
  OperatorSchedule s;
  s.input("x_0", 0, 4).input("x_1", 1, 4).input("k", 1, 3, "keys").input("q", 0, 2, "queries");
  s.operator_input("B", 1, 0);
  // HyperGAT's scores a·leaky_relu(x): the activated features as the keys, messages x itself.
  s.step(into(0, "activated").sum(from(0).act(Activation::leaky_relu)));
  s.step(into(1, "src").sum(from(0).attend("B", AttendOptions("a1")
                                                    .transposed(true)
                                                    .source_only(true)
                                                    .keys(CochainKey{0, "activated"})
                                                    .activation(Activation::none)
                                                    .norm(AttentionNorm::softmax))));
  s.step(into(0, "kq").sum(from(1).attend("B", AttendOptions("a2")
                                                   .shape({5, 1})
                                                   .keys(CochainKey{1, "keys"})
                                                   .queries(CochainKey{0, "queries"}))));
  s.output("src", 1, "src").output("kq", 0, "kq");
  OperatorNetwork net(s);
  net->to(torch::kDouble);
  CHECK(net->parameter("a1").sizes() == torch::IntArrayRef({4}));
  CHECK(net->parameter("a2").sizes() == torch::IntArrayRef({5, 1}));
  const auto out =
      net->forward({{"x_0", x0}, {"x_1", x1}, {"k", keys}, {"q", queries}}, {{"B", B}});
  const auto D = B.to_dense(), Dt = D.t();
  // Each edge: softmax over its nodes j of a1·leaky_relu_0.01(x0_j), messages x0_j (over Bᵀ).
  const auto s1 = torch::leaky_relu(x0, 0.01).matmul(net->parameter("a1"));
  const auto scores1 = s1.unsqueeze(0).expand({7, 5});
  CHECK(torch::allclose(out.at("src"), (masked_softmax(scores1, Dt) * Dt).mm(x0), 1e-10, 1e-12));
  // Each node i, edge j: elu(a2[:3]·keys_j + a2[3:]·queries_i) times B's value, messages x1_j.
  const auto a2 = net->parameter("a2").reshape({-1});
  const auto scores2 = torch::elu(keys.matmul(a2.narrow(0, 0, 3)).unsqueeze(0) +
                                  queries.matmul(a2.narrow(0, 3, 2)).unsqueeze(1));
  CHECK(torch::allclose(out.at("kq"), (scores2 * D).mm(x1), 1e-10, 1e-12));
}

TEST_CASE("key weights folded into the scores give what keys formed first give",
          "[nn][schedule][attention]") {
  // Edges (7, 4 channels) -> nodes (5) over B, 1 or 2 heads: keys x_1 K_h (K: H × 4 × 3) formed
  // as a state first, or folded (key_weights); scores source-only (AllSetTransformer's) or against
  // queries x_0 (a_t after a_s); attention's kernel, or torch's operations (fuse_attention off).
  // Outputs and every gradient agree.
  const auto B = random_operator(5, 7, 31);
  torch::manual_seed(32);
  const auto x0 = torch::randn({5, 6}, torch::kDouble), x1 = torch::randn({7, 4}, torch::kDouble);
  for (const std::int64_t H : {1, 2})
    for (const bool fused : {true, false})
      for (const bool source_only : {true, false}) {
        INFO("heads " << H << ", fuse_attention " << fused << ", source_only " << source_only);
        const auto attend = [&](AttendOptions o) {
          o.heads(H).source_only(source_only).activation(Activation::leaky_relu);
          if (!source_only) o.queries(CochainKey{0, ""});
          return from(1).head_weights("V", H, 2).attend("B", o.norm(AttentionNorm::softmax));
        };
        OperatorSchedule formed, folded;
        for (auto* s : {&formed, &folded})
          s->input("x_0", 0, 6).input("x_1", 1, 4).operator_input("B", 1, 0);
        formed.step(into(1, "keys").sum(from(1).head_weights("K", H, 3)));
        formed.step(into(0, "y").sum(attend(AttendOptions("a").keys(CochainKey{1, "keys"}))));
        folded.step(into(0, "y").sum(
            attend(AttendOptions("a").keys(CochainKey{1, ""}).key_weights(KeyWeights("K", 3)))));
        formed.output("y", 0, "y"), folded.output("y", 0, "y");
        OperatorNetwork a(formed), b(folded);
        a->to(torch::kDouble), b->to(torch::kDouble);
        a->fast_paths().fuse_attention(fused), b->fast_paths().fuse_attention(fused);
        CHECK(b->parameter("K").sizes() == torch::IntArrayRef({H, 4, 3}));
        REQUIRE(b->parameter("a").sizes() == a->parameter("a").sizes());
        {
          torch::NoGradGuard g;
          for (const auto* name : {"K", "V", "a"}) b->parameter(name).copy_(a->parameter(name));
        }
        const auto run = [&](OperatorNetwork& net) {
          const auto X0 = x0.clone().requires_grad_(), X1 = x1.clone().requires_grad_();
          const auto y = net->forward({{"x_0", X0}, {"x_1", X1}}, {{"B", B}}).at("y");
          (y * torch::cos(y)).sum().backward();
          return std::vector<torch::Tensor>{y.detach(),
                                            X0.grad(),
                                            X1.grad(),
                                            net->parameter("K").grad(),
                                            net->parameter("V").grad(),
                                            net->parameter("a").grad()};
        };
        const auto want = run(a), got = run(b);
        CHECK(want[0].abs().sum().item<double>() > 0);
        for (std::size_t i = 0; i < want.size(); ++i) {
          INFO("output or gradient " << i);
          if (i == 1 && source_only) continue;  // x_0 is read only as the queries
          CHECK(torch::allclose(got[i], want[i], 1e-10, 1e-12));
        }
      }
  // No channel per head: an error naming the key weights.
  OperatorSchedule bad;
  bad.input("x_0", 0, 6).input("x_1", 1, 4).operator_input("B", 1, 0);
  bad.step(into(0).sum(from(1).attend("B", AttendOptions("a")
                                               .source_only(true)
                                               .keys(CochainKey{1, ""})
                                               .key_weights(KeyWeights("K", 0)))));
  bad.output("y", 0);
  CHECK_THAT(build_error(bad), Contains("one channel per head of key weights 'K'"));
}

TEST_CASE("head weights, a bias, a constant scale, concatenated terms, declared parameters",
          "[nn][schedule]") {
  torch::manual_seed(27);
  const auto x = torch::randn({4, 3}, torch::kDouble);
  OperatorSchedule s;
  s.input("x", 0, 3);
  s.step(into(0, "h").sum(from(0).head_weights("hw", 2, 5)).bias("b", {2, 1, 5}).scale(0.5));
  s.step(into(0, "c").concat(from(0), from(0, "h")));
  s.parameter("unused.w", {3, 1}, 1.0);
  s.output("h", 0, "h").output("c", 0, "c");
  OperatorNetwork net(s);
  net->to(torch::kDouble);
  CHECK(parameter_names(*net) == std::set<std::string>{"hw", "b", "unused.w"});
  CHECK(net->parameter("hw").sizes() == torch::IntArrayRef({2, 3, 5}));
  CHECK(net->parameter("unused.w").sizes() == torch::IntArrayRef({3, 1}));
  const auto& b = net->parameter("b");
  CHECK(torch::equal(b, torch::zeros({2, 1, 5}, torch::kDouble)));  // a new bias is zero
  {
    torch::NoGradGuard g;
    b.copy_(torch::randn({2, 1, 5}, torch::kDouble));
  }
  const auto out = net->forward({{"x", x}}, {});
  const auto& W = net->parameter("hw");
  const auto h = 0.5 * (torch::cat({x.mm(W[0]), x.mm(W[1])}, 1) + b.reshape({1, -1}));
  CHECK(torch::allclose(out.at("h"), h, 1e-12, 1e-12));
  CHECK(torch::allclose(out.at("c"), torch::cat({x, h}, 1), 1e-12, 1e-12));
  CHECK_THAT(s.str(), Contains("cat[") && Contains("parameter unused.w"));
  // A selection operator gathers rows: S x = x[index].
  const auto index = torch::tensor({2, 0, 2}, torch::kLong);
  const auto S = SparseOperator::selection(index, 4);
  CHECK(torch::equal(spmm(S, x), x.index_select(0, index)));
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
    s.step(into(0).sum(from(0)).apply(models::InitialResidual({1, ""}, 0.1, 0.5, "lin")));
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
  // The attention options and the other operations.
  auto error = [&](OperatorStep step) {
    auto s = base();
    s.step(std::move(step.named("bad")));
    return build_error(s);
  };
  CHECK_THAT(error(into(0).sum(from(1).attend("B", AttendOptions("att").heads(3)))),
             Contains("bad") && Contains("with 3 heads"));
  models::CanAttention v2("B", "att", CochainKey{0, ""}, 1);
  v2.v2 = true;
  CHECK_THAT(error(into(0).sum(from(1).apply(v2))),
             Contains("bad") && Contains("CAN attention over 'B' (GATv2) needs queries as wide as "
                                         "its keys, got 3 and 2"));
  CHECK_THAT(error(into(0).sum(from(1).apply(models::CanAttention("B", "att", {0, ""}, 2)))),
             Contains("bad") && Contains("with 2 heads: the messages (2) and queries (3) need "
                                         "channels divisible by the heads"));
  CHECK_THAT(
      error(into(0).sum(from(1).attend("B", AttendOptions("att").keys(CochainKey{1, "nope"})))),
      Contains("bad") && Contains("takes its keys from (1, \"nope\")"));
  CHECK_THAT(error(into(0).sum(from(1).attend("B", AttendOptions("att").shape({3, 1})))),
             Contains("bad") && Contains("needs 5 entries in 'att', its shape [3, 1] has 3"));
  CHECK_THAT(error(into(0).sum(from(1).attend("B", AttendOptions("att").dropout(1.5)))),
             Contains("bad") && Contains("needs a dropout rate in [0, 1]"));
  CHECK_THAT(error(into(0).sum(from(0)).bias("b", {2})),
             Contains("bad") && Contains("bias 'b' of shape [2] added to 3 channels"));
  CHECK_THAT(error(into(0).sum(from(0).head_weights("w", 0, 2))),
             Contains("bad") && Contains("head weights 'w' need at least one head"));
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
                    Contains("operator 'B' is 5 × 7 and maps rank 1 cochains to rank 0") &&
                        Contains("input 'x_1' has 6 rows: give a 5 × 6 operator"));
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

  // HyperGAT's compatible mode keeps the attention vectors it does not use.
  models::HyperGAT hypergat(models::HyperGATOptions(3, 4).n_layers(1).topomodelx_compatible(true));
  CHECK(parameter_names(*hypergat) == std::set<std::string>{"layers.0.weight1", "layers.0.weight2",
                                                            "layers.0.att_weight1",
                                                            "layers.0.att_weight2"});
  CHECK(hypergat->parameter("layers.0.att_weight2").sizes() == torch::IntArrayRef({8, 1}));
  // CAN v2 with shared weights: lin_dst is lin_src, under both names (TopoModelX's state_dict).
  models::CAN can(models::CANOptions(2, 3, 4).n_layers(1).version("v2").share_weights(true));
  auto named = can->named_parameters();
  REQUIRE(named.contains("layers.0.upper_att.lin_dst.weight"));
  CHECK(named["layers.0.upper_att.lin_dst.weight"].is_same(
      named["layers.0.upper_att.lin_src.weight"]));
  CHECK(named["layers.0.upper_att.att_weight"].sizes() == torch::IntArrayRef({1, 2, 2}));
  // AllSetTransformer: TopoModelX's multi-head layout.
  models::AllSetTransformer allset(models::AllSetTransformerOptions(3, 8).heads(2));
  CHECK(allset->parameter("layers.0.vertex2edge.multihead_att.K_weight").sizes() ==
        torch::IntArrayRef({2, 3, 4}));
  CHECK(allset->parameter("layers.0.edge2vertex.multihead_att.Q_weight").sizes() ==
        torch::IntArrayRef({2, 1, 4}));
}

TEST_CASE("scale and bias: a learned or buffered scalar, a learned row", "[nn][schedule]") {
  const auto A = random_operator(4, 4, 9);
  torch::manual_seed(10);
  const auto x = torch::randn({4, 3}, torch::kDouble);
  OperatorSchedule s;
  s.input("x", 0, 3).operator_input("A", 0, 0);
  s.step(into(0)
             .sum(from(0).scale("layer.eps", 0.25, /*trainable=*/false, /*offset=*/1),
                  from(0).via("A").scale("layer.gain", -0.5))
             .bias("layer.bias", {1, 3}, 1.0));
  s.output("y", 0);
  OperatorNetwork net(s);
  net->to(torch::kDouble);
  // The untrained scalar is a buffer, saved at its path like a parameter.
  CHECK(parameter_names(*net) == std::set<std::string>{"layer.gain", "layer.bias"});
  CHECK(net->named_buffers().size() == 1);
  CHECK(net->named_buffers().contains("layer.eps"));
  CHECK(net->parameter("layer.eps").sizes() == torch::IntArrayRef({1}));
  CHECK(net->parameter("layer.eps").item<double>() == 0.25);
  CHECK(net->parameter("layer.gain").item<double>() == -0.5);
  const auto b = net->parameter("layer.bias");
  CHECK(b.sizes() == torch::IntArrayRef({1, 3}));
  CHECK(b.abs().max().item<double>() <= std::sqrt(6.0 / (1 + 3)));  // Glorot, gain 1
  const auto y = net->forward({{"x", x}}, {{"A", A}}).at("y");
  const auto expect = 1.25 * x - 0.5 * A.to_dense().mm(x) + b.expand({4, 3});
  CHECK(torch::allclose(y, expect, 1e-12, 1e-12));
  y.sum().backward();
  CHECK(torch::allclose(net->parameter("layer.gain").grad(), (A.to_dense().mm(x)).sum().view({1}),
                        1e-12, 1e-12));
  CHECK(torch::allclose(b.grad(), torch::full({1, 3}, 4.0, torch::kDouble)));
  CHECK_THAT(s.str(), Contains("(1+layer.eps)·(0)") && Contains("] + layer.bias"));
}

TEST_CASE("pow and normalize: generalised means, differentiated L2 normalisation",
          "[nn][schedule]") {
  const auto A = random_operator(5, 6, 11);  // edges (6) -> nodes (5)
  torch::manual_seed(12);
  const auto x = torch::rand({6, 3}, torch::kDouble) + 0.1;
  const auto z = torch::randn({5, 3}, torch::kDouble).requires_grad_(true);
  OperatorSchedule s;
  s.input("x", 1, 3).input("z", 0, 3, "z").operator_input("A", 1, 0);
  s.step(into(0).sum(from(1).pow(3).pattern("A", Aggr::mean).pow(1.0 / 3)));
  s.parallel({into(0, "rows").sum(from(0, "z")).normalize(),
              into(0, "whole").sum(from(0, "z")).normalize(/*per_row=*/false)});
  s.output("mean", 0).output("rows", 0, "rows").output("whole", 0, "whole");
  OperatorNetwork net(s);
  const auto out = net->forward({{"x", x}, {"z", z}}, {{"A", A}});
  // (mean over each node's edges of x³)^(1/3), nodes without edges 0.
  const auto P = (A.to_dense() != 0).to(torch::kDouble);
  const auto mean = (P.mm(x.pow(3)) / P.sum(1, true).clamp_min(1)).pow(1.0 / 3);
  CHECK(torch::allclose(out.at("mean"), mean, 1e-12, 1e-12));
  CHECK(torch::allclose(out.at("rows"), z / z.norm(2, 1, true), 1e-12, 1e-12));
  CHECK(torch::allclose(out.at("whole"), z / z.norm(), 1e-12, 1e-12));
  // The norm is differentiated: moving along its own direction changes nothing, so the gradient
  // of <normalize(z), normalize(z) held constant> vanishes (unit_rows' would not).
  const auto rows = out.at("rows");
  (rows * rows.detach()).sum().backward();
  CHECK(z.grad().abs().max().item<double>() < 1e-12);
  CHECK_THAT(s.str(), Contains("(mean|A|·((1))^3)^0.333333") && Contains("normalize_rows(") &&
                          Contains("normalize(sum["));
  // A zero row stays zero.
  const auto zero = torch::zeros({5, 3}, torch::kDouble);
  CHECK(torch::equal(net->forward({{"x", x}, {"z", zero}}, {{"A", A}}).at("rows"), zero));
}

TEST_CASE("the hypergraph schedules keep TopoModelX's parameter and buffer names",
          "[nn][schedule][models]") {
  auto buffer_names = [](const torch::nn::Module& m) {
    std::set<std::string> out;
    for (const auto& b : m.named_buffers()) out.insert(b.key());
    return out;
  };
  models::UniGIN unigin(models::UniGINOptions(3, 4).n_layers(2));
  CHECK(parameter_names(*unigin) ==
        std::set<std::string>{"initial_linear_layer.weight", "initial_linear_layer.bias",
                              "layers.0.linear.weight", "layers.0.linear.bias",
                              "layers.1.linear.weight", "layers.1.linear.bias"});
  CHECK(buffer_names(*unigin) == std::set<std::string>{"layers.0.eps", "layers.1.eps"});
  models::UniGIN trained(models::UniGINOptions(3, 4).n_layers(1).eps(0.5).train_eps(true));
  CHECK(parameter_names(*trained).count("layers.0.eps") == 1);
  CHECK(buffer_names(*trained).empty());
  CHECK(trained->parameter("layers.0.eps").item<double>() == 0.5);

  models::HNHN hnhn(models::HNHNOptions(3, 4).n_layers(1));
  CHECK(parameter_names(*hnhn) ==
        std::set<std::string>{"layers.0.conv_0_to_1.weight", "layers.0.conv_1_to_0.weight",
                              "layers.0.bias_0_to_1", "layers.0.bias_1_to_0"});
  CHECK(hnhn->parameter("layers.0.conv_0_to_1.weight").sizes() == torch::IntArrayRef({3, 4}));
  CHECK(hnhn->parameter("layers.0.bias_1_to_0").sizes() == torch::IntArrayRef({1, 4}));
  models::HNHN unbiased(models::HNHNOptions(3, 4).n_layers(1).use_bias(false));
  CHECK(parameter_names(*unbiased).size() == 2);

  // [Linear, BatchNorm1d, activation, Dropout, Linear], numbered as torch.nn.Sequential.
  models::AllSet allset(
      models::AllSetOptions(3, 4).n_layers(1).mlp_norm(models::MlpNorm::batch_norm));
  std::set<std::string> expected;
  for (const std::string block : {"vertex2edge", "edge2vertex"}) {
    expected.insert("layers.0." + block + ".conv.weight");
    for (const std::string mlp : {".encoder", ".decoder"})
      for (const std::string name : {".0.weight", ".1.weight", ".1.bias", ".4.weight"})
        expected.insert("layers.0." + block + mlp + name);
  }
  CHECK(parameter_names(*allset) == expected);
  CHECK(buffer_names(*allset).count("layers.0.edge2vertex.decoder.1.running_mean") == 1);
  CHECK(allset->parameter("layers.0.vertex2edge.encoder.0.weight").sizes() ==
        torch::IntArrayRef({4, 3}));

  // HyperSAGE's "uniform" initialisation: U(-1/sqrt(out), 1/sqrt(out)).
  models::HyperSAGE sage(models::HyperSAGEOptions(3, 4));
  CHECK(parameter_names(*sage) == std::set<std::string>{"layers.0.weight", "layers.1.weight"});
  CHECK(sage->parameter("layers.0.weight").sizes() == torch::IntArrayRef({3, 4}));
  CHECK(sage->parameter("layers.1.weight").abs().max().item<double>() <= 0.5);
}

TEST_CASE("SCA-CMPS's IntraAggregate weights each cell by its agreement with the whole cochain",
          "[nn][schedule]") {
  const auto A = random_operator(5, 6, 21);  // edges (6) -> nodes (5)
  torch::manual_seed(22);
  const auto x = torch::randn({6, 3}, torch::kDouble).requires_grad_(true);
  OperatorSchedule s;
  s.input("x", 1, 3).operator_input("A", 1, 0);
  s.step(into(0)
             .mean(from(1).via("A").apply(models::IntraAggregate()), from(1).via("A"))
             .act(Activation::relu));
  s.output("y", 0);
  OperatorNetwork net(s);
  const auto y = net->forward({{"x", x}}, {{"A", A}}).at("y");
  // By hand: m = A x; row i of m times σ(Σ_c relu(Σ_j m_jc) m_ic); the mean with m, then relu.
  const auto m = A.to_dense().mm(x);
  const auto g = torch::sigmoid((m * torch::relu(m.sum(0, true))).sum(1, true));
  const auto expect = torch::relu((m * g + m) / 2);
  CHECK(torch::allclose(y, expect, 1e-12, 1e-12));
  auto xr = x.detach().clone().requires_grad_(true);
  const auto mr = A.to_dense().mm(xr);
  const auto gr = torch::sigmoid((mr * torch::relu(mr.sum(0, true))).sum(1, true));
  const auto R = torch::randn({5, 3}, torch::kDouble);
  (y * R).sum().backward();
  (torch::relu((mr * gr + mr) / 2) * R).sum().backward();
  CHECK(torch::allclose(x.grad(), xr.grad(), 1e-12, 1e-12));
  CHECK_THAT(s.str(), Contains("intra(A·(1))"));
}

TEST_CASE(
    "HMC's attention: offsets read the vector cyclically, and mirrored rows swap a row's weights",
    "[nn][schedule][attention]") {
  const auto A = random_operator(5, 7, 31);  // cells of rank 1 (7) -> rank 0 (5)
  torch::manual_seed(32);
  const auto k = torch::randn({7, 3}, torch::kDouble), q = torch::randn({5, 2}, torch::kDouble);
  auto base = [](const CochainKey& queries) {
    models::HmcAttention a("A", "a", queries);
    a.shape = {5, 1};
    return a;
  };
  OperatorSchedule s;
  s.input("k", 1, 3).input("q", 0, 2).operator_input("A", 1, 0);
  // Forward: a_s from entry 4 (wrapping to 0, 1), a_t from entry 2. Reverse: keys q (rank 0)
  // over Aᵀ, queries k, a_s from entry 3, a_t from entry 0; mirrored rows.
  auto fwd = base(CochainKey{0, ""});
  fwd.source_offset = 4;
  fwd.target_offset = 2;
  auto rev = base(CochainKey{1, ""});
  rev.transposed = true;
  rev.source_offset = 3;
  rev.target_offset = 0;
  rev.mirrored_rows = true;
  s.parallel({into(0, "fwd").sum(from(1).apply(fwd)), into(1, "rev").sum(from(0).apply(rev))});
  s.output("fwd", 0, "fwd").output("rev", 1, "rev");
  CHECK_THAT(s.str(), Contains("hmc_attend[a]A·(1)") && Contains("hmc_attend[a]Aᵀ·(0)"));
  OperatorNetwork net(s);
  net->to(torch::kDouble);
  const auto a = net->parameter("a").reshape({-1});
  const auto out = net->forward({{"k", k}, {"q", q}}, {{"A", A}});
  const auto at = [&](std::vector<std::int64_t> i) { return a.index_select(0, torch::tensor(i)); };
  const auto D = A.to_dense();
  // Forward by hand: softmax per node of leaky_relu(k_j·a[4,0,1] + q_i·a[2,3]).
  const auto sf = torch::leaky_relu(
      k.matmul(at({4, 0, 1})).unsqueeze(0) + q.matmul(at({2, 3})).unsqueeze(1), 0.2);
  CHECK(torch::allclose(out.at("fwd"), (masked_softmax(sf, D) * D).mm(k), 1e-10, 1e-12));
  // Reverse: per edge j over its nodes i, leaky_relu(q_i·a[3,4] + k_j·a[0,1,2]), then each row's
  // weights mirrored (its first entry takes its last's weight, ...).
  const auto Dt = D.t().contiguous();
  const auto sr = torch::leaky_relu(
      q.matmul(at({3, 4})).unsqueeze(0) + k.matmul(at({0, 1, 2})).unsqueeze(1), 0.2);
  auto w = masked_softmax(sr, Dt);
  for (std::int64_t j = 0; j < 7; ++j) {
    const auto cols = (Dt[j] != 0).nonzero().squeeze(1);
    w[j].index_put_({cols}, w[j].index_select(0, cols).flip(0));
  }
  CHECK(torch::allclose(out.at("rev"), (w * Dt).mm(q), 1e-10, 1e-12));
  CHECK_FALSE(torch::allclose(out.at("rev"), (masked_softmax(sr, Dt) * Dt).mm(q), 1e-6, 1e-6));

  // Offsets inside the vector, and a vector of both parts.
  OperatorSchedule bad;
  bad.input("k", 1, 3).input("q", 0, 2).operator_input("A", 1, 0).output("y", 0);
  auto too_far = bad;
  auto far = base(CochainKey{0, ""});
  far.target_offset = 5;
  too_far.step(into(0).sum(from(1).apply(far)).named("hbs"));
  CHECK_THAT(build_error(too_far),
             Contains("hbs (into (0)): HMC attention over 'A' needs offsets in [0, 5), got 5"));
  auto one_part = bad;
  auto short_vector = base(CochainKey{0, ""});
  short_vector.shape = {3, 1};
  one_part.step(into(0).sum(from(1).apply(short_vector)).named("hbs"));
  CHECK_THAT(build_error(one_part),
             Contains("hbs (into (0)): HMC attention over 'A' needs 5 entries in 'a', its shape "
                      "[3, 1] has 3"));
}

TEST_CASE("HMPNN's dropped incidence entries, patterns over the transpose, its rescaled dropout",
          "[nn][schedule]") {
  // A node × hyperedge pattern of 12 × 8 with about half the entries.
  torch::manual_seed(41);
  const auto B =
      SparseOperator::from_dense((torch::rand({12, 8}, torch::kDouble) < 0.5).to(torch::kDouble));
  OperatorSchedule s;
  s.input("nodes", 0, 12).input("edges", 1, 8).operator_input("B", 1, 0);
  // B's entries dropped at rate 0.5, one draw under the key "B.kept" shared by both directions.
  const models::DroppedPattern up("B", "B.kept", 0.5, /*transposed=*/true);
  const models::DroppedPattern down("B", "B.kept", 0.5);
  // One-hot features: what reaches each cell names the entries kept.
  s.parallel(
      {into(1, "from_nodes").sum(from(0).apply(up)), into(0, "from_edges").sum(from(1).apply(down)),
       into(1, "mean").sum(from(0).apply(models::DroppedPattern("B", "", 0, true, Aggr::mean)))});
  s.output("from_nodes", 1, "from_nodes").output("from_edges", 0, "from_edges");
  s.output("mean", 1, "mean");
  OperatorNetwork net(s);
  const std::map<std::string, torch::Tensor> in{{"nodes", torch::eye(12, torch::kDouble)},
                                                {"edges", torch::eye(8, torch::kDouble)}};
  const auto D = B.to_dense();
  CHECK_THAT(s.str(), Contains("sum|Bᵀ dropped 0.5 [B.kept]|·(0)") &&
                          Contains("sum|B dropped 0.5 [B.kept]|·(1)") && Contains("mean|Bᵀ|·(0)"));
  net->eval();  // every entry
  auto out = net->forward(in, {{"B", B}});
  CHECK(torch::equal(out.at("from_nodes"), D.t()));
  CHECK(torch::equal(out.at("from_edges"), D));
  CHECK(torch::allclose(out.at("mean"), D.t() / D.sum(0).clamp_min(1).unsqueeze(1)));
  net->train();  // one draw, both directions
  out = net->forward(in, {{"B", B}});
  const auto kept = out.at("from_edges");
  CHECK(torch::equal(out.at("from_nodes"), kept.t()));
  CHECK(torch::equal(kept * D, kept));  // a subset of B's entries
  const auto n = kept.sum().item<double>(), nnz = static_cast<double>(B.nnz());
  CHECK(n > 0.2 * nnz);
  CHECK(n < 0.8 * nnz);
  CHECK_FALSE(torch::equal(net->forward(in, {{"B", B}}).at("from_edges"), kept));  // a new draw

  // TopoModelX HMPNN's dropout: entries kept with probability p, row i times (2n - kept_i) / n.
  OperatorSchedule d;
  d.input("x", 0, 4).output("y", 0);
  d.step(into(0).sum(from(0).apply(models::RescaledDropout(0.3))));
  OperatorNetwork drop(d);
  const auto ones = torch::ones({10, 4}, torch::kDouble);
  torch::manual_seed(43);
  const auto y = drop->forward({{"x", ones}}, {}).at("y");  // 10 rows: factors (20 - kept) / 10 > 0
  const auto kept_per_row = (y != 0).sum(1, true).to(torch::kDouble);
  CHECK(torch::allclose(y, (y != 0).to(torch::kDouble) * (20 - kept_per_row) / 10));
  CHECK(kept_per_row.sum().item<double>() > 0);
  CHECK(kept_per_row.sum().item<double>() < 0.6 * 40);
  drop->eval();
  CHECK(torch::equal(drop->forward({{"x", ones}}, {}).at("y"), ones));

  // Errors name the step.
  const auto with = [&](const models::DroppedPattern& op) {
    OperatorSchedule t = s;
    t.step(into(1, "bad").sum(from(0).apply(op)).named("dropping"));
    return build_error(t);
  };
  CHECK_THAT(with(models::DroppedPattern("nowhere", "C", 0.1, true)),
             Contains("dropping (into (1, \"bad\")): unknown operator 'nowhere'"));
  CHECK_THAT(
      with(models::DroppedPattern("B", "C", 1.5, true)),
      Contains("dropping") && Contains("the rate of dropped entries of 'B' must be in [0, 1]"));
  CHECK_THAT(with(models::DroppedPattern("B", "", 0.1, true)),
             Contains("dropping") && Contains("entries of 'B' dropped need a key"));
  OperatorSchedule bad_dropout;
  bad_dropout.input("x", 0, 2).output("y", 0);
  bad_dropout.step(into(0).sum(from(0).dropout(2)).named("dropping"));
  CHECK_THAT(build_error(bad_dropout), Contains("dropping (into (0)): a dropout rate"));
  OperatorSchedule wrong_rank;
  wrong_rank.input("x", 1, 2).operator_input("B", 1, 0).output("y", 1);
  wrong_rank.step(into(1).sum(from(1).apply(models::DroppedPattern("B", "", 0, true))));
  CHECK_THAT(build_error(wrong_rank), Contains("operator 'Bᵀ' applies to rank 0 cochains"));
}

TEST_CASE("HMC and HMPNN as schedules keep TopoModelX's parameter names and shapes",
          "[nn][schedule][models]") {
  models::HMCChannels c(1);
  c[0] = {{{2, 3, 4}, {5, 6, 7}, {8, 9, 10}}};  // in, intermediate, out of ranks 0, 1, 2
  models::HMC hmc{models::HMCOptions(c)};
  const auto names = parameter_names(*hmc);
  CHECK(names.size() == 20);  // 4 HBS (weight, attention) and 4 HBNS (w_s, w_t, attention)
  CHECK(hmc->parameter("layers.0.hbs_0_level1.weight.0").sizes() == torch::IntArrayRef({2, 5}));
  CHECK(hmc->parameter("layers.0.hbs_0_level1.att_weight.0").sizes() ==
        torch::IntArrayRef({10, 1}));
  CHECK(hmc->parameter("layers.0.hbs_2_level2.weight.0").sizes() == torch::IntArrayRef({7, 10}));
  // HBNS(source rank 2, target rank 1): w_s source in × target out, w_t target in × source out.
  CHECK(hmc->parameter("layers.0.hbns_1_2_level1.w_s").sizes() == torch::IntArrayRef({4, 6}));
  CHECK(hmc->parameter("layers.0.hbns_1_2_level1.w_t").sizes() == torch::IntArrayRef({3, 7}));
  CHECK(hmc->parameter("layers.0.hbns_0_1_level2.att_weight").sizes() ==
        torch::IntArrayRef({17, 1}));
  CHECK(names.count("layers.0.hbs_1_level1.weight.0") == 0);  // level 1: rank 0's HBS only
  c.push_back({{{8, 9, 1}, {1, 1, 1}, {1, 1, 1}}});
  CHECK_THROWS_WITH(models::HMC(models::HMCOptions(c)),
                    Contains("layer 0's output channels differ from layer 1's"));

  models::HMPNN hmpnn(models::HMPNNOptions(3, 4).n_layers(1));
  CHECK(parameter_names(*hmpnn) ==
        std::set<std::string>{
            "linear_node.weight", "linear_node.bias", "linear_edge.weight", "linear_edge.bias",
            "layers.0.node_to_hyperedge_messenger.messaging_func.0.weight",
            "layers.0.node_to_hyperedge_messenger.messaging_func.0.bias",
            "layers.0.hyperedge_to_node_messenger.messaging_func.linear.weight",
            "layers.0.hyperedge_to_node_messenger.messaging_func.linear.bias",
            "layers.0.node_batchnorm.weight", "layers.0.node_batchnorm.bias",
            "layers.0.hyperedge_batchnorm.weight", "layers.0.hyperedge_batchnorm.bias"});
  CHECK(hmpnn->parameter("layers.0.hyperedge_to_node_messenger.messaging_func.linear.weight")
            .sizes() == torch::IntArrayRef({4, 8}));
  CHECK_THAT(hmpnn->schedule().str(), Contains("incidence_1.layer_0"));
  models::HMPNN compatible(models::HMPNNOptions(3, 4).n_layers(1).topomodelx_compatible(true));
  CHECK_THAT(compatible->schedule().str(), !Contains("incidence_1.layer_0"));
}

TEST_CASE("a filter bank's attention and an affine power against dense products (SAN)",
          "[nn][schedule][attention]") {
  const auto L = random_operator(9, 9, 51);
  const auto M = random_operator(9, 9, 52);
  torch::manual_seed(53);
  const auto x = torch::randn({9, 4}, torch::kDouble);
  OperatorSchedule s;
  s.input("x", 1, 4).operator_input("L", 1, 1).operator_input("M", 1, 1).output("y", 1);
  s.step(into(1, "bank").sum(from(1).head_weights("W", 3, 2)));  // [x W_0 | x W_1 | x W_2]
  s.step(into(1).sum(from(1, "bank").apply(models::SanFilterAttention("L", "a", {1, "bank"}, 3)),
                     from(1).weight("H", 2).apply(models::AffinePower({"L", "M"}, 3, 1.0, -0.1))));
  OperatorNetwork net(s);
  net->to(torch::kDouble);
  const auto y = net->forward({{"x", x}}, {{"L", L}, {"M", M}}).at("y");
  // By hand: m_p = x W_p; one softmax over L's pattern of elu(a_s·[m]_j + a_t·[m]_i), times L's
  // values; Σ_p A^(p+1) m_p; plus (I - 0.1 (L + M))^3 x H.
  const auto W = net->parameter("W"), a = net->parameter("a"), H = net->parameter("H");
  const auto m = torch::cat({x.mm(W[0]), x.mm(W[1]), x.mm(W[2])}, 1);
  const auto D = L.to_dense();
  const auto scores =
      torch::elu(m.mv(a.narrow(0, 0, 6)).unsqueeze(0) + m.mv(a.narrow(0, 6, 6)).unsqueeze(1));
  const auto A = masked_softmax(scores, D) * D;
  auto expect = A.mm(x.mm(W[0])) + A.mm(A.mm(x.mm(W[1]))) + A.mm(A.mm(A.mm(x.mm(W[2]))));
  const auto T = torch::eye(9, torch::kDouble) - 0.1 * (D + M.to_dense());
  expect = expect + T.mm(T.mm(T.mm(x.mm(H))));
  CHECK(torch::allclose(y, expect, 1e-10, 1e-12));
  CHECK_THAT(s.str(), Contains("(1 I + -0.1 (L + M))^3") &&
                          Contains("san_attend[a ×3 filters]L·(1, \"bank\")"));

  OperatorSchedule bad;
  bad.input("x", 1, 4).input("x0", 0, 4).operator_input("L", 1, 1).output("y", 1);
  bad.operator_input("B", 0, 1);
  auto no_filter = bad;
  no_filter.step(into(1).sum(from(1).apply(models::SanFilterAttention("L", "a", {1, ""}, 0))));
  CHECK_THAT(build_error(no_filter), Contains("SAN attention over 'L' with 0 filters"));
  auto uneven = bad;
  uneven.step(
      into(1).sum(from(1).apply(models::SanFilterAttention("L", "a", {1, ""}, 3))).named("bank"));
  CHECK_THAT(build_error(uneven),
             Contains("bank (into (1)): SAN attention over 'L' with 3 filters needs messages (4 "
                      "channels) of whole filters"));
  auto not_square = bad;
  not_square.step(
      into(1).sum(from(1).apply(models::AffinePower({"L", "B"}, 2, 1.0, -0.1))).named("harmonic"));
  CHECK_THAT(
      build_error(not_square),
      Contains("harmonic (into (1)): the affine power needs operators from rank 1 to itself, "
               "'B' maps 0 -> 1"));
  auto negative = bad;
  negative.step(into(1).sum(from(1).apply(models::AffinePower({"L"}, -1, 1.0, -0.1))));
  CHECK_THAT(build_error(negative), Contains("exponent is negative"));
}

TEST_CASE("an optional operator left out skips the terms that apply it", "[nn][schedule]") {
  const auto A = random_operator(5, 5, 3), B = random_operator(5, 5, 4);
  OperatorSchedule s;
  s.input("x", 0, 3).operator_input("A", 0, 0).optional_operator("B", 0, 0);
  s.step(into(0).sum(from(0).conv("a", 4).via("A"), from(0).conv("b", 4).via("B")));
  s.step(into(0, "kept").sum(from(0, "").via("B")));  // only an optional term: keeps the value
  s.output("y", 0).output("kept", 0, "kept");
  REQUIRE_THROWS_WITH(OperatorNetwork(OperatorSchedule(s).step(
                          into(0).concat(from(0), from(0).via("B")).named("cat"))),
                      Contains("cat (into (0)): the term from (0) applies the optional operator "
                               "'B', which only a step that sums or averages its terms can skip"));
  REQUIRE_THROWS_WITH(
      OperatorNetwork(OperatorSchedule(s).step(into(0).sum(from(0)).via("B").named("tail"))),
      Contains("tail (into (0)): the step's own operations apply the optional operator 'B', "
               "which cannot be skipped there"));
  OperatorNetwork net(s);
  net->to(torch::kDouble);
  torch::manual_seed(3);
  const auto x = torch::randn({5, 3}, torch::kDouble);
  const auto Wa = net->parameter("a.weight"), Wb = net->parameter("b.weight");
  const auto both = net->forward({{"x", x}}, {{"A", A}, {"B", B}});
  CHECK(torch::allclose(both.at("y"), A.to_dense().mm(x.mm(Wa)) + B.to_dense().mm(x.mm(Wb)), 1e-5,
                        1e-6));
  // Without B, TopoModelX's None: the A term alone; (0, "kept") had no value before its step.
  CHECK_THROWS_WITH(net->forward({{"x", x}}, {{"A", A}}),
                    Contains("every term applies an optional operator left out, and (0, "
                             "\"kept\") has no value to keep"));
  OperatorSchedule t;
  t.input("x", 0, 3).operator_input("A", 0, 0).optional_operator("B", 0, 0);
  t.step(into(0).sum(from(0).conv("a", 4).via("A"), from(0).conv("b", 4).via("B")));
  t.step(into(0).sum(from(0).conv("c", 4).via("B")));  // left out: (0) stays as it was
  t.output("y", 0);
  OperatorNetwork skip(t);
  skip->to(torch::kDouble);
  const auto one = skip->forward({{"x", x}}, {{"A", A}}).at("y");
  CHECK(torch::allclose(one, A.to_dense().mm(x.mm(skip->parameter("a.weight"))), 1e-5, 1e-6));
}

TEST_CASE("a forward's inputs and operators are checked against the schedule's declarations",
          "[nn][schedule][checks]") {
  // Nodes (4, 3 channels), edges (4, 3 channels): B maps edges to nodes, L nodes to nodes.
  OperatorSchedule s;
  s.input("x_0", 0, 3).input("x_1", 1, 3).operator_input("B", 1, 0).optional_operator("L", 0, 0);
  s.step(into(0).sum(from(1).via("B"), from(0).via("L")).linear("lin", 2).named("update"));
  s.output("y", 0);
  OperatorNetwork net(s);
  torch::manual_seed(5);
  const auto x0 = torch::randn({4, 3}), x1 = torch::randn({4, 3});
  const auto B = random_operator(4, 4, 1).to(torch::kFloat),
             L = random_operator(4, 4, 2).to(torch::kFloat);
  const auto& W = net->parameter("lin.weight");
  const auto& b = net->parameter("lin.bias");
  const auto y = net->forward({{"x_0", x0}, {"x_1", x1}}, {{"B", B}, {"L", L}}).at("y");
  CHECK(torch::allclose(y, torch::linear(B.to_dense().mm(x1) + L.to_dense().mm(x0), W, b), 1e-5,
                        1e-6));
  const auto error = [&](const std::map<std::string, torch::Tensor>& in,
                         const std::map<std::string, SparseOperator>& ops) {
    try {
      net->forward(in, ops);
    } catch (const ScheduleError& e) {
      return std::string(e.what());
    }
    return std::string();
  };
  // A 5 × 4 operator into 4 nodes: its rows are the target rank's cells (it gave 5 rows).
  const auto B54 = random_operator(5, 4, 3).to(torch::kFloat);
  CHECK_THAT(error({{"x_0", x0}, {"x_1", x1}}, {{"B", B54}}),
             Contains("operator 'B' is 5 × 4 and maps rank 1 cochains to rank 0") &&
                 Contains("input 'x_0' has 4 rows: give a 4 × 4 operator, or declare the ranks "
                          "it maps with operator_input(\"B\", source_rank, target_rank)"));
  // Its columns are the source rank's cells; two operators must agree where no input says.
  CHECK_THAT(error({{"x_0", x0}, {"x_1", torch::randn({5, 3})}}, {{"B", B}}),
             Contains("operator 'B' is 4 × 4") && Contains("input 'x_1' has 5 rows"));
  // A name the schedule does not declare while the optional operator is missing: likely its
  // misspelling, which would drop its term without a word.
  CHECK_THAT(error({{"x_0", x0}, {"x_1", x1}}, {{"B", B}, {"l", L}}),
             Contains("operator 'l' is not one the schedule declares ('B', 'L') and the optional "
                      "operator 'L' was not given, so its terms would be dropped: give it under "
                      "its declared name, or declare 'l' with operator_input(\"l\", source_rank, "
                      "target_rank)"));
  // Otherwise a warning naming it, once per name (a caller may hold a larger dictionary).
  struct Warnings : c10::WarningHandler {
    std::vector<std::string> seen;
    void process(const c10::SourceLocation&, const std::string& msg, bool) override {
      seen.push_back(msg);
    }
  } warnings;
  {
    c10::Warning::WarningHandlerGuard guard(&warnings);
    for (int i = 0; i < 2; ++i)
      net->forward({{"x_0", x0}, {"x_1", x1}, {"x_2", x1}}, {{"B", B}, {"L", L}, {"U", L}});
  }
  REQUIRE(warnings.seen.size() == 2);
  CHECK_THAT(warnings.seen[0], Contains("operator 'U' is not one the schedule declares ('B', "
                                        "'L') and is ignored: give only the declared ones "
                                        "(net->declared_operators(all))"));
  CHECK_THAT(warnings.seen[1], Contains("input 'x_2' is not one the schedule declares ('x_0', "
                                        "'x_1') and is ignored"));
  CHECK(net->declared_operators({{"B", B}, {"U", L}}).count("U") == 0);
  // float64 features for a float32 network: the input named, and what to write.
  CHECK_THAT(error({{"x_0", x0.to(torch::kDouble)}, {"x_1", x1}}, {{"B", B}}),
             Contains("input 'x_0' is float64, the network's parameters float32: write "
                      "x.to(torch::kFloat32), or convert the network with "
                      "net->to(torch::kFloat64)"));
  // Parameters only a submodule's (an MLP): the reference is found once and follows the
  // network's conversion.
  OperatorSchedule in_mlp;
  in_mlp.input("x", 0, 3).output("y", 0);
  in_mlp.step(into(0).sum(from(0).mlp("m", MlpOptions(3, 8, 3))));
  OperatorNetwork mlp_net(in_mlp);
  REQUIRE(mlp_net->forward({{"x", x0}}, {}).at("y").scalar_type() == torch::kFloat);
  mlp_net->to(torch::kDouble);
  CHECK_THROWS_WITH(mlp_net->forward({{"x", x0}}, {}),
                    Contains("input 'x' is float32, the network's parameters float64: write "
                             "x.to(torch::kFloat64)"));
  REQUIRE(mlp_net->forward({{"x", x0.to(torch::kDouble)}}, {}).at("y").scalar_type() ==
          torch::kDouble);
  // Inputs of one rank in two states must have as many rows.
  OperatorSchedule states;
  states.input("x", 0, 3).input("z", 0, 3, "z").output("y", 0);
  states.step(into(0).sum(from(0), from(0, "z")));
  CHECK_THROWS_WITH(OperatorNetwork(states)->forward({{"x", x0}, {"z", torch::randn({5, 3})}}, {}),
                    Contains("input 'z' has 5 rows, but input 'x' has 4 rows: give one row per "
                             "cell of rank 0"));
  // An optional operator that no step applies is a misspelt name.
  OperatorSchedule typo = s;
  typo.optional_operator("Lup", 0, 0);
  CHECK_THAT(build_error(typo),
             Contains("optional operator 'Lup' is applied by no step (they apply 'B', 'L'): "
                      "write the name a term applies, or remove the optional_operator"));
}

TEST_CASE("LibTorch's errors inside a step name the step and what it reads",
          "[nn][schedule][checks]") {
  // run_layer takes the cochains as they are (a complex may change between layers): a 5 × 4
  // operator into 4 nodes fails in the sum, and the error names the step and its terms, not
  // LibTorch's stack.
  OperatorSchedule s;
  s.input("x_0", 0, 3).input("x_1", 1, 3).operator_input("B", 1, 0);
  s.layer("only").step(into(0).sum(from(0), from(1).via("B")).named("mix"));
  s.output("y", 0);
  OperatorNetwork net(s);
  auto h = net->input_cochains({{"x_0", torch::randn({4, 3})}, {"x_1", torch::randn({4, 3})}});
  try {
    net->run_layer(h, {{"B", random_operator(5, 4, 3).to(torch::kFloat)}}, "only");
    FAIL("a 5-row term summed with a 4-row one ran");
  } catch (const ScheduleError& e) {
    const std::string what = e.what();
    CHECK_THAT(what, Contains("mix (into (0)): the term B·(1) gives 5 rows, the term (0) gives "
                              "4: the terms of a step must give one row per cell of its target"));
    CHECK(what.find('\n') == std::string::npos);  // no LibTorch stack
  }
}

// The internal run_groups is not proposed to a caller: the call resolves to a template whose
// static_assert says to write run_layer or forward.
template <class N, class = void>
struct run_groups_says_what_to_write : std::false_type {};
template <class N>
struct run_groups_says_what_to_write<
    N, std::void_t<decltype(std::declval<N&>().run_groups(
           std::declval<Cochains&>(), std::declval<const std::map<std::string, SparseOperator>&>(),
           nullptr, std::size_t{0}, std::size_t{1}, true))>>
    : std::is_same<decltype(std::declval<N&>().run_groups(
                       std::declval<Cochains&>(),
                       std::declval<const std::map<std::string, SparseOperator>&>(), nullptr,
                       std::size_t{0}, std::size_t{1}, true)),
                   topos::detail::Unavailable> {};

TEST_CASE("a call to the internal run_groups says what to write instead", "[nn][schedule]") {
  STATIC_REQUIRE(run_groups_says_what_to_write<OperatorNetworkImpl>::value);
}

TEST_CASE("features with leading batch dimensions run element by element, as TopoModelX's",
          "[nn][schedule]") {
  // SCoNe on a batch of 3 trajectories of edge features: (3, edges, channels).
  const auto B1 = random_operator(4, 6, 5), B2 = random_operator(6, 2, 6);
  models::SCoNe net(models::SCoNeOptions(2, 5, 2));
  net->to(torch::kDouble);
  torch::manual_seed(8);
  const auto x = torch::randn({3, 6, 2}, torch::kDouble);
  const auto batched = net->forward(x, B1, B2);
  REQUIRE(batched.sizes() == torch::IntArrayRef({3, 6, 5}));
  for (std::int64_t b = 0; b < 3; ++b)
    CHECK(torch::allclose(batched[b], net->forward(x[b], B1, B2), 1e-6, 1e-7));
  // Two leading dimensions, and gradients through the stack.
  const auto x4 = torch::randn({2, 3, 6, 2}, torch::dtype(torch::kDouble).requires_grad(true));
  const auto y4 = net->forward(x4, B1, B2);
  REQUIRE(y4.sizes() == torch::IntArrayRef({2, 3, 6, 5}));
  y4.sum().backward();
  CHECK(x4.grad().abs().sum().item<double>() > 0);
  // Inputs must agree on their leading dimensions.
  OperatorSchedule s;
  s.input("a", 0, 2).input("b", 1, 2).operator_input("B", 1, 0);
  s.step(into(0).sum(from(0), from(1).via("B")));
  s.output("y", 0);
  OperatorNetwork two(s);
  CHECK_THROWS_WITH(two->forward({{"a", torch::ones({3, 4, 2}, torch::kDouble)},
                                  {"b", torch::ones({2, 6, 2}, torch::kDouble)}},
                                 {{"B", random_operator(4, 6, 7)}}),
                    Contains("input 'b' has leading dimensions [2] but input 'a' has [3]"));
}

TEST_CASE("a filter's taps weighted on their source's rows: the sums and gradients as written",
          "[nn][schedule]") {
  // Ranks of 4, 30 and 6 cells into rank 1 (30): the taps from ranks 0 and 2 cost less weighted
  // on their source's rows, then carried by their chains (a shared prefix, a row-normalised
  // product, a tap given twice); the taps from rank 1, one not a product, stay stacked.
  const auto B1 = random_operator(4, 30, 31), B2 = random_operator(30, 6, 32);
  const auto Ld = random_operator(30, 30, 33, 0.1), Lu = random_operator(30, 30, 34, 0.1);
  const std::int64_t c = 8;
  OperatorSchedule s;
  for (int r = 0; r < 3; ++r) s.input("x_" + std::to_string(r), r, c);
  s.operator_input("B1", 1, 0).operator_input("B2", 2, 1);
  s.operator_input("Ld", 1, 1).operator_input("Lu", 1, 1);
  s.step(into(1)
             .filter("w", c, from(0).via_t("B1"), from(0).via_t("B1").via("Ld"),
                     from(0).via_t("B1").via("Lu", true), from(1), from(1).via("Ld"),
                     from(1).via("Ld"), from(1).via("Lu").act(Activation::tanh), from(2).via("B2"),
                     from(2).via("B2").via("Ld"), from(2).via("B2").via("Ld"))
             .act(Activation::sigmoid));
  s.output("y", 1);
  OperatorNetwork net(s);
  net->to(torch::kDouble);
  torch::manual_seed(35);
  std::map<std::string, torch::Tensor> x;
  for (int r : {0, 1, 2}) {
    const std::int64_t n = r == 0 ? 4 : r == 1 ? 30 : 6;
    x["x_" + std::to_string(r)] = torch::randn({n, c}, torch::kDouble).requires_grad_();
  }
  const std::map<std::string, SparseOperator> ops{{"B1", B1}, {"B2", B2}, {"Ld", Ld}, {"Lu", Lu}};
  auto run = [&](bool fast) {
    net->set_fast_paths(fast);
    net->zero_grad();
    for (auto& [k, v] : x) v.mutable_grad() = torch::Tensor();
    const auto y = net->forward(x, ops).at("y");
    y.pow(3).sum().backward();
    std::vector<torch::Tensor> r{y.detach(), net->parameter("w").grad().clone()};
    for (auto& [k, v] : x) r.push_back(v.grad().clone());
    return r;
  };
  const auto fast = run(true), plain = run(false);
  // By hand, densely.
  const auto W = net->parameter("w");
  const auto b1 = B1.to_dense().t(), b2 = B2.to_dense(), ld = Ld.to_dense(), lu = Lu.to_dense();
  const auto lu_n =
      lu / torch::where(lu.sum(1, true) == 0, torch::ones_like(lu.sum(1, true)), lu.sum(1, true));
  const auto x0 = x["x_0"].detach(), x1 = x["x_1"].detach(), x2 = x["x_2"].detach();
  const std::vector<torch::Tensor> T{
      b1.mm(x0),        ld.mm(b1.mm(x0)), lu_n.mm(b1.mm(x0)),     x1,
      ld.mm(x1),        ld.mm(x1),        torch::tanh(lu.mm(x1)), b2.mm(x2),
      ld.mm(b2.mm(x2)), ld.mm(b2.mm(x2))};
  auto z = torch::zeros({30, c}, torch::kDouble);
  for (std::size_t k = 0; k < T.size(); ++k) z += T[k].mm(W.select(2, static_cast<long>(k)));
  CHECK(torch::allclose(fast[0], torch::sigmoid(z), 1e-12, 1e-12));
  for (std::size_t i = 0; i < fast.size(); ++i) {
    INFO("tensor " << i);
    CHECK(torch::allclose(fast[i], plain[i], 1e-10, 1e-12));
  }
  // The fast path ran: its sums are taken in another order.
  CHECK_FALSE(torch::equal(fast[0], plain[0]));
}

TEST_CASE("plan_str lists what forward runs with its FLOPs, counted by hand",
          "[nn][schedule][plan]") {
  // Nodes (5, 3 channels), edges (7, 2 channels); B: nodes × edges, L: nodes × nodes, T: edges ×
  // edges, each with a known pattern.
  const auto pattern = [](std::int64_t r, std::int64_t c, int k) {
    auto d = torch::zeros({r, c}, torch::kDouble);
    for (std::int64_t i = 0; i < r; ++i)
      for (std::int64_t j = 0; j < c; ++j)
        if ((i + 2 * j) % k == 0) d[i][j] = 1.0 + static_cast<double>(i + j);
    return d;
  };
  const auto Bd = pattern(5, 7, 3), Ld = pattern(5, 5, 2), Td = pattern(7, 7, 4);
  const auto nnz = [](const torch::Tensor& d) { return (d != 0).sum().item<std::int64_t>(); };
  OperatorSchedule s;
  s.input("x_0", 0, 3).input("x_1", 1, 2).operator_input("B", 1, 0).operator_input("L", 0, 0);
  s.operator_input("T", 1, 1).optional_operator("U", 0, 0);
  s.step(into(0)
             .sum(from(0).conv("a", 4).via("L").act(Activation::relu),
                  from(1).via("B").linear("b", 4), from(0).via("U").conv("u", 4))
             .weight("c", 2, 1.0)
             .act(Activation::tanh)
             .named("mix"));
  s.step(into(1).filter("f", 3, from(0).via_t("B"), from(1).powers({{"T", 2}})).named("filter"));
  s.step(into(1, "unused").sum(from(1).conv("dead", 5)).named("dead"));
  s.step(into(0).sum(from(0).via("U").conv("kept", 3)).named("kept"));
  s.output("y_1", 1);
  OperatorNetwork net(s);
  net->to(torch::kDouble);
  const std::map<std::string, torch::Tensor> x{{"x_0", torch::randn({5, 3}, torch::kDouble)},
                                               {"x_1", torch::randn({7, 2}, torch::kDouble)}};
  const std::map<std::string, SparseOperator> ops{{"B", SparseOperator::from_dense(Bd)},
                                                  {"L", SparseOperator::from_dense(Ld)},
                                                  {"T", SparseOperator::from_dense(Td)}};
  const auto plan = net->plan_str(x, ops);
  INFO(plan);
  // mix: x_0·a (5 × 3 · 3 × 4), L·, B· on 2 channels, b (2 -> 4 on 5 rows), ·c (4 -> 2); the
  // term through the optional U, not given, is skipped. filter: Bᵀ· on 2 channels, T· twice on
  // 2, the taps (7 rows, 2 channels × 4 taps, 3 out). The dead step does not run.
  const std::int64_t mix = 2 * 5 * 3 * 4 + 2 * nnz(Ld) * 4 + 2 * nnz(Bd) * 2 + 2 * 5 * 2 * 4 +
                           2 * 5 * 4 * 2,
                     filter = 2 * nnz(Bd) * 2 + 2 * 2 * nnz(Td) * 2 + 2 * 7 * (2 * 4) * 3;
  CHECK_THAT(plan, Contains("step mix (into (0)"));
  // fuse_products: x_0·a, L· and relu run as one node; B· then b (a Linear, not a weight) do not.
  CHECK_THAT(plan, Contains("x·a.weight  dense 2·5·3·4  120 FLOPs  (one node with the next two)"
                            "  -> 5 × 4\n"));
  CHECK_THAT(plan, Contains("b(x)  dense 2·5·2·4  80 FLOPs  -> 5 × 4\n"));
  CHECK_THAT(plan, Contains("sparse 2·" + std::to_string(nnz(Ld)) + "·4  " +
                            std::to_string(2 * nnz(Ld) * 4) + " FLOPs"));
  CHECK_THAT(plan, Contains("filter f  dense 2·7·8·3  336 FLOPs"));
  CHECK(plan.find("U·") == std::string::npos);
  CHECK(plan.find("dead") == std::string::npos);
  auto total = plan.substr(plan.rfind("total ") + 6);
  total.erase(std::remove(total.begin(), total.end(), ','), total.end());
  CHECK(std::stoll(total) == mix + filter);

  // The plan itself: its total, and each step's route.
  const auto p = net->plan(x, ops);
  CHECK(p.total_flops == mix + filter);
  CHECK(p.str() == plan);
  // The buffers the operations write (plain order), by hand: mix's term from (0) 5 × 4 three
  // times (x·a, L·, relu), from (1) B· 5 × 2 and b 5 × 4, its operations 5 × 2 twice; filter's
  // Bᵀ· 7 × 2 (x_0 has the mix's 2 channels by then), the powers' three terms (x, T·x, T²·x) 7 × 2
  // each, the taps' product 7 × 3.
  const std::int64_t mix_values = 3 * 5 * 4 + 5 * 2 + 5 * 4 + 2 * 5 * 2,
                     filter_values = 7 * 2 + 3 * 7 * 2 + 7 * 3;
  CHECK(p.total_values == mix_values + filter_values);
  CHECK(p.value_bytes == 8);  // double
  CHECK_THAT(plan, Contains("relu(x)  -> 5 × 4\n"));
  CHECK_THAT(plan, Contains(" FLOPs  -> 7 × 2, 3 terms\n"));
  CHECK_THAT(plan, Contains("filter f  dense 2·7·8·3  336 FLOPs  -> 7 × 3\n"));
  CHECK_THAT(plan, EndsWith("\nbuffers 187 values (1.5 KiB)\n"));  // 187 · 8 = 1,496 bytes
  CHECK(p.absent == std::set<std::string>{"U"});
  CHECK_FALSE(p.over_batch);
  const auto step = [](const Plan& pl, const std::string& name) -> const PlannedStep& {
    for (const auto& group : pl.groups)
      for (const auto& ps : group)
        if (ps.step->name == name) return ps;
    throw std::runtime_error("no step " + name);
  };
  CHECK(step(p, "mix").route == StepRoute::general);
  CHECK(step(p, "mix").terms.size() == 2);               // the term through U is left out
  CHECK(step(p, "filter").route == StepRoute::general);  // powers fan out into more taps
  CHECK(step(p, "dead").route == StepRoute::chain);
  CHECK_FALSE(step(p, "dead").live);
  CHECK(step(p, "kept").route == StepRoute::keep);
  CHECK_THAT(plan, Contains("step filter (into (1), group 1): general"));
  CHECK_THAT(plan, Contains("fast paths: row_subset, prefix_cache, compact_cochains"));
  // With U given, the kept step is one chain.
  auto with_u = ops;
  with_u.emplace("U", SparseOperator::from_dense(Ld));
  CHECK(step(net->plan(x, with_u), "kept").route == StepRoute::chain);
  CHECK_THAT(net->plan(x, with_u).str(), Contains("U·x  sparse 2·" + std::to_string(nnz(Ld)) +
                                                  "·3  " + std::to_string(2 * nnz(Ld) * 3) +
                                                  " FLOPs  (one node with the next operation)"
                                                  "  -> 5 × 3\n"));
  net->set_fast_paths(false);
  CHECK_THAT(net->plan(x, ops).str(), StartsWith("fast paths: none\n"));
  CHECK(net->plan(x, ops).str().find("one node") == std::string::npos);

  // A filter whose taps are one each: filter taps, or with filter_taps off the general way, with
  // the same numbers up to rounding.
  OperatorSchedule f;
  f.input("x_0", 0, 3).input("x_1", 1, 2).operator_input("T", 1, 1);
  f.step(
      into(1).filter("f", 3, from(1), from(1).via("T"), from(1).via("T").via("T")).named("taps"));
  f.output("y_1", 1);
  OperatorNetwork taps(f);
  taps->to(torch::kDouble);
  CHECK(step(taps->plan(x, ops), "taps").route == StepRoute::filter);
  const auto fast = taps->forward(x, ops).at("y_1");
  taps->fast_paths().filter_taps(false);
  const auto slow = taps->plan(x, ops);
  CHECK(step(slow, "taps").route == StepRoute::general);
  CHECK_THAT(slow.str(), Contains("fast paths: row_subset, prefix_cache, compact_cochains, "
                                  "split_first_layer, reorder_products, fuse_activations, "
                                  "fuse_products, fuse_attention, fuse_residuals, "
                                  "csr_aggregation\n"));
  CHECK(torch::allclose(taps->forward(x, ops).at("y_1"), fast, 1e-12, 1e-12));
}

TEST_CASE("a plan counts the products of head weights, GCN's and GAT's propagation",
          "[nn][schedule][plan]") {
  // Nodes (5, 3 channels) on a ring without self-loops (A: 10 entries), edges (4, 3 channels),
  // B: nodes × edges.
  auto Ad = torch::zeros({5, 5}), Bd = torch::zeros({5, 4});
  for (std::int64_t i = 0; i < 5; ++i) Ad[i][(i + 1) % 5] = 1, Ad[(i + 1) % 5][i] = 1;
  for (std::int64_t j = 0; j < 4; ++j) Bd[j][j] = 1, Bd[j + 1][j] = 1;  // 8 entries
  OperatorSchedule s;
  s.input("x_0", 0, 3).input("x_1", 1, 3).operator_input("A", 0, 0).operator_input("B", 1, 0);
  s.step(into(0, "h").sum(from(0).head_weights("hw", 2, 4)).named("heads"));
  s.step(into(0, "g").sum(from(0).gcn("A")).named("gcn"));
  s.step(into(0, "a").sum(from(0).gat("A", "att")).named("gat"));
  s.step(into(0, "t")
             .sum(from(1).gat("B", "att_t", GatOptions().part(GatPart::union_targets)))
             .named("gat_targets"));
  s.output("h", 0, "h").output("g", 0, "g").output("a", 0, "a").output("t", 0, "t");
  OperatorNetwork net(s);
  const std::map<std::string, torch::Tensor> x{{"x_0", torch::randn({5, 3})},
                                               {"x_1", torch::randn({4, 3})}};
  const std::map<std::string, SparseOperator> ops{{"A", SparseOperator::from_dense(Ad)},
                                                  {"B", SparseOperator::from_dense(Bd)}};
  const auto p = net->plan(x, ops);
  INFO(p.str());
  // Two heads of 4 side by side: 5 rows, 3 -> 8. GCN and GAT over the graph: its 10 entries and a
  // self-loop per node; GAT's targets' part: each of the 5 targets itself, and B's 8 entries.
  CHECK_THAT(p.str(), Contains("x·hw[×2]  dense 2·5·3·8  240 FLOPs  -> 5 × 8\n"));
  CHECK_THAT(p.str(), Contains("gcn[A](x)  sparse 2·15·3  90 FLOPs  -> 5 × 3\n"));
  CHECK_THAT(p.str(), Contains("gat[A](x)  sparse 2·15·3  90 FLOPs  -> 5 × 3\n"));
  CHECK_THAT(p.str(), Contains("gat[B, targets](x)  sparse 2·13·3  78 FLOPs  -> 5 × 3\n"));
  CHECK(p.total_flops == 240 + 90 + 90 + 78);
}

TEST_CASE("a step kept as it was lists no operation, FLOPs or buffer", "[nn][schedule][plan]") {
  // Its one term goes through U, left out: the target stays, so its weight and relu never run.
  OperatorSchedule s;
  s.input("x_0", 0, 3).optional_operator("U", 0, 0);
  s.step(into(0).sum(from(0).via("U")).weight("w", 3).act(Activation::relu).named("k"));
  s.output("y", 0);
  OperatorNetwork net(s);
  const auto x = torch::randn({4, 3});
  const auto p = net->plan({{"x_0", x}}, {});
  REQUIRE(p.groups.size() == 1);
  REQUIRE(p.groups[0].size() == 1);
  CHECK(p.groups[0][0].route == StepRoute::keep);
  CHECK(p.groups[0][0].lines.empty());
  CHECK(p.total_flops == 0);
  CHECK(p.total_values == 0);
  CHECK_THAT(p.str(), Contains("step k (into (0), group 0): keep\ntotal 0 FLOPs\n"));
  CHECK(torch::equal(net->forward({{"x_0", x}}, {}).at("y"), x));
}

TEST_CASE("dropout(0) is left out and a LayerNorm fuses the activation after it",
          "[nn][schedule][fast_paths]") {
  // TopoBench's AllSetTransformer: Linear, dropout(0), relu; LayerNorm, relu, dropout(0).
  OperatorSchedule s;
  s.input("x", 0, 6);
  s.step(into(0, "h")
             .sum(from(0).linear("l", 6, false).dropout(0).act(Activation::relu))
             .named("mlp"));
  s.step(into(0)
             .sum(from(0), from(0, "h"))
             .layer_norm("ln")
             .act(Activation::relu)
             .dropout(0)
             .named("norm"));
  s.output("y", 0);
  CHECK(s.str().find("dropout") == std::string::npos);
  OperatorNetwork net(s);
  net->to(torch::kDouble);
  torch::manual_seed(5);
  const auto x0 = torch::randn({40, 6}, torch::kDouble).requires_grad_();
  const auto run = [&](bool fast) {
    net->set_fast_paths(fast);
    net->zero_grad();
    const auto x = x0.detach().clone().requires_grad_();
    const auto y = net->forward({{"x", x}}, {}).at("y");
    (y * torch::linspace(-1, 1, 6, torch::kDouble)).sum().backward();
    return std::make_tuple(y, x.grad(), net->named_parameters()["ln.weight"].grad().clone(),
                           net->named_parameters()["l.weight"].grad().clone());
  };
  const auto [y, dx, dln, dl] = run(true);
  // One node each: the Linear's kernel applies the relu, the LayerNorm's kernel its relu.
  REQUIRE(y.grad_fn()->name().find("LayerNorm") != std::string::npos);
  REQUIRE((y == 0).any().item<bool>());
  const auto [y_plain, dx_plain, dln_plain, dl_plain] = run(false);
  REQUIRE(y_plain.grad_fn()->name().find("Relu") != std::string::npos);
  CHECK(torch::equal(y, y_plain));
  CHECK(torch::allclose(dx, dx_plain, 1e-12, 1e-12));
  CHECK(torch::allclose(dln, dln_plain, 1e-12, 1e-12));
  CHECK(torch::allclose(dl, dl_plain, 1e-12, 1e-12));
  // A rate outside [0, 1] is still refused when the network is built.
  OperatorSchedule bad;
  bad.input("x", 0, 2).output("y", 0);
  bad.step(into(0).sum(from(0).dropout(-0.5)).named("neg"));
  CHECK_THAT(build_error(bad), Contains("neg (into (0)): a dropout rate"));
}

TEST_CASE("fuse_residuals: a sum of two terms, or a bias, forms in the LayerNorm after it",
          "[nn][schedule][fast_paths]") {
  // AllSetTransformer's block: messages plus a bias (the query) into a LayerNorm; then the
  // residual sum into a LayerNorm and its relu.
  OperatorSchedule s;
  s.input("x", 0, 8);
  s.step(into(0, "h").sum(from(0).linear("l", 8).bias("q", {2, 4}).layer_norm("ln0")).named("pma"));
  s.step(into(0)
             .sum(from(0), from(0, "h").linear("m", 8, false).act(Activation::relu))
             .layer_norm("ln1")
             .act(Activation::relu)
             .named("residual"));
  s.step(into(0).sum(from(0), from(0, "h")).mean().layer_norm("ln2").named("mean"));  // not a sum
  s.output("y", 0);
  OperatorNetwork net(s);
  net->to(torch::kDouble);
  torch::manual_seed(7);
  {
    torch::NoGradGuard no_grad;
    net->named_parameters()["q"].normal_();
  }
  const auto x0 = torch::randn({300, 8}, torch::kDouble);
  const auto run = [&](FastPaths f) {
    net->fast_paths() = f;
    net->zero_grad();
    const auto x = x0.clone().requires_grad_();
    const auto y = net->forward({{"x", x}}, {}).at("y");
    (y * torch::linspace(-1, 1, 8, torch::kDouble)).sum().backward();
    std::vector<torch::Tensor> out{y, x.grad()};
    for (const auto& p : net->parameters()) out.push_back(p.grad().clone());
    return out;
  };
  const auto fused = run(FastPaths::none().fuse_residuals(true).fuse_activations(true));
  const auto plain = run(FastPaths::none().fuse_activations(true));
  const auto alone = run(FastPaths::none().fuse_residuals(true));  // the relu on its own
  const auto off = run(FastPaths::none());
  const auto all = run(FastPaths::all());
  REQUIRE(fused.size() == plain.size());
  for (std::size_t i = 0; i < fused.size(); ++i) {
    INFO("value " << i);
    // The sum formed in the kernel is torch's add's, normalised by the same kernel.
    CHECK(torch::allclose(fused[i], plain[i], 1e-12, 1e-12));
    CHECK(torch::allclose(alone[i], off[i], 1e-12, 1e-12));
    CHECK(torch::allclose(fused[i], off[i], 1e-12, 1e-12));
    CHECK(torch::allclose(all[i], off[i], 1e-12, 1e-12));
  }
  CHECK(torch::equal(fused[0], plain[0]));
  CHECK(torch::equal(alone[0], off[0]));
  // The nodes: with the fast path no add is left between the products and the LayerNorms.
  net->fast_paths() = FastPaths::none().fuse_residuals(true).fuse_activations(true);
  const auto y = net->forward({{"x", x0.clone().requires_grad_()}}, {}).at("y");
  std::set<std::string> names;
  std::vector<torch::autograd::Node*> todo{y.grad_fn().get()};
  while (!todo.empty()) {
    auto* n = todo.back();
    todo.pop_back();
    const auto id = n ? n->name() + "@" + std::to_string(reinterpret_cast<std::uintptr_t>(n)) : "";
    if (n == nullptr || !names.insert(id).second) continue;
    for (const auto& e : n->next_edges()) todo.push_back(e.function.get());
  }
  int adds = 0, norms = 0;
  for (const auto& n : names) {
    adds += n.rfind("AddBackward", 0) == 0;
    norms += n.find("LayerNormFunction") != std::string::npos;
  }
  CHECK(norms == 3);
  CHECK(adds == 1);  // the mean step's sum, which is not fused
  // A user's operation declaring the traits gets the path: forward_residual with the two terms.
  struct Doubled final : Operation {
    mutable int fused_calls = 0;
    std::string str(const std::string& x) const override { return "2·(" + x + ")"; }
    TermShape infer(BuildContext&, TermShape x) const override { return x; }
    torch::Tensor forward(RunContext&, const torch::Tensor& x) const override { return 2 * x; }
    torch::Tensor forward_residual(RunContext& ctx, const torch::Tensor& x, const torch::Tensor& r,
                                   std::optional<Activation> a, double slope) const override {
      ++fused_calls;
      return Operation::forward_residual(ctx, x, r, a, slope);
    }
    OperationTraits traits() const override {
      OperationTraits t;
      t.fuses_residual = true;
      return t;
    }
  };
  auto doubled = std::make_shared<Doubled>();
  OperatorSchedule u;
  u.input("x", 0, 3).output("y", 0);
  u.step(into(0).sum(from(0), from(0).scale(3)).apply(doubled).act(Activation::relu));
  OperatorNetwork user(u);
  const auto xu = torch::randn({4, 3});
  CHECK(torch::allclose(user->forward({{"x", xu}}, {}).at("y"), torch::relu(8 * xu)));
  CHECK(doubled->fused_calls == 1);
  user->fast_paths().fuse_residuals(false);
  CHECK(torch::allclose(user->forward({{"x", xu}}, {}).at("y"), torch::relu(8 * xu)));
  CHECK(doubled->fused_calls == 1);
  // An operation declaring a row offset that is no parameter: a clear error when the fused path
  // would read it, not an out-of-range exception.
  struct Offset final : Operation {
    std::string str(const std::string& x) const override { return x + " + missing"; }
    TermShape infer(BuildContext&, TermShape x) const override { return x; }
    torch::Tensor forward(RunContext&, const torch::Tensor& x) const override { return x; }
    OperationTraits traits() const override {
      OperationTraits t;
      t.row_offset = "missing";
      return t;
    }
  };
  OperatorSchedule bad;
  bad.input("x", 0, 3).output("y", 0);
  bad.step(into(0).sum(from(0).apply(Offset()).layer_norm("ln")).named("offset"));
  OperatorNetwork offset(bad);
  CHECK_THROWS_WITH(offset->forward({{"x", xu}}, {}),
                    Contains("offset (into (0))") &&
                        Contains("declares the row offset 'missing', which is no parameter"));
}

TEST_CASE("FastPaths: each fast path by name, all and none", "[nn][schedule][fast_paths]") {
  CHECK(FastPaths::names().size() == 11);
  for (const auto& name : FastPaths::names()) {
    CHECK(FastPaths().get(name));
    CHECK_FALSE(FastPaths::none().get(name));
    CHECK(FastPaths::none().set(name, true).get(name));
  }
  CHECK_FALSE(FastPaths().prefix_cache(false).prefix_cache());
  REQUIRE_THROWS_WITH(FastPaths().set("prefix", true),
                      Contains("no fast path 'prefix'") && Contains("prefix_cache"));
  OperatorSchedule s;
  s.input("x", 0, 2).operator_input("A", 0, 0).step(into(0).sum(from(0).via("A"))).output("y", 0);
  OperatorNetwork net(s);
  net->fast_paths().fuse_activations(false);
  CHECK_FALSE(net->fast_paths().fuse_activations());
  CHECK(net->fast_paths().row_subset());
  net->set_fast_paths(false);
  CHECK_FALSE(net->fast_paths().row_subset());
}
