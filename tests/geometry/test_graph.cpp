// Tests of topos/geometry/graph.hpp: the BGL adapter against a direct BFS, and splitting a
// triangle soup into objects.
#include <catch2/catch.hpp>

#include "topos/mesh/primitives.hpp"
#include "topos/geometry/graph.hpp"

#include <boost/graph/breadth_first_search.hpp>
#include <boost/graph/visitors.hpp>

#include <queue>

using namespace topos;

TEST_CASE("BGL breadth-first search on a RankGraph equals a direct BFS", "[geometry][graph]") {
  auto l = lift_meshes({uv_sphere(8, 8), box_mesh(2)});
  const RankGraph g(l.complex, 0, 1);
  REQUIRE(num_vertices(g) == l.complex.size(0));
  REQUIRE(g.num_directed_edges() == 2 * l.complex.size(1));
  std::vector<std::int64_t> dist(static_cast<std::size_t>(num_vertices(g)), -1);
  dist[0] = 0;
  boost::breadth_first_search(
      g, std::int64_t{0},
      boost::visitor(boost::make_bfs_visitor(boost::record_distances(
          boost::make_iterator_property_map(dist.begin(),
                                            boost::typed_identity_property_map<std::int64_t>()),
          boost::on_tree_edge()))));
  // Direct BFS over the first-seen edge list.
  std::vector<std::vector<std::int64_t>> adj(static_cast<std::size_t>(l.complex.size(0)));
  for (auto& e : l.edges) {
    adj[static_cast<std::size_t>(e[0])].push_back(e[1]);
    adj[static_cast<std::size_t>(e[1])].push_back(e[0]);
  }
  std::vector<std::int64_t> ref(adj.size(), -1);
  std::queue<std::int64_t> q;
  ref[0] = 0;
  q.push(0);
  while (!q.empty()) {
    auto u = q.front();
    q.pop();
    for (auto v : adj[static_cast<std::size_t>(u)])
      if (ref[static_cast<std::size_t>(v)] < 0) {
        ref[static_cast<std::size_t>(v)] = ref[static_cast<std::size_t>(u)] + 1;
        q.push(v);
      }
  }
  // Unreached nodes (the second object) stay -1 in both: BGL leaves them untouched.
  REQUIRE(dist == ref);
  REQUIRE(*std::max_element(ref.begin(), ref.end()) == 8);  // pole to pole of the 8-ring sphere
  auto [count, labels] = connected_components(l.complex, 0, 1);
  REQUIRE(count == 2);
  REQUIRE(labels[0] != labels.back());
  // Faces through shared edges: also two components.
  REQUIRE(connected_components(l.complex, 2, 1).first == 2);
}

TEST_CASE("a triangle soup splits into its connected objects", "[geometry][graph]") {
  const TriangleMesh a = cylinder_mesh(), b = box_mesh(3), c = uv_sphere(5, 6);
  TriangleMesh soup;
  soup.name = "soup";
  soup.vertices.resize(a.num_vertices() + b.num_vertices() + c.num_vertices(), 3);
  soup.vertices << a.vertices, b.vertices, c.vertices;
  soup.faces.resize(a.num_faces() + b.num_faces() + c.num_faces(), 3);
  soup.faces << a.faces, (b.faces.array() + a.num_vertices()).matrix(),
      (c.faces.array() + a.num_vertices() + b.num_vertices()).matrix();
  const auto parts = split_connected(soup);
  REQUIRE(parts.size() == 3);
  REQUIRE(parts[0].vertices == a.vertices);
  REQUIRE(parts[0].faces == a.faces);
  REQUIRE(parts[1].vertices == b.vertices);
  REQUIRE(parts[1].faces == b.faces);
  REQUIRE(parts[2].faces == c.faces);
}
