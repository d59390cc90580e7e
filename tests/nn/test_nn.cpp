// Tests of topos/nn: aggregations against hand-written loops, the Mlp block, ComplexBatch, the
// operator schedule over a batch's neighbourhoods (mlps, roles, guards, the fast paths against
// the plain ones, finite-difference gradients in double, batching, empty ranks, errors) and
// parameter save/load by name.
#include "support/torch_prelude.hpp"
#include "support/threads.hpp"

#include "topos/core/mesh_lifting.hpp"
#include "topos/mesh/primitives.hpp"
#include "topos/nn/cloneable.hpp"
#include "topos/nn/cpu.hpp"
#include "topos/nn/device.hpp"
#include "topos/nn/distributed.hpp"
#include "topos/nn/operator_schedule.hpp"
#include "topos/nn/serialization.hpp"

#include <caffe2/serialize/inline_container.h>

#include <array>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <random>
#include <set>
#include <mutex>
#include <thread>
#include <tuple>
#if defined(_OPENMP)
#include <omp.h>
#endif

#include <unistd.h>

using namespace topos;
using namespace topos::nn;
using namespace topos::nn::ops;

namespace {

// Two small closed meshes; faces are per-complex cells; optionally a "contact" rank-3 cell
// joining face 0 of object 0 (role -1) and face 0 of object 1 (role +1).
ComplexView make_view(int variant, bool with_contact) {
  auto lifted =
      lift_meshes({box_mesh(1), uv_sphere(3, 4 + variant)}, LiftOptions().with_object_rank(4));
  auto& cc = lifted.complex;
  if (with_contact) {
    const auto f0 = lifted.faces.row(0), f1 = lifted.faces.row(lifted.face_offset[1]);
    std::vector<std::int64_t> nodes{f0(0), f0(1), f0(2), f1(0), f1(1), f1(2)};
    auto a = cc.find({f0(0), f0(1), f0(2)})->id, b = cc.find({f1(0), f1(1), f1(2)})->id;
    cc.add_cell(nodes, 3, {{2, a, -1.0, -1}, {2, b, 1.0, 1}});
  }
  ComplexView v;
  v.sizes = cc.shape();
  v.sizes.resize(5, 0);
  v.neighborhoods["B01"] = incidence_neighborhood(cc, 0, 1);
  v.neighborhoods["B02"] = incidence_neighborhood(cc, 0, 2);
  v.neighborhoods["B12"] = incidence_neighborhood(cc, 1, 2);
  v.neighborhoods["B04"] = incidence_neighborhood(cc, 0, 4);
  v.neighborhoods["B40"] = incidence_neighborhood(cc, 4, 0);
  if (with_contact) {
    v.neighborhoods["B23"] = incidence_neighborhood(cc, 2, 3);
    v.neighborhoods["B32"] = incidence_neighborhood(cc, 3, 2);
  } else {
    Neighborhood e23;
    e23.source_rank = 2;
    e23.target_rank = 3;
    e23.num_source = cc.size(2);
    e23.num_target = 0;
    e23.roles = {};
    v.neighborhoods["B23"] = e23;
    v.neighborhoods["B32"] = e23.reversed("B32");
  }
  return v;
}

/// The second view of a rank-3 cell's features: column 0 negated, then columns (1, 0, 2).
struct SwapView : Operation {
  std::string str(const std::string& x) const override { return "swap(" + x + ")"; }
  TermShape infer(BuildContext& ctx, TermShape x) const override {
    if (x.channels != 3) ctx.fail("swap needs 3 channels");
    return x;
  }
  torch::Tensor forward(RunContext&, const torch::Tensor& x) const override {
    auto sign = torch::ones({3}, x.options());
    sign[0] = -1;
    return (x * sign).index_select(1, torch::tensor({1, 0, 2}, torch::kLong));
  }
};

// A multi-step schedule over a batch's neighbourhoods with roles, guards, a maximum and a
// parallel group; hidden width D.
OperatorSchedule test_schedule(std::int64_t D, Activation act = Activation::gelu) {
  const auto m = [&](std::int64_t in, std::int64_t out, bool last = true) {
    return MlpOptions(in, D, out).final_activation(last).layer_norm(last).activation(act);
  };
  OperatorSchedule s;
  for (auto [name, rank, width] : std::vector<std::tuple<std::string, int, int>>{
           {"x0", 0, 3}, {"x1", 1, 2}, {"x2", 2, 2}, {"x3", 3, 3}, {"x4", 4, 2}})
    s.input(name, rank, width, "x");
  s.operator_input("B01", 0, 1).operator_input("B02", 0, 2).operator_input("B12", 1, 2);
  s.operator_input("B04", 0, 4).operator_input("B40", 4, 0).operator_input("B23", 2, 3);
  s.operator_input("B32", 3, 2);
  s.parallel(
      {into(0).sum(from(0, "x").mlp("e0", m(3, D))), into(1).sum(from(1, "x").mlp("e1", m(2, D))),
       into(2).sum(from(2, "x").mlp("e2", m(2, D))), into(4).sum(from(4, "x").mlp("e4", m(2, D))),
       into(3, "minus").sum(from(3, "x").mlp("e3", m(3, D))),
       into(3, "plus").sum(from(3, "x").apply(SwapView()).mlp("e3", m(3, D)))});
  s.step(into(2)
             .concat(from(2), from(0).mlp("p02", m(D, D)).pattern("B02"),
                     from(1).mlp("p12", m(D, D)).pattern("B12", Aggr::mean))
             .mlp("u2", m(3 * D, D)));
  const auto side = [&](int role) { return from(2).mlp("p23", m(D, D)).pattern("B23").only(role); };
  s.step(into(3, "plus")
             .concat(from(3, "plus"), side(-1), side(1))
             .mlp("u3", m(3 * D, D))
             .when_nonempty(3));
  s.step(into(2)
             .concat(from(2), from(3, "plus").pattern("B32").only(1),
                     from(3, "minus").pattern("B32").only(-1))
             .mlp("u2b", m(3 * D, D))
             .when_nonempty(3));
  s.parallel(
      {into(0).concat(from(0), from(4).mlp("p40", m(D, D)).pattern("B40")).mlp("u0", m(2 * D, D)),
       into(4)
           .concat(from(4), from(0).mlp("p04", m(D, D)).pattern("B04", Aggr::max))
           .mlp("u4", m(2 * D, D))});
  s.step(into(0, "a0").sum(from(0).mlp("d0", m(D, 3, false))));
  s.step(into(2, "a2").sum(from(2).mlp("d2", m(D, 1, false))));
  s.output("a0", 0, "a0").output("a2", 2, "a2");
  return s;
}

std::map<std::string, torch::Tensor> random_inputs(const ComplexBatch& b, torch::Dtype dt,
                                                   int seed) {
  torch::manual_seed(seed);
  return {{"x0", torch::randn({b.size(0), 3}, dt)},
          {"x1", torch::randn({b.size(1), 2}, dt)},
          {"x2", torch::randn({b.size(2), 2}, dt)},
          {"x3", torch::randn({b.size(3), 3}, dt)},
          {"x4", torch::randn({b.size(4), 2}, dt)}};
}

}  // namespace

TEST_CASE("dropout keeps 1 - p of the entries, scaled, repeatably, with its mask as gradient",
          "[nn][dropout]") {
  // 0.5 and 0.75 take 8 bits an element (8 a draw), 1/1024 16 bits, 0.1 32 bits.
  for (double p : {0.1, 0.5, 0.75, 1.0 / 1024}) {
    INFO("p = " << p);
    const std::int64_t n = 1'000'003;  // not a multiple of 8: the last elements take part of a draw
    const auto x = torch::ones({n}, torch::kFloat).requires_grad_(true);
    torch::manual_seed(7);
    const auto y = nn::dropout(x, p, true);
    const auto kept = y.ne(0);
    // Binomial(n, 1 - p): within 5 standard deviations.
    const double frac = kept.to(torch::kDouble).mean().item<double>();
    CHECK(std::abs(frac - (1 - p)) < 5 * std::sqrt(p * (1 - p) / static_cast<double>(n)));
    CHECK(torch::allclose(y.masked_select(kept), torch::full({1}, 1 / (1 - p))));
    // Neighbouring elements (lanes of one 64-bit draw, and of consecutive draws) independent.
    const auto k = kept.to(torch::kDouble);
    for (std::int64_t lag : {1, 2, 3, 4, 5, 7, 8, 9}) {
      const auto a = k.slice(0, 0, n - lag) - (1 - p), b = k.slice(0, lag) - (1 - p);
      CHECK(std::abs((a * b).mean().item<double>()) < 5 * p * (1 - p) / std::sqrt(double(n)));
    }
    // The gradient is the mask; the same seed gives the same mask, the next call another.
    y.sum().backward();
    CHECK(torch::equal(x.grad(), y.detach()));
    torch::manual_seed(7);
    CHECK(torch::equal(nn::dropout(x, p, true), y));
    CHECK_FALSE(torch::equal(nn::dropout(x, p, true), y));
    // Threads split the draws by position, so any thread count gives the same mask.
    const int threads = at::get_num_threads();
    at::set_num_threads(2);
    torch::manual_seed(7);
    CHECK(torch::equal(nn::dropout(x, p, true), y));
    at::set_num_threads(threads);
  }
  const auto x = torch::randn({5, 3}, torch::kDouble);
  CHECK(torch::equal(nn::dropout(x, 0.5, false), x));  // evaluation: the identity
  CHECK(torch::equal(nn::dropout(x, 0.0, true), x));
  CHECK(nn::dropout(x, 1.0, true).eq(0).all().item<bool>());
  const auto y = nn::dropout(x, 0.5, true);
  CHECK((y.eq(0) | y.isclose(2 * x)).all().item<bool>());
  CHECK_THROWS_WITH(nn::dropout(x, 1.5, true), Catch::Contains("rate 1.5"));
  // A transposed (non-contiguous) input: the backward draws the same mask again, so the
  // gradient of <y, g> is g where y kept x (scaled), 0 elsewhere; and differentiates again.
  const auto xt = torch::randn({40, 30}, torch::kFloat).t().requires_grad_(true);
  const auto g = torch::randn({30, 40});
  const auto yt = nn::dropout(xt, 0.25, true);
  const auto kept_t = yt.detach().ne(0);
  CHECK(torch::allclose(yt.detach(), torch::where(kept_t, xt.detach() / 0.75, torch::zeros({}))));
  const auto dx = torch::autograd::grad({(yt * g).sum()}, {xt}, {}, true, true)[0];
  CHECK(torch::allclose(dx, torch::where(kept_t, g / 0.75, torch::zeros({}))));
  const auto z = nn::dropout(xt * xt, 0.25, true);  // d²<z, g>/dx² summed: 2 g where kept
  const auto kept_z = z.detach().ne(0);
  const auto dz = torch::autograd::grad({(z * g).sum()}, {xt}, {}, true, true)[0];
  const auto ddz = torch::autograd::grad({dz.sum()}, {xt})[0];
  CHECK(torch::allclose(ddz, torch::where(kept_z, 2 * g / 0.75, torch::zeros({}))));
}

TEST_CASE("a state snapshot restores parameters and BatchNorm's running statistics",
          "[nn][snapshot]") {
  torch::manual_seed(3);
  torch::nn::Sequential net(torch::nn::Linear(4, 5), torch::nn::BatchNorm1d(5));
  net->train();
  for (int i = 0; i < 3; ++i) net->forward(torch::randn({16, 4}));  // running stats move
  const auto x = torch::randn({7, 4});
  net->eval();
  const auto at_best = net->forward(x).detach().clone();
  const topos::nn::StateSnapshot best(*net);
  CHECK_FALSE(best.empty());
  std::vector<torch::Tensor> params_at_best;  // what the TopoBench loop used to keep
  for (const auto& p : net->parameters()) params_at_best.push_back(p.detach().clone());
  // Training goes on: the weights and the running statistics change.
  net->train();
  torch::optim::SGD opt(net->parameters(), 0.5);
  for (int i = 0; i < 3; ++i) {
    opt.zero_grad();
    net->forward(torch::randn({16, 4}) * 3 + 1).pow(2).sum().backward();
    opt.step();
  }
  net->eval();
  REQUIRE_FALSE(torch::allclose(net->forward(x), at_best));
  // Restoring only the parameters (what the TopoBench loop did) leaves the last statistics.
  {
    torch::NoGradGuard no_grad;
    auto params = net->parameters();
    for (std::size_t k = 0; k < params.size(); ++k) params[k].copy_(params_at_best[k]);
  }
  CHECK_FALSE(torch::allclose(net->forward(x), at_best));
  best.restore(*net);
  CHECK(torch::equal(net->forward(x), at_best));
  // A module of another shape is refused by name.
  torch::nn::Sequential other(torch::nn::Linear(4, 6), torch::nn::BatchNorm1d(6));
  CHECK_THROWS_WITH(best.restore(*other),
                    Catch::Matchers::Contains("StateSnapshot::restore: parameters '0.weight' is "
                                              "missing or has another shape in the copy"));
  CHECK_THROWS(topos::nn::StateSnapshot().restore(*net));
}

TEST_CASE("aggregations equal hand-written loops", "[nn][aggregate]") {
  Neighborhood n;
  n.source_rank = 0;
  n.target_rank = 1;
  n.num_source = 4;
  n.num_target = 3;
  n.source = {0, 1, 2, 3, 1};
  n.target = {0, 0, 1, 1, 1};
  n.values = {2.0, -1.0, 0.5, 1.0, 3.0};
  n.roles = {1, -1, 1, -1, 1};
  ComplexView v{{4, 3}, {{"n", n}}};
  const auto b = ComplexBatch::collate({v}, 1);
  const auto& tn = b.neighborhood("n");
  const auto x = torch::randn({4, 2}, torch::kDouble);
  auto loop = [&](Aggr r, bool weighted, int role) {
    auto out = torch::zeros({3, 2}, torch::kDouble);
    std::vector<int> count(3, 0);
    std::vector<bool> seen(3, false);
    for (std::size_t k = 0; k < n.source.size(); ++k) {
      if (role != 0 && n.roles[k] != role) continue;
      auto m = x[n.source[k]] * (weighted ? n.values[k] : 1.0);
      const auto t = n.target[k];
      if (r == Aggr::max)
        out[t] = seen[static_cast<std::size_t>(t)] ? torch::max(out[t], m) : m;
      else
        out[t] += m;
      seen[static_cast<std::size_t>(t)] = true;
      ++count[static_cast<std::size_t>(t)];
    }
    if (r == Aggr::mean)
      for (int t = 0; t < 3; ++t)
        if (count[static_cast<std::size_t>(t)]) out[t] /= count[static_cast<std::size_t>(t)];
    return out;
  };
  for (Aggr r : {Aggr::sum, Aggr::mean, Aggr::max})
    for (bool w : {false, true})
      for (int role : {0, 1, -1}) {
        INFO(aggr_name(r) << " weighted " << w << " role " << role);
        for (bool csr : {true, false}) {  // a sum as a CSR product, or gathered rows
          const auto got = aggregate(
              x, tn,
              AggregateOptions().with_reduce(r).with_weighted(w).with_role(role).with_csr(csr));
          REQUIRE(torch::allclose(got, loop(r, w, role), 1e-12, 1e-12));
          REQUIRE(got[2].abs().sum().item<double>() == 0.0);  // target 2 receives nothing
        }
      }
}

