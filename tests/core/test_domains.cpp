// Tests of the topological domains (simplicial_complex.hpp, cell_complex.hpp, hypergraph.hpp,
// domain.hpp) and their operators (operators.hpp, normalization.hpp): boundary of boundary for
// every rank of every domain, Hodge Laplacian = B^T B + B B^T against dense products, Euler
// characteristic of sphere triangulations, Betti numbers from Laplacian kernels (sphere, torus,
// cell-complex torus, annulus), TopoNetX's cell orders, normalisations on small analytic cases,
// Hodge decomposition, pseudo-inverse, Lanczos against the grid's analytic spectrum, bad input.
#include <catch2/catch.hpp>

#include "topos/core/domain.hpp"
#include "topos/core/normalization.hpp"
#include "topos/core/operators.hpp"
#include "topos/core/spectral.hpp"
#include "topos/mesh/primitives.hpp"

#include <cmath>
#include <numeric>
#include <random>
#include <set>
#include <type_traits>

using namespace topos;
using Dense = Eigen::MatrixXd;

namespace {

// Does `incidence_matrix(1, x)` (or an adjacency) with an argument of type A give an operator? A
// call that must not compile resolves to a template whose static_assert says what to write.
template <class D, class A, class = void>
struct incidence_takes : std::false_type {};
template <class D, class A>
struct incidence_takes<
    D, A, std::void_t<decltype(std::declval<const D&>().incidence_matrix(1, std::declval<A>()))>>
    : std::is_same<decltype(std::declval<const D&>().incidence_matrix(1, std::declval<A>())),
                   SparseMatrix> {};
template <class D, class A, class = void>
struct adjacency_takes : std::false_type {};
template <class D, class A>
struct adjacency_takes<
    D, A, std::void_t<decltype(std::declval<const D&>().adjacency_matrix(1, std::declval<A>()))>>
    : std::is_same<decltype(std::declval<const D&>().adjacency_matrix(1, std::declval<A>())),
                   SparseMatrix> {};
template <class D, class A, class = void>
struct coadjacency_takes : std::false_type {};
template <class D, class A>
struct coadjacency_takes<
    D, A, std::void_t<decltype(std::declval<const D&>().coadjacency_matrix(2, std::declval<A>()))>>
    : std::is_same<decltype(std::declval<const D&>().coadjacency_matrix(2, std::declval<A>())),
                   SparseMatrix> {};

// Triangulated n x m torus: vertex (i, j) = i*m + j, two triangles per square, wrapping around.
std::vector<std::vector<std::int64_t>> torus_triangles(int n, int m) {
  std::vector<std::vector<std::int64_t>> t;
  const auto v = [&](int i, int j) {
    return static_cast<std::int64_t>(((i + n) % n) * m + (j + m) % m);
  };
  for (int i = 0; i < n; ++i)
    for (int j = 0; j < m; ++j) {
      t.push_back({v(i, j), v(i + 1, j), v(i + 1, j + 1)});
      t.push_back({v(i, j), v(i, j + 1), v(i + 1, j + 1)});
    }
  return t;
}

SimplicialComplex sphere_sc(int rings = 6, int segments = 7) {
  const TriangleMesh m = uv_sphere(rings, segments);
  return SimplicialComplex::from_flat(m.faces.data(), static_cast<std::size_t>(m.num_faces()), 3,
                                      m.num_vertices());
}

// Quadrangulated n x m torus as a cell complex (square 2-cells).
CellComplex torus_cells(int n, int m) {
  CellComplex cx(n * m);
  const auto v = [&](int i, int j) {
    return static_cast<std::int64_t>(((i + n) % n) * m + (j + m) % m);
  };
  for (int i = 0; i < n; ++i)
    for (int j = 0; j < m; ++j) cx.add_cell({v(i, j), v(i, j + 1), v(i + 1, j + 1), v(i + 1, j)});
  return cx;
}

std::vector<std::int64_t> betti(const SparseMatrix& l0, const SparseMatrix& l1,
                                const SparseMatrix& l2) {
  return {harmonic_basis(l0).cols(), harmonic_basis(l1).cols(), harmonic_basis(l2).cols()};
}

SimplicialComplex random_sc(std::mt19937& rng, int n, int count, int max_size) {
  std::uniform_int_distribution<int> size(1, max_size), node(0, n - 1);
  std::vector<std::vector<std::int64_t>> s;
  for (int c = 0; c < count; ++c) {
    std::set<std::int64_t> set;
    const int k = size(rng);
    while (static_cast<int>(set.size()) < k) set.insert(node(rng));
    std::vector<std::int64_t> v(set.begin(), set.end());
    std::shuffle(v.begin(), v.end(), rng);
    s.push_back(v);
  }
  return SimplicialComplex::from_simplices(s, n);
}

}  // namespace

