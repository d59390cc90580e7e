// Tests of topos/geometry/graph_and_point_cloud_lifting.hpp: clique complex of a Boost graph (= the
// edge-list one), cell complex from a cycle basis (b1 of the graph cycles filled: b1 = 0, one
// 2-cell per independent cycle), Delaunay triangulations (Euler characteristic of a disc, the empty
// circumcircle property of every triangle), alpha complexes in 2-D and 3-D against a brute-force
// alpha filtration of the Delaunay complex (every simplex's value from its smallest circumsphere
// and the points inside it), at alphas between every two consecutive filtration values.
#include <catch2/catch.hpp>

#include "topos/core/spectral.hpp"
#include "topos/geometry/graph_and_point_cloud_lifting.hpp"

#include <boost/graph/adjacency_list.hpp>

#include <algorithm>
#include <limits>
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

TEST_CASE("Delaunay complexes: a disc in 2-D, a ball in 3-D, empty circumcircles",
          "[geometry][lifting]") {
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
    const double d =
        2 * (a.x() * (b.y() - c.y()) + b.x() * (c.y() - a.y()) + c.x() * (a.y() - b.y()));
    const Eigen::Vector2d o((a.squaredNorm() * (b.y() - c.y()) + b.squaredNorm() * (c.y() - a.y()) +
                             c.squaredNorm() * (a.y() - b.y())) /
                                d,
                            (a.squaredNorm() * (c.x() - b.x()) + b.squaredNorm() * (a.x() - c.x()) +
                             c.squaredNorm() * (b.x() - a.x())) /
                                d);
    const double r2 = (a - o).squaredNorm();
    for (Eigen::Index i = 0; i < p2.rows(); ++i)
      if (i != t[0] && i != t[1] && i != t[2])
        REQUIRE((Eigen::Vector2d(p2.row(i)) - o).squaredNorm() >= r2 * (1 - 1e-9));
  }
  Eigen::MatrixXd p3(40, 3);
  for (Eigen::Index i = 0; i < p3.rows(); ++i) p3.row(i) << u(rng), u(rng), u(rng);
  const SimplicialComplex d3 = delaunay_complex(p3);
  REQUIRE(d3.dim() == 3);
  REQUIRE(d3.euler_characteristic() == 1);
  REQUIRE_THROWS_WITH(delaunay_complex(Eigen::MatrixXd::Zero(3, 4)),
                      Catch::Contains("n x 2 or n x 3"));
}