TEST_CASE(
    "a sum over a neighbourhood's pairs as a CSR product: the gathered sum's values and "
    "gradients",
    "[nn][aggregate]") {
  // Unsorted pairs with repeats (summed into one entry by the CSR form), a target and a source
  // without pairs, values with a zero; the same neighbourhood read weighted and unweighted, in
  // float and double (each its own cached operator).
  torch::manual_seed(3);
  Neighborhood n;
  n.source_rank = 0;
  n.target_rank = 1;
  n.num_source = 7;
  n.num_target = 6;
  n.source = {4, 0, 2, 2, 5, 1, 0, 3, 2, 5, 4};
  n.target = {3, 0, 5, 5, 0, 2, 3, 1, 0, 2, 3};
  n.values = {0.5, -1.0, 2.0, 0.25, 0.0, 1.5, -2.0, 3.0, 0.75, -0.5, 1.0};
  n.roles = {1, -1, 1, 1, -1, 1, -1, 1, 1, -1, 1};
  const auto b = ComplexBatch::collate({ComplexView{{7, 6}, {{"n", n}}}}, 1);
  const auto& tn = b.neighborhood("n");
  // A sum or a mean, over every pair or one role's (role 2 has none: zeros), weighted or not.
  for (const auto dtype : {torch::kFloat, torch::kDouble})
    for (const auto r : {Aggr::sum, Aggr::mean})
      for (int role : {0, 1, -1, 2})
        for (bool w : {false, true})
          for (int repeat = 0; repeat < 2; ++repeat) {  // the second time from the cache
            INFO("dtype " << dtype << " " << aggr_name(r) << " role " << role << " weighted " << w
                          << " repeat " << repeat);
            const auto x0 = torch::randn({7, 5}, dtype);
            const auto g = torch::randn({6, 5}, dtype);
            const auto options = [&](bool csr) {
              return AggregateOptions().with_reduce(r).with_role(role).with_weighted(w).with_csr(
                  csr);
            };
            const auto run = [&](bool csr) {
              const auto x = x0.clone().requires_grad_(true);
              const auto y = aggregate(x, tn, options(csr));
              y.backward(g);
              return std::make_pair(y.detach(), x.grad());
            };
            const auto [y_csr, dx_csr] = run(true);
            const auto [y_rows, dx_rows] = run(false);
            {  // which path ran: one sparse product node, or the gathered rows' index_add
              const auto x = x0.clone().requires_grad_(true);
              const auto names = [&](bool csr) {
                const auto y = aggregate(x, tn, options(csr));
                const auto* node = y.grad_fn().get();
                std::string all = node->name();
                for (const auto& e : node->next_edges())
                  if (e.function) all += " " + e.function->name();
                return all;
              };
              REQUIRE_THAT(names(true), Catch::Contains("SpmmFunction"));
              REQUIRE_THAT(names(false), !Catch::Contains("SpmmFunction"));
            }
            const double tol = dtype == torch::kFloat ? 1e-5 : 1e-12;
            REQUIRE(torch::allclose(y_csr, y_rows, tol, tol));
            REQUIRE(torch::allclose(dx_csr, dx_rows, tol, tol));
            REQUIRE(y_csr[4].abs().sum().item<double>() == 0.0);   // target 4 receives nothing
            REQUIRE(dx_csr[6].abs().sum().item<double>() == 0.0);  // source 6 sends nothing
            if (role == 2) REQUIRE(y_csr.abs().sum().item<double>() == 0.0);
          }
  {  // a mean divides by the pairs counted, repeats included: target 5 gets source 2 twice
    const auto x = torch::arange(7, torch::kDouble).unsqueeze(1);
    const auto y = aggregate(x, tn, AggregateOptions().with_reduce(Aggr::mean));
    REQUIRE(y[5].item<double>() == 2.0);
    REQUIRE(y[3].item<double>() == (4.0 + 0.0 + 4.0) / 3);
    const auto y1 = aggregate(x, tn, AggregateOptions().with_reduce(Aggr::mean).with_role(-1));
    REQUIRE(y1[3].item<double>() == 0.0);  // its one role -1 pair comes from source 0
    REQUIRE(y1[2].item<double>() == 5.0);
  }
  // Values changed in place (their version counter moves): the operator is made again.
  const auto x1 = torch::randn({7, 3});
  const auto before = aggregate(x1, tn, AggregateOptions().with_weighted(true));
  tn.values.mul_(2);
  REQUIRE(torch::allclose(aggregate(x1, tn, AggregateOptions().with_weighted(true)), 2 * before,
                          1e-5, 1e-5));
  tn.values.div_(2);
  // A batch made under InferenceMode (no version counters): the same sums, nothing kept.
  {
    c10::InferenceMode guard;
    const auto ib = ComplexBatch::collate({ComplexView{{7, 6}, {{"n", n}}}}, 1);
    const auto& in = ib.neighborhood("n");
    REQUIRE(in.source.is_inference());
    REQUIRE(torch::allclose(
        aggregate(x1, in, AggregateOptions().with_weighted(true)),
        aggregate(x1, in, AggregateOptions().with_weighted(true).with_csr(false)), 1e-5, 1e-5));
  }
  // A batch with version counters aggregated first under InferenceMode: nothing made there is
  // kept (it would be an inference tensor), so a later forward with gradients can save it. The
  // sum is kept by its second call; the mean then finds it without counts, twice.
  {
    const auto fb = ComplexBatch::collate({ComplexView{{7, 6}, {{"n", n}}}}, 1);
    const auto& fn = fb.neighborhood("n");
    const auto x = torch::randn({7, 3});
    for (const auto r : {Aggr::sum, Aggr::mean}) {
      INFO(aggr_name(r));
      const auto options = AggregateOptions().with_reduce(r).with_weighted(true);
      torch::Tensor y_inference;
      {
        c10::InferenceMode guard;
        y_inference = aggregate(x, fn, options);
      }
      const auto xg = x.clone().requires_grad_(true);
      const auto y = aggregate(xg, fn, options);
      y.sum().backward();
      REQUIRE(xg.grad().defined());
      REQUIRE(torch::allclose(y.detach(), y_inference, 1e-6, 1e-6));
    }
  }
  // Backward values: the CSR product goes back by their own operator (its pattern differs: pair
  // 4's value is zero but its backward value is not; pair 1's backward value is zero), with the
  // gathered path's values and gradients, sums and means, every role; unweighted ignores them.
  n.backward_values = {2.0, 0.0, 1.0, 3.0, -1.5, 2.0, 0.5, 1.0, 4.0, 2.0, -1.0};
  const auto bb = ComplexBatch::collate({ComplexView{{7, 6}, {{"n", n}}}}, 1);
  const auto& bn = bb.neighborhood("n");
  for (const auto r : {Aggr::sum, Aggr::mean})
    for (int role : {0, 1, -1})
      for (bool w : {false, true}) {
        INFO("backward values " << aggr_name(r) << " role " << role << " weighted " << w);
        const auto x0 = torch::randn({7, 4}, torch::kDouble);
        const auto g = torch::randn({6, 4}, torch::kDouble);
        const auto run = [&](bool csr) {
          const auto x = x0.clone().requires_grad_(true);
          const auto y = aggregate(
              x, bn,
              AggregateOptions().with_reduce(r).with_role(role).with_weighted(w).with_csr(csr));
          y.backward(g);
          return std::make_tuple(y.detach(), x.grad(), std::string(y.grad_fn()->name()));
        };
        const auto [y_csr, dx_csr, node_csr] = run(true);
        const auto [y_rows, dx_rows, node_rows] = run(false);
        if (r == Aggr::sum) REQUIRE_THAT(node_csr, Catch::Contains("SpmmFunction"));
        REQUIRE(torch::allclose(y_csr, y_rows, 1e-12, 1e-12));
        REQUIRE(torch::allclose(dx_csr, dx_rows, 1e-12, 1e-12));
      }
  {  // by hand: a sum of ones over all pairs sends source s the sum of its backward values
    const auto x = torch::ones({7, 1}, torch::kDouble).requires_grad_(true);
    aggregate(x, bn, AggregateOptions().with_weighted(true)).sum().backward();
    REQUIRE(x.grad()[2].item<double>() == 1.0 + 3.0 + 4.0);  // pairs 2, 3 and 8
    REQUIRE(x.grad()[5].item<double>() == -1.5 + 2.0);       // pair 4 (value 0) and pair 9
    REQUIRE(x.grad()[0].item<double>() == 0.0 + 0.5);        // pair 1 (backward 0) and pair 6
    const auto y = aggregate(x.detach(), bn, AggregateOptions().with_weighted(true));
    REQUIRE(y[0].item<double>() == -1.0 + 0.0 + 0.75);  // forward by the values
  }
}

TEST_CASE("a neighbourhood with one pair per target, in order, aggregates as a gather",
          "[nn][aggregate]") {
  Neighborhood n;
  n.source_rank = 1;
  n.target_rank = 0;
  n.num_source = 2;
  n.num_target = 4;
  n.source = {1, 0, 0, 1};
  n.target = {0, 1, 2, 3};
  n.values = {2.0, -1.0, 0.5, 1.0};
  const auto b = ComplexBatch::collate({ComplexView{{4, 2}, {{"n", n}}}}, 1);
  REQUIRE(b.neighborhood("n").one_per_target);
  const auto x = torch::randn({2, 3}, torch::kDouble);
  for (Aggr r : {Aggr::sum, Aggr::mean, Aggr::max})
    for (bool w : {false, true}) {
      const auto got =
          aggregate(x, b.neighborhood("n"), AggregateOptions().with_reduce(r).with_weighted(w));
      for (int t = 0; t < 4; ++t)
        REQUIRE(torch::allclose(got[t], x[n.source[static_cast<std::size_t>(t)]] *
                                            (w ? n.values[static_cast<std::size_t>(t)] : 1.0)));
    }
  n.target = {0, 1, 3, 2};  // a permutation is not "in order"
  REQUIRE_FALSE(
      ComplexBatch::collate({ComplexView{{4, 2}, {{"n", n}}}}, 1).neighborhood("n").one_per_target);
}

TEST_CASE("a batch whose first complex has no pairs keeps the others' values and roles",
          "[nn][batch]") {
  // A trajectory chunk starting at a timestep without contacts: its B23/B32 have no pairs, so no
  // values and roles; the next timestep's must still reach the batch.
  Neighborhood none, two;
  none.source_rank = two.source_rank = 1;
  none.target_rank = two.target_rank = 0;
  none.num_source = none.num_target = 0;
  two.num_source = 2;
  two.num_target = 1;
  two.source = {0, 1};
  two.target = {0, 0};
  two.values = {2.0, -3.0};
  two.backward_values = {4.0, 5.0};
  two.roles = {-1, 1};
  const auto b = ComplexBatch::collate(
      {ComplexView{{0, 0}, {{"n", none}}}, ComplexView{{1, 2}, {{"n", two}}}}, 1);
  const auto& t = b.neighborhood("n");
  REQUIRE(t.values.defined());
  REQUIRE(t.backward_values.defined());
  REQUIRE(t.roles.defined());
  REQUIRE(t.values.allclose(torch::tensor({2.0f, -3.0f})));
  REQUIRE(t.backward_values.allclose(torch::tensor({4.0f, 5.0f})));
  REQUIRE(t.roles.to(torch::kLong).equal(torch::tensor({-1, 1}, torch::kLong)));
  const auto x = torch::tensor({{1.0f}, {10.0f}});
  REQUIRE(aggregate(x, t, AggregateOptions().with_weighted(true)).item<float>() == -28.0f);
  REQUIRE(aggregate(x, t, AggregateOptions().with_role(1)).item<float>() == 10.0f);
}

TEST_CASE("Mlp follows the reference layout and parameter count", "[nn][mlp]") {
  Mlp m(MlpOptions(16, 128, 128));
  std::int64_t count = 0;
  std::vector<std::string> names;
  for (const auto& p : m->named_parameters()) {
    count += p.value().numel();
    names.push_back(p.key());
  }
  REQUIRE(count == 128 * 16 + 16896);
  REQUIRE(names == std::vector<std::string>{"0.weight", "0.bias", "2.weight", "2.bias", "4.weight",
                                            "4.bias"});
  Mlp dec(MlpOptions(128, 128, 3).final_activation(false).layer_norm(false));
  REQUIRE(dec->named_parameters().size() == 4);
  Mlp one(MlpOptions(4, 8, 5).layers(1));
  REQUIRE(one->named_parameters().size() == 2);  // L = 1: no LayerNorm
  REQUIRE(one->forward(torch::zeros({2, 4})).sizes() == std::vector<std::int64_t>{2, 5});
  REQUIRE_THROWS_AS(activation_from_string("swish"), std::invalid_argument);
}

TEST_CASE(
    "cpu gemm onednn and topos: an Mlp's products through oneDNN or the dense kernel, float32 "
    "sums in another order",
    "[nn][mlp]") {
  torch::manual_seed(4);
  // oneDNN takes the maps of more than 64 outputs (128 and 80; the last Linear's 3 keep their
  // own kernels); topos's dense kernel takes 24 -> 128 and 128 -> 128 (not 80 or 3 outputs).
  Mlp m(MlpOptions(24, 128, 80).layers(3));
  Mlp dec(MlpOptions(80, 96, 3).final_activation(false).layer_norm(false));
  const auto x = torch::randn({700, 24}).requires_grad_();
  const auto W = torch::randn({128, 50}), b = torch::randn({128});
  const auto z = torch::randn({300, 60}).narrow(1, 5, 50);  // strided rows: passed, not copied
  const auto run = [&](CpuGemm g) {
    struct Restore {  // the setting is process-wide: back to BLAS even if this throws
      ~Restore() { set_cpu_gemm(CpuGemm::blas); }
    } restore;
    set_cpu_gemm(g);
    m->zero_grad(), dec->zero_grad(), x.mutable_grad() = torch::Tensor();
    const auto y = dec->forward(m->forward(x));
    (y * torch::linspace(-1, 1, 3)).sum().backward();
    std::vector<torch::Tensor> out{y.detach(), x.grad().clone(), nn::linear(z, W, b)};
    for (const auto& p : m->parameters()) out.push_back(p.grad().clone());
    for (const auto& p : dec->parameters()) out.push_back(p.grad().clone());
    return out;
  };
  const auto blas = run(CpuGemm::blas);
  std::vector<CpuGemm> others{CpuGemm::topos};
  if (onednn_gemm_available())
    others.push_back(CpuGemm::onednn);
  else
    WARN("this LibTorch has no oneDNN: only topos's kernel compared");
  for (const auto g : others) {
    INFO("cpu gemm " << to_string(g));
    const auto other = run(g);
    REQUIRE(blas.size() == other.size());
    bool differs = false;
    for (std::size_t i = 0; i < blas.size(); ++i) {
      INFO("tensor " << i);
      REQUIRE(other[i].sizes() == blas[i].sizes());
      CHECK(((other[i] - blas[i]).norm() / blas[i].norm()).item<double>() < 1e-5);
      differs = differs || !torch::equal(other[i], blas[i]);
    }
    CHECK(differs);  // the other library did multiply
  }
  REQUIRE(get_cpu_gemm() == CpuGemm::blas);
  REQUIRE(cpu_gemm_from_string("onednn") == CpuGemm::onednn);
  REQUIRE(cpu_gemm_from_string("topos") == CpuGemm::topos);
  REQUIRE(std::string(to_string(CpuGemm::topos)) == "topos");
  REQUIRE_THROWS_WITH(cpu_gemm_from_string("mkl"),
                      Catch::Contains("unknown cpu gemm 'mkl' (blas, onednn, topos)"));
}