TEST_CASE("every domain models the concept", "[core][domains]") {
  STATIC_REQUIRE(is_domain_v<SimplicialComplex>);
  STATIC_REQUIRE(is_domain_v<CellComplex>);
  STATIC_REQUIRE(is_domain_v<CombinatorialComplex<>>);
  STATIC_REQUIRE(is_domain_v<Hypergraph>);
  STATIC_REQUIRE(!is_domain_v<int>);
}

TEST_CASE("simplicial complex: faces implied, lexicographic order, TopoNetX signs",
          "[core][domains]") {
  const auto sc = SimplicialComplex::from_simplices({{3, 1, 2}, {0, 1}});
  REQUIRE(sc.shape() == std::vector<std::int64_t>{4, 4, 1});
  REQUIRE(sc.dim() == 2);
  REQUIRE(sc.skeleton(1) == std::vector<std::vector<std::int64_t>>{{0, 1}, {1, 2}, {1, 3}, {2, 3}});
  REQUIRE(sc.find({3, 2}) == std::optional<std::int64_t>(3));
  REQUIRE_FALSE(sc.find({0, 2}).has_value());
  // B2 of [1,2,3]: faces [2,3] (+1), [1,3] (-1), [1,2] (+1).
  const Dense b2(sc.incidence_matrix(2));
  REQUIRE(b2(1, 0) == 1.0);
  REQUIRE(b2(2, 0) == -1.0);
  REQUIRE(b2(3, 0) == 1.0);
  REQUIRE(b2(0, 0) == 0.0);
  // B1 of [0,1]: -1 at 0, +1 at 1.
  const Dense b1(sc.incidence_matrix(1));
  REQUIRE(b1(0, 0) == -1.0);
  REQUIRE(b1(1, 0) == 1.0);
  REQUIRE(Dense(sc.incidence_matrix(2, Signed::no)).cwiseAbs() == b2.cwiseAbs());
  REQUIRE(Dense(sc.incidence_matrix(0)) == Dense::Ones(1, 4));
  // A sign is Signed, never an int or a bool: TopoNetX's incidence_matrix(1, 0) is |B_1| (n_0 ×
  // n_1), while the inclusion of rank 1 in rank 0 is n_1 × n_0, the same size on a complex with as
  // many edges as nodes (this one). So the int and bool forms do not compile, and the inclusion
  // and the adjacencies through a rank have names of their own.
  REQUIRE(Dense(sc.incidence_matrix(1, Signed::no)) == b1.cwiseAbs());
  REQUIRE(Dense(sc.inclusion_matrix(1, 0)) == b1.cwiseAbs().transpose());
  REQUIRE(sc.num_cells(0) == sc.num_cells(1));
  REQUIRE(Dense(sc.inclusion_matrix(1, 0)) != Dense(sc.incidence_matrix(1, Signed::no)));
  STATIC_REQUIRE_FALSE(incidence_takes<SimplicialComplex, bool>::value);
  STATIC_REQUIRE_FALSE(adjacency_takes<SimplicialComplex, bool>::value);
  STATIC_REQUIRE_FALSE(incidence_takes<CellComplex, bool>::value);
  STATIC_REQUIRE_FALSE(adjacency_takes<CellComplex, bool>::value);
  STATIC_REQUIRE(incidence_takes<SimplicialComplex, Signed>::value);
  STATIC_REQUIRE(incidence_takes<CellComplex, Signed>::value);
  STATIC_REQUIRE_FALSE(incidence_takes<SimplicialComplex, int>::value);
  STATIC_REQUIRE_FALSE(incidence_takes<CellComplex, int>::value);
  STATIC_REQUIRE_FALSE(adjacency_takes<SimplicialComplex, int>::value);
  STATIC_REQUIRE_FALSE(adjacency_takes<CellComplex, int>::value);
  STATIC_REQUIRE_FALSE(coadjacency_takes<SimplicialComplex, int>::value);
  STATIC_REQUIRE_FALSE(coadjacency_takes<CellComplex, int>::value);
  STATIC_REQUIRE(coadjacency_takes<SimplicialComplex, Signed>::value);
  // Where no sign form exists, two ints are two ranks, TopoNetX's meaning there.
  STATIC_REQUIRE(incidence_takes<CombinatorialComplex<>, int>::value);
  STATIC_REQUIRE(incidence_takes<Hypergraph, int>::value);
  REQUIRE(sc.faces(2, 0, 0) == std::vector<std::int64_t>{1, 2, 3});
  REQUIRE(sc.cofaces(0, 1, 1) == std::vector<std::int64_t>{0, 1, 2});
  REQUIRE(sc.star(0, 3).size() == 4);  // node 3, edges 13 and 23, triangle 123
  const auto link = sc.link(0, 3);     // nodes 1, 2 and the edge 12
  REQUIRE(link == std::vector<std::pair<int, std::int64_t>>{{0, 1}, {0, 2}, {1, 1}});
}

