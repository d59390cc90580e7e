// Tests of TopoTune's neighbourhood vocabulary on lifted graphs (topobench/routes.hpp,
// lifting.hpp) and of GCCN (models/combinatorial/gccn.hpp): every neighbourhood of a square and a
// triangle sharing an edge, counted by hand and recomputed densely from the incidences; batches;
// bad names; GCCN's outputs and gradients against PyG's GCN, GIN, GraphSAGE and GAT written out
// densely on the route graphs and the inter-rank union graphs, with the network's parameters; and
// its initialisation against PyG's.
#include "support/torch_prelude.hpp"

#include "topos/models/combinatorial/gccn.hpp"
#include "topos/models/topobench/batch.hpp"
#include "support/topobench.hpp"

#include <cmath>
#include <map>
#include <string>
#include <vector>

using namespace topos;
using namespace topos::models;
using namespace topos::models::topobench;

namespace {

// The square 0-1-2-3 and the triangle 2-3-4 share the edge 2-3 (two basis cycles); the second
// graph is a triangle 0-1-2 with a pendant node 3.
const std::vector<std::array<std::int64_t, 2>> kSquareTriangle = {{0, 1}, {0, 3}, {1, 2},
                                                                  {2, 3}, {2, 4}, {3, 4}};
const std::vector<std::array<std::int64_t, 2>> kTrianglePendant = {{0, 1}, {0, 2}, {1, 2}, {2, 3}};

const std::vector<std::string> kNames = {
    "up_adjacency-0",    "up_adjacency-1",   "up_adjacency-2",   "1-up_adjacency-1",
    "down_adjacency-1",  "down_adjacency-2", "2-up_adjacency-0", "2-down_adjacency-2",
    "up_laplacian-1",    "down_laplacian-1", "down_laplacian-2", "up_incidence-0",
    "up_incidence-1",    "down_incidence-1", "down_incidence-2", "2-up_incidence-0",
    "2-down_incidence-2"};

LiftedGraph lift(const std::vector<std::array<std::int64_t, 2>>& edges, std::int64_t n,
                 std::set<std::string> names, std::int64_t width = 1) {
  GraphLiftingOptions o;
  o.operators = std::move(names);
  torch::manual_seed(n);
  const auto x = torch::randn({n, width});
  std::vector<float> xv(x.data_ptr<float>(), x.data_ptr<float>() + x.numel());
  return lift_graph(n, edges, xv, width, {}, Domain::cell, o);
}

using topos::testing::dense;

torch::Tensor pattern(const torch::Tensor& m) {
  return (m != 0).to(torch::kFloat);
}

// The neighbourhood recomputed densely from |B_1|, |B_2| (b[1], b[2]) by its definition.
torch::Tensor expected(const std::string& name, const std::vector<torch::Tensor>& b) {
  const auto r = neighborhood_route(name);
  const int lo = r.up ? r.rank : r.rank - r.hops, hi = r.up ? r.rank + r.hops : r.rank;
  auto m = b[static_cast<std::size_t>(lo + 1)];
  for (int k = lo + 2; k <= hi; ++k) m = m.matmul(b[static_cast<std::size_t>(k)]);
  if (r.kind == NeighborhoodRoute::Kind::incidence) return pattern(r.up ? m.t() : m);
  auto g = pattern(r.up ? m.matmul(m.t()) : m.t().matmul(m));
  if (r.kind == NeighborhoodRoute::Kind::adjacency) g = g * (1 - torch::eye(g.size(0)));
  return g;
}

std::int64_t nnz(const torch::Tensor& d) {
  return (d != 0).sum().item<std::int64_t>();
}

}  // namespace

