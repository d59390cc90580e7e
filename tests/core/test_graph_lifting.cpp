// Tests of TopoBench's graph liftings (topos/core/domain_lifting.hpp): clique_lifting,
// cycle_basis / cycle_lifting and khop_lifting on hand-derived graphs (cells, order, incidence
// signs), against brute force (every pairwise-adjacent node subset; BFS distances) and against an
// independent, literal re-implementation of networkx's cycle_basis loop, with the properties of a
// cycle basis (m - n + c cycles, simple closed cycles of graph edges, independent over GF(2)), on
// random graphs and, with TOPOS_DATASETS_DIR, on MUTAG and PROTEINS graphs read here from the
// raw TU files.
#include <catch2/catch.hpp>

#include "support/reference.hpp"
#include "topos/core/domain_lifting.hpp"

#include <fstream>
#include <functional>
#include <limits>
#include <map>
#include <numeric>
#include <random>
#include <set>
#include <sstream>

using namespace topos;
using Dense = Eigen::MatrixXd;
using Edges = std::vector<std::array<std::int64_t, 2>>;
using Cycles = std::vector<std::vector<std::int64_t>>;

namespace {

struct Graph {
  std::int64_t n = 0;
  Edges edges;  // u < v, unique
};

// Dense adjacency of a graph given with any orientation and repeats.
std::vector<std::vector<bool>> adjacency(std::int64_t n, const Edges& edges) {
  std::vector<std::vector<bool>> a(static_cast<std::size_t>(n),
                                   std::vector<bool>(static_cast<std::size_t>(n), false));
  for (const auto& e : edges)
    a[static_cast<std::size_t>(e[0])][static_cast<std::size_t>(e[1])] =
        a[static_cast<std::size_t>(e[1])][static_cast<std::size_t>(e[0])] = true;
  return a;
}

Graph random_graph(std::mt19937& rng, int n, double p) {
  Graph g;
  g.n = n;
  std::bernoulli_distribution coin(p);
  for (int u = 0; u < n; ++u)
    for (int v = u + 1; v < n; ++v)
      if (coin(rng)) g.edges.push_back({u, v});
  return g;
}

// The same graph as a messy edge list: shuffled, random orientations, some edges repeated.
Edges messy(std::mt19937& rng, const Edges& edges) {
  Edges out;
  std::bernoulli_distribution coin(0.5), repeat(0.2);
  for (const auto& e : edges) {
    out.push_back(coin(rng) ? e : std::array<std::int64_t, 2>{e[1], e[0]});
    if (repeat(rng)) out.push_back({e[1], e[0]});
  }
  std::shuffle(out.begin(), out.end(), rng);
  return out;
}

// Every set of k + 1 pairwise adjacent nodes, sorted, in lexicographic order: all (k+1)-subsets
// by nested index loops, a prefix that is not a clique cut short (its extensions are not either).
std::vector<std::vector<std::int64_t>> brute_force_cliques(
    const std::vector<std::vector<bool>>& adj, int k) {
  const auto n = static_cast<std::int64_t>(adj.size());
  std::vector<std::vector<std::int64_t>> out;
  std::vector<std::int64_t> s;
  std::function<void(std::int64_t)> grow = [&](std::int64_t from) {
    if (static_cast<int>(s.size()) == k + 1) {
      out.push_back(s);
      return;
    }
    for (std::int64_t v = from; v < n; ++v) {
      bool ok = true;
      for (std::int64_t u : s)
        ok = ok && adj[static_cast<std::size_t>(u)][static_cast<std::size_t>(v)];
      if (!ok) continue;
      s.push_back(v);
      grow(v + 1);
      s.pop_back();
    }
  };
  grow(0);
  return out;
}

void check_clique_lifting(const Graph& g, int complex_dim) {
  const SimplicialComplex sc = clique_lifting(g.n, g.edges, complex_dim);
  const auto adj = adjacency(g.n, g.edges);
  REQUIRE(sc.num_nodes() == g.n);
  const int top = std::max(complex_dim, 1);
  for (int k = 1; k <= top + 1; ++k) {
    const auto expect =
        k <= top ? brute_force_cliques(adj, k) : std::vector<std::vector<std::int64_t>>{};
    REQUIRE(sc.num_cells(k) == static_cast<std::int64_t>(expect.size()));
    if (!expect.empty()) REQUIRE(sc.skeleton(k) == expect);
  }
}

// networkx's cycle_basis (networkx/algorithms/cycles.py, 3.2 and later) written out literally
// with ordered containers: gnodes an insertion-ordered node list popped from the back, G[z] the
// adjacency in the order the edges of a coalesced, symmetric edge_index insert them (ascending),
// pred a map, used a map of sets.
Cycles reference_cycle_basis(std::int64_t n, const Edges& edges) {
  std::vector<std::set<std::int64_t>> adj(static_cast<std::size_t>(n));
  for (const auto& e : edges) {
    adj[static_cast<std::size_t>(e[0])].insert(e[1]);
    adj[static_cast<std::size_t>(e[1])].insert(e[0]);
  }
  std::vector<std::int64_t> gnodes(static_cast<std::size_t>(n));
  std::iota(gnodes.begin(), gnodes.end(), 0);
  Cycles cycles;
  while (!gnodes.empty()) {
    const std::int64_t root = gnodes.back();  // gnodes.popitem()[0]
    gnodes.pop_back();
    std::vector<std::int64_t> stack{root};
    std::map<std::int64_t, std::int64_t> pred{{root, root}};
    std::map<std::int64_t, std::set<std::int64_t>> used{{root, {}}};
    while (!stack.empty()) {
      const std::int64_t z = stack.back();
      stack.pop_back();
      const std::set<std::int64_t> zused = used[z];
      for (std::int64_t nbr : adj[static_cast<std::size_t>(z)]) {
        if (!used.count(nbr)) {
          pred[nbr] = z;
          stack.push_back(nbr);
          used[nbr] = {z};
        } else if (!zused.count(nbr)) {
          const std::set<std::int64_t>& pn = used[nbr];
          std::vector<std::int64_t> cycle{nbr, z};
          std::int64_t p = pred[z];
          while (!pn.count(p)) {
            cycle.push_back(p);
            p = pred[p];
          }
          cycle.push_back(p);
          cycles.push_back(cycle);
          used[nbr].insert(z);
        }
      }
    }
    for (const auto& [node, from] : pred) {
      (void)from;
      gnodes.erase(std::remove(gnodes.begin(), gnodes.end(), node), gnodes.end());
    }
  }
  return cycles;
}

std::int64_t num_components(std::int64_t n, const Edges& edges) {
  std::vector<std::int64_t> parent(static_cast<std::size_t>(n));
  std::iota(parent.begin(), parent.end(), 0);
  std::function<std::int64_t(std::int64_t)> find = [&](std::int64_t x) {
    return parent[static_cast<std::size_t>(x)] == x
               ? x
               : parent[static_cast<std::size_t>(x)] = find(parent[static_cast<std::size_t>(x)]);
  };
  std::int64_t c = n;
  for (const auto& e : edges) {
    const auto a = find(e[0]), b = find(e[1]);
    if (a != b) parent[static_cast<std::size_t>(a)] = b, --c;
  }
  return c;
}

// The properties of a cycle basis, and equality with the literal re-implementation.
void check_cycle_basis(const Graph& g, const Cycles& cycles) {
  REQUIRE(cycles == reference_cycle_basis(g.n, g.edges));
  const auto m = static_cast<std::int64_t>(g.edges.size());
  REQUIRE(static_cast<std::int64_t>(cycles.size()) == m - g.n + num_components(g.n, g.edges));
  std::map<std::pair<std::int64_t, std::int64_t>, std::size_t> edge_id;
  for (const auto& e : g.edges) edge_id.emplace(std::make_pair(e[0], e[1]), edge_id.size());
  const auto id = [&](std::int64_t u, std::int64_t v) {
    const auto it = edge_id.find({std::min(u, v), std::max(u, v)});
    REQUIRE(it != edge_id.end());  // every step of a cycle is a graph edge
    return it->second;
  };
  const std::size_t words = (edge_id.size() + 63) / 64;
  std::vector<std::vector<std::uint64_t>> rows;  // each cycle's edges over GF(2)
  std::set<std::size_t> seen_edges;
  for (const auto& c : cycles) {
    REQUIRE(c.size() >= 3);
    REQUIRE(std::set<std::int64_t>(c.begin(), c.end()).size() == c.size());  // simple
    std::vector<std::uint64_t> row(words, 0);
    for (std::size_t i = 0; i < c.size(); ++i) {
      const std::size_t e = id(c[i], c[(i + 1) % c.size()]);
      row[e / 64] |= std::uint64_t{1} << (e % 64);
    }
    // The edge it was found at (nbr, z) is new: no earlier cycle uses it.
    REQUIRE(seen_edges.count(id(c[0], c[1])) == 0);
    for (std::size_t i = 0; i < c.size(); ++i) seen_edges.insert(id(c[i], c[(i + 1) % c.size()]));
    rows.push_back(row);
  }
  // Gaussian elimination over GF(2): full rank, so the cycles are independent.
  std::size_t rank = 0;
  for (std::size_t bit = 0; bit < edge_id.size() && rank < rows.size(); ++bit) {
    const std::size_t w = bit / 64;
    const std::uint64_t mask = std::uint64_t{1} << (bit % 64);
    std::size_t r = rank;
    while (r < rows.size() && !(rows[r][w] & mask)) ++r;
    if (r == rows.size()) continue;
    std::swap(rows[r], rows[rank]);
    for (std::size_t o = 0; o < rows.size(); ++o)
      if (o != rank && (rows[o][w] & mask))
        for (std::size_t x = 0; x < words; ++x) rows[o][x] ^= rows[rank][x];
    ++rank;
  }
  REQUIRE(rank == rows.size());
}

// Hyperedge v = {u : dist(u, v) <= k}, distances by Floyd-Warshall.
std::vector<std::vector<std::int64_t>> brute_force_khop(const Graph& g, int k) {
  const auto n = static_cast<std::size_t>(g.n);
  const std::int64_t inf = std::numeric_limits<std::int64_t>::max() / 4;  // unreachable
  std::vector<std::vector<std::int64_t>> d(n, std::vector<std::int64_t>(n, inf));
  for (std::size_t v = 0; v < n; ++v) d[v][v] = 0;
  for (const auto& e : g.edges)
    d[static_cast<std::size_t>(e[0])][static_cast<std::size_t>(e[1])] =
        d[static_cast<std::size_t>(e[1])][static_cast<std::size_t>(e[0])] = 1;
  for (std::size_t w = 0; w < n; ++w)
    for (std::size_t u = 0; u < n; ++u)
      for (std::size_t v = 0; v < n; ++v) d[u][v] = std::min(d[u][v], d[u][w] + d[w][v]);
  std::vector<std::vector<std::int64_t>> out(n);
  for (std::size_t v = 0; v < n; ++v)
    for (std::size_t u = 0; u < n; ++u)
      if (d[v][u] <= k) out[v].push_back(static_cast<std::int64_t>(u));
  return out;
}

void check_khop(const Graph& g, int k, const Edges& given) {
  const Hypergraph h = khop_lifting(g.n, given, k);
  const auto expect = brute_force_khop(g, k);
  REQUIRE(h.num_nodes() == g.n);
  REQUIRE(h.num_hyperedges() == g.n);
  for (std::int64_t v = 0; v < g.n; ++v) {
    INFO("n " << g.n << " edges " << given.size() << " k " << k << " node " << v);
    REQUIRE(h.hyperedge(v) == expect[static_cast<std::size_t>(v)]);
  }
}

// Graphs of a TU dataset (raw _A and _graph_indicator files), node ids per graph in file order.
std::vector<Graph> read_tu_graphs(const std::filesystem::path& dir, const std::string& name) {
  std::ifstream gi(dir / (name + "_graph_indicator.txt")), a(dir / (name + "_A.txt"));
  REQUIRE(gi);
  REQUIRE(a);
  std::vector<std::int64_t> graph_of;
  for (std::int64_t g; gi >> g;) graph_of.push_back(g - 1);
  REQUIRE(!graph_of.empty());
  std::vector<Graph> graphs(static_cast<std::size_t>(graph_of.back() + 1));
  std::vector<std::int64_t> local(graph_of.size());
  for (std::size_t v = 0; v < graph_of.size(); ++v)
    local[v] = graphs[static_cast<std::size_t>(graph_of[v])].n++;
  std::string line;
  while (std::getline(a, line)) {
    std::int64_t u = 0, v = 0;
    char comma = 0;
    std::istringstream s(line);
    REQUIRE(static_cast<bool>(s >> u >> comma >> v));
    --u, --v;
    Graph& g = graphs[static_cast<std::size_t>(graph_of[static_cast<std::size_t>(u)])];
    REQUIRE(graph_of[static_cast<std::size_t>(u)] == graph_of[static_cast<std::size_t>(v)]);
    if (u < v)
      g.edges.push_back({local[static_cast<std::size_t>(u)], local[static_cast<std::size_t>(v)]});
  }
  for (Graph& g : graphs) {
    std::sort(g.edges.begin(), g.edges.end());
    g.edges.erase(std::unique(g.edges.begin(), g.edges.end()), g.edges.end());
  }
  return graphs;
}

}  // namespace