TEST_CASE("the dense kernel from packed panels: the unpacked kernel's numbers, bit for bit",
          "[nn][kernels]") {
  using topos::nn::detail::packs_panels;
  const auto x300 = torch::randn({300, 8});
  if (!packs_panels(x300, 300, 8, 128)) {
    WARN("this CPU has no AVX-512: products never run from packed panels here");
    return;
  }
  REQUIRE(get_cpu_gemm() == CpuGemm::blas);      // linear_act's products on topos's kernels
  CHECK_FALSE(packs_panels(x300, 255, 8, 128));  // too few rows: not repaid
  CHECK_FALSE(packs_panels(x300, 300, 8, 64));   // one panel: M as it is
  CHECK_FALSE(packs_panels(x300, 300, 0, 128));  // no inputs: the unpacked kernel writes b
  CHECK_FALSE(packs_panels(x300.to(torch::kDouble), 300, 8, 128));
  torch::manual_seed(12);
  {  // No inputs: act(b) on every row; no outputs: dx = 0 (the backward once divided by N).
    const auto b = torch::randn({128});
    const auto y = linear_act(torch::zeros({300, 0}), torch::zeros({128, 0}), b, Epilogue::relu,
                              MatmulPrecision::highest);
    CHECK(torch::equal(y, torch::relu(b).expand({300, 128})));
    const auto x = torch::randn({300, 128}).requires_grad_();
    const auto none =
        linear_act(x, torch::zeros({0, 128}), {}, Epilogue::none, MatmulPrecision::highest);
    const auto dx = torch::autograd::grad({none.sum()}, {x}, {}, false, false, true)[0];
    REQUIRE(dx.defined());
    CHECK(torch::equal(dx, torch::zeros_like(x)));
  }
  // dx = dZ W runs packed where K is a multiple of 64 above 64 (not at 64 inputs); 192 and 1024
  // inputs or outputs take blocks of 128 of the depth with a partial last one.
  const std::vector<std::pair<std::int64_t, std::int64_t>> shapes{
      {128, 128}, {256, 128}, {192, 192}, {64, 128}, {512, 256}, {1024, 128}};
  for (const auto& [K, N] : shapes)
    for (const auto e : {Epilogue::none, Epilogue::relu, Epilogue::elu, Epilogue::sigmoid}) {
      INFO(K << " -> " << N << ", activation " << static_cast<int>(e));
      const auto x = torch::randn({300, K}).requires_grad_();
      const auto W = (torch::randn({N, K}) / std::sqrt(static_cast<double>(K))).requires_grad_();
      const auto b = torch::randn({N});
      const auto g = torch::randn({300, N});
      // 300 rows run packed; the same rows in three calls of 100 run unpacked. Each row's sums
      // are the same in the same order either way: outputs and dx equal bit for bit.
      const auto run = [&](std::int64_t rows) {
        std::vector<torch::Tensor> y, dx;
        torch::Tensor dW = torch::zeros_like(W);
        for (std::int64_t i = 0; i < 300; i += rows) {
          const auto xi = x.detach().narrow(0, i, rows).requires_grad_();
          const auto yi = linear_act(xi, W, b, e, MatmulPrecision::highest);
          const auto grads = torch::autograd::grad({yi}, {xi, W}, {g.narrow(0, i, rows)});
          y.push_back(yi.detach()), dx.push_back(grads[0]), dW += grads[1];
        }
        return std::vector<torch::Tensor>{torch::cat(y), torch::cat(dx), dW};
      };
      const auto packed = run(300), unpacked = run(100);
      CHECK(torch::equal(packed[0], unpacked[0]));
      CHECK(torch::equal(packed[1], unpacked[1]));
      // And both are the product: against double.
      const auto xd = x.detach().to(torch::kDouble), Wd = W.detach().to(torch::kDouble);
      auto z = torch::addmm(b.to(torch::kDouble), xd, Wd.t());
      const auto yd = e == Epilogue::relu      ? torch::relu(z)
                      : e == Epilogue::elu     ? torch::elu(z)
                      : e == Epilogue::sigmoid ? torch::sigmoid(z)
                                               : z;
      CHECK(torch::allclose(packed[0].to(torch::kDouble), yd, 1e-4, 1e-4));
      const auto act_grad = e == Epilogue::relu ? (z > 0).to(torch::kDouble)
                            : e == Epilogue::elu
                                ? torch::where(z > 0, torch::ones_like(z), torch::exp(z))
                            : e == Epilogue::sigmoid ? yd * (1 - yd)
                                                     : torch::ones_like(z);
      const auto dz = g.to(torch::kDouble) * act_grad;
      CHECK(torch::allclose(packed[1].to(torch::kDouble), dz.mm(Wd), 1e-4, 1e-4));
      CHECK(torch::allclose(packed[2].to(torch::kDouble), dz.t().mm(xd), 1e-4, 1e-3));
    }
}

TEST_CASE("linear_act on four outputs or four inputs: topos's kernel, against double",
          "[nn][kernels]") {
  // Four outputs are attention's folded keys (one score per head); four inputs an encoder's
  // first layer, whose fused backward sums dW over four columns of x.
  torch::manual_seed(13);
  const std::vector<std::pair<std::int64_t, std::int64_t>> shapes{
      {64, 4}, {20, 4}, {4, 4}, {4, 64}, {4, 128}};
  for (const auto kind : {torch::kFloat, torch::kDouble})
    for (const auto& [K, N] : shapes)
      for (const auto e : {Epilogue::none, Epilogue::relu, Epilogue::sigmoid}) {
        INFO(K << " -> " << N << ", activation " << static_cast<int>(e) << ", "
               << torch::toString(kind));
        const auto o = torch::TensorOptions().dtype(kind);
        const auto x = torch::randn({257, K}, o).requires_grad_();
        const auto W = torch::randn({N, K}, o).requires_grad_(), b = torch::randn({N}, o);
        const auto g = torch::randn({257, N}, o);
        const auto y = linear_act(x, W, b, e, MatmulPrecision::highest);
        if (N <= 64) {  // the dense kernel's widths: one fused node (wider: BLAS's product)
          REQUIRE(y.grad_fn());
          CHECK_THAT(y.grad_fn()->name(), Catch::Contains("LinearFunction"));
        }
        const auto grads = torch::autograd::grad({y}, {x, W}, {g});
        const auto xd = x.detach().to(torch::kDouble), Wd = W.detach().to(torch::kDouble);
        const auto z = torch::addmm(b.to(torch::kDouble), xd, Wd.t());
        const auto yd = e == Epilogue::relu      ? torch::relu(z)
                        : e == Epilogue::sigmoid ? torch::sigmoid(z)
                                                 : z;
        const auto act_grad = e == Epilogue::relu      ? (z > 0).to(torch::kDouble)
                              : e == Epilogue::sigmoid ? yd * (1 - yd)
                                                       : torch::ones_like(z);
        const auto dz = g.to(torch::kDouble) * act_grad;
        CHECK(torch::allclose(y.to(torch::kDouble), yd, 1e-5, 1e-5));
        CHECK(torch::allclose(grads[0].to(torch::kDouble), dz.mm(Wd), 1e-5, 1e-5));
        CHECK(torch::allclose(grads[1].to(torch::kDouble), dz.t().mm(xd), 1e-5, 1e-4));
      }
}

TEST_CASE("dense_operand lays a map out as LibTorch's copies do, and a scope keeps it per weight",
          "[nn][kernels]") {
  using nn::detail::dense_operand;
  using nn::detail::weight_operand;
  torch::manual_seed(13);
  // Any strides (a weight's transpose, a strided slice, contiguous), float and double, whole and
  // partial 16 × 16 tiles; panels of 64 columns where N is a multiple of 64.
  for (const auto dtype : {torch::kFloat, torch::kDouble}) {
    const auto opt = torch::TensorOptions().dtype(dtype);
    const std::vector<std::pair<std::string, torch::Tensor>> maps{
        {"transpose 80 x 192", torch::randn({192, 80}, opt).t()},
        {"transpose 37 x 53", torch::randn({53, 37}, opt).t()},
        {"strided 80 x 192", torch::randn({160, 768}, opt).slice(0, 0, 160, 2).slice(1, 0, 384, 2)},
        {"contiguous 64 x 128", torch::randn({64, 128}, opt)}};
    for (const auto& [name, M] : maps) {
      INFO(name << ", " << dtype);
      const auto K = M.size(0), N = M.size(1);
      const auto flat = dense_operand(M, false);
      CHECK(flat.is_contiguous());
      CHECK(torch::equal(flat, M.contiguous()));
      if (M.is_contiguous()) CHECK(flat.data_ptr() == M.data_ptr());  // no copy
      if (N % 64 == 0) {
        const auto panels = dense_operand(M, true);
        CHECK(panels.sizes() == torch::IntArrayRef({N / 64, K, 64}));
        CHECK(torch::equal(panels, M.contiguous().view({K, N / 64, 64}).permute({1, 0, 2})));
      }
    }
  }
  // linear_act's float32 products on topos's kernels read W's transpose laid out: inside a
  // PackedWeightsScope once per weight and version, outside at every call.
  at::set_num_threads(1);
  REQUIRE(get_cpu_gemm() == CpuGemm::blas);
  torch::NoGradGuard no_grad;
  auto& cache = nn::detail::packed_pairs_cache();
  const auto x = torch::randn({300, 64});
  // 32 outputs run on the dense kernel on every CPU; 128 from packed panels on 300 rows where the
  // CPU has AVX-512 (BLAS's elsewhere, which reads W as it is).
  for (const std::int64_t N : {32, 128}) {
    INFO(N << " outputs");
    auto W = torch::randn({N, 64}) / 8;
    const auto product = [&] {
      return linear_act(x, W, {}, Epilogue::none, MatmulPrecision::highest);
    };
    const auto outside = product();
    const bool panels = nn::detail::packs_panels(x, 300, 64, N);
    CHECK(weight_operand(W.t(), panels).data_ptr() != weight_operand(W.t(), panels).data_ptr());
    {
      const PackedWeightsScope scope;
      const auto kept = weight_operand(W.t(), panels);
      CHECK(weight_operand(W.t(), panels).data_ptr() == kept.data_ptr());
      CHECK(torch::equal(kept, dense_operand(W.t(), panels)));
      const auto before = product();
      CHECK(torch::equal(before, outside));  // bit for bit: the same operand, the same sums
      CHECK(torch::equal(product(), before));
      W.narrow(0, 0, 16).mul_(2);  // through a view, which shares the version counter
      const auto after = product();
      CHECK(torch::equal(after.narrow(1, 0, 16), 2 * before.narrow(1, 0, 16)));
      CHECK(torch::equal(after.narrow(1, 16, N - 16), before.narrow(1, 16, N - 16)));
      for (int k = 0; k < 10; ++k) {  // fresh weights of the same shape
        W = torch::randn({N, 64}) / 8;
        CHECK(torch::allclose(product(), x.mm(W.t()), 1e-5, 1e-5));
      }
    }
    CHECK(cache.operands.entries.empty());  // dropped with the scope
    W.data().mul_(0);
    CHECK(torch::equal(product(), torch::zeros({300, N})));
  }
}

TEST_CASE("selected_weight keeps a weight's slices inside a scope, per version and index",
          "[nn][kernels]") {
  using nn::detail::selected_weight;
  torch::manual_seed(17);
  const auto W = torch::randn({8, 12, 3}).requires_grad_();
  const std::vector<std::int64_t> cols{1, 4, 5, 11}, taps{2, 0};
  const auto want = [&](std::int64_t dim, const std::vector<std::int64_t>& index) {
    return W.detach().index_select(dim, torch::tensor(index));
  };
  {  // outside a scope: a fresh copy at every call, on the autograd graph
    const auto a = selected_weight(W, 1, cols);
    CHECK(torch::equal(a, want(1, cols)));
    CHECK(a.requires_grad());
    a.sum().backward();
    CHECK(torch::equal(W.grad().sum(2).sum(0),
                       torch::tensor({0, 24, 0, 0, 24, 24, 0, 0, 0, 0, 0, 24}).to(torch::kFloat)));
  }
  const PackedWeightsScope scope;
  {  // recording a gradient through W: never kept
    const auto a = selected_weight(W, 1, cols);
    CHECK(a.requires_grad());
    CHECK(a.data_ptr() != selected_weight(W, 1, cols).data_ptr());
  }
  torch::NoGradGuard no_grad;
  const auto kept = selected_weight(W, 1, cols);
  CHECK(torch::equal(kept, want(1, cols)));
  CHECK(selected_weight(W, 1, cols).data_ptr() == kept.data_ptr());
  const auto other = selected_weight(W, 2, taps);  // another dimension and index: its own entry
  CHECK(torch::equal(other, want(2, taps)));
  CHECK(other.data_ptr() != kept.data_ptr());
  CHECK(torch::equal(selected_weight(W, 1, {1, 4, 5}), want(1, {1, 4, 5})));
  // An optimizer's in-place step on W: selected again, into the kept tensor, whose version moves
  // so that the layouts kept of it are redone.
  const auto version = kept._version();
  W.add_(1);
  const auto after = selected_weight(W, 1, cols);
  CHECK(after.data_ptr() == kept.data_ptr());
  CHECK(after._version() > version);
  CHECK(torch::equal(after, want(1, cols)));
  {  // inside InferenceMode too the slice is a normal tensor, which the products' caches can key
    const c10::InferenceMode inference;
    const auto fresh = torch::randn({4, 6});
    const auto s = selected_weight(fresh, 1, {0, 5});
    CHECK_FALSE(s.is_inference());
    CHECK(torch::equal(s, fresh.index_select(1, torch::tensor({0, 5}))));
  }
}

TEST_CASE("nn::layer_norm equals torch's layer_norm, values and gradients", "[nn][kernels]") {
  torch::manual_seed(11);
  // Channels: a multiple of the vector width, a tail, fewer than a vector; rows: one block of the
  // backward's partial sums, and several (summed in block order).
  for (const auto dtype : {torch::kFloat, torch::kDouble})
    for (const std::int64_t C : {128, 37, 3})
      for (const std::int64_t n : {5, 3000})
        for (const int affine : {0, 1, 2}) {  // no weight or bias, both, weight only
          INFO("dtype " << dtype << ", " << n << " × " << C << ", affine " << affine);
          const auto opt = torch::TensorOptions().dtype(dtype);
          const auto x0 = (torch::randn({n, C}, opt) * 3 + 1).requires_grad_();
          const auto x1 = x0.detach().clone().requires_grad_();
          torch::Tensor w0, b0, w1, b1;
          if (affine > 0) {
            w0 = torch::randn({C}, opt).requires_grad_();
            w1 = w0.detach().clone().requires_grad_();
          }
          if (affine == 1) {
            b0 = torch::randn({C}, opt).requires_grad_();
            b1 = b0.detach().clone().requires_grad_();
          }
          const auto want = torch::layer_norm(x0, {C}, w0, b0, 1e-5);
          const auto got = nn::layer_norm(x1, w1, b1, 1e-5);
          const double tol = dtype == torch::kFloat ? 1e-5 : 1e-12;
          REQUIRE(got.sizes() == want.sizes());
          CHECK(((got - want).abs().max() / want.abs().max()).item<double>() < tol);
          const auto dy = torch::randn({n, C}, opt);
          want.backward(dy);
          got.backward(dy);
          const auto close = [&](const torch::Tensor& a, const torch::Tensor& b) {
            return ((a - b).norm() / b.norm()).item<double>() < 10 * tol;
          };
          CHECK(close(x1.grad(), x0.grad()));
          if (affine > 0) CHECK(close(w1.grad(), w0.grad()));
          if (affine == 1) CHECK(close(b1.grad(), b0.grad()));
        }
  // Other shapes go to torch's own (three dimensions: normalised over the last).
  const auto x3 = torch::randn({2, 4, 8});
  CHECK(torch::allclose(nn::layer_norm(x3, {}, {}), torch::layer_norm(x3, {8})));
}

TEST_CASE("nn::layer_norm's rows in groups of 16 are each row's LayerNorm alone, bit for bit",
          "[nn][kernels]") {
  // Rows 16 at a time share their reductions (kernels/layer_norm.hpp); a lone row (or the last
  // n % 16) takes the row kernel. Each row's values, statistics and input gradient must not
  // depend on which.
  torch::manual_seed(17);
  for (const std::int64_t C : {16, 48, 64, 128})
    for (const int residual : {0, 1, 2})  // none, a tensor, one row
      for (const auto act : {Epilogue::none, Epilogue::relu, Epilogue::elu, Epilogue::sigmoid})
        for (const bool affine : {false, true}) {
          INFO(C << " channels, residual " << residual << ", act " << static_cast<int>(act)
                 << ", affine " << affine);
          const std::int64_t n = 37;
          const auto x = (torch::randn({n, C}) * 3 + 1).requires_grad_();
          const auto r = residual == 1   ? torch::randn({n, C})
                         : residual == 2 ? torch::randn({C})
                                         : torch::Tensor();
          const auto w = affine ? torch::randn({C}) : torch::Tensor();
          const auto b = affine ? torch::randn({C}) : torch::Tensor();
          const auto ln = [&](const torch::Tensor& xs, const torch::Tensor& rs) {
            return rs.defined() ? nn::add_layer_norm(xs, rs, w, b, 1e-5, act)
                                : nn::layer_norm(xs, w, b, 1e-5, act);
          };
          const auto all = ln(x, r);
          const auto dy = torch::randn({n, C});
          all.backward(dy);
          for (std::int64_t i = 0; i < n; ++i) {
            INFO("row " << i);
            const auto xi = x.detach().slice(0, i, i + 1).clone().requires_grad_();
            const auto ri = residual == 1 ? r.slice(0, i, i + 1) : r;
            const auto one = ln(xi, ri);
            REQUIRE(torch::equal(one, all.detach().slice(0, i, i + 1)));
            one.backward(dy.slice(0, i, i + 1));
            REQUIRE(torch::equal(xi.grad(), x.grad().slice(0, i, i + 1)));
          }
        }
}