TEST_CASE("TopoTune's neighbourhoods of a square and a triangle sharing an edge", "[gccn]") {
  std::set<std::string> names(kNames.begin(), kNames.end());
  names.insert({"incidence_1", "incidence_2"});
  const auto g = lift(kSquareTriangle, 5, names);
  const auto b1 = dense(g.operators.at("incidence_1")), b2 = dense(g.operators.at("incidence_2"));
  REQUIRE(b2.size(1) == 2);  // the square and the triangle
  const auto sizes = b2.sum(0);
  CHECK(sizes.min().item<float>() == 3);
  CHECK(sizes.max().item<float>() == 4);
  // Edges and 2-cells by their nodes, to check entries by hand.
  const auto edge = [&](std::int64_t u, std::int64_t v) {
    for (std::int64_t e = 0; e < b1.size(1); ++e)
      if (b1[u][e].item<float>() != 0 && b1[v][e].item<float>() != 0) return e;
    FAIL("no edge " << u << "-" << v);
    return std::int64_t{-1};
  };
  const std::int64_t square = sizes[0].item<float>() == 4 ? 0 : 1, triangle = 1 - square;
  for (const auto& name : kNames) {
    INFO(name);
    const auto got = dense(g.operators.at(name));
    const auto want = expected(name, {torch::Tensor(), b1, b2, torch::zeros({2, 0})});
    REQUIRE(got.sizes() == want.sizes());
    CHECK(torch::equal(got, want));
  }
  const auto op = [&](const std::string& n) { return dense(g.operators.at(n)); };
  // Counted by hand: 6 edges; pairs of edges in the square (6) or the triangle (3); pairs of
  // edges at a node Σ C(deg, 2) = 1 + 1 + 3 + 3 + 1; node pairs in a 2-cell: 6 + 3 - 1 (2-3).
  CHECK(nnz(op("up_adjacency-0")) == 12);
  CHECK(nnz(op("up_adjacency-1")) == 18);
  CHECK(nnz(op("down_adjacency-1")) == 18);
  CHECK(nnz(op("up_laplacian-1")) == 24);    // + every edge with itself (each has a 2-cell)
  CHECK(nnz(op("down_laplacian-1")) == 24);  // + every edge with itself
  CHECK(nnz(op("2-up_adjacency-0")) == 16);
  CHECK(nnz(op("up_adjacency-2")) == 0);
  CHECK(torch::equal(op("down_adjacency-2"), torch::tensor({{0.f, 1.f}, {1.f, 0.f}})));
  CHECK(torch::equal(op("2-down_adjacency-2"), torch::tensor({{0.f, 1.f}, {1.f, 0.f}})));
  CHECK(torch::equal(op("down_laplacian-2"), torch::ones({2, 2})));
  CHECK(torch::equal(op("1-up_adjacency-1"), op("up_adjacency-1")));
  const auto a2 = op("2-up_adjacency-0");  // the square's diagonals, not node 4 to 0 or 1
  CHECK(a2[0][2].item<float>() == 1);
  CHECK(a2[1][3].item<float>() == 1);
  CHECK(a2[0][4].item<float>() == 0);
  CHECK(a2[1][4].item<float>() == 0);
  CHECK(a2[2][4].item<float>() == 1);
  const auto a1 = op("up_adjacency-1");  // 0-1 and 2-4 share no 2-cell; 0-1 and 2-3 share one
  CHECK(a1[edge(0, 1)][edge(2, 4)].item<float>() == 0);
  CHECK(a1[edge(0, 1)][edge(2, 3)].item<float>() == 1);
  CHECK(a1[edge(2, 4)][edge(2, 3)].item<float>() == 1);
  // Incidences: target × source.
  CHECK(op("up_incidence-0").sizes() == torch::IntArrayRef({6, 5}));
  CHECK(nnz(op("up_incidence-0")) == 12);
  CHECK(op("down_incidence-2").sizes() == torch::IntArrayRef({6, 2}));
  CHECK(nnz(op("down_incidence-2")) == 7);
  const auto n2 = op("2-up_incidence-0");  // 2-cells × nodes
  CHECK(n2.sizes() == torch::IntArrayRef({2, 5}));
  CHECK(torch::equal(n2[square], torch::tensor({1.f, 1.f, 1.f, 1.f, 0.f})));
  CHECK(torch::equal(n2[triangle], torch::tensor({0.f, 0.f, 1.f, 1.f, 1.f})));
  CHECK(torch::equal(op("2-down_incidence-2"), n2.t()));
  // Routes.
  const auto route = [](const std::string& n) {
    const auto r = neighborhood_route(n);
    return std::pair<int, int>(r.source_rank(), r.target_rank());
  };
  CHECK(route("up_adjacency-1") == std::pair<int, int>(1, 1));
  CHECK(route("2-up_adjacency-0") == std::pair<int, int>(0, 0));
  CHECK(route("up_incidence-0") == std::pair<int, int>(0, 1));
  CHECK(route("down_incidence-2") == std::pair<int, int>(2, 1));
  CHECK(route("2-up_incidence-0") == std::pair<int, int>(0, 2));
}

