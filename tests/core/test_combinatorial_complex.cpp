// Tests of topos/core/combinatorial_complex.hpp and neighborhood.hpp: operators against brute-force
// set inclusion on random complexes, boundary of boundary, adjacency = BBᵀ off the diagonal,
// rollback of per-frame cells, and every error path.
#include <catch2/catch.hpp>

#include "topos/core/combinatorial_complex.hpp"
#include "topos/core/neighborhood.hpp"

#include <algorithm>
#include <random>
#include <set>

using topos::ComplexError;
using CC = topos::CombinatorialComplex<>;

namespace {

// A random complex: random node subsets of size k at rank k-1 (so inclusion never breaks ranks).
CC random_complex(std::mt19937& rng, int n_nodes, int n_cells) {
  CC cc(n_nodes);
  std::uniform_int_distribution<int> size(2, 5), node(0, n_nodes - 1);
  for (int c = 0; c < n_cells; ++c) {
    const int k = size(rng);
    std::set<std::int64_t> s;
    while (static_cast<int>(s.size()) < k) s.insert(node(rng));
    cc.add_cell(std::vector<std::int64_t>(s.begin(), s.end()), k - 1);
  }
  return cc;
}

bool subset(const std::vector<std::int64_t>& a, const std::vector<std::int64_t>& b) {
  return std::includes(b.begin(), b.end(), a.begin(), a.end());
}

}  // namespace

TEST_CASE("incidence matrices equal brute-force set inclusion on random complexes",
          "[core][complex]") {
  std::mt19937 rng(42);
  for (int trial = 0; trial < 20; ++trial) {
    CC cc = random_complex(rng, 12, 60);
    for (int r = 0; r <= cc.max_rank(); ++r) {
      for (int s = 0; s <= cc.max_rank(); ++s) {
        if (r == s) continue;
        const auto B = Eigen::MatrixXd(cc.incidence_matrix(r, s));
        REQUIRE(B.rows() == cc.size(r));
        REQUIRE(B.cols() == cc.size(s));
        for (std::int64_t i = 0; i < cc.size(r); ++i) {
          for (std::int64_t j = 0; j < cc.size(s); ++j) {
            const auto ci = cc.cell_nodes(r, i), cj = cc.cell_nodes(s, j);
            const bool inc = r < s ? subset(ci, cj) : subset(cj, ci);
            REQUIRE(B(i, j) == (inc ? 1.0 : 0.0));
          }
        }
      }
    }
  }
}

TEST_CASE("adjacency and coadjacency equal the Gram matrices off the diagonal", "[core][complex]") {
  std::mt19937 rng(7);
  CC cc = random_complex(rng, 10, 50);
  for (int r = 0; r < cc.max_rank(); ++r) {
    for (int via = r + 1; via <= cc.max_rank(); ++via) {
      Eigen::MatrixXd B = cc.incidence_matrix(r, via);
      Eigen::MatrixXd G = B * B.transpose();
      G.diagonal().setZero();
      REQUIRE(Eigen::MatrixXd(cc.adjacency_matrix(r, via)) == G);
      Eigen::MatrixXd H = B.transpose() * B;
      H.diagonal().setZero();
      REQUIRE(Eigen::MatrixXd(cc.coadjacency_matrix(via, r)) == H);
    }
  }
}

TEST_CASE("signed incidences of an oriented surface satisfy B1 B2 = 0", "[core][complex]") {
  // Octahedron with outward orientation; edges oriented arbitrarily (reversed half of them).
  CC cc(6);
  const std::vector<std::array<std::int64_t, 3>> faces = {
      {0, 2, 4}, {2, 1, 4}, {1, 3, 4}, {3, 0, 4}, {2, 0, 5}, {1, 2, 5}, {3, 1, 5}, {0, 3, 5}};
  int flip = 0;
  for (auto& f : faces)
    for (int k = 0; k < 3; ++k) {
      std::int64_t a = f[k], b = f[(k + 1) % 3];
      if (cc.find({a, b})) continue;
      if (flip++ % 2) std::swap(a, b);
      cc.add_cell({a, b}, 1);
    }
  for (auto& f : faces) cc.add_cell({f[0], f[1], f[2]}, 2);
  const Eigen::MatrixXd B1 = cc.signed_incidence_matrix(0, 1),
                        B2 = cc.signed_incidence_matrix(1, 2);
  REQUIRE(B1.rows() == 6);
  REQUIRE(B2.cols() == 8);
  REQUIRE((B1 * B2).cwiseAbs().maxCoeff() == 0.0);
  // Each edge of a closed consistently oriented surface sees its two faces with opposite signs.
  REQUIRE((B2.rowwise().sum()).cwiseAbs().maxCoeff() == 0.0);
  // Unsigned incidence has the same pattern.
  REQUIRE(Eigen::MatrixXd(cc.incidence_matrix(1, 2)) == B2.cwiseAbs());
}