TEST_CASE("nn::layer_norm with an activation is one node: the same as LayerNorm then the act",
          "[nn][kernels]") {
  torch::manual_seed(13);
  for (const auto dtype : {torch::kFloat, torch::kDouble})
    for (const std::int64_t C : {64, 37})
      for (const std::int64_t n : {7, 3000})
        for (const auto act : {Epilogue::relu, Epilogue::elu, Epilogue::sigmoid}) {
          INFO("dtype " << dtype << ", " << n << " × " << C << ", act " << static_cast<int>(act));
          const auto opt = torch::TensorOptions().dtype(dtype);
          const auto x0 = (torch::randn({n, C}, opt) * 3 + 1).requires_grad_();
          const auto x1 = x0.detach().clone().requires_grad_();
          const auto w0 = torch::randn({C}, opt).requires_grad_(), b0 = torch::randn({C}, opt);
          const auto w1 = w0.detach().clone().requires_grad_();
          const auto b1 = b0.detach().clone().requires_grad_();
          b0.requires_grad_();
          // Unfused: topos's LayerNorm, then torch's activation (its own autograd node).
          const auto want = nn::detail::activate(nn::layer_norm(x0, w0, b0, 1e-5), act);
          const auto got = nn::layer_norm(x1, w1, b1, 1e-5, act);
          REQUIRE(got.grad_fn()->name().find("LayerNorm") != std::string::npos);
          const double tol = dtype == torch::kFloat ? 1e-6 : 1e-14;
          // relu: the same bits; elu: topos's vectorised expm1 against torch's (float: libm's).
          if (act == Epilogue::relu) REQUIRE(torch::equal(got, want));
          REQUIRE(torch::allclose(got, want, tol, tol));
          REQUIRE((got == 0).any().item<bool>() == (act == Epilogue::relu));  // some cut off
          const auto dy = torch::randn({n, C}, opt);
          want.backward(dy);
          got.backward(dy);
          REQUIRE(torch::allclose(x1.grad(), x0.grad(), 10 * tol, 10 * tol));
          REQUIRE(torch::allclose(w1.grad(), w0.grad(), 100 * tol, 100 * tol));
          REQUIRE(torch::allclose(b1.grad(), b0.grad(), 100 * tol, 100 * tol));
          if (act == Epilogue::relu) REQUIRE(torch::equal(x1.grad(), x0.grad()));
          torch::NoGradGuard no_grad;  // a rollout's path: no node, the same values
          REQUIRE(torch::equal(nn::layer_norm(x1, w1, b1, 1e-5, act), got.detach()));
        }
  // Other shapes: torch's layer_norm, then the activation.
  const auto x3 = torch::randn({2, 4, 8});
  CHECK(torch::allclose(nn::layer_norm(x3, {}, {}, 1e-5, Epilogue::relu),
                        torch::relu(torch::layer_norm(x3, {8}))));
}

TEST_CASE("nn::add_layer_norm forms x + r in its kernel: LayerNorm of the sum, gradients included",
          "[nn][kernels]") {
  torch::manual_seed(19);
  // r a tensor of x's shape (a residual connection) or one row (a bias); every activation; rows
  // over several blocks of the backward's partial sums; a tail of channels.
  for (const auto dtype : {torch::kFloat, torch::kDouble})
    for (const std::int64_t C : {64, 37})
      for (const std::int64_t n : {3, 3000})
        for (const bool row : {false, true})
          for (const auto act :
               {Epilogue::none, Epilogue::relu, Epilogue::elu, Epilogue::sigmoid}) {
            INFO("dtype " << dtype << ", " << n << " × " << C << (row ? ", a row" : ", a tensor")
                          << ", act " << static_cast<int>(act));
            const auto opt = torch::TensorOptions().dtype(dtype);
            const auto x0 = (torch::randn({n, C}, opt) * 3 + 1).requires_grad_();
            const auto r0 =
                torch::randn(row ? std::vector<std::int64_t>{C} : std::vector<std::int64_t>{n, C},
                             opt)
                    .requires_grad_();
            const auto w0 = torch::randn({C}, opt).requires_grad_();
            const auto b0 = torch::randn({C}, opt).requires_grad_();
            const auto copy = [](const torch::Tensor& t) {
              return t.detach().clone().requires_grad_();
            };
            const auto x1 = copy(x0), r1 = copy(r0), w1 = copy(w0), b1 = copy(b0);
            // Unfused: torch's add, topos's LayerNorm with the activation.
            const auto want = nn::layer_norm(x0 + r0, w0, b0, 1e-5, act);
            const auto got = nn::add_layer_norm(x1, r1, w1, b1, 1e-5, act);
            REQUIRE(got.grad_fn()->name().find("LayerNormFunction") != std::string::npos);
            // The same sum, normalised by the same kernel: the same bits.
            REQUIRE(torch::equal(got, want));
            const auto dy = torch::randn({n, C}, opt);
            want.backward(dy);
            got.backward(dy);
            CHECK(torch::equal(x1.grad(), x0.grad()));
            CHECK(torch::equal(w1.grad(), w0.grad()));
            CHECK(torch::equal(b1.grad(), b0.grad()));
            // A row's gradient is dx summed over the rows: in blocks here, by torch there.
            const double tol = dtype == torch::kFloat ? 1e-4 : 1e-12;
            CHECK(torch::allclose(r1.grad(), r0.grad(), tol, tol));
            if (!row) CHECK(torch::equal(r1.grad(), r0.grad()));
            torch::NoGradGuard no_grad;  // a rollout's path: no node, the same values
            CHECK(torch::equal(nn::add_layer_norm(x1, r1, w1, b1, 1e-5, act), got.detach()));
          }
  // A residual that needs a gradient while x does not; r of another shape goes through torch's
  // broadcasting add.
  const auto x = torch::randn({5, 8});
  const auto r = torch::randn({5, 8}).requires_grad_();
  nn::add_layer_norm(x, r, {}, {}).sum().backward();
  CHECK(r.grad().abs().max().item<double>() < 1e-5);  // a LayerNorm's rows sum to 0
  const auto r2 = torch::randn({1, 8});
  CHECK(torch::allclose(nn::add_layer_norm(x, r2, {}, {}), torch::layer_norm(x + r2, {8}), 1e-5,
                        1e-5));
}

TEST_CASE("nn::head_scores is one node: per cell and head <f_h, a_h>, gradients included",
          "[nn][kernels]") {
  torch::manual_seed(17);
  // Heads of a vector's channels, a tail, fewer than a vector; rows over several blocks of the
  // backward's partial sums; a the parameter's slice as Attend passes it.
  for (const auto dtype : {torch::kFloat, torch::kDouble})
    for (const auto& [H, C] :
         {std::pair<std::int64_t, std::int64_t>{4, 32}, {1, 64}, {3, 7}, {2, 3}})
      for (const std::int64_t n : {1, 5, 5000}) {
        INFO("dtype " << dtype << ", " << n << " cells, " << H << " heads of " << C);
        const auto opt = torch::TensorOptions().dtype(dtype);
        const auto f0 = torch::randn({n, H * C}, opt).requires_grad_();
        const auto f1 = f0.detach().clone().requires_grad_();
        const auto p0 = torch::randn({2 * H * C}, opt).requires_grad_();
        const auto p1 = p0.detach().clone().requires_grad_();
        // The product written out with torch's ops, in double for the reference.
        const auto want = (f0.to(torch::kDouble).view({n, H, C}) *
                           p0.narrow(0, H * C, H * C).to(torch::kDouble).view({1, H, C}))
                              .sum(-1);
        const auto got = nn::head_scores(f1, p1.narrow(0, H * C, H * C), H);
        REQUIRE(got.grad_fn()->name().find("HeadScores") != std::string::npos);
        REQUIRE(got.sizes() == (H == 1 ? torch::IntArrayRef{n} : torch::IntArrayRef{n, H}));
        const double tol = dtype == torch::kFloat ? 1e-5 : 1e-13;
        CHECK(torch::allclose(got.to(torch::kDouble), want.reshape(got.sizes()), tol, tol));
        const auto g = torch::randn(got.sizes(), opt);
        (want.reshape(got.sizes()) * g.to(torch::kDouble)).sum().backward();
        (got * g).sum().backward();
        CHECK(
            torch::allclose(f1.grad().to(torch::kDouble), f0.grad().to(torch::kDouble), tol, tol));
        CHECK(torch::allclose(p1.grad().to(torch::kDouble), p0.grad().to(torch::kDouble),
                              tol * std::sqrt(double(n)), tol * std::sqrt(double(n))));
        CHECK(p1.grad().narrow(0, 0, H * C).abs().max().item<double>() == 0);  // not the slice
        {
          torch::NoGradGuard no_grad;  // no node: the same values
          CHECK(torch::equal(nn::head_scores(f1, p1.narrow(0, H * C, H * C), H), got.detach()));
        }
        // Only a needing its gradient (f a constant), and a thread count of two: the same bits.
        const auto f2 = f1.detach();
        const auto p2 = p1.detach().clone().requires_grad_();
        const int threads = at::get_num_threads();
        at::set_num_threads(2);
        (nn::head_scores(f2, p2.narrow(0, H * C, H * C), H) * g).sum().backward();
        at::set_num_threads(1);
        p1.grad().zero_();
        (nn::head_scores(f2, p1.narrow(0, H * C, H * C), H) * g).sum().backward();
        at::set_num_threads(threads);
        CHECK(torch::equal(p2.grad(), p1.grad()));
      }
  // Channels the heads do not divide, or weights of another count, are refused; other devices
  // and dtypes take torch's ops.
  CHECK_THROWS_WITH(nn::head_scores(torch::randn({3, 7}), torch::randn({7}), 2),
                    Catch::Contains("7 channels with 7 attention weights in 2 heads"));
  CHECK_THROWS_WITH(nn::head_scores(torch::randn({3, 8}), torch::randn({6}), 2),
                    Catch::Contains("8 channels with 6 attention weights"));
  const auto fi = torch::randn({3, 4}, torch::kBFloat16), ai = torch::randn({4}, torch::kBFloat16);
  CHECK(torch::allclose(nn::head_scores(fi, ai, 2).to(torch::kFloat),
                        (fi.view({3, 2, 2}) * ai.view({1, 2, 2})).sum(-1).to(torch::kFloat), 1e-2,
                        1e-2));
}

TEST_CASE("medium matmul precision: bfloat16 products, float32 out, close to highest",
          "[nn][mlp]") {
  torch::manual_seed(3);
  Mlp m(MlpOptions(24, 64, 32).layers(3));
  const auto x = torch::randn({500, 24});
  const auto run = [&](MatmulPrecision p) {
    struct Restore {  // the setting is process-wide: back to highest even if this throws
      ~Restore() { set_float32_matmul_precision(MatmulPrecision::highest); }
    } restore;
    set_float32_matmul_precision(p);
    m->zero_grad();
    auto y = m->forward(x);
    (y * torch::linspace(-1, 1, 32)).sum().backward();
    return std::make_pair(y.detach(), m->named_parameters()["2.weight"].grad().clone());
  };
  // The highest path is torch::linear's products (and nn::layer_norm), bit for bit.
  const auto [y_hi, g_hi] = run(MatmulPrecision::highest);
  auto plain = x;
  for (const auto& c : m->children()) {
    if (const auto* l = c->as<torch::nn::LinearImpl>())
      plain = torch::linear(plain, l->weight, l->bias);
    else if (c->as<torch::nn::ReLUImpl>())
      plain = torch::relu(plain);
    else
      plain = nn::layer_norm(plain, *c->as<torch::nn::LayerNormImpl>());
  }
  REQUIRE(torch::equal(y_hi, plain.detach()));
  const auto [y_md, g_md] = run(MatmulPrecision::medium);
  REQUIRE(y_md.scalar_type() == torch::kFloat);
  REQUIRE(g_md.scalar_type() == torch::kFloat);
  REQUIRE_FALSE(torch::equal(y_md, y_hi));  // it did multiply in bfloat16
  // bfloat16 keeps 8 significant bits: about 0.4 % per rounding, a few roundings deep.
  const auto rel = [](const torch::Tensor& a, const torch::Tensor& b) {
    return ((a - b).norm() / b.norm()).item<double>();
  };
  CHECK(rel(y_md, y_hi) < 2e-2);
  CHECK(rel(g_md, g_hi) < 3e-2);
  REQUIRE(get_float32_matmul_precision() == MatmulPrecision::highest);
  REQUIRE(matmul_precision_from_string("medium") == MatmulPrecision::medium);
  REQUIRE_THROWS_WITH(matmul_precision_from_string("high"),
                      Catch::Contains("unknown matmul precision 'high'"));
}

TEST_CASE("medium matmul precision: maps the bfloat16 kernels do not take stay float32",
          "[nn][mlp]") {
  struct Restore {  // process-wide settings: back to the defaults even if this throws
    ~Restore() {
      set_float32_matmul_precision(MatmulPrecision::highest);
      set_cpu_gemm(CpuGemm::blas);
    }
  } restore;
  set_cpu_gemm(CpuGemm::blas);
  torch::manual_seed(5);
  // 24 inputs and 3 outputs are no multiples of 16.
  const auto x = torch::randn({300, 24}), W = torch::randn({64, 24}), b = torch::randn({64});
  const auto h = torch::randn({300, 64}), W3 = torch::randn({3, 64});
  if (!nn::detail::cpu_has_bf16()) {
    // Without topos's kernels (or with TOPOS_DISABLE_BF16) every map is oneDNN's bfloat16.
    REQUIRE_FALSE(
        torch::equal(nn::linear(x, W, b, MatmulPrecision::medium), torch::linear(x, W, b)));
    return;
  }
  // With them, float32 products: bit for bit highest's, forward and gradients, whichever library.
  std::vector<CpuGemm> gemms{CpuGemm::blas, CpuGemm::topos};
  if (onednn_gemm_available()) gemms.push_back(CpuGemm::onednn);
  for (const auto g : gemms) {
    INFO("gemm " << static_cast<int>(g));
    set_cpu_gemm(g);
    const auto run = [&](MatmulPrecision p) {
      const auto Wg = W.clone().requires_grad_(true);
      const auto y = nn::linear(x, Wg, b, p);
      (y * y).sum().backward();
      return std::make_pair(y.detach(), Wg.grad());
    };
    const auto [y_md, g_md] = run(MatmulPrecision::medium);
    const auto [y_hi, g_hi] = run(MatmulPrecision::highest);
    REQUIRE(torch::equal(y_md, y_hi));
    REQUIRE(torch::equal(g_md, g_hi));
    REQUIRE(torch::equal(nn::linear(h, W3, {}, MatmulPrecision::medium), torch::linear(h, W3)));
  }
  set_cpu_gemm(CpuGemm::blas);
  const auto W16 = W.narrow(1, 0, 16).t().contiguous();  // 64 -> 16: a bfloat16 product
  REQUIRE_FALSE(
      torch::equal(nn::linear(h, W16, {}, MatmulPrecision::medium), torch::linear(h, W16)));
  // In an MLP such a first layer is one node with its ReLU, and no cast is left in the graph.
  set_float32_matmul_precision(MatmulPrecision::medium);
  for (const auto g : gemms) {
    set_cpu_gemm(g);
    Mlp m(MlpOptions(24, 128, 3).final_activation(false).layer_norm(false));
    const auto y = m->forward(x);
    REQUIRE(y.grad_fn());
    std::set<std::string> names;
    std::set<const torch::autograd::Node*> seen;
    std::vector<torch::autograd::Node*> todo{y.grad_fn().get()};
    while (!todo.empty()) {
      auto* n = todo.back();
      todo.pop_back();
      if (n == nullptr || !seen.insert(n).second) continue;
      names.insert(n->name());
      for (const auto& e : n->next_edges()) todo.push_back(e.function.get());
    }
    INFO("gemm " << static_cast<int>(g));
    CHECK(names.count("AddmmBackward0") == 1);  // the last Linear's 3 outputs: torch's float32
    CHECK(names.count("ToCopyBackward0") == 0);
    CHECK(names.count("ConstantPadNdBackward0") == 0);
    if (g == CpuGemm::blas) {
      CHECK(names.count("ReluBackward0") == 1);  // torch's Linear, then the ReLU module
    } else {
      CHECK(names.count("ReluBackward0") == 0);  // fused with its Linear
      CHECK(std::any_of(names.begin(), names.end(), [](const std::string& n) {
        return n.find("LinearFunction") != std::string::npos;
      }));
    }
  }
}