TEST_CASE("TopoTune's neighbourhoods batch block-diagonally", "[gccn]") {
  const std::set<std::string> names = {"2-up_adjacency-0", "down_incidence-2", "up_incidence-0"};
  const std::vector<LiftedGraph> gs = {lift(kSquareTriangle, 5, names),
                                       lift(kTrianglePendant, 4, names)};
  const auto b = collate(gs, {0, 1});
  for (const auto& name : names) {
    INFO(name);
    const auto a = dense(gs[0].operators.at(name)), c = dense(gs[1].operators.at(name));
    auto want = torch::zeros({a.size(0) + c.size(0), a.size(1) + c.size(1)});
    want.slice(0, 0, a.size(0)).slice(1, 0, a.size(1)).copy_(a);
    want.slice(0, a.size(0)).slice(1, a.size(1)).copy_(c);
    CHECK(torch::equal(b.operators.at(name).to_dense(), want));
  }
}

TEST_CASE("A bad neighbourhood name is an error listing the valid forms", "[gccn]") {
  const auto throws_with = [](const std::string& name, const std::string& part, Domain d) {
    INFO(name);
    GraphLiftingOptions o;
    o.operators = {name};
    try {
      lift_graph(3, {{0, 1}, {1, 2}, {0, 2}}, {0, 0, 0}, 1, {}, d, o);
      FAIL("no error");
    } catch (const std::invalid_argument& e) {
      CHECK_THAT(e.what(), Catch::Matchers::Contains(part));
    }
  };
  for (const char* bad : {"up_adjacancy-1", "up-adjacency-1", "sideways_adjacency-0",
                          "up_adjacency-x", "0-up_adjacency-1", "3-down_incidence-2"})
    throws_with(bad, "valid forms are [h-]up_adjacency-k", Domain::cell);
  throws_with("up_incidence-2", "above the lifted ranks", Domain::cell);
  throws_with("3-up_adjacency-1", "above the lifted ranks", Domain::simplicial);
  throws_with("up_adjacency-0", "cell or simplicial domain", Domain::graph);
  CHECK_THROWS_WITH(gccn_schedule(GCCNOptions(4, {"up_adjacency-1", "upadjacency-0"})),
                    Catch::Matchers::Contains("valid forms"));
  CHECK_THROWS_WITH(
      gccn_gnn("GATv2"),
      Catch::Matchers::Contains("unknown GNN 'GATv2' (known: GCN, GIN, GraphSAGE, GAT)"));
  CHECK(gccn_gnn("GAT") == GccnGnn::gat);
  CHECK_THROWS_WITH(
      gccn_schedule(GCCNOptions(4, {"up_adjacency-1"}).gnn(GccnGnn::gat).gat_heads(3)),
      Catch::Matchers::Contains("GAT's 3 heads must divide the 4 channels"));
}