namespace {

// Centre and squared radius of the smallest sphere (circle in 2-D) through the points of s.
std::pair<Eigen::VectorXd, double> smallest_circumsphere(const Eigen::MatrixXd& p,
                                                         const std::vector<std::int64_t>& s) {
  const Eigen::VectorXd a = p.row(s[0]).transpose();
  if (s.size() == 1) return {a, 0.0};
  // The centre a + U^T y lies in the affine hull (U: the rows p_i - a) and is equidistant from
  // all points: (U U^T) y = |u_i|^2 / 2.
  const Eigen::Index m = static_cast<Eigen::Index>(s.size()) - 1;
  Eigen::MatrixXd u(m, p.cols());
  for (Eigen::Index i = 0; i < m; ++i)
    u.row(i) = p.row(s[static_cast<std::size_t>(i) + 1]) - a.transpose();
  const Eigen::VectorXd rhs = 0.5 * u.rowwise().squaredNorm();
  const Eigen::VectorXd y = (u * u.transpose()).fullPivLu().solve(rhs);
  const Eigen::VectorXd c = a + u.transpose() * y;
  return {c, (c - a).squaredNorm()};
}

// The alpha filtration value of every simplex of a Delaunay complex, by brute force: a top
// simplex gets its squared circumradius; a lower one its smallest circumsphere's squared radius
// when no other point lies strictly inside that sphere, else the least value of its cofaces
// (the Voronoi face dual to it then reaches the balls first on its boundary).
std::vector<std::vector<double>> alpha_filtration(const Eigen::MatrixXd& p,
                                                  const SimplicialComplex& del) {
  std::vector<std::vector<double>> f(static_cast<std::size_t>(del.dim()) + 1);
  for (int k = del.dim(); k >= 0; --k) {
    auto& fk = f[static_cast<std::size_t>(k)];
    fk.assign(static_cast<std::size_t>(del.num_cells(k)), std::numeric_limits<double>::infinity());
    for (std::int64_t id = 0; id < del.num_cells(k); ++id) {
      const auto s = del.simplex(k, id);
      const auto [c, r2] = smallest_circumsphere(p, s);
      bool attached = false;
      for (Eigen::Index i = 0; i < p.rows() && !attached; ++i)
        if (std::find(s.begin(), s.end(), i) == s.end())
          attached = (p.row(i).transpose() - c).squaredNorm() < r2 * (1 - 1e-12);
      if (k == del.dim() || !attached) {
        fk[static_cast<std::size_t>(id)] = r2;
      } else {
        for (std::int64_t t : del.cofaces(k, id, k + 1))
          fk[static_cast<std::size_t>(id)] =
              std::min(fk[static_cast<std::size_t>(id)],
                       f[static_cast<std::size_t>(k) + 1][static_cast<std::size_t>(t)]);
      }
    }
  }
  return f;
}

// alpha_complex(p, alpha) for alpha below, between and above all filtration values equals the
// Delaunay simplices whose brute-force value is <= alpha.
void check_alpha_complexes(const Eigen::MatrixXd& p) {
  const SimplicialComplex del = delaunay_complex(p);
  const auto f = alpha_filtration(p, del);
  std::vector<double> values;
  for (const auto& fk : f) values.insert(values.end(), fk.begin(), fk.end());
  std::sort(values.begin(), values.end());
  values.erase(std::unique(values.begin(), values.end()), values.end());
  std::vector<double> alphas{0.0, 100.0, 1e300};
  for (std::size_t i = 0; i + 1 < values.size(); ++i)
    alphas.push_back(0.5 * (values[i] + values[i + 1]));
  for (double alpha : alphas) {
    CAPTURE(alpha);
    const SimplicialComplex a = alpha_complex(p, alpha);
    std::vector<std::int64_t> shape;
    for (int k = 0; k <= del.dim(); ++k) {
      std::vector<std::vector<std::int64_t>> expected;
      for (std::int64_t id = 0; id < del.num_cells(k); ++id)
        if (f[static_cast<std::size_t>(k)][static_cast<std::size_t>(id)] <= alpha)
          expected.push_back(del.simplex(k, id));
      if (expected.empty()) break;
      shape.push_back(static_cast<std::int64_t>(expected.size()));
      CAPTURE(k);
      REQUIRE(a.skeleton(k) == expected);  // both lexicographic
    }
    REQUIRE(a.shape() == shape);
  }
  // Just above the largest value (rounding: the brute force's radii are computed in doubles).
  REQUIRE(alpha_complex(p, values.back() * (1 + 1e-9)).shape() == del.shape());
  REQUIRE(alpha_complex(p, 0.0).shape() == std::vector<std::int64_t>{p.rows()});
}

}  // namespace

TEST_CASE("alpha complexes equal a brute-force alpha filtration of the Delaunay complex",
          "[geometry][lifting]") {
  std::mt19937 rng(6);
  std::uniform_real_distribution<double> u(0, 1);
  Eigen::MatrixXd p3(40, 3);
  for (Eigen::Index i = 0; i < p3.rows(); ++i) p3.row(i) << u(rng), u(rng), u(rng);
  check_alpha_complexes(p3);
  // The 40 points' hull carries slivers: a Delaunay tetrahedron with circumradius above 10 is
  // in no alpha complex below alpha = 100 (so alpha = 100 is not yet the Delaunay complex).
  const SimplicialComplex del = delaunay_complex(p3);
  const auto f = alpha_filtration(p3, del);
  const double largest = *std::max_element(f[3].begin(), f[3].end());
  CAPTURE(largest);
  REQUIRE(largest > 100.0);
  REQUIRE(alpha_complex(p3, 100.0).num_cells(3) < del.num_cells(3));
  Eigen::MatrixXd p2(50, 2);
  for (Eigen::Index i = 0; i < p2.rows(); ++i) p2.row(i) << u(rng), u(rng);
  check_alpha_complexes(p2);
  const SimplicialComplex mid = alpha_complex(p3, 0.02);
  REQUIRE(sparse::multiply(mid.incidence_matrix(1), mid.incidence_matrix(2)).nonZeros() == 0);
  REQUIRE_THROWS_WITH(alpha_complex(Eigen::MatrixXd::Zero(3, 4), 1.0),
                      Catch::Contains("n x 2 or n x 3"));
  REQUIRE_THROWS_WITH(alpha_complex(p3, -1.0), Catch::Contains(">= 0"));
}
