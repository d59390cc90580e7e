// Fuzz harness: the TU text format (data/graph_datasets.hpp, parse_tu_dataset). The input is
// either one _A.txt for a fixed small set (8 nodes in 3 graphs, with node labels), or a whole
// set: A, graph_indicator, graph_labels[, node_labels[, edge_labels]] separated by NUL bytes.
#include "fuzz_target.hpp"

#include "topos/data/graph_datasets.hpp"

#include <algorithm>

#include <string>
#include <vector>

TOPOS_FUZZ_TARGET(tu) {
  using namespace topos_fuzz;
  const std::string in = text(data, size);
  std::vector<std::string> parts{""};
  for (const char c : in) {
    if (c == '\0')
      parts.emplace_back();
    else
      parts.back() += c;
  }
  const auto file = [](const char* part, std::string content) {
    return topos::data::TextFile{std::string(source()) + "/TOY_" + part + ".txt",
                                 std::move(content)};
  };
  topos::data::TuFiles f;
  f.A = file("A", parts[0]);
  if (parts.size() == 1) {
    f.graph_indicator = file("graph_indicator", "1\n1\n1\n2\n2\n3\n3\n3\n");
    f.graph_labels = file("graph_labels", "1\n-1\n1\n");
    f.node_labels = file("node_labels", "0\n1\n2\n0\n1\n2\n0\n1\n");
  } else {
    f.graph_indicator = file("graph_indicator", parts[1]);
    f.graph_labels = file("graph_labels", parts.size() > 2 ? parts[2] : "");
    if (parts.size() > 3) f.node_labels = file("node_labels", parts[3]);
    if (parts.size() > 4) f.edge_labels = file("edge_labels", parts[4]);
  }
  try {
    const auto ds = topos::data::parse_tu_dataset(f, "TOY");
    check(ds.num_classes == static_cast<std::int64_t>(ds.class_values.size()), "class count");
    check(std::is_sorted(ds.class_values.begin(), ds.class_values.end()), "sorted classes");
    for (const auto& g : ds.graphs) {
      check(g.num_nodes > 0, "no empty graph");
      check(g.label >= 0 && g.label < ds.num_classes, "graph label in range");
      check(std::is_sorted(g.edges.begin(), g.edges.end()), "sorted edges");
      check(std::adjacent_find(g.edges.begin(), g.edges.end()) == g.edges.end(), "unique edges");
      for (const auto& e : g.edges)
        check(0 <= e[0] && e[0] < e[1] && e[1] < g.num_nodes, "edge u < v inside the graph");
      check(g.node_labels.size() == (f.node_labels ? static_cast<std::size_t>(g.num_nodes) : 0),
            "one node label per node");
      for (const auto l : g.node_labels) check(l >= 0 && l < ds.num_node_labels, "node label");
      check(g.edge_labels.size() == (f.edge_labels ? g.edges.size() : 0), "one label per edge");
      for (const auto l : g.edge_labels) check(l >= 0 && l < ds.num_edge_labels, "edge label");
    }
  } catch (const std::runtime_error& e) {
    expect_error(e.what());
  }
  return 0;
}