namespace {

// PyG's layers written out densely on a graph given as E (E[i][j] = 1: an edge j → i).
using Params = std::map<std::string, torch::Tensor>;

torch::Tensor linear(const Params& p, const std::string& path, const torch::Tensor& x,
                     bool bias = true) {
  auto y = x.matmul(p.at(path + ".weight").t());
  return bias ? y + p.at(path + ".bias") : y;
}
// BatchNorm1d in training: the batch's mean and biased variance.
torch::Tensor batch_norm(const Params& p, const std::string& path, const torch::Tensor& x) {
  const auto mean = x.mean(0), var = x.var(0, false);
  return (x - mean) / (var + 1e-5).sqrt() * p.at(path + ".weight") + p.at(path + ".bias");
}
torch::Tensor conv(GccnGnn gnn, const Params& p, const std::string& path, const torch::Tensor& e,
                   const torch::Tensor& x, bool last = false, std::int64_t heads = 1) {
  switch (gnn) {
    case GccnGnn::gat: {  // remove_self_loops, add_self_loops; per head h and edge j → i:
      // α = softmax_j LeakyReLU_0.2(a_src·W x_j + a_dst·W x_i), Σ_j α W x_j; heads concatenated
      // (hidden) or averaged (last); + b.
      const auto n = e.size(0);
      const auto eye = torch::eye(n);
      const auto es = (e * (1 - eye) + eye) > 0;
      const auto xw = linear(p, path + ".lin", x, false).view({n, heads, -1});
      const auto as = (xw * p.at(path + ".att_src")).sum(-1);  // n × heads
      const auto ad = (xw * p.at(path + ".att_dst")).sum(-1);
      const auto score = torch::leaky_relu(ad.unsqueeze(1) + as.unsqueeze(0), 0.2)
                             .masked_fill(~es.unsqueeze(2), -INFINITY);  // i × j × heads
      const auto out = torch::einsum("ijh,jhc->ihc", {torch::softmax(score, 1), xw});
      return (last ? out.mean(1) : out.reshape({n, -1})) + p.at(path + ".bias");
    }
    case GccnGnn::gcn: {  // add_remaining_self_loops, in-degrees, D^-1/2 Ê D^-1/2 (x Θ) + b
      const auto es = ((e + torch::eye(e.size(0))) > 0).to(torch::kFloat);
      const auto d = es.sum(1).rsqrt();
      const auto xw = linear(p, path + ".lin", x, false);
      return (d.unsqueeze(1) * es * d.unsqueeze(0)).matmul(xw) + p.at(path + ".bias");
    }
    case GccnGnn::gin: {  // MLP((1 + 0) x + Σ_j x_j)
      auto h = linear(p, path + ".nn.lins.0", x + e.matmul(x));
      h = torch::relu(batch_norm(p, path + ".nn.norms.0.module", h));
      return linear(p, path + ".nn.lins.1", h);
    }
    case GccnGnn::sage: {  // lin_l(mean_j x_j) + lin_r(x)
      const auto mean = e.matmul(x) / e.sum(1, true).clamp_min(1);
      return linear(p, path + ".lin_l", mean) + linear(p, path + ".lin_r", x, false);
    }
  }
  return x;
}
// PyG's BasicGNN: conv, then BatchNorm, relu (dropout 0) between the convolutions.
torch::Tensor basic_gnn(GccnGnn gnn, const Params& p, const std::string& prefix, int layers,
                        const torch::Tensor& e, torch::Tensor x, std::int64_t heads) {
  for (int j = 0; j < layers; ++j) {
    x = conv(gnn, p, prefix + "convs." + std::to_string(j), e, x, j == layers - 1, heads);
    if (j < layers - 1)
      x = torch::relu(batch_norm(p, prefix + "norms." + std::to_string(j) + ".module", x));
  }
  return x;
}

// TopoTune's forward: per layer and route the GNN on the route's graph, or on the union graph
// [targets (zeros); sources] with an edge from each source to each target it reaches.
std::vector<torch::Tensor> gccn_reference(GccnGnn gnn, const Params& p,
                                          const std::vector<std::string>& names,
                                          const std::map<std::string, torch::Tensor>& ops,
                                          std::vector<torch::Tensor> x, int layers, int gnn_layers,
                                          std::int64_t heads) {
  for (int l = 0; l < layers; ++l) {
    std::map<int, torch::Tensor> sum;
    for (std::size_t i = 0; i < names.size(); ++i) {
      const auto r = neighborhood_route(names[i]);
      const int s = r.source_rank(), d = r.target_rank();
      const auto& a = ops.at(names[i]);
      const std::string prefix =
          "graph_routes." + std::to_string(l) + "." + std::to_string(i) + ".";
      torch::Tensor out;
      if (s == d) {
        out = basic_gnn(gnn, p, prefix, gnn_layers, pattern(a), x[static_cast<std::size_t>(s)],
                        heads);
      } else {
        const auto nd = a.size(0), ns = a.size(1);
        auto e = torch::zeros({nd + ns, nd + ns});
        e.slice(0, 0, nd).slice(1, nd).copy_(pattern(a));
        const auto xs = x[static_cast<std::size_t>(s)];
        out = basic_gnn(gnn, p, prefix, gnn_layers, e,
                        torch::cat({torch::zeros({nd, xs.size(1)}), xs}), heads)
                  .slice(0, 0, nd);
      }
      sum[d] = sum.count(d) ? sum[d] + out : out;
    }
    for (auto& [rank, v] : sum) x[static_cast<std::size_t>(rank)] = torch::relu(v);
  }
  return x;
}

}  // namespace

