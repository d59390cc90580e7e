// topos/data/topobench_datasets-inl.hpp
// Part of graph_datasets-inl.hpp (included by it, not by users): TopoBench's datasets by name
// (load_topobench_graph_dataset, load_topobench_node_dataset) and the node features TopoBench
// builds for each (one-hot labels, degrees, its Gaussian features).
#pragma once

#include "topos/data/graph_datasets.hpp"
#include "topos/data/graph_io-inl.hpp"

#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <stdexcept>
#include <string>
#include <vector>

namespace topos::data {

// --- TopoBench's datasets and features -----------------------------------------------------

namespace graph_io {

inline std::string ascii_lower(std::string s) {
  for (auto& c : s) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  return s;
}

inline void one_hot_node_labels(GraphClassificationDataset& ds) {
  const auto w = ds.num_node_labels;
  for (auto& g : ds.graphs) {
    g.x.assign(static_cast<std::size_t>(g.num_nodes * w), 0.0f);
    for (std::size_t i = 0; i < g.node_labels.size(); ++i)
      g.x[i * static_cast<std::size_t>(w) + static_cast<std::size_t>(g.node_labels[i])] = 1.0f;
  }
  ds.num_node_features = w;
}

inline void one_hot_edge_labels(GraphClassificationDataset& ds) {
  const auto w = ds.num_edge_labels;
  for (auto& g : ds.graphs) {
    g.edge_attr.assign(g.edges.size() * static_cast<std::size_t>(w), 0.0f);
    for (std::size_t e = 0; e < g.edge_labels.size(); ++e)
      g.edge_attr[e * static_cast<std::size_t>(w) + static_cast<std::size_t>(g.edge_labels[e])] =
          1.0f;
  }
  ds.num_edge_features = w;
}

/// TopoBench's NodeDegrees + OneHotDegreeFeatures: the degree of each node (the row sums of
/// the dense adjacency of PyG's symmetric edge_index, i.e. the undirected degree) one-hot over
/// 0..max_degree; a larger degree is an error, as torch's one_hot makes it.
inline void one_hot_degree(GraphClassificationDataset& ds, std::int64_t max_degree) {
  const auto w = static_cast<std::size_t>(max_degree + 1);
  for (std::size_t gi = 0; gi < ds.graphs.size(); ++gi) {
    auto& g = ds.graphs[gi];
    std::vector<std::int64_t> degree(static_cast<std::size_t>(g.num_nodes), 0);
    for (const auto& e : g.edges)
      ++degree[static_cast<std::size_t>(e[0])], ++degree[static_cast<std::size_t>(e[1])];
    g.x.assign(degree.size() * w, 0.0f);
    for (std::size_t v = 0; v < degree.size(); ++v) {
      if (degree[v] > max_degree)
        throw std::runtime_error(ds.name + ": node " + std::to_string(v) + " of graph " +
                                 std::to_string(gi + 1) + " has degree " +
                                 std::to_string(degree[v]) + ", above TopoBench's max_degree " +
                                 std::to_string(max_degree));
      g.x[v * w + static_cast<std::size_t>(degree[v])] = 1.0f;
    }
  }
  ds.num_node_features = static_cast<std::int64_t>(w);
}

inline bool exists(const fs::path& p) {
  std::error_code ec;
  return fs::exists(p, ec);
}

}  // namespace graph_io

TOPOS_INLINE GraphClassificationDataset
load_topobench_graph_dataset(const std::filesystem::path& datasets_root, const std::string& name,
                             const TopoBenchOptions& options) {
  namespace fs = std::filesystem;
  static const char* const known[] = {"MUTAG",       "PROTEINS",   "NCI1",         "NCI109",
                                      "IMDB-BINARY", "IMDB-MULTI", "REDDIT-BINARY"};
  std::string canonical;
  for (const char* k : known)
    if (graph_io::ascii_lower(name) == graph_io::ascii_lower(k)) canonical = k;
  if (canonical.empty()) {
    std::string list;
    for (const char* k : known) list += std::string(list.empty() ? "" : ", ") + k;
    throw std::invalid_argument("load_topobench_graph_dataset: unknown dataset '" + name +
                                "'; known: " + list);
  }
  const auto tu = datasets_root / "tu";
  // TU folders or zips to try, by prefix, in order.
  std::vector<std::string> prefixes{canonical};
  if (canonical == "PROTEINS") prefixes.push_back("PROTEINS_full");
  std::optional<GraphClassificationDataset> ds;
  std::string looked;
  for (const auto& p : prefixes) {
    for (const auto& where : {tu / p, tu / (p + ".zip")}) {
      looked += (looked.empty() ? "" : ", ") + where.string();
      if (!ds && graph_io::exists(where)) ds = read_tu_dataset(where, p);
    }
  }
  if (!ds && canonical == "REDDIT-BINARY") {
    for (const auto& where : {datasets_root / "dgcnn" / "REDDIT-BINARY.zip",
                              datasets_root / "dgcnn" / "REDDIT-BINARY.txt"}) {
      looked += ", " + where.string();
      if (!ds && graph_io::exists(where)) ds = read_dgcnn_dataset(where, canonical);
    }
  }
  if (!ds)
    throw std::runtime_error("load_topobench_graph_dataset: " + canonical +
                             " not found (looked for " + looked + ")");
  ds->name = canonical;
  if (canonical == "IMDB-BINARY") {
    graph_io::one_hot_degree(*ds, 135);
  } else if (canonical == "IMDB-MULTI") {
    graph_io::one_hot_degree(*ds, 88);
  } else if (canonical == "REDDIT-BINARY") {
    const auto v = graph_io::torch_cpu_normal(options.seed, 10, 0.0, 0.1);
    for (auto& g : ds->graphs) {
      g.node_labels.clear();
      g.x.clear();
      for (std::int64_t i = 0; i < g.num_nodes; ++i) g.x.insert(g.x.end(), v.begin(), v.end());
    }
    ds->num_node_labels = 0;
    ds->num_node_features = 10;
  } else {
    if (ds->num_node_labels == 0)
      throw std::runtime_error("load_topobench_graph_dataset: " + canonical +
                               " has no node labels to build features from");
    graph_io::one_hot_node_labels(*ds);
    if (canonical == "MUTAG") graph_io::one_hot_edge_labels(*ds);
  }
  return *ds;
}

TOPOS_INLINE GraphClassificationDataset
load_topobench_graph_dataset(const std::filesystem::path& datasets_root, const std::string& name) {
  return load_topobench_graph_dataset(datasets_root, name, TopoBenchOptions{});
}

TOPOS_INLINE NodeClassificationDataset
load_topobench_node_dataset(const std::filesystem::path& datasets_root, const std::string& name) {
  auto key = graph_io::ascii_lower(name);
  if (key.rfind("cocitation_", 0) == 0) key = key.substr(11);
  const char* canonical = key == "cora"       ? "Cora"
                          : key == "citeseer" ? "CiteSeer"
                          : key == "pubmed"   ? "PubMed"
                                              : nullptr;
  if (canonical == nullptr)
    throw std::invalid_argument("load_topobench_node_dataset: unknown dataset '" + name +
                                "'; known: cocitation_cora (Cora), cocitation_citeseer (CiteSeer), "
                                "cocitation_pubmed (PubMed)");
  auto ds = read_planetoid_dataset(datasets_root / "planetoid", key);
  ds.name = canonical;
  return ds;
}

}  // namespace topos::data