TEST_CASE("clique lifting: hand-derived complexes and incidence signs",
          "[core][lifting][topobench]") {
  const Edges k4{{0, 1}, {0, 2}, {0, 3}, {1, 2}, {1, 3}, {2, 3}};
  Edges k5;
  for (int u = 0; u < 5; ++u)
    for (int v = u + 1; v < 5; ++v) k5.push_back({u, v});
  // K4 and K5: C(n, k + 1) simplices of rank k, up to complex_dim.
  REQUIRE(clique_lifting(4, k4, 2).shape() == std::vector<std::int64_t>{4, 6, 4});
  REQUIRE(clique_lifting(4, k4, 3).shape() == std::vector<std::int64_t>{4, 6, 4, 1});
  REQUIRE(clique_lifting(4, k4).shape() == std::vector<std::int64_t>{4, 6, 4, 1});  // default 3
  REQUIRE(clique_lifting(5, k5, 2).shape() == std::vector<std::int64_t>{5, 10, 10});
  REQUIRE(clique_lifting(5, k5, 3).shape() == std::vector<std::int64_t>{5, 10, 10, 5});
  REQUIRE(clique_lifting(5, k5, 3).skeleton(3) ==
          std::vector<std::vector<std::int64_t>>{
              {0, 1, 2, 3}, {0, 1, 2, 4}, {0, 1, 3, 4}, {0, 2, 3, 4}, {1, 2, 3, 4}});
  // complex_dim 0 or 1: the graph itself (TopoNetX's SimplicialComplex(graph) has the edges).
  REQUIRE(clique_lifting(4, k4, 1).shape() == std::vector<std::int64_t>{4, 6});
  REQUIRE(clique_lifting(4, k4, 0).shape() == std::vector<std::int64_t>{4, 6});
  REQUIRE_THROWS_WITH(clique_lifting(4, k4, -1), Catch::Contains("complex_dim -1"));

  // K4, complex_dim 3. Edges [01 02 03 12 13 23], triangles [012 013 023 123]; face i (node i
  // dropped) of a sorted simplex has sign (-1)^i.
  const SimplicialComplex sc = clique_lifting(4, k4, 3);
  Dense b2 = Dense::Zero(6, 4);
  b2.col(0) << 1, -1, 0, 1, 0, 0;  // 012: +12 -02 +01
  b2.col(1) << 1, 0, -1, 0, 1, 0;  // 013: +13 -03 +01
  b2.col(2) << 0, 1, -1, 0, 0, 1;  // 023: +23 -03 +02
  b2.col(3) << 0, 0, 0, 1, -1, 1;  // 123: +23 -13 +12
  REQUIRE(Dense(sc.incidence_matrix(2)) == b2);
  Dense b3(4, 1);
  b3 << -1, 1, -1, 1;  // 0123: +123 -023 +013 -012
  REQUIRE(Dense(sc.incidence_matrix(3)) == b3);
  REQUIRE(Dense(sc.incidence_matrix(3, Signed::no)) == b3.cwiseAbs());
  Dense b1 = Dense::Zero(4, 6);
  b1.col(0) << -1, 1, 0, 0;  // 01: -0 +1
  b1.col(5) << 0, 0, -1, 1;  // 23: -2 +3
  REQUIRE(Dense(sc.incidence_matrix(1)).col(0) == b1.col(0));
  REQUIRE(Dense(sc.incidence_matrix(1)).col(5) == b1.col(5));

  // A square 0-1-2-3 with the diagonal 0-2: two triangles, no tetrahedron.
  const SimplicialComplex sq = clique_lifting(4, {{0, 1}, {1, 2}, {2, 3}, {3, 0}, {0, 2}}, 3);
  REQUIRE(sq.shape() == std::vector<std::int64_t>{4, 5, 2});
  REQUIRE(sq.skeleton(2) == std::vector<std::vector<std::int64_t>>{{0, 1, 2}, {0, 2, 3}});
  // Two triangles sharing node 2, an isolated node 5, a separate edge 6-7.
  const SimplicialComplex bow =
      clique_lifting(8, {{0, 1}, {1, 2}, {0, 2}, {2, 3}, {3, 4}, {2, 4}, {6, 7}}, 3);
  REQUIRE(bow.shape() == std::vector<std::int64_t>{8, 7, 2});
  REQUIRE(bow.skeleton(2) == std::vector<std::vector<std::int64_t>>{{0, 1, 2}, {2, 3, 4}});
  REQUIRE(bow.skeleton(1).back() == std::vector<std::int64_t>{6, 7});
  REQUIRE(bow.cofaces(0, 5, 1).empty());  // node 5 is a node of the complex, on no edge
  // No edges at all: only nodes.
  REQUIRE(clique_lifting(3, {}, 3).shape() == std::vector<std::int64_t>{3});
}