TEST_CASE("cells get dense ids in insertion order and are found by their nodes",
          "[core][complex]") {
  CC cc(5);
  REQUIRE(cc.add_cell({3, 1}, 1) == std::make_pair<std::int64_t, bool>(0, true));
  REQUIRE(cc.add_cell({0, 4}, 1) == std::make_pair<std::int64_t, bool>(1, true));
  REQUIRE(cc.add_cell({1, 3}, 1) == std::make_pair<std::int64_t, bool>(0, false));
  REQUIRE(cc.add_cell({0, 1, 3, 4}, 3).first == 0);
  REQUIRE(cc.shape() == std::vector<std::int64_t>{5, 2, 0, 1});
  REQUIRE(cc.find({4, 0})->id == 1);
  REQUIRE(cc.find({4, 0})->rank == 1);
  REQUIRE_FALSE(cc.find({2, 4}));
  REQUIRE(cc.oriented_nodes(1, 0) == std::vector<std::int64_t>{3, 1});
  REQUIRE(cc.skeleton(1) == std::vector<std::vector<std::int64_t>>{{1, 3}, {0, 4}});
  // Rank 2 exists (below max rank) with zero cells: operators are empty, not errors.
  REQUIRE(cc.incidence_matrix(2, 3).rows() == 0);
  REQUIRE(cc.incidence_matrix(2, 3).cols() == 1);
}

TEST_CASE("declared values and roles reach the incidence matrix and the neighborhood",
          "[core][complex][neighborhood]") {
  CC cc(6);
  const auto fa = cc.add_cell({0, 1, 2}, 2).first, fb = cc.add_cell({3, 4, 5}, 2).first;
  cc.add_cell({0, 1, 2, 3, 4, 5}, 3, {{2, fa, -1.0, -1}, {2, fb, +1.0, +1}});
  const Eigen::MatrixXd B23 = cc.incidence_matrix(2, 3);
  REQUIRE(B23(0, 0) == -1.0);
  REQUIRE(B23(1, 0) == 1.0);
  const auto n = topos::incidence_neighborhood(cc, 3, 2);
  REQUIRE(n.source_rank == 3);
  REQUIRE(n.target_rank == 2);
  REQUIRE(n.source == std::vector<std::int64_t>{0, 0});
  REQUIRE(n.target == std::vector<std::int64_t>{0, 1});
  REQUIRE(n.roles == std::vector<std::int8_t>{-1, 1});
  const auto r = n.reversed();
  REQUIRE(r.source == n.target);
  REQUIRE(r.source_rank == 2);
  REQUIRE(r.num_target == 1);
  REQUIRE_NOTHROW(r.validate());
  // Plain inclusion neighborhoods carry no values.
  REQUIRE(topos::incidence_neighborhood(cc, 0, 2).values.empty());
  REQUIRE(topos::incidence_neighborhood(cc, 0, 2).nnz() == 6);
}

TEST_CASE("rollback removes per-frame cells and keeps the static part", "[core][complex]") {
  CC cc(6);
  cc.add_cell({0, 1}, 1);
  cc.add_cell({0, 1, 2}, 4);
  const auto m = cc.mark();
  for (int frame = 0; frame < 3; ++frame) {
    cc.add_cell({3, 4, 5}, 2);
    cc.add_cell({2, 3, 4, 5}, 3);
    // A rank-3 cell may not contain the rank-4 object {0, 1, 2}.
    REQUIRE_THROWS_AS(cc.add_cell({0, 1, 2, 3, 4, 5}, 3), ComplexError);
    REQUIRE(cc.shape() == std::vector<std::int64_t>{6, 1, 1, 1, 1});
    cc.rollback(m);
    REQUIRE(cc.shape() == std::vector<std::int64_t>{6, 1, 0, 0, 1});
    REQUIRE_FALSE(cc.find({3, 4, 5}));
    REQUIRE(cc.find({0, 1}));
  }
}

TEST_CASE("bad cells are rejected with a message naming cell and rank", "[core][complex][errors]") {
  CC cc(4);
  cc.add_cell({0, 1, 2}, 2);
  auto throws_with = [](auto&& f, const std::string& what) {
    try {
      f();
    } catch (const ComplexError& e) {
      INFO(e.what());
      CHECK(std::string(e.what()).find(what) != std::string::npos);
      return;
    }
    FAIL("no ComplexError thrown; expected one mentioning " << what);
  };
  throws_with([&] { cc.add_cell({0, 9}, 1); }, "node 9 of cell {0,9} at rank 1 is out of range");
  throws_with([&] { cc.add_cell(std::vector<std::int64_t>{}, 1); }, "empty cell at rank 1");
  throws_with([&] { cc.add_cell({1, 1}, 1); }, "repeats a node");
  throws_with([&] { cc.add_cell({0, 1}, 3); }, "is a subset of cell 0 of lower rank 2");
  throws_with([&] { cc.add_cell({0, 1, 2, 3}, 1); }, "contains cell 0 of higher rank 2");
  throws_with([&] { cc.add_cell({0, 1, 2}, 3); }, "already exists at rank 2");
  throws_with([&] { cc.add_cell({0}, 0); }, "rank 0 is not allowed");
  throws_with([&] { cc.incidence_matrix(1, 7); }, "rank 7 holds no cells");
  throws_with([&] { cc.incidence_matrix(1, 1); }, "ranks must differ");
  throws_with([&] { cc.adjacency_matrix(2, 1); }, "must be above rank 2");
  throws_with([&] { cc.cell_nodes(2, 5); }, "cell 5 of rank 2 does not exist");
  throws_with(
      [&] {
        cc.add_cell({0, 1, 2, 3}, 3, {{2, 4, 1.0, 0}});
      },
      "which does not exist below it");
  CC cc5(5);
  cc5.add_cell({4, 1}, 1);
  throws_with(
      [&] {
        cc5.add_cell({0, 1, 2, 3}, 3, {{1, 0, 1.0, 0}});
      },
      "which is not a subset of it");
  throws_with([&] { cc.rollback(CC::Mark{{2}}); }, "nodes cannot be removed");
}