TEST_CASE("tensor cache keys (versions, views, freed storage) and the cache's bound", "[nn]") {
  using nn::detail::TensorKey;
  auto t = torch::arange(12, torch::kFloat).view({3, 4});
  const auto key = TensorKey::of(t);
  REQUIRE(key.matches(t));
  REQUIRE(key.matches(t.view({3, 4})));                 // another view of the same elements
  REQUIRE_FALSE(key.same_tensor(t.t()));                // strides
  REQUIRE_FALSE(key.same_tensor(t.narrow(0, 1, 2)));    // offset and size
  REQUIRE_FALSE(key.same_tensor(t.narrow(0, 0, 2)));    // size
  REQUIRE_FALSE(key.same_tensor(t.view(torch::kInt)));  // dtype
  REQUIRE(key.same_storage(t.narrow(0, 0, 2)));         // where a caller says what it reads
  REQUIRE(key.same_storage(t.t()));
  REQUIRE_FALSE(key.same_storage(t.narrow(0, 1, 2)));
  REQUIRE_FALSE(key.same_storage(t.view(torch::kInt)));
  REQUIRE_FALSE(key.same_tensor(t.to(torch::kDouble)));
  REQUIRE_FALSE(key.same_tensor(t.clone()));  // another storage
  t.add_(1);                                  // an in-place change: the same tensor, a new version
  REQUIRE(key.same_tensor(t));
  REQUIRE_FALSE(key.matches(t));
  REQUIRE(TensorKey::of(torch::Tensor()).matches(torch::Tensor()));
  REQUIRE_FALSE(TensorKey::of(torch::Tensor()).matches(t));
  REQUIRE_FALSE(key.matches(torch::Tensor()));
  REQUIRE_FALSE(TensorKey::of(torch::Tensor()).expired());
  {
    const c10::InferenceMode guard;
    REQUIRE_FALSE(TensorKey::keyable(torch::ones({2})));
  }
  REQUIRE(TensorKey::keyable(t));
  REQUIRE(TensorKey::keyable(torch::Tensor()));
  t = torch::Tensor();  // the storage is freed: the key expires and matches nothing
  REQUIRE(key.expired());
  struct Entry {
    TensorKey tensor;
    int id = 0;
    bool expired() const { return tensor.expired(); }
  };
  nn::detail::TensorCache<Entry> cache(3);
  std::vector<torch::Tensor> alive;
  for (int i = 0; i < 3; ++i) {
    alive.push_back(torch::full({2}, i));
    cache.insert({TensorKey::of(alive.back()), i});
  }
  const auto find = [&](const torch::Tensor& x) {
    const auto* e = cache.find([&](const Entry& e) { return e.tensor.matches(x); });
    return e ? e->id : -1;
  };
  REQUIRE(find(alive[1]) == 1);
  REQUIRE(find(torch::full({2}, 1)) == -1);
  cache.insert({TensorKey::of(alive.emplace_back(torch::full({2}, 3))), 3});  // full: the oldest
  REQUIRE(cache.entries.size() == 3);
  REQUIRE(find(alive[0]) == -1);
  REQUIRE(find(alive[3]) == 3);
  alive[1] = torch::Tensor(), alive[2] = torch::Tensor();  // freed entries go before any live one
  cache.insert({TensorKey::of(alive.emplace_back(torch::full({2}, 4))), 4});
  REQUIRE(cache.entries.size() == 2);
  REQUIRE(find(alive[3]) == 3);
  REQUIRE(find(alive[4]) == 4);
  cache.clear();
  REQUIRE(cache.entries.empty());
}

TEST_CASE("bfloat16 kernels: act(x Wᵀ + b) and its gradients against double on rounded inputs",
          "[nn][kernels][mlp]") {
  // The rounding: torch's own float -> bfloat16 conversion (nearest, ties to even) is the check.
  torch::manual_seed(11);
  const auto v = torch::cat(
      {torch::randn({4096}), torch::tensor({1.00390625f, 1.01171875f, -3.0078125f, 0.0f})});
  const auto bits = v.to(torch::kBFloat16).view(torch::kInt16);
  for (std::int64_t i = 0; i < v.numel(); ++i)
    REQUIRE(static_cast<std::int16_t>(nn::detail::bf16_bits(v[i].item<float>())) ==
            bits[i].item<std::int16_t>());
  if (!nn::detail::cpu_has_bf16()) {
    WARN("this CPU has no AVX-512 BF16: the bfloat16 kernels are not checked");
    return;
  }
  // Weights are packed in pairs a vector at a time (rows or columns contiguous): the same pairs
  // as element by element.
  const auto M = torch::randn({64, 48});
  const auto* m = M.data_ptr<float>();
  REQUIRE(nn::detail::pack_bf16_pairs(m, 64, 48, 48, 1) ==
          nn::detail::pack_bf16_pairs_scalar(m, 64, 48, 48, 1));
  REQUIRE(nn::detail::pack_bf16_pairs(m, 48, 64, 1, 48) ==
          nn::detail::pack_bf16_pairs_scalar(m, 48, 64, 1, 48));
  REQUIRE(nn::detail::bf16_kernel_fits(576, 64));
  REQUIRE_FALSE(nn::detail::bf16_kernel_fits(24, 64));  // inputs not a multiple of 16: other paths
  REQUIRE_FALSE(nn::detail::bf16_kernel_fits(64, 3));
  topos::test::RestoreThreads restore;
  const auto rounded = [](const torch::Tensor& t) {
    return t.detach().to(torch::kBFloat16).to(torch::kDouble);
  };
  const auto activation = [](const torch::Tensor& z, Epilogue e) {
    return e == Epilogue::none   ? z
           : e == Epilogue::relu ? torch::relu(z)
           : e == Epilogue::elu  ? torch::elu(z)
                                 : torch::sigmoid(z);
  };
  // dZ = g ⊙ act'(y) from the output y, in the kernel's float32 order (a different rounding of
  // dZ can round it to another bfloat16, a 4e-3 step).
  const auto output_gradient = [](const torch::Tensor& g, const torch::Tensor& y, Epilogue e) {
    const auto yd = y.detach();
    return e == Epilogue::none   ? g
           : e == Epilogue::relu ? g * (yd > 0)
           : e == Epilogue::elu  ? torch::where(yd > 0, g, g * (yd + 1))
                                 : g * ((1 - yd) * yd);
  };
  const auto max_gap = [](const torch::Tensor& a, const torch::Tensor& r) {
    return (a.to(torch::kDouble) - r).abs().max().item<double>() /
           std::max(1.0, r.abs().max().item<double>());
  };
  // On a CPU with AMX every product runs on its tiles and on AVX-512 BF16 alone.
  struct RestoreAmx {
    ~RestoreAmx() { nn::detail::set_amx_enabled(true); }
  } restore_amx;
  std::vector<bool> amx_modes{false};
  if (nn::detail::cpu_has_amx()) amx_modes.push_back(true);
  // Rows: one, odd (a lone last row in the weight gradient's pairs), many on two threads, tiles
  // of 16 with a remainder; widths: one vector, panels of 64 with tails of 16-48, the widest
  // (1024), summed widths in whole tiles of 32 (AMX's) or not (48, 80: the tiles' remainder).
  const std::vector<std::array<std::int64_t, 4>> shapes{
      {1, 16, 16, 1},   {37, 64, 64, 1},  {101, 576, 64, 1},  {50, 64, 576, 1}, {20000, 128, 48, 2},
      {7, 1024, 80, 1}, {9, 32, 1024, 1}, {300, 128, 128, 1}, {45, 256, 48, 1}, {1000, 48, 80, 1}};
  for (const bool amx : amx_modes)
    for (const auto& [n, K, N, threads] : shapes)
      for (const auto e : {Epilogue::none, Epilogue::relu, Epilogue::elu, Epilogue::sigmoid}) {
        INFO(n << " x " << K << " -> " << N << ", epilogue " << static_cast<int>(e) << ", AMX "
               << amx);
        nn::detail::set_amx_enabled(amx);
        at::set_num_threads(static_cast<int>(threads));
        const auto x = torch::randn({n, K}, torch::requires_grad());
        const auto W = (torch::randn({N, K}) / std::sqrt(static_cast<double>(K))).requires_grad_();
        const auto b = torch::randn({N}, torch::requires_grad());
        const auto y = linear_act(x, W, b, e, MatmulPrecision::medium);
        REQUIRE(y.scalar_type() == torch::kFloat);
        const auto g = torch::randn_like(y);
        const auto grads = torch::autograd::grad({y}, {x, W, b}, {g});
        // Reference: the same products in double from the bfloat16-rounded inputs; dZ = g ⊙ act'(y)
        // in float32, rounded for the two products as the kernel rounds it.
        const auto ref =
            activation(torch::linear(rounded(x), rounded(W), b.detach().to(torch::kDouble)), e);
        const auto dZ = output_gradient(g, y, e);
        // float32 sums of K (or n) products: a few units in the 7th digit, far below bfloat16's
        // 3rd (a product in float32 of the unrounded inputs would be off by ~1e-2).
        CHECK(max_gap(y, ref) < 2e-5);
        CHECK(max_gap(grads[0], rounded(dZ).mm(rounded(W))) < 2e-5);
        CHECK(max_gap(grads[1], rounded(dZ).t().mm(rounded(x))) < 2e-5);
        CHECK(max_gap(grads[2], dZ.to(torch::kDouble).sum(0)) < 2e-5);
      }
  // Inside a PackedWeightsScope a weight's pairs are kept between calls: an in-place update (here
  // through a view, which shares the version counter) and a new tensor must not reuse old pairs;
  // a write through .data() (as torch::optim::SGD steps) is seen once the scope has ended.
  {
    at::set_num_threads(1);
    torch::NoGradGuard no_grad;
    const auto x = torch::randn({30, 64});
    auto W = torch::randn({32, 64});
    const auto product = [&] {
      return linear_act(x, W, {}, Epilogue::none, MatmulPrecision::medium);
    };
    torch::Tensor before;
    {
      const PackedWeightsScope scope;
      before = product();
      REQUIRE(torch::equal(before, product()));
      W.narrow(0, 0, 16).mul_(2);  // doubling is exact in bfloat16: the rows double exactly
      const auto after = product();
      REQUIRE(torch::equal(after.narrow(1, 0, 16), 2 * before.narrow(1, 0, 16)));
      REQUIRE(torch::equal(after.narrow(1, 16, 16), before.narrow(1, 16, 16)));
      for (int k = 0; k < 20; ++k) {  // fresh weights of the same shape
        W = torch::randn({32, 64});
        REQUIRE((product().to(torch::kDouble) - rounded(x).mm(rounded(W).t()))
                    .abs()
                    .max()
                    .item<double>() < 1e-4);
      }
    }
    const PackedWeightsScope first;
    const auto y = product();
    W.data().mul_(2);  // no version bump: unseen inside this scope...
    REQUIRE(torch::equal(product(), y));
    {
      const PackedWeightsScope nested;  // ...and in a nested one
      REQUIRE(torch::equal(product(), y));
    }
  }
  // A helper thread adopts the scope of the thread it works for: it keeps its pairs from one job
  // to the next of that scope (a write through .data() stays unseen, as in the scope itself) and
  // drops them when a job comes from another scope or from none.
  {
    torch::NoGradGuard no_grad;
    const auto x = torch::randn({30, 64});
    const auto W = torch::randn({32, 64});
    const PackedWeightsScope caller;
    const auto id = nn::detail::packed_weights_scope();
    REQUIRE(id != 0);
    std::thread([&] {
      at::set_num_threads(1);
      auto& cache = nn::detail::packed_pairs_cache();
      const auto product = [&] {
        return linear_act(x, W, {}, Epilogue::none, MatmulPrecision::medium);
      };
      nn::detail::adopt_packed_weights_scope(id);  // job 1
      CHECK((cache.scopes == 1 && nn::detail::packed_weights_scope() == id));
      const auto y = product();
      CHECK(cache.entries.entries.size() == 1);
      W.data().mul_(2);
      nn::detail::adopt_packed_weights_scope(id);  // job 2, the same scope: the same pairs
      CHECK(torch::equal(product(), y));
      {
        const PackedWeightsScope nested;  // a job's own scope nests in the adopted one
        CHECK(torch::equal(product(), y));
      }
      CHECK((cache.scopes == 1 && cache.entries.entries.size() == 1));
      nn::detail::adopt_packed_weights_scope(id + 1000);  // another scope: packed afresh
      CHECK((cache.scopes == 1 && cache.entries.entries.empty()));
      CHECK(torch::equal(product(), 2 * y));
      nn::detail::adopt_packed_weights_scope(0);  // none: every call packs afresh
      CHECK((cache.scopes == 0 && cache.entries.entries.empty() &&
             nn::detail::packed_weights_scope() == 0));
      W.data().mul_(0.5);
      CHECK(torch::equal(product(), y));
      CHECK(cache.entries.entries.empty());
    }).join();
  }
  {
    torch::NoGradGuard no_grad;
    const auto x = torch::randn({30, 64});
    const auto W = torch::randn({32, 64});
    const auto y = linear_act(x, W, {}, Epilogue::none, MatmulPrecision::medium);
    W.data().mul_(2);  // outside a scope every call packs afresh
    REQUIRE(torch::equal(linear_act(x, W, {}, Epilogue::none, MatmulPrecision::medium), 2 * y));
  }
  // linear_blocks: blocks side by side into one row of pairs, a base and a bias (each optional),
  // every gradient; blocks of 16 and 32 columns start their weight columns off the panels of 64;
  // 9,000 rows on two threads sum two chunks of the weight's and the bias's gradients; 128
  // outputs (wider than the float32 kernel's 64: the bfloat16 kernels take them alone).
  struct BlockCase {
    std::int64_t n;
    std::vector<std::int64_t> widths;
    Epilogue e;
    int threads;
    std::int64_t N;
    bool base, bias;
  };
  const std::vector<BlockCase> block_cases{
      {45, {64, 128, 64}, Epilogue::none, 1, 64, true, false},
      {45, {64, 128, 64}, Epilogue::sigmoid, 1, 64, true, true},
      {31, {16, 16, 32}, Epilogue::relu, 1, 64, true, false},
      {9000, {32, 16}, Epilogue::elu, 2, 64, true, true},
      {300, {128, 128, 128}, Epilogue::relu, 1, 128, true, true},
      {9000, {128, 256}, Epilogue::relu, 2, 128, false, true},
      {37, {128, 128}, Epilogue::none, 1, 128, true, false}};
  for (const bool amx : amx_modes)
    for (const auto& c : block_cases) {
      INFO("linear_blocks, " << c.n << " rows, " << c.N << " outputs, epilogue "
                             << static_cast<int>(c.e) << ", base " << c.base << ", bias " << c.bias
                             << ", AMX " << amx);
      nn::detail::set_amx_enabled(amx);
      at::set_num_threads(c.threads);
      struct Restore {
        ~Restore() { set_float32_matmul_precision(MatmulPrecision::highest); }
      } back;
      set_float32_matmul_precision(MatmulPrecision::medium);
      std::vector<torch::Tensor> xs;
      std::int64_t Ktot = 0;
      for (const auto w : c.widths)
        xs.push_back(torch::randn({c.n, w}, torch::requires_grad())), Ktot += w;
      const auto W = (torch::randn({c.N, Ktot}) / 16).requires_grad_();
      const auto base = c.base ? torch::randn({c.n, c.N}, torch::requires_grad()) : torch::Tensor();
      const auto bias = c.bias ? torch::randn({c.N}, torch::requires_grad()) : torch::Tensor();
      const auto y = linear_blocks(xs, W, c.e, base, bias);
      CHECK_THAT(y.grad_fn()->name(), Catch::Contains("LinearBlocksFunction"));
      const auto g = torch::randn_like(y);
      std::vector<torch::Tensor> wrt(xs);
      wrt.push_back(W);
      if (c.base) wrt.push_back(base);
      if (c.bias) wrt.push_back(bias);
      const auto grads = torch::autograd::grad({y}, wrt, {g});
      std::vector<torch::Tensor> parts;
      for (const auto& x : xs) parts.push_back(rounded(x));
      const auto xcat = torch::cat(parts, 1);
      auto z = xcat.mm(rounded(W).t());
      if (c.base) z = z + base.detach().to(torch::kDouble);
      if (c.bias) z = z + bias.detach().to(torch::kDouble);
      const auto ref = activation(z, c.e);
      const auto dZ = output_gradient(g, y, c.e);
      CHECK(max_gap(y, ref) < 2e-5);
      const auto dx = rounded(dZ).mm(rounded(W));
      std::int64_t off = 0;
      for (std::size_t k = 0; k < xs.size(); off += xs[k].size(1), ++k)
        CHECK(max_gap(grads[k], dx.narrow(1, off, xs[k].size(1))) < 2e-5);
      std::size_t i = xs.size();
      CHECK(max_gap(grads[i++], rounded(dZ).t().mm(xcat)) < 2e-5);
      if (c.base) CHECK(max_gap(grads[i++], dZ.to(torch::kDouble)) < 1e-6);
      // The bias's gradient sums dZ in float32: its error grows with the rows summed.
      if (c.bias) CHECK(max_gap(grads[i++], dZ.to(torch::kDouble).sum(0)) < 1e-7 * c.n);
    }
  // A bias of the wrong shape is named, with what to give instead.
  REQUIRE_THROWS_WITH(linear_blocks({torch::randn({4, 16}), torch::randn({4, 16})},
                                    torch::randn({32, 32}), Epilogue::none, {}, torch::randn({31})),
                      Catch::Contains("one entry per output"));
  // Through the schedule's sparse weight (SparseLinearFunction keeps the path for its backward):
  // against double, rounding where the kernels round (x or A x, W, and the gradient entering the
  // dense product) and in float32 where they sum in float32 (the sparse products).
  at::set_num_threads(1);
  std::vector<std::int64_t> r, c;
  std::vector<double> val;
  auto Ad = torch::zeros({40, 40}, torch::kDouble);
  for (std::int64_t i = 0; i < 40; ++i)
    for (std::int64_t k : {i, (i * 7 + 3) % 40}) {
      r.push_back(i), c.push_back(k), val.push_back(1.5);
      Ad[i][k] += 1.5;
    }
  const auto A = SparseOperator::from_triplets(40, 40, r, c, val);
  const auto x = torch::randn({40, 32}, torch::requires_grad());
  const auto Wio = torch::randn({32, 64}, torch::requires_grad());  // in × out, as stored
  const auto f32 = [](const torch::Tensor& t) { return t.to(torch::kFloat).to(torch::kDouble); };
  for (const bool weight_first : {true, false}) {
    INFO("weight first " << weight_first);
    struct Restore {
      ~Restore() { set_float32_matmul_precision(MatmulPrecision::highest); }
    } back;
    set_float32_matmul_precision(MatmulPrecision::medium);
    const auto y = sparse_linear_act(A, x, Wio, weight_first, Epilogue::relu);
    const auto g = torch::randn_like(y);
    const auto grads = torch::autograd::grad({y}, {x, Wio}, {g});
    const auto dY = (g * (y.detach() > 0)).to(torch::kDouble);
    torch::Tensor y_ref, dx_ref, dW_ref;
    if (weight_first) {  // y = relu(A (x W))
      const auto t = f32(rounded(x).mm(rounded(Wio)));
      y_ref = torch::relu(Ad.mm(t));
      const auto dt = f32(Ad.t().mm(dY));
      dx_ref = rounded(dt).mm(rounded(Wio).t());
      dW_ref = rounded(x).t().mm(rounded(dt));
    } else {  // y = relu((A x) W)
      const auto z = f32(Ad.mm(x.detach().to(torch::kDouble)));
      y_ref = torch::relu(rounded(z).mm(rounded(Wio)));
      dx_ref = Ad.t().mm(f32(rounded(dY).mm(rounded(Wio).t())));
      dW_ref = rounded(z).t().mm(rounded(dY));
    }
    const auto max_gap = [](const torch::Tensor& a, const torch::Tensor& ref) {
      return (a.to(torch::kDouble) - ref).abs().max().item<double>() /
             std::max(1.0, ref.abs().max().item<double>());
    };
    CHECK(max_gap(y, y_ref) < 2e-5);
    CHECK(max_gap(grads[0], dx_ref) < 2e-5);
    CHECK(max_gap(grads[1], dW_ref) < 2e-5);
  }
}

