// Fuzz harness: the DGCNN/GIN text format (data/graph_datasets.hpp, parse_dgcnn_dataset).
#include "fuzz_target.hpp"

#include "topos/data/graph_datasets.hpp"

#include <algorithm>

TOPOS_FUZZ_TARGET(dgcnn) {
  using namespace topos_fuzz;
  try {
    const auto ds = topos::data::parse_dgcnn_dataset({source(), text(data, size)}, "fuzz");
    check(!ds.graphs.empty(), "at least one graph");
    check(ds.num_classes == static_cast<std::int64_t>(ds.class_values.size()), "class count");
    for (const auto& g : ds.graphs) {
      check(g.label >= 0 && g.label < ds.num_classes, "graph label in range");
      check(std::is_sorted(g.edges.begin(), g.edges.end()), "sorted edges");
      check(std::adjacent_find(g.edges.begin(), g.edges.end()) == g.edges.end(), "unique edges");
      for (const auto& e : g.edges)
        check(0 <= e[0] && e[0] < e[1] && e[1] < g.num_nodes, "edge u < v inside the graph");
      check(g.node_labels.size() == static_cast<std::size_t>(g.num_nodes), "one tag per node");
      for (const auto l : g.node_labels) check(l >= 0 && l < ds.num_node_labels, "tag in range");
    }
  } catch (const std::runtime_error& e) {
    expect_error(e.what());
  }
  return 0;
}