TEST_CASE("clique lifting equals brute-force clique enumeration on random graphs",
          "[core][lifting][topobench]") {
  std::mt19937 rng(30);
  for (int trial = 0; trial < 40; ++trial) {
    const int n = 1 + trial % 14;
    const Graph g = random_graph(rng, n, std::vector<double>{0.2, 0.5, 0.8, 1.0}[trial % 4]);
    for (int complex_dim : {0, 1, 2, 3, 4}) check_clique_lifting(g, complex_dim);
    // Messy input (orientation, order, repeats) gives the same complex.
    const SimplicialComplex a = clique_lifting(g.n, messy(rng, g.edges), 3),
                            b = clique_lifting(g.n, g.edges, 3);
    REQUIRE(a.shape() == b.shape());
    for (int k = 0; k <= a.dim(); ++k) REQUIRE(a.skeleton(k) == b.skeleton(k));
  }
}

TEST_CASE("cycle basis: networkx's cycles on hand-traced graphs", "[core][lifting][topobench]") {
  // Square 0-1-2-3 with diagonal 0-2; adjacency 0:[1 2 3] 1:[0 2] 2:[0 1 3] 3:[0 2].
  // Root 3 (highest node) pushes 0, 2; pop 2: 0 is known, not in used[2] = {3}: cycle
  // [0, 2, pred(2) = 3] (3 is in used[0] = {3}), used[0] += 2; 1 is new; pop 1: 0 known, cycle
  // [0, 1, pred(1) = 2] (2 in used[0]); pop 0: 1, 2, 3 all in used[0].
  REQUIRE(cycle_basis(4, {{0, 1}, {1, 2}, {2, 3}, {3, 0}, {0, 2}}) == Cycles{{0, 2, 3}, {0, 1, 2}});
  // K4: root 3 pushes 0, 1, 2; pop 2 closes [0 2 3] and [1 2 3]; pop 1 closes [0 1 3].
  REQUIRE(cycle_basis(4, {{0, 1}, {0, 2}, {0, 3}, {1, 2}, {1, 3}, {2, 3}}) ==
          Cycles{{0, 2, 3}, {1, 2, 3}, {0, 1, 3}});
  // Two triangles sharing node 0: root 4 pushes 0, 3; pop 3 closes [0 3 4]; pop 0 pushes 1, 2;
  // pop 2 closes [1 2 0].
  REQUIRE(cycle_basis(5, {{0, 1}, {1, 2}, {0, 2}, {0, 3}, {3, 4}, {0, 4}}) ==
          Cycles{{0, 3, 4}, {1, 2, 0}});
  // A cycle through two non-tree edges: tree 4-0, 4-3, 3-1. Pop 3 closes [0 3 4] and adds 3 to
  // used[0]; pop 1 closes at 3, already in used[0]: [0 1 3] uses edges 0-1 and 3-0, both
  // off the tree. Node 2 is isolated (its own component, no cycle).
  REQUIRE(cycle_basis(5, {{4, 0}, {4, 3}, {3, 0}, {3, 1}, {1, 0}}) == Cycles{{0, 3, 4}, {0, 1, 3}});
  // Components are rooted from the highest unvisited node: the square with diagonal on 4..7
  // first, the triangle 0-1-2 last; 3 and 8 are isolated.
  REQUIRE(cycle_basis(9, {{0, 1}, {1, 2}, {2, 0}, {4, 5}, {5, 6}, {6, 7}, {7, 4}, {6, 4}}) ==
          Cycles{{4, 6, 7}, {4, 5, 6}, {0, 1, 2}});
  // A forest has no cycle; repeats and orientation do not matter.
  REQUIRE(cycle_basis(5, {{0, 1}, {1, 2}, {1, 3}, {4, 3}, {1, 0}}).empty());
  REQUIRE(cycle_basis(4, {{2, 0}, {3, 2}, {0, 2}, {1, 0}, {0, 3}, {2, 1}}) ==
          Cycles{{0, 2, 3}, {0, 1, 2}});
  REQUIRE_THROWS_WITH(cycle_basis(3, {{1, 1}}), Catch::Contains("self-loop"));
  REQUIRE_THROWS_WITH(cycle_basis(3, {{0, 3}}), Catch::Contains("uses node 3"));
}