TEST_CASE("a batch of complexes gives the per-complex results", "[nn][batch][schedule]") {
  const std::vector<ComplexView> views{make_view(0, true), make_view(1, false), make_view(2, true)};
  const auto batch = ComplexBatch::collate(views, 4);
  REQUIRE(batch.size(3) == 2);
  REQUIRE(batch.counts(3) == std::vector<std::int64_t>{1, 0, 1});
  OperatorNetwork net(test_schedule(16));
  const auto inputs = random_inputs(batch, torch::kFloat, 3);
  const auto all = net->forward(inputs, batch);
  for (std::size_t c = 0; c < views.size(); ++c) {
    const auto single = ComplexBatch::collate({views[c]}, 4);
    std::map<std::string, torch::Tensor> in;
    const int ranks[] = {0, 1, 2, 3, 4};
    const char* names[] = {"x0", "x1", "x2", "x3", "x4"};
    for (int r : ranks)
      in[names[r]] = inputs.at(names[r]).slice(0, batch.ptr(r)[c], batch.ptr(r)[c + 1]);
    const auto out = net->forward(in, single);
    REQUIRE(torch::allclose(
        out.at("a0"), all.at("a0").slice(0, batch.ptr(0)[c], batch.ptr(0)[c + 1]), 1e-6, 1e-6));
    REQUIRE(torch::allclose(
        out.at("a2"), all.at("a2").slice(0, batch.ptr(2)[c], batch.ptr(2)[c + 1]), 1e-6, 1e-6));
  }
  // All-guarded batch (no rank-3 cells anywhere) and an empty batch run too.
  const auto guarded = ComplexBatch::collate({views[1]}, 4);
  REQUIRE(net->forward(random_inputs(guarded, torch::kFloat, 4), guarded).at("a0").size(0) ==
          guarded.size(0));
  const auto empty = ComplexBatch::collate({}, 4, &views[0]);
  REQUIRE(net->forward(random_inputs(empty, torch::kFloat, 5), empty).at("a0").size(0) == 0);
}

TEST_CASE("the fast paths give the plain schedule's outputs and gradients", "[nn][schedule]") {
  // Only half of the faces hear from their edges and nodes, so the edges are encoded compactly
  // (rank 1 is only read, through B12) and p02 maps only the nodes that send; p40's object
  // message goes through u0's weight before it is spread over the nodes.
  std::vector<ComplexView> views{make_view(0, true), make_view(1, false)};
  for (auto& v : views) {
    for (const char* name : {"B12", "B02"}) {
      auto& n = v.neighborhoods.at(name);
      Neighborhood kept = n;
      kept.source.clear(), kept.target.clear(), kept.values.clear(), kept.roles.clear();
      for (std::size_t k = 0; k < n.source.size(); ++k)
        if (n.target[k] < n.num_target / 2)
          kept.source.push_back(n.source[k]), kept.target.push_back(n.target[k]);
      n = kept;
    }
  }
  const auto batch = ComplexBatch::collate(views, 4);
  OperatorNetwork net(test_schedule(8));
  net->to(torch::kDouble);
  const auto inputs = random_inputs(batch, torch::kDouble, 11);
  auto run = [&](bool fast) {
    net->set_fast_paths(fast);
    net->zero_grad();
    auto out = net->forward(inputs, batch);
    (out.at("a0").pow(2).sum() + out.at("a2").sin().sum()).backward();
    std::vector<torch::Tensor> r{out.at("a0").detach(), out.at("a2").detach()};
    for (const auto& p : net->parameters())
      r.push_back(p.grad().defined() ? p.grad().clone() : torch::zeros_like(p));
    return r;
  };
  const auto fast = run(true), plain = run(false);
  REQUIRE(fast.size() == plain.size());
  for (std::size_t i = 0; i < fast.size(); ++i) {
    INFO("tensor " << i);
    REQUIRE(torch::allclose(fast[i], plain[i], 1e-10, 1e-12));
  }
  REQUIRE(fast[0].abs().sum().item<double>() > 0);
}

TEST_CASE("a schedule at medium matmul precision stays float32 and close to highest",
          "[nn][schedule][mlp]") {
  // The fast paths include the update's first layer split by column blocks (nn::linear on the
  // concatenation, the object message through its block before the spread).
  const auto batch = ComplexBatch::collate({make_view(0, true), make_view(1, false)}, 4);
  torch::manual_seed(5);
  OperatorNetwork net(test_schedule(32));
  const auto inputs = random_inputs(batch, torch::kFloat, 11);
  const auto run = [&](MatmulPrecision p) {
    struct Restore {
      ~Restore() { set_float32_matmul_precision(MatmulPrecision::highest); }
    } restore;
    set_float32_matmul_precision(p);
    net->zero_grad();
    auto out = net->forward(inputs, batch);
    (out.at("a0").pow(2).sum() + out.at("a2").sin().sum()).backward();
    std::vector<torch::Tensor> r{out.at("a0").detach(), out.at("a2").detach()};
    for (const auto& q : net->parameters())
      r.push_back(q.grad().defined() ? q.grad().clone() : torch::zeros_like(q));
    return r;
  };
  const auto hi = run(MatmulPrecision::highest), md = run(MatmulPrecision::medium);
  double worst = 0;
  for (std::size_t i = 0; i < hi.size(); ++i) {
    INFO("tensor " << i);
    REQUIRE(md[i].scalar_type() == torch::kFloat);
    REQUIRE(torch::isfinite(md[i]).all().item<bool>());
    if (hi[i].norm().item<double>() > 0)
      worst = std::max(worst, ((md[i] - hi[i]).norm() / hi[i].norm()).item<double>());
  }
  CHECK(worst > 0);     // the products did run in bfloat16
  CHECK(worst < 5e-2);  // 8-bit mantissas, a few products deep
}

TEST_CASE("linear_layer_norm: the last Linear layer, its activation and LayerNorm as one node",
          "[nn][kernels][bf16]") {
  // Against double: the product of bfloat16-rounded x and W plus b, activated, normalised;
  // gradients against the unfused nodes (linear_act at medium, then nn::layer_norm), which round
  // the same operands.
  topos::test::RestoreThreads restore;
  struct Restore {
    ~Restore() {
      set_float32_matmul_precision(MatmulPrecision::highest);
      nn::detail::set_amx_enabled(true);
    }
  } back;
  const auto rounded = [](const torch::Tensor& t) {
    return t.detach().to(torch::kBFloat16).to(torch::kDouble);
  };
  const auto gap = [](const torch::Tensor& a, const torch::Tensor& r) {
    return (a.to(torch::kDouble) - r.to(torch::kDouble)).abs().max().item<double>() /
           std::max(1.0, r.abs().max().item<double>());
  };
  std::vector<bool> amx_modes{false};
  if (nn::detail::cpu_has_amx()) amx_modes.push_back(true);
  // Rows: fewer than a tile, a block and a remainder, two chunks on two threads; K and N: 128
  // (HOPNet's), 64 × 48 (a block's tail of 16), 32 × 256.
  const std::vector<std::array<std::int64_t, 4>> shapes{
      {5, 128, 128, 1}, {61, 128, 128, 1}, {9000, 128, 128, 2}, {100, 64, 48, 1}, {50, 32, 256, 1}};
  for (const bool amx : amx_modes)
    for (const auto& [n, K, N, threads] : shapes)
      for (const bool bias : {true, false}) {
        const auto act = bias ? Epilogue::relu : Epilogue::none;  // HOPNet's: relu and a bias
        INFO(n << " rows, " << K << " -> " << N << ", bias " << bias << ", AMX " << amx);
        nn::detail::set_amx_enabled(amx);
        at::set_num_threads(threads);
        set_float32_matmul_precision(MatmulPrecision::medium);
        const auto x = torch::randn({n, K}, torch::requires_grad());
        const auto W = (torch::randn({N, K}) / 8).requires_grad_();
        const auto b = bias ? torch::randn({N}, torch::requires_grad()) : torch::Tensor();
        const auto gamma = (1 + torch::randn({N}) / 4).requires_grad_();
        const auto beta = torch::randn({N}, torch::requires_grad());
        const auto y = nn::linear_layer_norm(x, W, b, gamma, beta, 1e-5, act);
        const bool fused = nn::detail::cpu_has_bf16();
        if (fused) CHECK_THAT(y.grad_fn()->name(), Catch::Contains("LinearLayerNormFunction"));
        auto z = rounded(x).mm(rounded(W).t());
        if (bias) z = z + b.detach().to(torch::kDouble);
        if (act == Epilogue::relu) z = torch::relu(z);
        const auto ref = torch::layer_norm(z, {N}, gamma.detach().to(torch::kDouble),
                                           beta.detach().to(torch::kDouble), 1e-5);
        CHECK(gap(y, ref) < 1e-4);
        // The unfused nodes round the same operands: the gradients agree to float rounding.
        const auto g = torch::randn_like(y);
        std::vector<torch::Tensor> wrt{x, W, gamma, beta};
        if (bias) wrt.push_back(b);
        const auto fused_grads = torch::autograd::grad({y}, wrt, {g});
        const auto y2 = nn::layer_norm(linear_act(x, W, b, act), gamma, beta);
        CHECK(gap(y, y2) < 1e-4);
        const auto plain_grads = torch::autograd::grad({y2}, wrt, {g});
        for (std::size_t i = 0; i < wrt.size(); ++i) {
          INFO("gradient " << i);
          CHECK(gap(fused_grads[i], plain_grads[i]) < 2e-4);
          CHECK(fused_grads[i].abs().sum().item<double>() > 0);
        }
        // Without a gradient to take: no node, the same values.
        torch::NoGradGuard no_grad;
        CHECK(gap(nn::linear_layer_norm(x, W, b, gamma, beta, 1e-5, act), y.detach()) < 1e-6);
      }
  // At highest precision, or where the kernels do not serve: exactly the two nodes.
  set_float32_matmul_precision(MatmulPrecision::highest);
  const auto x = torch::randn({20, 32}), W = torch::randn({16, 32}), b = torch::randn({16});
  const auto gamma = torch::randn({16}), beta = torch::randn({16});
  REQUIRE(torch::equal(nn::linear_layer_norm(x, W, b, gamma, beta),
                       nn::layer_norm(nn::linear(x, W, b), gamma, beta)));
  REQUIRE(torch::equal(nn::linear_layer_norm(x, W, b, gamma, beta, 1e-5, Epilogue::relu),
                       nn::layer_norm(linear_act(x, W, b, Epilogue::relu), gamma, beta)));
}

TEST_CASE("at medium precision a split first layer multiplies the terms where they lie",
          "[nn][schedule][mlp]") {
  // On the bfloat16 kernels, a concatenation into an mlp runs as one linear_blocks node: the
  // terms, the bias, the sum of the terms split off early and the activation after the layer (a
  // fusable relu; gelu stays a module of its own). The same values as the plain route (the
  // concatenation through the whole mlp) up to bfloat16's rounding of other sums, gradients too.
  const auto batch = ComplexBatch::collate({make_view(0, true), make_view(1, false)}, 4);
  for (const auto act : {Activation::relu, Activation::gelu}) {
    INFO("activation " << activation_name(act));
    torch::manual_seed(5);
    OperatorNetwork net(test_schedule(32, act));
    const auto inputs = random_inputs(batch, torch::kFloat, 11);
    bool blocks = false;
    const auto run = [&](FastPaths f) {
      struct Restore {
        ~Restore() { set_float32_matmul_precision(MatmulPrecision::highest); }
      } restore;
      set_float32_matmul_precision(MatmulPrecision::medium);
      net->fast_paths() = f;
      net->zero_grad();
      auto out = net->forward(inputs, batch);
      // Which nodes the graph holds: the split route's product is one LinearBlocksFunction.
      std::vector<torch::autograd::Node*> todo{out.at("a0").grad_fn().get()};
      std::set<torch::autograd::Node*> seen;
      blocks = false;
      while (!todo.empty()) {
        auto* node = todo.back();
        todo.pop_back();
        if (!node || !seen.insert(node).second) continue;
        blocks = blocks || node->name().find("LinearBlocksFunction") != std::string::npos;
        for (const auto& e : node->next_edges()) todo.push_back(e.function.get());
      }
      (out.at("a0").pow(2).sum() + out.at("a2").sin().sum()).backward();
      std::vector<torch::Tensor> r{out.at("a0").detach(), out.at("a2").detach()};
      for (const auto& q : net->parameters())
        r.push_back(q.grad().defined() ? q.grad().clone() : torch::zeros_like(q));
      return r;
    };
    const auto plain = run(FastPaths().split_first_layer(false));
    CHECK_FALSE(blocks);
    const auto split = run(FastPaths());
    CHECK(blocks == nn::detail::cpu_has_bf16());
    // Gaps over the outputs and over all gradients at once (a parameter's gradient near zero
    // alone would make any relative gap large). Both routes round other sums to bfloat16 (the
    // split one multiplies a term before its aggregation): with relu's kinks a few per cent.
    const auto gap = [&](std::size_t from, std::size_t to) {
      double d = 0, r = 0;
      for (std::size_t i = from; i < to; ++i) {
        REQUIRE(torch::isfinite(split[i]).all().item<bool>());
        d += (split[i] - plain[i]).pow(2).sum().item<double>();
        r += plain[i].pow(2).sum().item<double>();
      }
      return std::sqrt(d / r);
    };
    const double outputs = gap(0, 2), gradients = gap(2, plain.size());
    CAPTURE(outputs, gradients);
    CHECK(outputs < 1e-2);
    CHECK(gradients < 2e-2);
  }
}