TEST_CASE("simplicial complex in an explicit order gives permuted operators", "[core][domains]") {
  std::mt19937 rng(3);
  const SimplicialComplex sc = random_sc(rng, 9, 12, 4);
  std::vector<std::vector<std::vector<std::int64_t>>> cells(static_cast<std::size_t>(sc.dim()) + 1);
  std::vector<std::vector<std::int64_t>> perm(cells.size());
  for (int k = 0; k <= sc.dim(); ++k) {
    perm[static_cast<std::size_t>(k)].resize(static_cast<std::size_t>(sc.num_cells(k)));
    std::iota(perm[static_cast<std::size_t>(k)].begin(), perm[static_cast<std::size_t>(k)].end(),
              0);
    if (k > 0)
      std::shuffle(perm[static_cast<std::size_t>(k)].begin(),
                   perm[static_cast<std::size_t>(k)].end(), rng);
    for (auto id : perm[static_cast<std::size_t>(k)]) {
      auto s = sc.simplex(k, id);
      std::reverse(s.begin(), s.end());  // any node order: orientation is the sorted order
      cells[static_cast<std::size_t>(k)].push_back(s);
    }
  }
  const auto ordered = SimplicialComplex::from_ordered(cells);
  REQUIRE(ordered.explicit_order());
  for (int k = 1; k <= sc.dim(); ++k) {
    const Dense a(sc.incidence_matrix(k)), b(ordered.incidence_matrix(k));
    for (std::size_t i = 0; i < perm[static_cast<std::size_t>(k - 1)].size(); ++i)
      for (std::size_t j = 0; j < perm[static_cast<std::size_t>(k)].size(); ++j)
        REQUIRE(b(static_cast<Eigen::Index>(i), static_cast<Eigen::Index>(j)) ==
                a(perm[static_cast<std::size_t>(k - 1)][i], perm[static_cast<std::size_t>(k)][j]));
  }
}

