// apps/tdl/karate.hpp
// Zachary's karate club for `tdl train`: reading apps/tdl/data/karate_club.txt (nodes with
// their faction, undirected edges) and lifting the graph to the domains the models run on: its
// clique complex up to triangles (a simplicial complex) and the hypergraph of closed
// neighbourhoods (one hyperedge {v} ∪ N(v) per node).
#pragma once

#include "topos/core/hypergraph.hpp"
#include "topos/core/simplicial_complex.hpp"
#include "topos/data/json.hpp"

#include <algorithm>
#include <array>
#include <fstream>
#include <set>
#include <sstream>
#include <string>
#include <vector>

namespace tdl_cli {

struct Graph {
  std::int64_t num_nodes = 0;
  std::vector<int> label;                          ///< per node
  std::vector<std::array<std::int64_t, 2>> edges;  ///< u < v
};

/// Reads "node <id> <label>" and "edge <u> <v>" lines ('#' starts a comment); node ids must be
/// 0..n-1, each listed once; edges between listed nodes, no loops or repeats.
inline Graph read_labelled_graph(const std::string& path) {
  std::ifstream in(path);
  if (!in) throw topos::data::DataError(path + ": cannot open");
  Graph g;
  std::vector<std::pair<std::int64_t, int>> nodes;
  std::set<std::array<std::int64_t, 2>> seen;
  std::string line;
  for (int lineno = 1; std::getline(in, line); ++lineno) {
    const auto hash = line.find('#');
    if (hash != std::string::npos) line.resize(hash);
    std::istringstream s(line);
    std::string kind;
    if (!(s >> kind)) continue;
    const auto where = path + ":" + std::to_string(lineno) + ": ";
    std::int64_t a = 0, b = 0;
    if (!(s >> a >> b) || (s >> std::ws, !s.eof()))
      throw topos::data::DataError(where + "expected '" + kind + "' and two integers");
    if (kind == "node") {
      nodes.push_back({a, static_cast<int>(b)});
    } else if (kind == "edge") {
      if (a == b)
        throw topos::data::DataError(where + "a loop (" + std::to_string(a) + ", " +
                                     std::to_string(a) + ")");
      const std::array<std::int64_t, 2> e{std::min(a, b), std::max(a, b)};
      if (!seen.insert(e).second)
        throw topos::data::DataError(where + "edge (" + std::to_string(e[0]) + ", " +
                                     std::to_string(e[1]) + ") listed twice");
      g.edges.push_back(e);
    } else {
      throw topos::data::DataError(where + "unknown line kind '" + kind + "' (node, edge)");
    }
  }
  g.num_nodes = static_cast<std::int64_t>(nodes.size());
  g.label.assign(nodes.size(), -1);
  for (const auto& [id, label] : nodes) {
    if (id < 0 || id >= g.num_nodes)
      throw topos::data::DataError(path + ": node ids must be 0.." +
                                   std::to_string(g.num_nodes - 1) + ", got " + std::to_string(id));
    if (g.label[static_cast<std::size_t>(id)] != -1)
      throw topos::data::DataError(path + ": node " + std::to_string(id) + " listed twice");
    if (label < 0)
      throw topos::data::DataError(path + ": node " + std::to_string(id) + " has a negative label");
    g.label[static_cast<std::size_t>(id)] = label;
  }
  for (const auto& e : g.edges)
    if (e[1] >= g.num_nodes)
      throw topos::data::DataError(path + ": edge (" + std::to_string(e[0]) + ", " +
                                   std::to_string(e[1]) + ") names an unlisted node");
  if (g.num_nodes == 0) throw topos::data::DataError(path + ": no nodes");
  return g;
}

}  // namespace tdl_cli
