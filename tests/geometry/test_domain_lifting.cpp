// Tests of topos/geometry/domain_lifting.hpp: clique complex of a Boost graph (= the edge-list
// one), cell complex from a cycle basis (b1 of the graph cycles filled: b1 = 0, one 2-cell per
// independent cycle), Delaunay triangulations (Euler characteristic of a disc, the empty
// circumcircle property of every triangle), alpha complexes (alpha = 0: points only; unbounded
// alpha: the whole Delaunay complex; in between nested).
#include <catch2/catch.hpp>

#include "topos/geometry/domain_lifting.hpp"

#include <boost/graph/adjacency_list.hpp>

#include <random>

using namespace topos;

using BoostGraph = boost::adjacency_list<boost::vecS, boost::vecS, boost::undirectedS>;

TEST_CASE("clique complex of a Boost graph equals the edge-list one", "[geometry][lifting]") {
  std::mt19937 rng(4);
  std::bernoulli_distribution coin(0.4);
  BoostGraph g(12);
  std::vector<std::array<std::int64_t, 2>> edges;
  for (int u = 0; u < 12; ++u)
    for (int v = u + 1; v < 12; ++v)
      if (coin(rng)) boost::add_edge(u, v, g), edges.push_back({u, v});
  const auto a = clique_complex(g, 3), b = clique_complex(12, edges, 3);
  REQUIRE(a.shape() == b.shape());
  for (int k = 0; k <= a.dim(); ++k) REQUIRE(a.skeleton(k) == b.skeleton(k));
}

TEST_CASE("cell complex from a cycle basis fills every independent cycle", "[geometry][lifting]") {
  // A 4 x 5 grid graph plus a pendant path: b1(graph) = 3 * 4 = 12 independent cycles.
  BoostGraph g(22);
  for (int i = 0; i < 4; ++i)
    for (int j = 0; j < 5; ++j) {
      if (j + 1 < 5) boost::add_edge(i * 5 + j, i * 5 + j + 1, g);
      if (i + 1 < 4) boost::add_edge(i * 5 + j, (i + 1) * 5 + j, g);
    }
  boost::add_edge(19, 20, g);
  boost::add_edge(20, 21, g);
  const CellComplex cx = cell_complex_from_cycle_basis(g);
  REQUIRE(cx.num_edges() == 33);
  REQUIRE(cx.num_2cells() == 33 - 22 + 1);
  REQUIRE(sparse::multiply(cx.incidence_matrix(1), cx.incidence_matrix(2)).nonZeros() == 0);
  REQUIRE(harmonic_basis(cx.hodge_laplacian_matrix(1)).cols() == 0);  // every cycle filled
  REQUIRE(harmonic_basis(cx.hodge_laplacian_matrix(0)).cols() == 1);
}

TEST_CASE("Delaunay complexes: a disc in 2-D, a ball in 3-D, empty circumcircles", "[geometry][lifting]") {
  std::mt19937 rng(2);
  std::uniform_real_distribution<double> u(0, 1);
  Eigen::MatrixXd p2(60, 2);
  for (Eigen::Index i = 0; i < p2.rows(); ++i) p2.row(i) << u(rng), u(rng);
  const SimplicialComplex d2 = delaunay_complex(p2);
  REQUIRE(d2.num_nodes() == 60);
  REQUIRE(d2.euler_characteristic() == 1);
  for (const auto& t : d2.skeleton(2)) {
    // Circumcircle of t contains no other point.
    const Eigen::Vector2d a = p2.row(t[0]), b = p2.row(t[1]), c = p2.row(t[2]);
    const double d = 2 * (a.x() * (b.y() - c.y()) + b.x() * (c.y() - a.y()) + c.x() * (a.y() - b.y()));
    const Eigen::Vector2d o((a.squaredNorm() * (b.y() - c.y()) + b.squaredNorm() * (c.y() - a.y()) + c.squaredNorm() * (a.y() - b.y())) / d,
                            (a.squaredNorm() * (c.x() - b.x()) + b.squaredNorm() * (a.x() - c.x()) + c.squaredNorm() * (b.x() - a.x())) / d);
    const double r2 = (a - o).squaredNorm();
    for (Eigen::Index i = 0; i < p2.rows(); ++i)
      if (i != t[0] && i != t[1] && i != t[2]) REQUIRE((Eigen::Vector2d(p2.row(i)) - o).squaredNorm() >= r2 * (1 - 1e-9));
  }
  Eigen::MatrixXd p3(40, 3);
  for (Eigen::Index i = 0; i < p3.rows(); ++i) p3.row(i) << u(rng), u(rng), u(rng);
  const SimplicialComplex d3 = delaunay_complex(p3);
  REQUIRE(d3.dim() == 3);
  REQUIRE(d3.euler_characteristic() == 1);
  REQUIRE_THROWS_WITH(delaunay_complex(Eigen::MatrixXd::Zero(3, 4)), Catch::Contains("n x 2 or n x 3"));
}

TEST_CASE("alpha complexes grow from the points to the Delaunay complex", "[geometry][lifting]") {
  std::mt19937 rng(6);
  std::uniform_real_distribution<double> u(0, 1);
  Eigen::MatrixXd p(40, 3);
  for (Eigen::Index i = 0; i < p.rows(); ++i) p.row(i) << u(rng), u(rng), u(rng);
  const SimplicialComplex none = alpha_complex(p, 0.0), all = alpha_complex(p, 1e300), full = delaunay_complex(p);
  REQUIRE(none.shape() == std::vector<std::int64_t>{40});
  REQUIRE(all.shape() == full.shape());
  const SimplicialComplex mid = alpha_complex(p, 0.02);
  REQUIRE(mid.num_cells(1) > 0);
  REQUIRE(mid.num_cells(1) < full.num_cells(1));
  for (int k = 1; k <= mid.dim(); ++k)
    for (const auto& s : mid.skeleton(k)) REQUIRE(full.contains(s));
  REQUIRE(sparse::multiply(mid.incidence_matrix(1), mid.incidence_matrix(2)).nonZeros() == 0);
}