TEST_CASE("boundary of boundary is zero for every rank of every domain", "[core][domains]") {
  std::mt19937 rng(11);
  for (int trial = 0; trial < 10; ++trial) {
    const SimplicialComplex sc = random_sc(rng, 10, 8, 5);
    for (int k = 1; k < sc.dim(); ++k)
      REQUIRE(sparse::multiply(sc.incidence_matrix(k), sc.incidence_matrix(k + 1)).nonZeros() == 0);
  }
  const CellComplex cx = torus_cells(4, 5);
  REQUIRE(sparse::multiply(cx.incidence_matrix(1), cx.incidence_matrix(2)).nonZeros() == 0);
  REQUIRE(sparse::multiply(cx.incidence_matrix(0), cx.incidence_matrix(1)).nonZeros() == 0);
  // A cell complex in an explicit order with edges oriented against the node order.
  const auto cx2 = CellComplex::from_ordered(4, {{1, 0}, {2, 1}, {2, 3}, {3, 0}, {0, 2}},
                                             {{0, 1, 2, 3}, {2, 0, 3}, {0, 1, 2}});
  REQUIRE(sparse::multiply(cx2.incidence_matrix(1), cx2.incidence_matrix(2)).nonZeros() == 0);
  // The combinatorial complex of a torus triangulation, with its simplicial orientation.
  const SimplicialComplex torus = SimplicialComplex::from_simplices(torus_triangles(3, 4));
  CombinatorialComplex<> cc(torus.num_nodes());
  for (int k = 1; k <= 2; ++k)
    for (const auto& s : torus.skeleton(k)) cc.add_cell(s, k);
  REQUIRE(sparse::multiply(cc.signed_incidence_matrix(0, 1), cc.signed_incidence_matrix(1, 2))
              .nonZeros() == 0);
  // A hypergraph has one incidence (nodes x hyperedges): nothing to compose; its adjacency is
  // the Gram matrix of that incidence off the diagonal.
  Hypergraph h(5);
  h.add_hyperedge({0, 1, 2});
  h.add_hyperedge({2, 3});
  h.add_hyperedge({0, 2, 4});
  const Dense b(h.incidence_matrix(0, 1));
  Dense a = b * b.transpose();
  a.diagonal().setZero();
  REQUIRE(Dense(h.adjacency_matrix(0, 1)) == a);
  Dense co = b.transpose() * b;
  co.diagonal().setZero();
  REQUIRE(Dense(h.coadjacency_matrix(1, 0)) == co);
}

TEST_CASE("Hodge Laplacians equal B^T B + B B^T, unsigned ones |.|, adjacency their off-diagonal",
          "[core][domains]") {
  std::mt19937 rng(5);
  const SimplicialComplex sc = random_sc(rng, 12, 14, 4);
  REQUIRE(sc.dim() == 3);
  for (int k = 0; k <= sc.dim(); ++k) {
    Dense l = Dense::Zero(sc.num_cells(k), sc.num_cells(k));
    if (k > 0) l += Dense(sc.incidence_matrix(k)).transpose() * Dense(sc.incidence_matrix(k));
    if (k < sc.dim())
      l += Dense(sc.incidence_matrix(k + 1)) * Dense(sc.incidence_matrix(k + 1)).transpose();
    REQUIRE(Dense(sc.hodge_laplacian_matrix(k)) == l);
    REQUIRE(Dense(sc.hodge_laplacian_matrix(k, false)) == l.cwiseAbs());
    if (k < sc.dim()) {
      Dense up = Dense(sc.incidence_matrix(k + 1)) * Dense(sc.incidence_matrix(k + 1)).transpose();
      REQUIRE(Dense(sc.up_laplacian_matrix(k)) == up);
      up.diagonal().setZero();
      REQUIRE(Dense(sc.adjacency_matrix(k, Signed::yes)) == up);
      REQUIRE(Dense(sc.adjacency_matrix(k)) == up.cwiseAbs());
    }
    if (k > 0) {
      Dense down = Dense(sc.incidence_matrix(k)).transpose() * Dense(sc.incidence_matrix(k));
      down.diagonal().setZero();
      REQUIRE(Dense(sc.coadjacency_matrix(k, Signed::yes)) == down);
    }
    REQUIRE(sc.hodge_laplacian_matrix(k).isApprox(
        SparseMatrix(sc.hodge_laplacian_matrix(k).transpose())));
    // Row sums of |L| from the factors, without forming L (cancellations included).
    if (k > 0 && k < sc.dim()) {
      const SparseMatrix b = sc.incidence_matrix(k), c = sc.incidence_matrix(k + 1);
      const SparseMatrix bt = b.transpose(), ct = c.transpose();
      REQUIRE(sparse::abs_row_sums_of_products({{&bt, &b}, {&c, &ct}}) ==
              l.cwiseAbs().rowwise().sum());
    }
  }
  const CellComplex cx = torus_cells(3, 4);
  const Dense b1(cx.incidence_matrix(1)), b2(cx.incidence_matrix(2));
  REQUIRE(Dense(cx.hodge_laplacian_matrix(0)) == b1 * b1.transpose());
  REQUIRE(Dense(cx.hodge_laplacian_matrix(1)) == b1.transpose() * b1 + b2 * b2.transpose());
  REQUIRE(Dense(cx.hodge_laplacian_matrix(2)) == b2.transpose() * b2);
  Dense a1 = b2.cwiseAbs() * b2.cwiseAbs().transpose();
  a1.diagonal().setZero();
  REQUIRE(Dense(cx.adjacency_matrix(1, Signed::yes)) == a1);  // TopoNetX: counts whatever `signed`
  REQUIRE(Dense(cx.adjacency_matrix_via(1, 2)) == a1);
}