TEST_CASE("GCCN is TopoTune's forward with PyG's GCN, GIN, GraphSAGE and GAT, gradients included",
          "[gccn]") {
  // topotune.yaml's cell routes.
  const std::vector<std::string> names = {"up_adjacency-1", "up_incidence-0", "down_incidence-2",
                                          "2-up_adjacency-0"};
  const std::set<std::string> wanted(names.begin(), names.end());
  const std::vector<LiftedGraph> gs = {lift(kSquareTriangle, 5, wanted),
                                       lift(kTrianglePendant, 4, wanted)};
  const auto b = collate(gs, {0, 1});
  std::map<std::string, torch::Tensor> dense_ops;
  for (const auto& n : names) dense_ops[n] = b.operators.at(n).to_dense();
  const std::int64_t c = 4;
  // GAT with one head (TopoTune's) and with two: concatenated in the hidden convolution, averaged
  // in the last.
  const std::vector<std::pair<GccnGnn, std::int64_t>> cases = {{GccnGnn::gcn, 1},
                                                               {GccnGnn::gin, 1},
                                                               {GccnGnn::sage, 1},
                                                               {GccnGnn::gat, 1},
                                                               {GccnGnn::gat, 2}};
  for (const auto& [gnn, heads] : cases) {
    INFO("gnn " << static_cast<int>(gnn) << ", heads " << heads);
    torch::manual_seed(11);
    nn::OperatorNetwork net(
        gccn_schedule(GCCNOptions(c, names).gnn(gnn).n_layers(2).gat_heads(heads)));
    Params p;
    {
      torch::NoGradGuard no_grad;
      for (auto& kv : net->named_parameters()) {
        kv.value().copy_(torch::randn_like(kv.value()) * 0.5);  // norms' γ, β included
        p[kv.key()] = kv.value().detach().clone().requires_grad_(true);
      }
    }
    // Every conv and norm of TopoTune's model is there under PyG's names, and nothing else.
    const std::size_t per_conv = gnn == GccnGnn::gcn   ? 2
                                 : gnn == GccnGnn::gin ? 6
                                 : gnn == GccnGnn::gat ? 4
                                                       : 3;
    CHECK(p.size() == 2 * names.size() * (2 * per_conv + 2));
    std::vector<torch::Tensor> x;
    std::map<std::string, torch::Tensor> in;
    for (int r = 0; r < 3; ++r) {
      x.push_back(torch::randn({b.x[static_cast<std::size_t>(r)].size(0), c}));
      in["x_" + std::to_string(r)] = x.back().clone().requires_grad_(true);
    }
    std::vector<torch::Tensor> xr;
    for (auto& t : x) xr.push_back(t.clone().requires_grad_(true));
    const auto out = net->forward(in, net->declared_operators(b.operators));
    const auto want = gccn_reference(gnn, p, names, dense_ops, xr, 2, 2, heads);
    torch::Tensor loss = torch::zeros({}), ref_loss = torch::zeros({});
    for (int r = 0; r < 3; ++r) {
      const auto R = std::to_string(r);
      INFO("rank " << r);
      CHECK(torch::allclose(out.at("x_" + R), want[static_cast<std::size_t>(r)], 1e-4, 1e-5));
      const auto w = torch::randn_like(want[static_cast<std::size_t>(r)]);
      loss = loss + (out.at("x_" + R) * w).sum();
      ref_loss = ref_loss + (want[static_cast<std::size_t>(r)] * w).sum();
    }
    loss.backward();
    ref_loss.backward();
    for (auto& kv : net->named_parameters()) {
      INFO(kv.key());
      REQUIRE(kv.value().grad().defined());
      // float32 through batch norms: a bias before one has an exact gradient of 0, here ~1e-5.
      CHECK(torch::allclose(kv.value().grad(), p.at(kv.key()).grad(), 1e-3, 1e-4));
    }
    for (int r = 0; r < 3; ++r)
      CHECK(torch::allclose(in.at("x_" + std::to_string(r)).grad(),
                            xr[static_cast<std::size_t>(r)].grad(), 1e-4, 1e-5));
  }
}