TEST_CASE("cycle lifting: 2-cells, max_cell_length and incidence signs",
          "[core][lifting][topobench]") {
  // Square with diagonal: edges (TopoNetX order) [01 02 03 12 23], cells [0 2 3] and [0 1 2].
  const CellComplex sq = cycle_lifting(4, {{0, 1}, {1, 2}, {2, 3}, {3, 0}, {0, 2}});
  REQUIRE(sq.shape() == std::vector<std::int64_t>{4, 5, 2});
  REQUIRE(sq.cell(0) == std::vector<std::int64_t>{0, 2, 3});
  REQUIRE(sq.cell(1) == std::vector<std::int64_t>{0, 1, 2});
  Dense b2 = Dense::Zero(5, 2);
  b2.col(0) << 0, 1, -1, 0, 1;  // 0->2 along 02, 2->3 along 23, 3->0 against 03
  b2.col(1) << 1, -1, 0, 1, 0;  // 0->1 along 01, 1->2 along 12, 2->0 against 02
  REQUIRE(Dense(sq.incidence_matrix(2)) == b2);
  REQUIRE((Dense(sq.incidence_matrix(1)) * b2).isZero());
  Dense b1 = Dense::Zero(4, 5);
  b1 << -1, -1, -1, 0, 0,  //
      1, 0, 0, -1, 0,      //
      0, 1, 0, 1, -1,      //
      0, 0, 1, 0, 1;
  REQUIRE(Dense(sq.incidence_matrix(1)) == b1);

  // Hexagon 0..5 and triangle 5-6-7: basis [5 6 7], [0 1 2 3 4 5] (root 7; the hexagon closes
  // when 1 meets 0, climbing 2, 3, 4 to 5 = pred(0)). Node 8 is isolated.
  const Edges hex{{0, 1}, {1, 2}, {2, 3}, {3, 4}, {4, 5}, {5, 0}, {5, 6}, {6, 7}, {7, 5}};
  REQUIRE(cycle_basis(9, hex) == Cycles{{5, 6, 7}, {0, 1, 2, 3, 4, 5}});
  const CellComplex cut = cycle_lifting(9, hex, 5);  // the hexagon is longer than 5
  REQUIRE(cut.shape() == std::vector<std::int64_t>{9, 9, 1});
  REQUIRE(cut.cell(0) == std::vector<std::int64_t>{5, 6, 7});
  REQUIRE(cycle_lifting(9, hex, 6).shape() == std::vector<std::int64_t>{9, 9, 2});   // <= kept
  REQUIRE(cycle_lifting(9, hex, -1).shape() == std::vector<std::int64_t>{9, 9, 2});  // no limit
  REQUIRE(cycle_lifting(9, hex).num_2cells() == 2);                                  // default 10
  REQUIRE(cycle_lifting(9, hex, 2).num_2cells() == 0);
  REQUIRE(cycle_lifting(9, hex).cell(1) == std::vector<std::int64_t>{0, 1, 2, 3, 4, 5});
  // A tree: nodes and edges only.
  REQUIRE(cycle_lifting(4, {{0, 1}, {1, 2}, {1, 3}}).shape() == std::vector<std::int64_t>{4, 3, 0});
}