TEST_CASE("weighted Hodge Laplacian with unit weights is the Hodge Laplacian", "[core][domains]") {
  const SimplicialComplex sc = sphere_sc(4, 5);
  REQUIRE(Dense(sc.weighted_hodge_laplacian_matrix(1, {}, {})) ==
          Dense(sc.hodge_laplacian_matrix(1)));
  const Eigen::VectorXd w = Eigen::VectorXd::LinSpaced(sc.num_cells(2), 1.0, 2.0);
  const Dense b2(sc.incidence_matrix(2)), b1(sc.incidence_matrix(1));
  const Dense expect = b1.transpose() * b1 + b2 * w.asDiagonal() * b2.transpose();
  REQUIRE(Dense(sc.weighted_hodge_laplacian_matrix(1, {}, w)).isApprox(expect, 1e-14));
  REQUIRE_THROWS_WITH(sc.weighted_hodge_laplacian_matrix(1, Eigen::VectorXd::Ones(3), {}),
                      Catch::Contains("3 entries"));
}

TEST_CASE("Euler characteristic of sphere triangulations is 2, of tori 0", "[core][domains]") {
  for (auto [r, s] : {std::pair{3, 4}, std::pair{6, 7}, std::pair{12, 9}}) {
    const SimplicialComplex sc = sphere_sc(r, s);
    REQUIRE(sc.euler_characteristic() == 2);
    REQUIRE(euler_characteristic(sc) == 2);
  }
  REQUIRE(SimplicialComplex::from_simplices(torus_triangles(3, 3)).euler_characteristic() == 0);
  REQUIRE(torus_cells(3, 5).euler_characteristic() == 0);
  // The boundary of a 4-simplex: a 3-sphere, chi = 0; its 2-skeleton's chi = 5 - 10 + 10 = 5.
  auto s4 = SimplicialComplex::from_simplices({{0, 1, 2, 3, 4}});
  REQUIRE(s4.skeleton_complex(3).euler_characteristic() == 0);
  REQUIRE(s4.skeleton_complex(2).euler_characteristic() == 5);
}

TEST_CASE("Betti numbers from the kernels of the Hodge Laplacians", "[core][domains]") {
  const SimplicialComplex sphere = sphere_sc(5, 6);
  REQUIRE(betti(sphere.hodge_laplacian_matrix(0), sphere.hodge_laplacian_matrix(1),
                sphere.hodge_laplacian_matrix(2)) == std::vector<std::int64_t>{1, 0, 1});
  const SimplicialComplex torus = SimplicialComplex::from_simplices(torus_triangles(3, 4));
  REQUIRE(torus.shape() == std::vector<std::int64_t>{12, 36, 24});
  REQUIRE(betti(torus.hodge_laplacian_matrix(0), torus.hodge_laplacian_matrix(1),
                torus.hodge_laplacian_matrix(2)) == std::vector<std::int64_t>{1, 2, 1});
  const CellComplex ct = torus_cells(3, 4);
  REQUIRE(betti(ct.hodge_laplacian_matrix(0), ct.hodge_laplacian_matrix(1),
                ct.hodge_laplacian_matrix(2)) == std::vector<std::int64_t>{1, 2, 1});
  // An annulus (orientable, one hole): the torus with one row of squares removed.
  CellComplex annulus(12);
  for (int i = 0; i < 2; ++i)
    for (int j = 0; j < 4; ++j)
      annulus.add_cell(
          {i * 4 + j, i * 4 + (j + 1) % 4, (i + 1) * 4 + (j + 1) % 4, (i + 1) * 4 + j});
  REQUIRE(betti(annulus.hodge_laplacian_matrix(0), annulus.hodge_laplacian_matrix(1),
                annulus.hodge_laplacian_matrix(2)) == std::vector<std::int64_t>{1, 1, 0});
  // Two disjoint triangles' boundaries: b0 = 2, b1 = 2.
  const auto two =
      SimplicialComplex::from_simplices({{0, 1}, {1, 2}, {0, 2}, {3, 4}, {4, 5}, {3, 5}});
  REQUIRE(harmonic_basis(two.hodge_laplacian_matrix(0)).cols() == 2);
  REQUIRE(harmonic_basis(two.hodge_laplacian_matrix(1)).cols() == 2);
}