TEST_CASE("GCCN's batch norm over a union updates its running statistics once per forward",
          "[gccn]") {
  const std::vector<std::string> names = {"up_incidence-0"};
  const auto g = lift(kSquareTriangle, 5, {names.begin(), names.end()});
  const auto b = collate({g}, {0});
  nn::OperatorNetwork net(gccn_schedule(GCCNOptions(3, names).n_layers(1)));
  torch::manual_seed(5);
  const auto x0 = torch::randn({5, 3}), x1 = torch::randn({6, 3});
  net->forward({{"x_0", x0}, {"x_1", x1}}, net->declared_operators(b.operators));
  // The union's rows after the first GCNConv: [targets (edges); sources (nodes)].
  Params p;
  for (auto& kv : net->named_parameters()) p[kv.key()] = kv.value().detach();
  const auto a = b.operators.at("up_incidence-0").to_dense();
  auto e = torch::zeros({11, 11});
  e.slice(0, 0, 6).slice(1, 6).copy_(a);
  const auto h =
      conv(GccnGnn::gcn, p, "graph_routes.0.0.convs.0", e, torch::cat({torch::zeros({6, 3}), x0}));
  torch::Tensor mean;
  for (auto& kv : net->named_buffers())
    if (kv.key() == "graph_routes.0.0.norms.0.module.running_mean") mean = kv.value();
  REQUIRE(mean.defined());
  CHECK(torch::allclose(mean, 0.1 * h.mean(0), 1e-5, 1e-6));
}