TEST_CASE("cycle basis: networkx's loop re-implemented, basis properties, random graphs",
          "[core][lifting][topobench]") {
  std::mt19937 rng(31);
  for (int trial = 0; trial < 200; ++trial) {
    const int n = 1 + trial % 30;
    const Graph g = random_graph(rng, n, std::vector<double>{0.05, 0.1, 0.2, 0.4, 0.8}[trial % 5]);
    const Cycles cycles = cycle_basis(g.n, g.edges);
    check_cycle_basis(g, cycles);
    REQUIRE(cycle_basis(g.n, messy(rng, g.edges)) == cycles);
    const CellComplex cx = cycle_lifting(g.n, g.edges, 6);
    std::int64_t kept = 0;
    for (const auto& c : cycles)
      if (c.size() <= 6) REQUIRE(cx.cell(kept++) == c);
    REQUIRE(cx.num_2cells() == kept);
    REQUIRE(cx.num_edges() == static_cast<std::int64_t>(g.edges.size()));
    REQUIRE(sparse::multiply(cx.incidence_matrix(1), cx.incidence_matrix(2)).nonZeros() == 0);
  }
}

TEST_CASE("k-hop lifting equals BFS distances", "[core][lifting][topobench]") {
  // Path 0-1-2-3 and isolated node 4.
  const Hypergraph h1 = khop_lifting(5, {{0, 1}, {1, 2}, {2, 3}});
  REQUIRE(h1.num_hyperedges() == 5);
  REQUIRE(h1.hyperedge(0) == std::vector<std::int64_t>{0, 1});
  REQUIRE(h1.hyperedge(1) == std::vector<std::int64_t>{0, 1, 2});
  REQUIRE(h1.hyperedge(4) == std::vector<std::int64_t>{4});
  const Hypergraph h2 = khop_lifting(5, {{0, 1}, {1, 2}, {2, 3}}, 2);
  REQUIRE(h2.hyperedge(0) == std::vector<std::int64_t>{0, 1, 2});
  REQUIRE(h2.hyperedge(1) == std::vector<std::int64_t>{0, 1, 2, 3});
  REQUIRE(khop_lifting(5, {{0, 1}}, 0).hyperedge(1) == std::vector<std::int64_t>{1});
  // The same node set twice is two hyperedges (one per node): K2.
  REQUIRE(Dense(khop_lifting(2, {{0, 1}}).incidence_matrix(0, 1)) == Dense::Ones(2, 2));
  REQUIRE_THROWS_WITH(khop_lifting(3, {{0, 1}}, -1), Catch::Contains("k -1"));

  std::mt19937 rng(32);
  for (int trial = 0; trial < 60; ++trial) {
    const Graph g =
        random_graph(rng, 1 + trial % 25, std::vector<double>{0.05, 0.1, 0.2, 0.5}[trial % 4]);
    for (int k : {0, 1, 2, 3, 6}) check_khop(g, k, messy(rng, g.edges));
    const Hypergraph nb = neighborhood_hypergraph(g.n, g.edges), kh = khop_lifting(g.n, g.edges);
    for (std::int64_t v = 0; v < g.n; ++v) REQUIRE(nb.hyperedge(v) == kh.hyperedge(v));
  }
}