TEST_CASE(
    "cell complex: TopoNetX's edge order and orientation, shared boundaries as separate columns",
    "[core][domains]") {
  CellComplex cx(5);
  cx.add_cell({3, 2, 1, 0});
  cx.add_cell({1, 4, 2});
  cx.add_cell({0, 1, 2, 3});
  cx.add_cell({3, 2, 1, 0});  // the same cycle again: grouped right after the first
  REQUIRE(cx.shape() == std::vector<std::int64_t>{5, 6, 4});
  REQUIRE(cx.edges() ==
          std::vector<CellComplex::Edge>{{0, 1}, {0, 3}, {1, 2}, {1, 4}, {2, 3}, {2, 4}});
  REQUIRE(cx.cell(0) == std::vector<std::int64_t>{3, 2, 1, 0});
  REQUIRE(cx.cell(1) == std::vector<std::int64_t>{3, 2, 1, 0});
  REQUIRE(cx.cell(2) == std::vector<std::int64_t>{1, 4, 2});
  const Dense b2(cx.incidence_matrix(2));
  // Cycle 3->2->1->0->3 runs against [2,3], [1,2], [0,1] and along [0,3].
  REQUIRE(b2.col(0) == (Eigen::VectorXd(6) << -1, 1, -1, 0, -1, 0).finished());
  REQUIRE(b2.col(1) == b2.col(0));
  REQUIRE(b2.col(3) == -b2.col(0));
  // 1->4->2->1: along [1,4], against [2,4], against [1,2].
  REQUIRE(b2.col(2) == (Eigen::VectorXd(6) << 0, 0, -1, 1, 0, -1).finished());
  REQUIRE(Dense(cx.incidence_matrix(0)).rows() == 0);
  REQUIRE(Dense(cx.coadjacency_matrix(2))(0, 1) == 4.0);  // the two equal cells share 4 edges
  // A closing repeat of the first vertex is accepted.
  CellComplex tri(3);
  tri.add_cell({0, 1, 2, 0});
  REQUIRE(tri.shape() == std::vector<std::int64_t>{3, 3, 1});
}

TEST_CASE("hypergraph <-> incidence matrix views", "[core][domains]") {
  Hypergraph h(6);
  h.add_hyperedge({4, 0, 2}, 2.0);
  h.add_hyperedge({5});
  h.add_hyperedge({0, 2, 4});  // the same node set again: its own column
  const SparseMatrix b = h.incidence_matrix(0, 1);
  REQUIRE(Dense(b) ==
          (Dense(6, 3) << 1, 0, 1, 0, 0, 0, 1, 0, 1, 0, 0, 0, 1, 0, 1, 0, 1, 0).finished());
  REQUIRE(Dense(h.incidence_matrix(0, 1, true)).col(0) == 2.0 * Dense(b).col(0));
  const Hypergraph back = Hypergraph::from_incidence_matrix(b);
  REQUIRE(back.shape() == h.shape());
  for (std::int64_t e = 0; e < 3; ++e) REQUIRE(back.hyperedge(e) == h.hyperedge(e));
  REQUIRE(h.node_degrees() == (Eigen::VectorXd(6) << 2, 0, 2, 0, 2, 1).finished());
  REQUIRE(h.dim() == 1);
}