TEST_CASE("schedule gradients match finite differences in double precision",
          "[nn][schedule][grad]") {
  const auto batch = ComplexBatch::collate({make_view(0, true), make_view(1, false)}, 4);
  OperatorNetwork net(test_schedule(6));
  net->to(torch::kDouble);
  const auto inputs = random_inputs(batch, torch::kDouble, 7);
  auto loss = [&] {
    auto out = net->forward(inputs, batch);
    return (out.at("a0").pow(2).sum() + out.at("a2").sin().sum());
  };
  net->zero_grad();
  loss().backward();
  std::mt19937 rng(1);
  int checked = 0;
  for (const auto& p : net->named_parameters()) {
    auto data = p.value().detach();
    auto flat = data.view({-1});
    const auto grad =
        p.value().grad().defined() ? p.value().grad().view({-1}) : torch::zeros_like(flat);
    for (int k = 0; k < 2; ++k) {
      const auto i = static_cast<std::int64_t>(rng() % static_cast<unsigned>(flat.size(0)));
      const double eps = 1e-6, orig = flat[i].item<double>();
      torch::NoGradGuard ng;
      flat[i] = orig + eps;
      const double up = loss().item<double>();
      flat[i] = orig - eps;
      const double down = loss().item<double>();
      flat[i] = orig;
      const double fd = (up - down) / (2 * eps), an = grad[i].item<double>();
      INFO(p.key() << "[" << i << "] analytic " << an << " numeric " << fd);
      REQUIRE(std::abs(fd - an) <= 1e-5 * std::max(1.0, std::abs(an)));
      ++checked;
    }
  }
  REQUIRE(checked >= 60);
}

TEST_CASE("schedules over a batch name their errors: when built, and when run",
          "[nn][schedule][errors]") {
  auto expect = [&](const OperatorSchedule& s, const std::string& what) {
    try {
      OperatorNetwork net(s);
    } catch (const ScheduleError& e) {
      INFO(e.what());
      CHECK(std::string(e.what()).find(what) != std::string::npos);
      return;
    }
    FAIL("no ScheduleError; expected: " << what);
  };
  const auto s = test_schedule(8);
  const MlpOptions m8(8, 8, 8), m16(16, 8, 8), m24(24, 8, 8);
  expect(OperatorSchedule(s).step(
             into(2).concat(from(2), from(0).pattern("B02")).mlp("u9", m24).named("chan")),
         "chan (into (2)): mlp 'u9' takes 24 channels but gets 16");
  expect(OperatorSchedule(s).step(
             into(2).concat(from(2), from(0).pattern("B02")).mlp("u0", m16).named("again")),
         "again (into (2)): mlp 'u0' is used again with other options");
  expect(OperatorSchedule(s).step(into(2).sum(from(1).pattern("B02")).named("dir")),
         "dir (into (2)): operator 'B02' applies to rank 0 cochains, not rank 1");
  expect(OperatorSchedule(s).step(
             into(2).sum(from(2).mlp("w", MlpOptions(8, 8, 4))).when_nonempty(3).named("g")),
         "g (into (2)): when_nonempty must keep the target's width (8), the step gives 4");
  expect(OperatorSchedule(s).step(into(2, "new").sum(from(2)).when_nonempty(3).named("g2")),
         "g2 (into (2, \"new\")): when_nonempty keeps the target's value elsewhere, but (2, "
         "\"new\") has none before the step");
  CHECK_THROWS_WITH(from(2).mlp("p", m8).only(1),
                    Catch::Contains("must follow a via or a pattern"));
  CHECK_THAT(s.str(), Catch::Contains("sum|B23[role -1]|·p23((2))") &&
                          Catch::Contains("where rank 3 is nonempty") &&
                          Catch::Contains("max|B04|·p04((0))") &&
                          Catch::Contains("e3(swap((3, \"x\")))"));

  // At run time: a neighbourhood that does not fit, a guard without a batch, roles and a
  // maximum over a sparse operator.
  const auto batch = ComplexBatch::collate({make_view(0, true)}, 4);
  OperatorNetwork net(s);
  auto inputs = random_inputs(batch, torch::kFloat, 1);
  inputs["x1"] = torch::randn({batch.size(1) + 1, 2});
  CHECK_THROWS_WITH(net->forward(inputs, batch),
                    Catch::Contains("input 'x1' has " + std::to_string(batch.size(1) + 1) +
                                    " rows, but the batch has " + std::to_string(batch.size(1)) +
                                    " cells of rank 1: give one row per cell of rank 1"));

  // Only via and an untransposed pattern aggregate over a neighbourhood of the batch.
  const auto misuse = [&](int rank, Term term) -> std::string {
    OperatorSchedule m = s;
    m.step(into(rank, "misuse").sum(std::move(term)).named("misuse"));
    m.output("misuse", rank, "misuse");
    OperatorNetwork bad(m);
    try {
      bad->forward(random_inputs(batch, torch::kFloat, 2), batch);
    } catch (const ScheduleError& e) {
      return e.what();
    }
    return "no error";
  };
  const std::string only_aggregations =
      ": 'B40' is a neighbourhood of the batch: only via (without row normalisation) and an "
      "untransposed pattern apply to it";
  CHECK_THAT(misuse(0, from(4).via("B40", /*row_norm=*/true)),
             Catch::Contains("misuse (into (0, \"misuse\"))" + only_aggregations));
  CHECK_THAT(misuse(4, from(0).via_t("B40")),
             Catch::Contains("misuse (into (4, \"misuse\"))" + only_aggregations));
  OperatorSchedule g;
  g.input("x", 2, 3).step(into(2).sum(from(2)).when_nonempty(3).named("guarded"));
  g.output("y", 2);
  CHECK_THROWS_WITH(OperatorNetwork(g)->forward({{"x", torch::ones({4, 3})}}, {}),
                    Catch::Contains("guarded (into (2)): when_nonempty(3) needs a ComplexBatch"));
  OperatorSchedule r;
  r.input("x", 0, 3).operator_input("A", 0, 0);
  r.step(into(0).sum(from(0).pattern("A").only(1)).named("roles"));
  r.output("y", 0);
  const auto A = SparseOperator::from_dense(torch::eye(4));
  CHECK_THROWS_WITH(OperatorNetwork(r)->forward({{"x", torch::ones({4, 3})}}, {{"A", A}}),
                    Catch::Contains("roles (into (0)): only(1) needs a neighbourhood with roles"));
  OperatorSchedule mx;
  mx.input("x", 0, 3).operator_input("A", 0, 0);
  mx.step(into(0).sum(from(0).pattern("A", Aggr::max)));
  mx.output("y", 0);
  CHECK_THROWS_WITH(OperatorNetwork(mx)->forward({{"x", torch::ones({4, 3})}}, {{"A", A}}),
                    Catch::Contains("max over a sparse operator's pattern is not supported"));
}

TEST_CASE("parameters round-trip by name through a file", "[nn][checkpoint]") {
  OperatorNetwork a(test_schedule(8)), b(test_schedule(8));
  const std::string path = "topos_test_params.pt";
  save_parameters(*a, path);
  const auto dict = read_tensor_dict(path);
  REQUIRE(dict.count("p23.0.weight") == 1);
  load_parameters(*b, dict, path);
  for (const auto& p : a->named_parameters())
    REQUIRE(torch::equal(p.value(), b->named_parameters()[p.key()]));
  auto missing = dict;
  missing.erase("u3.2.bias");
  REQUIRE_THROWS_WITH(load_parameters(*b, missing, "x.pt"), "x.pt: missing tensor 'u3.2.bias'");
  auto shaped = dict;
  shaped["u3.2.bias"] = torch::zeros({3});
  REQUIRE_THROWS_WITH(load_parameters(*b, shaped, "x.pt"),
                      Catch::Contains("tensor 'u3.2.bias' has shape [3], expected [8]"));
  auto extra = dict;
  extra["bogus"] = torch::zeros({1});
  REQUIRE_THROWS_WITH(load_parameters(*b, extra, "x.pt"), "x.pt: unexpected tensor 'bogus'");
  REQUIRE_THROWS_WITH(read_tensor_dict("/nonexistent.pt"), "/nonexistent.pt: cannot open file");
  std::remove(path.c_str());
}

TEST_CASE("epoch sharding: every item once per epoch, the same steps for any world size",
          "[nn][distributed]") {
  const std::int64_t n = 11;
  const auto order = epoch_order(n, 5, 0);
  REQUIRE(order == epoch_order(n, 5, 0));
  REQUIRE(std::set<std::int64_t>(order.begin(), order.end()).size() == static_cast<std::size_t>(n));
  REQUIRE(*std::min_element(order.begin(), order.end()) == 0);
  REQUIRE(*std::max_element(order.begin(), order.end()) == n - 1);
  REQUIRE(order != epoch_order(n, 5, 1));  // 1 in 11! to coincide
  REQUIRE(order != epoch_order(n, 6, 0));
  REQUIRE(epoch_order(0, 1, 0).empty());
  for (auto [world, per_rank] :
       std::vector<std::pair<int, int>>{{1, 1}, {1, 2}, {2, 1}, {3, 2}, {4, 1}, {16, 1}}) {
    INFO("world " << world << " per rank " << per_rank);
    const auto steps = steps_per_epoch(n, world, per_rank);
    REQUIRE(steps == (n + world * per_rank - 1) / (world * per_rank));
    std::multiset<std::int64_t> seen;
    for (std::int64_t s = 0; s < steps; ++s) {
      std::int64_t total = -1, count = 0;
      std::set<std::int64_t> step_items;
      for (int r = 0; r < world; ++r) {
        const auto sh = step_shard(order, s, world, r, per_rank);
        REQUIRE(sh.items.size() <= static_cast<std::size_t>(per_rank));
        if (total >= 0) REQUIRE(sh.total == total);  // every rank agrees on the divisor
        total = sh.total;
        count += static_cast<std::int64_t>(sh.items.size());
        seen.insert(sh.items.begin(), sh.items.end());
        step_items.insert(sh.items.begin(), sh.items.end());
      }
      REQUIRE(count == total);
      // A step of W ranks × K takes the same trajectories as one process taking W·K.
      const auto single = step_shard(order, s, 1, 0, world * per_rank);
      REQUIRE(std::set<std::int64_t>(single.items.begin(), single.items.end()) == step_items);
      REQUIRE(single.total == total);
    }
    REQUIRE(seen.size() == static_cast<std::size_t>(n));
    REQUIRE(std::set<std::int64_t>(seen.begin(), seen.end()).size() == static_cast<std::size_t>(n));
  }
}

TEST_CASE("a world of one: collectives are the identity, gradients are divided",
          "[nn][distributed]") {
  Distributed one;
  REQUIRE(one.world_size() == 1);
  REQUIRE(one.is_main());
  REQUIRE(one.backend_name() == "none");
  REQUIRE(one.all_reduce_sum({1.5, 2.0}) == std::vector<double>{1.5, 2.0});
  REQUIRE(one.broadcast_bytes("abc") == "abc");
  torch::nn::Linear lin(3, 2);
  lin->weight.mutable_grad() = torch::full({2, 3}, 6.0);
  one.average_gradients(lin->parameters(), 3.0);
  REQUIRE(torch::allclose(lin->weight.grad(), torch::full({2, 3}, 2.0)));
  REQUIRE_FALSE(lin->bias.grad().defined());  // no gradient: still none (an optimizer skips it)
  REQUIRE_THROWS_AS(one.average_gradients(lin->parameters(), 0.0), std::invalid_argument);
}

TEST_CASE("the environment of torchrun: read, and refused when inconsistent", "[nn][distributed]") {
  const auto with_env = [](std::vector<std::pair<const char*, const char*>> vars) {
    for (const char* k : {"RANK", "WORLD_SIZE", "LOCAL_RANK", "LOCAL_WORLD_SIZE", "MASTER_ADDR",
                          "MASTER_PORT", "TOPOS_RENDEZVOUS_FILE"})
      unsetenv(k);
    for (auto [k, v] : vars) setenv(k, v, 1);
  };
  with_env({});
  auto e = DistributedEnv::from_environment();
  REQUIRE((e.world_size == 1 && e.rank == 0 && e.local_rank == 0));
  with_env({{"RANK", "3"},
            {"WORLD_SIZE", "4"},
            {"LOCAL_RANK", "1"},
            {"LOCAL_WORLD_SIZE", "2"},
            {"MASTER_ADDR", "node7"},
            {"MASTER_PORT", "29555"}});
  e = DistributedEnv::from_environment();
  REQUIRE((e.rank == 3 && e.world_size == 4 && e.local_rank == 1 && e.local_world_size == 2 &&
           e.master_addr == "node7" && e.master_port == 29555));
  REQUIRE_FALSE(e.loopback());
  with_env({{"RANK", "2"}, {"WORLD_SIZE", "2"}});
  REQUIRE_THROWS_WITH(DistributedEnv::from_environment(), "RANK=2 is not below WORLD_SIZE=2");
  with_env({{"WORLD_SIZE", "2"}});
  REQUIRE_THROWS_WITH(DistributedEnv::from_environment(), "WORLD_SIZE=2 is set but RANK is not");
  with_env({{"RANK", "0"}, {"WORLD_SIZE", "two"}});
  REQUIRE_THROWS_WITH(DistributedEnv::from_environment(),
                      "environment variable WORLD_SIZE='two' is not an integer >= 1");
  with_env({{"RANK", "0"}, {"WORLD_SIZE", "1"}, {"MASTER_PORT", "70000"}});
  REQUIRE_THROWS_WITH(DistributedEnv::from_environment(),
                      Catch::Contains("MASTER_PORT=70000 is not a port"));
  with_env({});
}

TEST_CASE(
    "two ranks over Gloo: gradients averaged in buckets, broadcasts, and a dead peer is an error, "
    "not a hang",
    "[nn][distributed]") {
  if (!gloo_available()) {
    std::cout << "SKIPPED: this build has no c10d Gloo process group (libgloo-dev)\n";
    std::exit(TOPOS_SKIP_CODE);
  }
  const auto dir =
      std::filesystem::temp_directory_path() / ("topos_gloo_test_" + std::to_string(::getpid()));
  std::filesystem::remove_all(dir);
  std::filesystem::create_directories(dir);
  const auto env = [&](int rank) {
    DistributedEnv e;
    e.rank = rank, e.world_size = 2, e.local_rank = rank, e.local_world_size = 2;
    e.rendezvous_file = (dir / "store").string();
    return e;
  };
  // Small buckets: the 3 parameters below go through several all-reduces.
  const auto opts = DistributedOptions().timeout(std::chrono::seconds(4)).bucket_bytes(40);
  std::vector<torch::Tensor> grads(2), bias_grads(2), weights(2);
  std::vector<std::string> bytes(2), errors(2);
  std::vector<std::string> names(2);
  std::vector<int> ghost(2, -1);
  std::vector<std::vector<double>> sums(2);
  std::vector<std::thread> ranks;
  for (int r = 0; r < 2; ++r)
    ranks.emplace_back([&, r] {
      try {
        Distributed d(env(r), opts);
        names[static_cast<std::size_t>(r)] = d.backend_name();
        torch::manual_seed(
            static_cast<std::uint64_t>(10 + r));  // different replicas until the broadcast
        torch::nn::Linear a(4, 3), b(3, 1), c(1, 1);
        std::vector<torch::Tensor> params = a->parameters();
        for (auto& p : b->parameters()) params.push_back(p);
        params.push_back(c->weight);  // no gradient on either rank
        d.broadcast_(params);
        weights[static_cast<std::size_t>(r)] =
            torch::cat({a->weight.reshape(-1), b->weight.reshape(-1)}).clone();
        for (std::size_t i = 0; i < params.size(); ++i)
          if (!(r == 1 && i == 3) && i != 4)
            params[i].mutable_grad() =
                torch::full_like(params[i], static_cast<double>((r + 1) * (i + 1)));
        d.average_gradients(params, 2.0);
        grads[static_cast<std::size_t>(r)] = a->weight.grad().clone();
        bias_grads[static_cast<std::size_t>(r)] = b->bias.grad().clone();
        ghost[static_cast<std::size_t>(r)] = c->weight.grad().defined();
        bytes[static_cast<std::size_t>(r)] =
            d.broadcast_bytes(r == 0 ? std::string("statistics\0json", 15) : std::string());
        sums[static_cast<std::size_t>(r)] = d.all_reduce_sum({1.0 + r, 0.25});
        d.barrier();
        if (r == 1) return;  // rank 1 leaves: its group closes its connections
        std::this_thread::sleep_for(std::chrono::milliseconds(200));
        d.all_reduce_sum({1.0});
        errors[0] = "rank 0's all-reduce succeeded without rank 1";
      } catch (const std::exception& e) {
        errors[static_cast<std::size_t>(r)] = e.what();
      }
    });
  for (auto& t : ranks) t.join();
  std::filesystem::remove_all(dir);
  REQUIRE(names[0] == "gloo");
  REQUIRE(errors[1].empty());
  REQUIRE(ghost == std::vector<int>{0, 0});  // no gradient anywhere: none after averaging
  REQUIRE(torch::equal(weights[0], weights[1]));
  // a.weight is parameter 0: (1·1 + 2·1) / 2; b.bias is parameter 3, absent on rank 1: (1·4 + 0) /
  // 2.
  for (int r = 0; r < 2; ++r) {
    REQUIRE(torch::allclose(grads[static_cast<std::size_t>(r)], torch::full({3, 4}, 1.5)));
    REQUIRE(torch::allclose(bias_grads[static_cast<std::size_t>(r)], torch::full({1}, 2.0)));
    REQUIRE(bytes[static_cast<std::size_t>(r)] == std::string("statistics\0json", 15));
    REQUIRE(sums[static_cast<std::size_t>(r)] == std::vector<double>{3.0, 0.5});
  }
  INFO(errors[0]);
  REQUIRE_THAT(errors[0], Catch::Contains("distributed (rank 0 of 2): all-reduce failed: another "
                                          "worker died or stopped responding"));
}

