// Tests of topos/core/domain_lifting.hpp: the clique complex against brute-force clique
// enumeration (and its lexicographic order), mesh -> simplicial complex (Euler characteristic,
// boundary of boundary), SC -> hypergraph / combinatorial complex / cell complex with the same
// operators, graph -> neighbourhood hypergraph, bad input.
#include <catch2/catch.hpp>

#include "topos/core/domain_lifting.hpp"
#include "topos/mesh/primitives.hpp"

#include <random>

using namespace topos;
using Dense = Eigen::MatrixXd;
using Edges = std::vector<std::array<std::int64_t, 2>>;

namespace {
Edges random_graph(std::mt19937& rng, int n, double p) {
  Edges e;
  std::bernoulli_distribution coin(p);
  for (int u = 0; u < n; ++u)
    for (int v = u + 1; v < n; ++v)
      if (coin(rng)) e.push_back({coin(rng) ? u : v, coin(rng) ? v : u});  // either orientation
  for (auto& x : e)
    if (x[0] == x[1]) x[1] = (x[0] + 1) % n;
  return e;
}
}  // namespace

TEST_CASE("clique complex equals brute-force clique enumeration, in lexicographic order",
          "[core][lifting][domains]") {
  std::mt19937 rng(9);
  for (int trial = 0; trial < 5; ++trial) {
    const int n = 11;
    Edges edges = random_graph(rng, n, 0.5);
    edges.push_back(edges.front());  // a repeated edge is one edge
    std::vector<std::vector<bool>> adj(n, std::vector<bool>(n, false));
    for (auto& e : edges)
      adj[static_cast<std::size_t>(e[0])][static_cast<std::size_t>(e[1])] =
          adj[static_cast<std::size_t>(e[1])][static_cast<std::size_t>(e[0])] = true;
    const SimplicialComplex sc = clique_complex(n, edges, 3);
    REQUIRE(sc.num_nodes() == n);
    for (int k = 1; k <= 3; ++k) {
      std::vector<std::vector<std::int64_t>> expect;
      for (int mask = 0; mask < (1 << n); ++mask) {
        if (__builtin_popcount(static_cast<unsigned>(mask)) != k + 1) continue;
        std::vector<std::int64_t> s;
        for (int v = 0; v < n; ++v)
          if (mask >> v & 1) s.push_back(v);
        bool clique = true;
        for (std::size_t a = 0; a < s.size() && clique; ++a)
          for (std::size_t b = a + 1; b < s.size() && clique; ++b)
            clique = adj[static_cast<std::size_t>(s[a])][static_cast<std::size_t>(s[b])];
        if (clique) expect.push_back(s);
      }
      std::sort(expect.begin(), expect.end());
      if (expect.empty()) {
        REQUIRE(sc.num_cells(k) == 0);
        continue;
      }
      REQUIRE(sc.skeleton(k) == expect);
    }
    REQUIRE(sc.dim() <= 3);
  }
  REQUIRE(clique_complex(4, {{0, 1}, {1, 2}, {0, 2}, {2, 3}}, 1).shape() ==
          std::vector<std::int64_t>{4, 4});
  REQUIRE_THROWS_WITH(clique_complex(3, {{0, 0}}, 2), Catch::Contains("self-loop"));
  REQUIRE_THROWS_WITH(clique_complex(3, {{0, 3}}, 2), Catch::Contains("uses node 3"));
}

TEST_CASE("mesh -> simplicial complex: Euler characteristic and boundary of boundary",
          "[core][lifting][domains]") {
  for (const TriangleMesh& m : {uv_sphere(8, 8), box_mesh(3), cylinder_mesh(20, 3)}) {
    const SimplicialComplex sc = simplicial_complex_from_mesh(m);
    REQUIRE(sc.num_cells(2) == m.num_faces());
    REQUIRE(sc.euler_characteristic() == 2);
    REQUIRE(sparse::multiply(sc.incidence_matrix(1), sc.incidence_matrix(2)).nonZeros() == 0);
  }
}

TEST_CASE(
    "simplicial complex -> hypergraph, combinatorial complex, cell complex keep the operators",
    "[core][lifting][domains]") {
  const SimplicialComplex sc =
      SimplicialComplex::from_simplices({{0, 1, 2}, {1, 2, 3}, {3, 4}, {0, 1, 2, 5}});
  const Hypergraph h = to_hypergraph(sc);
  REQUIRE(h.num_hyperedges() == sc.num_cells(1) + sc.num_cells(2) + sc.num_cells(3));
  REQUIRE(h.hyperedge(0) == sc.simplex(1, 0));
  REQUIRE(h.hyperedge(sc.num_cells(1)) == sc.simplex(2, 0));
  const CombinatorialComplex<> cc = to_combinatorial_complex(sc);
  for (int k = 1; k <= sc.dim(); ++k) {
    REQUIRE(cc.size(k) == sc.num_cells(k));
    REQUIRE(Dense(cc.incidence_matrix(k - 1, k)) == Dense(sc.incidence_matrix(k, Signed::no)));
    REQUIRE(Dense(cc.signed_incidence_matrix(k - 1, k)) == Dense(sc.incidence_matrix(k)));
  }
  REQUIRE(Dense(cc.adjacency_matrix(0, 1)) == Dense(sc.adjacency_matrix(0)));
  const auto tri = SimplicialComplex::from_simplices({{0, 1, 2}, {1, 2, 3}, {3, 4}});
  const CellComplex cx = to_cell_complex(tri);
  for (int k = 1; k <= 2; ++k)
    REQUIRE(Dense(cx.incidence_matrix(k)) == Dense(tri.incidence_matrix(k)));
  for (int k = 0; k <= 2; ++k)
    REQUIRE(Dense(cx.hodge_laplacian_matrix(k)) == Dense(tri.hodge_laplacian_matrix(k)));
}

TEST_CASE("graph -> neighbourhood hypergraph", "[core][lifting][domains]") {
  const Hypergraph h = neighborhood_hypergraph(5, {{0, 1}, {2, 1}, {1, 3}});
  REQUIRE(h.num_hyperedges() == 5);
  REQUIRE(h.hyperedge(1) == std::vector<std::int64_t>{0, 1, 2, 3});
  REQUIRE(h.hyperedge(0) == std::vector<std::int64_t>{0, 1});
  REQUIRE(h.hyperedge(4) == std::vector<std::int64_t>{4});  // isolated: itself
}