TEST_CASE("normalisations on small analytic cases", "[core][domains][normalization]") {
  // Path 0-1-2: L0 = [[1,-1,0],[-1,2,-1],[0,-1,1]], eigenvalues 0, 1, 3.
  const auto path = SimplicialComplex::from_simplices({{0, 1}, {1, 2}});
  const SparseMatrix l0 = path.hodge_laplacian_matrix(0);
  REQUIRE(largest_magnitude_eigenvalue(l0) == Approx(3.0).epsilon(1e-14));
  REQUIRE(Dense(compute_laplacian_normalized_matrix(l0)).isApprox(Dense(l0) / 3.0, 1e-14));
  // Kipf with identity: A + I = [[1,1,0],[1,1,1],[0,1,1]], degrees 2, 3, 2.
  const SparseMatrix kipf =
      compute_kipf_adjacency_normalized_matrix(path.adjacency_matrix(0), true);
  REQUIRE(Dense(kipf)(0, 1) == Approx(1.0 / std::sqrt(6.0)));
  REQUIRE(Dense(kipf)(1, 1) == Approx(1.0 / 3.0));
  REQUIRE(Dense(kipf)(0, 2) == 0.0);
  // Xu: rows of B1 divided by their absolute sums; zero rows stay zero.
  const auto iso = SimplicialComplex::from_simplices({{0, 1}, {1, 2}}, 4);
  const Dense xu(compute_xu_asymmetric_normalized_matrix(iso.incidence_matrix(1)));
  REQUIRE(xu.row(1) == (Eigen::RowVector2d() << 0.5, -0.5).finished());
  REQUIRE(xu.row(3).isZero());
  // Normalised Laplacian: D^-1/2 L D^-1/2 with D the absolute row sums (2, 4, 2).
  const Dense nl(path.normalized_laplacian_matrix(0));
  REQUIRE(nl(0, 1) == Approx(-1.0 / std::sqrt(8.0)));
  REQUIRE(nl(1, 1) == Approx(0.5));
  // Bunch on a single triangle: D2 = I (every edge in one triangle), D1 = 2 diag(2, 2, 2).
  const auto tri = SimplicialComplex::from_simplices({{0, 1, 2}});
  const auto bunch =
      compute_bunch_normalized_matrices(tri.incidence_matrix(1), tri.incidence_matrix(2));
  REQUIRE(Dense(bunch[0]).isApprox(Dense(tri.incidence_matrix(1)) / 4.0));
  REQUIRE(Dense(bunch[1]).isApprox(Dense(tri.incidence_matrix(1)).transpose() / 4.0));
  REQUIRE(Dense(bunch[2]).isApprox(Dense(tri.incidence_matrix(2)) / 3.0));
  REQUIRE(Dense(bunch[3]).isApprox(Dense(tri.incidence_matrix(2)).transpose()));
}

TEST_CASE("Lanczos finds the largest eigenvalue of a 50x50 grid Laplacian", "[core][domains]") {
  const int n = 50;  // 2500 nodes: above the dense threshold
  CellComplex grid(n * n);
  for (int i = 0; i < n; ++i)
    for (int j = 0; j < n; ++j) {
      if (j + 1 < n) grid.add_edge(i * n + j, i * n + j + 1);
      if (i + 1 < n) grid.add_edge(i * n + j, (i + 1) * n + j);
    }
  // Grid graph = product of two paths: lambda_max = 2 (2 - 2 cos(pi (n-1) / n)).
  const double expect = 2.0 * (2.0 - 2.0 * std::cos(M_PI * (n - 1) / n));
  REQUIRE(largest_magnitude_eigenvalue(grid.hodge_laplacian_matrix(0)) ==
          Approx(expect).epsilon(1e-10));
}