TEST_CASE("devices by name: cpu, auto, and a clear error for CUDA where there is none",
          "[nn][device]") {
  REQUIRE(device_from_string("cpu") == torch::Device(torch::kCPU));
  REQUIRE_THROWS_WITH(device_from_string("tpu"),
                      "--device tpu: expected cpu, cuda, cuda:<index> or auto");
  REQUIRE_THROWS_WITH(device_from_string("cuda:x"), "--device cuda:x: expected cuda:<index>");
  if (cuda_available()) {
    REQUIRE(device_from_string("auto").is_cuda());
    REQUIRE(device_from_string("cuda", 0) == torch::Device(torch::kCUDA, 0));
    REQUIRE_THROWS_WITH(device_from_string("cuda:999"), Catch::Contains("GPU 999 does not exist"));
  } else {
    REQUIRE(device_from_string("auto") == torch::Device(torch::kCPU));
    REQUIRE_THROWS_WITH(device_from_string("cuda"),
                        Catch::Contains("--device cuda: no CUDA device"));
    REQUIRE_THROWS_WITH(device_from_string("cuda:0"), Catch::Contains("use --device cpu"));
  }
}

TEST_CASE(
    "Adam's state saved by parameter name resumes the same steps, with the same bytes in any "
    "process",
    "[nn][serialization]") {
  const auto make = [] {
    torch::manual_seed(3);
    return torch::nn::Sequential(torch::nn::Linear(4, 8), torch::nn::ReLU(),
                                 torch::nn::Linear(8, 2));
  };
  const auto x = torch::randn({16, 4}), y = torch::randn({16, 2});
  const auto step = [&](torch::nn::Sequential& m, torch::optim::Adam& opt) {
    opt.zero_grad();
    (m->forward(x) - y).pow(2).sum().backward();
    opt.step();
  };
  // Uninterrupted: five steps.
  auto a = make();
  torch::optim::Adam opt_a(a->parameters(), torch::optim::AdamOptions(1e-2).amsgrad(true));
  for (int i = 0; i < 2; ++i) step(a, opt_a);
  const auto saved =
      topos::nn::torch_file_bytes(c10::IValue(topos::nn::adam_state_dict(opt_a, *a)));
  for (int i = 0; i < 3; ++i) step(a, opt_a);
  // Interrupted after two: a new model (new tensor addresses) and optimizer from the saved state.
  auto b = make();
  torch::optim::Adam opt_b(b->parameters(), torch::optim::AdamOptions(1e-2).amsgrad(true));
  for (int i = 0; i < 2; ++i) step(b, opt_b);
  REQUIRE(topos::nn::torch_file_bytes(c10::IValue(topos::nn::adam_state_dict(opt_b, *b))) == saved);
  auto c = make();
  {
    torch::NoGradGuard ng;
    for (std::size_t i = 0; i < b->parameters().size(); ++i)
      c->parameters()[i].copy_(b->parameters()[i]);
  }
  torch::optim::Adam opt_c(c->parameters(), torch::optim::AdamOptions(1e-2).amsgrad(true));
  const auto dict = topos::nn::parse_tensor_dict(saved.data(), saved.size(), "adam.pt");
  REQUIRE(dict.count("0.weight.max_exp_avg_sq") == 1);
  topos::nn::load_adam_state(opt_c, *c, dict, "adam.pt");
  for (int i = 0; i < 3; ++i) step(c, opt_c);
  for (std::size_t i = 0; i < a->parameters().size(); ++i)
    REQUIRE(torch::equal(a->parameters()[i], c->parameters()[i]));
  // A state of another model is an error naming the tensor.
  auto other = torch::nn::Sequential(torch::nn::Linear(4, 3));
  torch::optim::Adam opt_o(other->parameters());
  REQUIRE_THROWS_WITH(
      topos::nn::load_adam_state(opt_o, *other, dict, "adam.pt"),
      Catch::Contains("adam.pt: tensor '0.weight.exp_avg' does not have its parameter's shape"));
}

TEST_CASE(
    "pickles Python writes (OrderedDict, SETITEM) reach the dict checks, and a malformed "
    "OrderedDict is an error",
    "[nn][serialization]") {
  // A torch file around a hand-written pickle (protocol 2).
  const auto torch_file = [](const std::string& pickle) {
    std::vector<char> out;
    caffe2::serialize::PyTorchStreamWriter writer([&](const void* b, std::size_t n) {
      out.insert(out.end(), static_cast<const char*>(b), static_cast<const char*>(b) + n);
      return n;
    });
    writer.writeRecord("data.pkl", pickle.data(), pickle.size());
    writer.writeEndOfFile();
    return out;
  };
  const auto parse = [&](const std::string& pickle) {
    const auto bytes = torch_file(pickle);
    return topos::nn::parse_tensor_dict(bytes.data(), bytes.size(), "t.pt");
  };
  using namespace std::string_literals;
  // {} via OrderedDict() (memoized class reused), with SETITEM and a _metadata BUILD: read as an
  // empty-then-filled plain dict, so the entry check (not LibTorch's unpickler) answers.
  const std::string od =
      "\x80\x02"
      "ccollections\nOrderedDict\nq\x00)Rq\x01"s;
  REQUIRE(parse(od + "}q\x02"
                     "X\x09\x00\x00\x00_metadatah\x00)Rsb."s)
              .empty());
  REQUIRE_THROWS_WITH(parse(od + "X\x01\x00\x00\x00"
                                 "aK\x01s."s),
                      Catch::Contains("t.pt: an entry is not a (name, tensor) pair"));
  REQUIRE_THROWS_WITH(
      parse("\x80\x02"
            "ccollections\nOrderedDict\nq\x00K\x01R."s),
      Catch::Contains(
          "t.pt: not a readable torch file: an OrderedDict made other than from an empty tuple"));
}

TEST_CASE("the caching CPU allocator reuses freed blocks by size class, within its limit",
          "[nn][cpu]") {
  using topos::nn::detail::CachingCPUAllocator;
  // Size classes: below 1 MB as asked; above, rounded up to an eighth of the power of two.
  REQUIRE(CachingCPUAllocator::size_class(1000) == 1000);
  REQUIRE(CachingCPUAllocator::size_class(1 << 20) == 1 << 20);
  REQUIRE(CachingCPUAllocator::size_class((1 << 20) + 1) == (1 << 20) + (1 << 17));
  REQUIRE(CachingCPUAllocator::size_class(3'865'600) == 15 << 18);  // 30200 × 32 floats
  for (std::size_t n : {std::size_t(1) << 20, std::size_t(3'000'001), std::size_t(50) << 20}) {
    const auto c = CachingCPUAllocator::size_class(n);
    REQUIRE(c >= n);
    REQUIRE(c <= n + n / 8 + 1);
  }

  c10::Allocator* previous = c10::GetAllocator(c10::DeviceType::CPU);
  release_cached_cpu_memory();
  use_caching_cpu_allocator(std::size_t(8) << 20);
  REQUIRE(c10::GetAllocator(c10::DeviceType::CPU) == &CachingCPUAllocator::instance());
  const void* first = nullptr;
  {
    auto a = torch::full({1000, 500}, 2.0f);  // 2 MB: cached when freed
    REQUIRE(a.sum().item<double>() == 1e6);
    REQUIRE(reinterpret_cast<std::uintptr_t>(a.data_ptr()) % 64 == 0);
    first = a.data_ptr();
  }
  REQUIRE(cached_cpu_bytes() == CachingCPUAllocator::size_class(2'000'000));
  {
    auto b = torch::empty({500, 1001});  // the same class: the same block, nothing cached
    REQUIRE(b.data_ptr() == first);
    REQUIRE(cached_cpu_bytes() == 0);
    auto small = torch::arange(10);  // below the threshold: malloc's, freed at once
    REQUIRE(small.sum().item<std::int64_t>() == 45);
    auto none = torch::empty({0});
    REQUIRE(none.numel() == 0);
  }
  REQUIRE(cached_cpu_bytes() == CachingCPUAllocator::size_class(2'000'000));
  {
    // Over the 8 MB limit: a 12 MB block is freed, not cached.
    auto big = torch::zeros({3, 1 << 20});
    REQUIRE(big.abs().sum().item<double>() == 0);
  }
  REQUIRE(cached_cpu_bytes() == CachingCPUAllocator::size_class(2'000'000));
  // Autograd through tensors of the cache gives the same numbers as before.
  torch::manual_seed(3);
  auto x = torch::randn({2000, 300}, torch::requires_grad());
  (x.tanh() * x).sum().backward();
  REQUIRE(torch::allclose(x.grad(), x.detach().tanh() + x.detach() / x.detach().cosh().pow(2)));
  release_cached_cpu_memory();
  REQUIRE(cached_cpu_bytes() == 0);
  c10::SetAllocator(c10::DeviceType::CPU, previous, /*priority=*/1);
  REQUIRE(c10::GetAllocator(c10::DeviceType::CPU) == previous);
}

TEST_CASE("denormals are flushed to zero inside ScopedFlushDenormals, on every intra-op thread",
          "[nn][cpu]") {
#if defined(__x86_64__) || defined(__i386__)
  using topos::nn::ScopedFlushDenormals;
  const float tiny = 1e-39f;  // below FLT_MIN (1.18e-38): a denormal
  REQUIRE(std::fpclassify(tiny) == FP_SUBNORMAL);
  volatile float a = tiny, b = 1e-30f, c = 1e-10f;  // volatile: computed at run time
  const int threads = at::get_num_threads();
  REQUIRE_FALSE(ScopedFlushDenormals::active());
  REQUIRE(a * 1.0f == tiny);
  REQUIRE(b * c > 0.0f);  // 1e-40: a denormal result
  // A tensor operation large enough to be split over two intra-op threads.
  const auto many = torch::full({1 << 20}, tiny);
  at::set_num_threads(2);
  REQUIRE((many * 1.0f).sum().item<double>() > 1e-34);
  {
    const ScopedFlushDenormals flush;
    REQUIRE(ScopedFlushDenormals::active());
    REQUIRE(a * 1.0f == 0.0f);    // denormal input read as zero
    REQUIRE(b * c == 0.0f);       // denormal result flushed
    REQUIRE(1e-20f * c != 0.0f);  // normal numbers unchanged
    if (ScopedFlushDenormals::reaches_intra_op_threads())
      REQUIRE((many * 1.0f).sum().item<double>() == 0.0);
    else
      WARN("LibTorch's OpenMP is not libgomp: the intra-op threads were not checked");
    {
      const ScopedFlushDenormals off(false);  // does nothing
      REQUIRE(ScopedFlushDenormals::active());
    }
    REQUIRE(ScopedFlushDenormals::active());
  }
  REQUIRE_FALSE(ScopedFlushDenormals::active());
  REQUIRE(a * 1.0f == tiny);
  REQUIRE((many * 1.0f).sum().item<double>() > 1e-34);
  at::set_num_threads(threads);
#else
  WARN("not x86: ScopedFlushDenormals does nothing here, and this test checks nothing");
#endif
}

TEST_CASE("topos's kernels run on LibTorch's intra-op threads, with the same results",
          "[nn][cpu]") {
  // topos::nn_headers compiles with OpenMP (GCC), so at::parallel_for in topos's kernels opens a
  // parallel region (without -fopenmp its pragma is ignored and every kernel ran on one thread).
  topos::test::RestoreThreads restore;
  at::set_num_threads(2);
  std::mutex m;
  std::set<std::thread::id> seen;
  at::parallel_for(0, 2, 1, [&](std::int64_t, std::int64_t) {
    const std::lock_guard<std::mutex> lock(m);
    seen.insert(std::this_thread::get_id());
  });
#if defined(_OPENMP)
  if (omp_get_thread_limit() >= 2 && !omp_get_dynamic())
    REQUIRE(seen.size() == 2);
  else
    WARN("OMP_THREAD_LIMIT or OMP_DYNAMIC keeps OpenMP to one thread: not checked");
#else
  WARN("built without OpenMP: topos's kernels run on one thread");
  REQUIRE(seen.size() == 1);
#endif
  // The dense kernel splits rows (the same arithmetic per row: bitwise equal); its backward sums
  // dW and db per thread, then adds the two (equal up to rounding).
  torch::manual_seed(4);
  const auto x = torch::randn({20000, 64}, torch::requires_grad());
  const auto W = torch::randn({64, 64}, torch::requires_grad());
  const auto b = torch::randn({64}, torch::requires_grad());
  const auto g = torch::randn({20000, 64});
  const auto run = [&](int n) {
    at::set_num_threads(n);
    for (auto t : {x, W, b}) t.mutable_grad() = torch::Tensor();
    const auto y = topos::nn::linear_act(x, W, b, topos::nn::Epilogue::relu);
    y.backward(g);
    return std::vector<torch::Tensor>{y.detach(), x.grad(), W.grad(), b.grad()};
  };
  const auto one = run(1), two = run(2);
  REQUIRE(torch::equal(one[0], two[0]));
  REQUIRE(torch::equal(one[1], two[1]));
  REQUIRE(torch::allclose(one[2], two[2], 1e-5, 1e-3));
  REQUIRE(torch::allclose(one[3], two[3], 1e-5, 1e-3));
  REQUIRE(torch::allclose(one[2], ((g * (one[0] > 0)).t().mm(x.detach())), 1e-4, 1e-2));
  // Row-parallel kernels give the same bits on any number of threads: LayerNorm without
  // statistics (a rollout's, which wrote through a null pointer on the second thread), the CSR
  // product, and dropout's counter-based mask.
  const auto w = torch::rand({64}), bias = torch::randn({64});
  std::vector<std::int64_t> r, c;
  std::vector<double> v;
  for (std::int64_t i = 0; i < 20000; ++i)
    for (std::int64_t k : {i, (i * 7 + 3) % 20000, (i * 13 + 5) % 20000})
      r.push_back(i), c.push_back(k), v.push_back(0.5 + static_cast<double>(k % 5));
  const auto A = topos::nn::SparseOperator::from_triplets(20000, 20000, r, c, v);
  const auto xs = x.detach();
  const auto each = [&](int n) {
    at::set_num_threads(n);
    torch::NoGradGuard no_grad;
    torch::manual_seed(9);
    return std::vector<torch::Tensor>{topos::nn::layer_norm(xs, w, bias, 1e-5),
                                      topos::nn::spmm(A, xs, topos::nn::Epilogue::relu),
                                      topos::nn::dropout(xs, 0.5, true)};
  };
  const auto serial = each(1), parallel = each(2);
  for (std::size_t k = 0; k < serial.size(); ++k) REQUIRE(torch::equal(serial[k], parallel[k]));
  REQUIRE(torch::allclose(serial[0], torch::layer_norm(xs, {64}, w, bias, 1e-5), 1e-5, 1e-4));
  // ELU's pass splits at whole vectors: each element takes the vectorised or the scalar expm1 as
  // on one thread. 1,000,003 elements: a tail after the last whole vector.
  const auto z = torch::randn({1'000'003});
  at::set_num_threads(1);
  const auto elu1 = topos::nn::apply_activation(z, topos::nn::Activation::elu);
  at::set_num_threads(2);
  REQUIRE(torch::equal(elu1, topos::nn::apply_activation(z, topos::nn::Activation::elu)));
  REQUIRE(torch::allclose(elu1, torch::elu(z), 1e-6, 1e-6));
}