TEST_CASE("graph liftings on MUTAG and PROTEINS graphs against brute force",
          "[core][lifting][topobench][datasets]") {
  const std::filesystem::path root = test::datasets_dir("graph liftings on MUTAG and PROTEINS");
  const std::vector<Graph> mutag = read_tu_graphs(root / "tu" / "MUTAG", "MUTAG");
  REQUIRE(mutag.size() == 188);
  std::int64_t cycles = 0;
  for (const Graph& g : mutag) {
    check_clique_lifting(g, 3);
    const Cycles basis = cycle_basis(g.n, g.edges);
    check_cycle_basis(g, basis);
    cycles += static_cast<std::int64_t>(basis.size());
    check_khop(g, 1, g.edges);
    check_khop(g, 2, g.edges);
  }
  // 3,721 edges, 3,371 nodes, 188 connected molecules: 3721 - 3371 + 188 independent cycles.
  REQUIRE(cycles == 3721 - 3371 + 188);
  const std::vector<Graph> proteins =
      read_tu_graphs(root / "tu" / "PROTEINS_full", "PROTEINS_full");
  REQUIRE(proteins.size() == 1113);
  for (std::size_t i = 0; i < proteins.size(); ++i) {  // up to 620 nodes
    const Graph& g = proteins[i];
    check_clique_lifting(g, 3);
    check_cycle_basis(g, cycle_basis(g.n, g.edges));
    if (i % 10 == 0) {
      check_khop(g, 1, g.edges);
      check_khop(g, 3, g.edges);
    }
  }
}