TEST_CASE("gcn and a batch norm over a union name what is wrong with them", "[gccn]") {
  using namespace nn::ops;
  using Catch::Matchers::Contains;
  nn::OperatorSchedule s;
  s.input("x_0", 0, 3).operator_input("B", 0, 1).output("x_1", 1);
  s.step(into(1).sum(from(0).gcn("B")));
  CHECK_THROWS_WITH(nn::OperatorNetwork(s), Contains("needs a square operator"));
  nn::OperatorSchedule t;
  t.input("x_0", 0, 3).operator_input("B", 0, 1).output("x_1", 1);
  t.step(into(1).sum(from(0).gcn("B", nn::GcnPart::union_targets)));
  CHECK_THROWS_WITH(nn::OperatorNetwork(t), Contains("reads rank 1 cochains, not rank 0"));
  nn::OperatorSchedule u;
  u.input("x_0", 0, 3).input("x_1", 1, 4).output("x_0", 0);
  u.step(into(0).sum(from(0).batch_norm("bn", {{0, ""}, {1, ""}}, 0)));
  CHECK_THROWS_WITH(nn::OperatorNetwork(u), Contains("(1) has 4 channels, the operand 3"));
  nn::OperatorSchedule v;
  v.input("x_0", 0, 3).input("x_1", 1, 3).output("x_0", 0);
  v.step(into(0).sum(from(0).batch_norm("bn", {{1, ""}, {0, ""}}, 0)));
  CHECK_THROWS_WITH(nn::OperatorNetwork(v), Contains("part 0 is (1) but the operand has rank 0"));
}

TEST_CASE("GCCN's convolutions start from PyG's initialisation", "[gccn]") {
  // Wide enough that the bounds tell the schemes apart: Glorot √(6 / (64 + 64)) ≈ 0.217,
  // torch.nn.Linear's 1/√64 = 0.125; a uniform draw of 4096 entries reaches 0.9 of its bound.
  const std::int64_t c = 64;
  const std::vector<std::string> names = {"up_adjacency-1", "up_incidence-0"};
  const auto spread = [](const torch::Tensor& t, double bound) {
    const auto m = t.abs().max().item<double>();
    CHECK(m <= bound * (1 + 1e-6));
    CHECK(m > 0.8 * bound);
  };
  const double glorot = std::sqrt(6.0 / (c + c)), torch_bound = 1 / std::sqrt(double(c));
  for (const auto gnn : {GccnGnn::gcn, GccnGnn::gin, GccnGnn::sage, GccnGnn::gat}) {
    INFO("gnn " << static_cast<int>(gnn));
    torch::manual_seed(3);
    const std::int64_t heads = 2;
    nn::OperatorNetwork net(
        gccn_schedule(GCCNOptions(c, names).gnn(gnn).gat_heads(heads).n_layers(1)));
    std::size_t seen = 0;
    for (auto& kv : net->named_parameters()) {
      const std::string& k = kv.key();
      const auto& v = kv.value();
      INFO(k);
      const bool last = k.find("convs.1.") != std::string::npos;
      if (k.find("norms") != std::string::npos) continue;  // BatchNorm: γ = 1, β = 0
      ++seen;
      if (gnn == GccnGnn::gcn || gnn == GccnGnn::gat) {
        if (k.size() > 5 && k.compare(k.size() - 5, 5, ".bias") == 0) {
          CHECK(torch::equal(v, torch::zeros_like(v)));
        } else if (k.find(".lin.weight") != std::string::npos) {  // GAT's last: heads × c out
          CHECK(v.size(1) == c);
          spread(v, std::sqrt(6.0 / double(v.size(0) + v.size(1))));
          if (gnn == GccnGnn::gcn || !last) spread(v, glorot);
        } else {  // GAT's att_src, att_dst: 1 × heads × C, PyG's glorot √(6 / (heads + C))
          REQUIRE(gnn == GccnGnn::gat);
          const std::int64_t C = last ? c : c / heads;
          CHECK(v.sizes() == torch::IntArrayRef({1, heads, C}));
          spread(v, std::sqrt(6.0 / double(heads + C)));
        }
      } else {  // GIN's MLP and SAGEConv's lins: torch.nn.Linear's ±1/√in, weight and bias
        CHECK(v.dim() <= 2);
        spread(v, torch_bound);
      }
    }
    CHECK(seen > 0);
  }
}