TEST_CASE("Hodge decomposition: orthogonal parts summing to the cochain, harmonic part in ker L",
          "[core][domains]") {
  const SimplicialComplex torus = SimplicialComplex::from_simplices(torus_triangles(3, 4));
  std::mt19937 rng(1);
  std::normal_distribution<double> g;
  Eigen::VectorXd x(torus.num_cells(1));
  for (Eigen::Index i = 0; i < x.size(); ++i) x[i] = g(rng);
  const auto h = hodge_decomposition(torus.incidence_matrix(1), torus.incidence_matrix(2), x);
  REQUIRE((h.gradient + h.curl + h.harmonic - x).norm() < 1e-12);
  REQUIRE(std::abs(h.gradient.dot(h.curl)) < 1e-10);
  REQUIRE(std::abs(h.gradient.dot(h.harmonic)) < 1e-10);
  REQUIRE(std::abs(h.curl.dot(h.harmonic)) < 1e-10);
  REQUIRE((torus.hodge_laplacian_matrix(1) * h.harmonic).norm() < 1e-10);
  REQUIRE(h.harmonic.norm() > 1e-3);  // b1 = 2: a random cochain has a harmonic part
  const Eigen::MatrixXd p = harmonic_projector(torus.hodge_laplacian_matrix(1));
  REQUIRE((p * x - h.harmonic).norm() < 1e-10);
}

TEST_CASE("pseudo-inverse satisfies the Penrose conditions", "[core][domains]") {
  const auto sc = SimplicialComplex::from_simplices(torus_triangles(3, 3));
  const Dense l(sc.hodge_laplacian_matrix(1));  // singular (b1 = 2)
  const Dense p = pinv(l);
  REQUIRE((l * p * l - l).norm() < 1e-10);
  REQUIRE((p * l * p - p).norm() < 1e-10);
  const Dense b(sc.incidence_matrix(2));  // rectangular
  const Dense q = pinv(b);
  REQUIRE((b * q * b - b).norm() < 1e-10);
  REQUIRE((q * b).transpose().isApprox(q * b, 1e-10));
}

TEST_CASE("bad input to the domains is a clear error", "[core][domains][errors]") {
  REQUIRE_THROWS_WITH(SimplicialComplex::from_simplices({{0, 1, 1}}),
                      Catch::Contains("repeats node 1"));
  REQUIRE_THROWS_WITH(SimplicialComplex::from_simplices({{}}), Catch::Contains("empty simplex"));
  REQUIRE_THROWS_WITH(SimplicialComplex::from_simplices({{0, 5}}, 3),
                      Catch::Contains("uses node 5"));
  REQUIRE_THROWS_WITH(
      SimplicialComplex::from_ordered({{{0}, {1}, {2}}, {{0, 1}, {1, 2}}, {{0, 1, 2}}}),
      Catch::Contains("face [0, 2]"));
  REQUIRE_THROWS_WITH(SimplicialComplex::from_ordered({{{0}, {1}}, {{0, 1}, {1, 0}}}),
                      Catch::Contains("listed twice"));
  REQUIRE_THROWS_WITH(SimplicialComplex::from_simplices({{0, 1}}).up_laplacian_matrix(1),
                      Catch::Contains("rank 1"));
  CellComplex cx(4);
  REQUIRE_THROWS_WITH(cx.add_cell_from_edges({{0, 1}, {1, 2}, {3, 0}}),
                      Catch::Contains("not a closed cycle"));
  REQUIRE_THROWS_WITH(cx.add_cell({0, 1, 7}), Catch::Contains("uses node 7"));
  REQUIRE_THROWS_WITH(cx.add_cell({0, 1, 2, 1}), Catch::Contains("repeats node 1"));
  REQUIRE_THROWS_WITH(cx.add_cell({0, 1}), Catch::Contains("at least 3"));
  REQUIRE_THROWS_WITH(CellComplex::from_ordered(4, {{0, 1}, {1, 2}}, {{0, 1, 2}}),
                      Catch::Contains("edge [2, 0] is not in the edge list"));
  REQUIRE_THROWS_WITH(CellComplex::from_ordered(3, {{0, 1}, {1, 0}}, {}),
                      Catch::Contains("listed twice"));
  REQUIRE_THROWS_WITH(cx.add_edge(2, 2), Catch::Contains("self-loop"));
  Hypergraph h(3);
  REQUIRE_THROWS_WITH(h.add_hyperedge({}), Catch::Contains("is empty"));
  REQUIRE_THROWS_WITH(h.add_hyperedge({0, 3}), Catch::Contains("uses node 3"));
  REQUIRE_THROWS_WITH(h.add_hyperedge({1, 1}), Catch::Contains("repeats node 1"));
  REQUIRE_THROWS_WITH(h.adjacency_matrix(1, 0), Catch::Contains("rank 0 via 1"));
}
