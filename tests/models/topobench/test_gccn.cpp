// Tests of TopoTune's neighbourhood vocabulary on lifted graphs (topobench/routes.hpp,
// lifting.hpp) and of GCCN (models/combinatorial/gccn.hpp): every neighbourhood of a square and a
// triangle sharing an edge, counted by hand and recomputed densely from the incidences; batches;
// bad names; and GCCN's outputs and gradients against PyG's GCN, GIN and GraphSAGE written out
// densely on the route graphs and the inter-rank union graphs, with the network's parameters.
#include "support/torch_prelude.hpp"

#include "topos/models/topobench/batch.hpp"
#include "support/topobench.hpp"

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
  LiftingOptions o;
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
    LiftingOptions o;
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
}
