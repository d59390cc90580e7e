// topos/data/graph_datasets-inl.hpp
// The implementation of graph_datasets.hpp: compiled into topos::data (src/data.cpp), or inline
// with TOPOS_HEADER_ONLY (topos/config.hpp).
//
// Readers for the raw files of the graph benchmarks TopoBench reports on, into graphs exactly as
// PyTorch Geometric holds them after reading (torch_geometric/io/tu.py, io/planetoid.py):
//  - the TU text format (MUTAG, PROTEINS, NCI1, NCI109, IMDB-BINARY, IMDB-MULTI; a folder or
//    the TU zip): self-loops removed, duplicate edges coalesced, node labels shifted by their
//    minimum, graph labels mapped to 0..C-1 in sorted order, isolated nodes kept;
//  - the DGCNN/GIN text format (our REDDIT-BINARY file);
//  - Planetoid's Python-2 pickles (Cora, Citeseer) through a small, strict pickle reader
//    (planetoid_pickle-inl.hpp, on the opcode decoder of io/pickle.hpp);
// and the node features TopoBench builds for each dataset (load_topobench_*). docs/datasets.md
// says what each step mirrors. std only; zipped files need libzip (the CMake target topos::data
// defines TOPOS_WITH_LIBZIP and links it). Untrusted input: counts are checked against the
// bytes before use, and bad input is a std::runtime_error naming the file and the 1-based line
// (the byte offset in a pickle); nothing half-read is returned.
#pragma once

#include "topos/data/graph_datasets.hpp"
#include "topos/data/graph_io-inl.hpp"
#include "topos/data/planetoid_pickle-inl.hpp"
#include "topos/data/topobench_datasets-inl.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
#include <map>
#include <memory>
#include <optional>
#include <random>
#include <stdexcept>
#include <string>
#include <string_view>
#include <unordered_map>
#include <utility>
#include <vector>

#ifdef TOPOS_WITH_LIBZIP
#include <zip.h>
#endif

namespace topos::data {

// --- TU text format ------------------------------------------------------------------------

TOPOS_INLINE GraphClassificationDataset parse_tu_dataset(const TuFiles& f,
                                                         const std::string& name) {
  using graph_io::fail;
  GraphClassificationDataset ds;
  ds.name = name;

  auto graph_label = graph_io::read_column(f.graph_labels, "a graph label");
  if (graph_label.empty()) fail(f.graph_labels.name, 1, "no graph labels (empty file)");
  const auto num_graphs = static_cast<std::int64_t>(graph_label.size());
  ds.class_values = graph_io::remap_sorted(graph_label);
  ds.num_classes = static_cast<std::int64_t>(ds.class_values.size());

  // Nodes, grouped by graph: graph g holds nodes start[g] .. start[g+1]-1 (0-based).
  std::vector<std::int64_t> node_graph, start;
  {
    graph_io::Lines in(f.graph_indicator.text, f.graph_indicator.name);
    std::string_view line;
    std::int64_t prev = 0;
    const std::string range = " outside 1.." + std::to_string(num_graphs) + " (" +
                              f.graph_labels.name + " has " + std::to_string(num_graphs) +
                              " lines)";
    while (in.next(line)) {
      const auto id = graph_io::parse_single(line, in, "a graph id");
      if (id < 1 || id > num_graphs) in.fail("graph id " + std::to_string(id) + range);
      if (id < prev)
        in.fail("graph id " + std::to_string(id) + " after " + std::to_string(prev) +
                ": nodes must be grouped by graph in order");
      if (id > prev + 1) in.fail("graph " + std::to_string(prev + 1) + " has no nodes");
      if (id > prev) start.push_back(static_cast<std::int64_t>(node_graph.size()));
      prev = id;
      node_graph.push_back(id - 1);
    }
    if (node_graph.empty()) fail(f.graph_indicator.name, 1, "no nodes (empty file)");
    if (prev < num_graphs)
      fail(f.graph_indicator.name, in.line(),
           "graphs " + std::to_string(prev + 1) + ".." + std::to_string(num_graphs) +
               " have no nodes (" + f.graph_labels.name + " has " + std::to_string(num_graphs) +
               " lines)");
    start.push_back(static_cast<std::int64_t>(node_graph.size()));
  }
  const auto num_nodes = static_cast<std::int64_t>(node_graph.size());

  std::vector<std::int64_t> node_label;
  if (f.node_labels) {
    node_label = graph_io::read_column(*f.node_labels, "a node label");
    graph_io::check_label_count(*f.node_labels, static_cast<std::int64_t>(node_label.size()),
                                num_nodes, "node", f.graph_indicator.name);
    ds.num_node_labels = graph_io::shift_labels(node_label, f.node_labels->name);
  }

  // Edges as (u, v, line index) with u < v, 0-based; self-loops dropped here.
  struct Rec {
    std::int64_t u, v, line;
  };
  std::vector<Rec> recs;
  std::int64_t num_lines = 0;
  {
    graph_io::Lines in(f.A.text, f.A.name);
    std::string_view line;
    const std::string range = " outside 1.." + std::to_string(num_nodes) + " (" +
                              f.graph_indicator.name + " has " + std::to_string(num_nodes) +
                              " nodes)";
    while (in.next(line)) {
      if (graph_io::trim(line).empty()) in.fail("empty line, expected an edge 'u, v'");
      const auto comma = line.find(',');
      if (comma == std::string_view::npos || line.find(',', comma + 1) != std::string_view::npos)
        in.fail("expected an edge 'u, v', found " + graph_io::quote(line));
      const auto u = graph_io::parse_int(line.substr(0, comma), in);
      const auto v = graph_io::parse_int(line.substr(comma + 1), in);
      for (const auto id : {u, v})
        if (id < 1 || id > num_nodes) in.fail("node id " + std::to_string(id) + range);
      if (node_graph[u - 1] != node_graph[v - 1])
        in.fail("edge (" + std::to_string(u) + ", " + std::to_string(v) + ") joins graph " +
                std::to_string(node_graph[u - 1] + 1) + " and graph " +
                std::to_string(node_graph[v - 1] + 1));
      if (u != v) recs.push_back({std::min(u, v) - 1, std::max(u, v) - 1, num_lines});
      ++num_lines;
    }
  }

  std::vector<std::int64_t> edge_label;
  if (f.edge_labels) {
    edge_label = graph_io::read_column(*f.edge_labels, "an edge label");
    graph_io::check_label_count(*f.edge_labels, static_cast<std::int64_t>(edge_label.size()),
                                num_lines, "edge", f.A.name);
  }
  const std::vector<std::int64_t> raw_edge_label = edge_label;
  // PyG takes the minimum over every line, self-loops included, before removing them.
  if (f.edge_labels) ds.num_edge_labels = graph_io::shift_labels(edge_label, f.edge_labels->name);

  std::sort(recs.begin(), recs.end(), [](const Rec& a, const Rec& b) {
    return a.u != b.u ? a.u < b.u : a.v != b.v ? a.v < b.v : a.line < b.line;
  });

  ds.graphs.resize(static_cast<std::size_t>(num_graphs));
  for (std::int64_t g = 0; g < num_graphs; ++g) {
    auto& gr = ds.graphs[static_cast<std::size_t>(g)];
    gr.num_nodes = start[g + 1] - start[g];
    gr.label = graph_label[static_cast<std::size_t>(g)];
    if (f.node_labels)
      gr.node_labels.assign(node_label.begin() + start[g], node_label.begin() + start[g + 1]);
  }
  std::size_t first = 0;  // the first copy (by line) of the current edge
  for (std::size_t i = 0; i < recs.size(); ++i) {
    const auto& r = recs[i];
    if (i > 0 && recs[i - 1].u == r.u && recs[i - 1].v == r.v) {
      if (f.edge_labels && edge_label[r.line] != edge_label[recs[first].line])
        fail(f.edge_labels->name, r.line + 1,
             "edge (" + std::to_string(r.u + 1) + ", " + std::to_string(r.v + 1) + ") has label " +
                 std::to_string(raw_edge_label[r.line]) + " here but " +
                 std::to_string(raw_edge_label[recs[first].line]) + " at line " +
                 std::to_string(recs[first].line + 1));
      continue;
    }
    first = i;
    const auto g = node_graph[r.u];
    auto& gr = ds.graphs[static_cast<std::size_t>(g)];
    gr.edges.push_back({r.u - start[g], r.v - start[g]});
    if (f.edge_labels) gr.edge_labels.push_back(edge_label[r.line]);
  }
  return ds;
}

namespace graph_io {

/// The files of TU dataset `prefix` in a folder or zip (by file name, any folder inside).
inline TuFiles tu_files(const fs::path& folder_or_zip, const std::string& prefix) {
  TuFiles f;
  const auto part = [&](const char* p) { return prefix + "_" + p + ".txt"; };
  std::error_code ec;
  if (fs::is_regular_file(folder_or_zip, ec) && is_zip_path(folder_or_zip)) {
#ifdef TOPOS_WITH_LIBZIP
    ZipArchive z(folder_or_zip);
    const auto get = [&](const char* p, bool required) -> std::optional<TextFile> {
      const auto i = z.find(part(p));
      if (!i) {
        if (required) throw std::runtime_error("reading " + z.path() + ": no entry " + part(p));
        return std::nullopt;
      }
      return z.read(*i);
    };
    f.A = *get("A", true);
    f.graph_indicator = *get("graph_indicator", true);
    f.graph_labels = *get("graph_labels", true);
    f.node_labels = get("node_labels", false);
    f.edge_labels = get("edge_labels", false);
    return f;
#else
    no_libzip(folder_or_zip);
#endif
  }
  if (!fs::is_directory(folder_or_zip, ec))
    throw std::runtime_error("reading " + folder_or_zip.string() + ": no such folder or zip file");
  const auto get = [&](const char* p, bool required) -> std::optional<TextFile> {
    const auto path = folder_or_zip / part(p);
    if (!required && !fs::exists(path, ec)) return std::nullopt;
    return TextFile{path.string(), read_bytes(path)};
  };
  f.A = *get("A", true);
  f.graph_indicator = *get("graph_indicator", true);
  f.graph_labels = *get("graph_labels", true);
  f.node_labels = get("node_labels", false);
  f.edge_labels = get("edge_labels", false);
  return f;
}

}  // namespace graph_io

TOPOS_INLINE GraphClassificationDataset read_tu_dataset(const std::filesystem::path& folder_or_zip,
                                                        const std::string& name) {
  return parse_tu_dataset(graph_io::tu_files(folder_or_zip, name), name);
}

// --- DGCNN / GIN text format ---------------------------------------------------------------

TOPOS_INLINE GraphClassificationDataset parse_dgcnn_dataset(const TextFile& file,
                                                            const std::string& name) {
  GraphClassificationDataset ds;
  ds.name = name;
  graph_io::Lines in(file.text, file.name);
  std::string_view line;
  std::vector<std::string_view> tok;
  const auto need = [&](const std::string& what) {
    if (!in.next(line))
      graph_io::fail(file.name, in.line() + 1, "unexpected end of file, expected " + what);
    graph_io::split_blanks(line, tok);
  };
  need("the number of graphs");
  if (tok.size() != 1)
    in.fail("expected the number of graphs, found " + std::to_string(tok.size()) + " values");
  const auto num_graphs = graph_io::parse_int(tok[0], in);
  if (num_graphs < 1) in.fail("the number of graphs must be positive");
  std::vector<std::int64_t> graph_label, tags, tag_line;
  for (std::int64_t g = 0; g < num_graphs; ++g) {
    const std::string gname = "graph " + std::to_string(g + 1);
    need("the line 'n label' of " + gname + " of " + std::to_string(num_graphs));
    if (tok.size() != 2)
      in.fail("expected 'n label' for " + gname + ", found " + std::to_string(tok.size()) +
              " values");
    const auto n = graph_io::parse_int(tok[0], in);
    if (n < 0) in.fail("negative node count " + std::to_string(n));
    graph_label.push_back(graph_io::parse_int(tok[1], in));
    LabeledGraph gr;
    gr.num_nodes = n;
    for (std::int64_t v = 0; v < n; ++v) {
      need("node " + std::to_string(v) + " of " + gname + " ('tag degree neighbours...')");
      if (tok.size() < 2) in.fail("expected 'tag degree neighbours...'");
      tags.push_back(graph_io::parse_int(tok[0], in));
      tag_line.push_back(in.line());
      const auto degree = graph_io::parse_int(tok[1], in);
      if (degree < 0 || static_cast<std::uint64_t>(degree) != tok.size() - 2)
        in.fail("degree " + std::to_string(degree) + " but " + std::to_string(tok.size() - 2) +
                " values follow (node attributes are not supported)");
      for (std::size_t k = 2; k < tok.size(); ++k) {
        const auto w = graph_io::parse_int(tok[k], in);
        if (w < 0 || w >= n)
          in.fail("neighbour " + std::to_string(w) + " outside 0.." + std::to_string(n - 1));
        if (w != v) gr.edges.push_back({std::min(v, w), std::max(v, w)});
      }
    }
    std::sort(gr.edges.begin(), gr.edges.end());
    gr.edges.erase(std::unique(gr.edges.begin(), gr.edges.end()), gr.edges.end());
    ds.graphs.push_back(std::move(gr));
  }
  while (in.next(line))
    if (!graph_io::trim(line).empty())
      in.fail("unexpected content after the " + std::to_string(num_graphs) +
              " graphs the first line announces");
  ds.class_values = graph_io::remap_sorted(graph_label);
  ds.num_classes = static_cast<std::int64_t>(ds.class_values.size());
  ds.num_node_labels = graph_io::shift_labels(tags, file.name, &tag_line);
  std::size_t t = 0;
  for (std::size_t g = 0; g < ds.graphs.size(); ++g) {
    auto& gr = ds.graphs[g];
    gr.label = graph_label[g];
    const auto n = static_cast<std::size_t>(gr.num_nodes);
    gr.node_labels.assign(tags.begin() + static_cast<std::ptrdiff_t>(t),
                          tags.begin() + static_cast<std::ptrdiff_t>(t + n));
    t += n;
  }
  return ds;
}

TOPOS_INLINE GraphClassificationDataset read_dgcnn_dataset(const std::filesystem::path& txt_or_zip,
                                                           const std::string& name) {
  std::error_code ec;
  if (graph_io::is_zip_path(txt_or_zip) && std::filesystem::is_regular_file(txt_or_zip, ec)) {
#ifdef TOPOS_WITH_LIBZIP
    graph_io::ZipArchive z(txt_or_zip);
    const auto i = z.find(name + ".txt");
    if (!i) throw std::runtime_error("reading " + z.path() + ": no entry " + name + ".txt");
    return parse_dgcnn_dataset(z.read(*i), name);
#else
    graph_io::no_libzip(txt_or_zip);
#endif
  }
  return parse_dgcnn_dataset(TextFile{txt_or_zip.string(), graph_io::read_bytes(txt_or_zip)}, name);
}

// --- Planetoid: Python-2 pickles (the object reader: planetoid_pickle-inl.hpp) ------------

TOPOS_INLINE PlanetoidPickle read_planetoid_pickle(std::string_view bytes,
                                                   const std::string& source,
                                                   std::int64_t max_elements) {
  using pickle::Kind;
  pickle::Machine m(bytes, source);
  const auto root = m.run();
  const auto fail = [&](const std::string& what) -> void {
    throw std::runtime_error(source + ": " + what);
  };
  PlanetoidPickle out;
  const auto check_size = [&](std::int64_t rows, std::int64_t cols) {
    // Each side on its own too: a 2^40 x 0 matrix holds nothing but would size the dataset.
    if (rows < 0 || cols < 0 || rows > max_elements || cols > max_elements ||
        (rows > 0 && cols > max_elements / rows))
      fail("a " + std::to_string(rows) + " x " + std::to_string(cols) +
           " matrix is over the limit of " + std::to_string(max_elements) + " entries");
    out.rows = rows;
    out.cols = cols;
  };
  const auto is_array = [](const pickle::Ref& v, std::size_t ndim) {
    return v && v->kind == Kind::NdArray && v->built && v->shape.size() == ndim;
  };
  if (root->kind == Kind::NdArray) {
    if (!is_array(root, 2)) fail("expected a 2-D array");
    check_size(root->shape[0], root->shape[1]);
    out.values.resize(static_cast<std::size_t>(out.rows * out.cols));
    for (std::size_t k = 0; k < out.values.size(); ++k)
      out.values[k] = static_cast<float>(pickle::element(*root, k));
    return out;
  }
  if (root->kind == Kind::Csr) {
    if (!root->built) fail("csr_matrix without state");
    const auto& d = root->state->str_keys;
    const auto get = [&](const char* key) -> pickle::Ref {
      const auto it = d.find(key);
      return it == d.end() ? nullptr : it->second;
    };
    const auto format = get("format");
    if (format && (format->kind != Kind::Str || format->s != "csr"))
      fail("csr_matrix with a format other than 'csr'");
    const auto shape = get("_shape");
    if (!shape || shape->kind != Kind::Tuple || shape->items.size() != 2 ||
        shape->items[0]->kind != Kind::Int || shape->items[1]->kind != Kind::Int)
      fail("csr_matrix without a 2-D _shape");
    const auto indptr = get("indptr"), indices = get("indices"), data = get("data");
    if (!is_array(indptr, 1) || !is_array(indices, 1) || !is_array(data, 1))
      fail("csr_matrix without 1-D indptr, indices and data arrays");
    for (const auto& a : {indptr, indices})
      if (a->dtype->s[0] != 'i') fail("csr_matrix index arrays must be integers");
    check_size(shape->items[0]->i, shape->items[1]->i);
    const auto nnz = static_cast<std::size_t>(indices->shape[0]);
    if (static_cast<std::int64_t>(indptr->shape[0]) != out.rows + 1)
      fail("csr_matrix indptr has " + std::to_string(indptr->shape[0]) + " entries for " +
           std::to_string(out.rows) + " rows");
    if (static_cast<std::size_t>(data->shape[0]) != nnz)
      fail("csr_matrix has " + std::to_string(nnz) + " indices but " +
           std::to_string(data->shape[0]) + " values");
    if (pickle::index_element(*indptr, 0) != 0) fail("csr_matrix indptr[0] is not 0");
    if (pickle::index_element(*indptr, static_cast<std::size_t>(out.rows)) !=
        static_cast<std::int64_t>(nnz))
      fail("csr_matrix indptr[rows] is not the number of entries");
    // Dense, summing duplicates as scipy's todense does (in the data's precision).
    const bool single = data->dtype->s == "f4";
    std::vector<double> wide(single ? 0 : static_cast<std::size_t>(out.rows * out.cols));
    out.values.assign(static_cast<std::size_t>(out.rows * out.cols), 0.0f);
    for (std::int64_t r = 0; r < out.rows; ++r) {
      const auto b = pickle::index_element(*indptr, static_cast<std::size_t>(r));
      const auto e = pickle::index_element(*indptr, static_cast<std::size_t>(r + 1));
      if (b > e || e > static_cast<std::int64_t>(nnz))
        fail("csr_matrix indptr is not non-decreasing at row " + std::to_string(r));
      for (auto k = b; k < e; ++k) {
        const auto c = pickle::index_element(*indices, static_cast<std::size_t>(k));
        if (c < 0 || c >= out.cols)
          fail("csr_matrix column " + std::to_string(c) + " outside 0.." +
               std::to_string(out.cols - 1));
        const auto at = static_cast<std::size_t>(r * out.cols + c);
        const double v = pickle::element(*data, static_cast<std::size_t>(k));
        if (single)
          out.values[at] += static_cast<float>(v);
        else
          wide[at] += v;
      }
    }
    if (!single)
      for (std::size_t k = 0; k < wide.size(); ++k) out.values[k] = static_cast<float>(wide[k]);
    return out;
  }
  if (root->kind == Kind::Dict) {
    if (!root->str_keys.empty()) fail("a graph dict with a non-integer key");
    out.kind = PlanetoidPickle::Kind::Graph;
    for (const auto& [key, value] : root->int_keys) {
      if (value->kind != Kind::List)
        fail("graph dict value for key " + std::to_string(key) + " is not a list");
      out.adjacency.emplace_back(key, value->ints);
    }
    return out;
  }
  fail(std::string("expected a csr_matrix, an ndarray or a dict, found a ") +
       pickle::kind_name(root->kind));
  return out;
}

TOPOS_INLINE NodeClassificationDataset read_planetoid_dataset(const std::filesystem::path& folder,
                                                              const std::string& name) {
  std::string lower = name;
  for (auto& c : lower) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  const auto path = [&](const std::string& part) {
    return (folder / ("ind." + lower + "." + part)).string();
  };
  const auto matrix = [&](const std::string& part) {
    const auto p = path(part);
    auto m = read_planetoid_pickle(graph_io::read_bytes(p), p);
    if (m.kind != PlanetoidPickle::Kind::Matrix)
      throw std::runtime_error(p + ": expected a matrix, found the graph dict");
    return m;
  };
  const auto x = matrix("x"), tx = matrix("tx"), allx = matrix("allx");
  const auto y = matrix("y"), ty = matrix("ty"), ally = matrix("ally");
  (void)x, (void)y;  // PyG reads them (train features, train labels) but builds nothing from them
  const auto graph_path = path("graph");
  const auto graph = read_planetoid_pickle(graph_io::read_bytes(graph_path), graph_path);
  if (graph.kind != PlanetoidPickle::Kind::Graph)
    throw std::runtime_error(graph_path + ": expected the graph dict, found a matrix");

  const auto index_path = path("test.index");
  std::vector<std::int64_t> test_index, test_line;
  {
    const auto text = graph_io::read_bytes(index_path);
    graph_io::Lines in(text, index_path);
    std::string_view line;
    while (in.next(line)) {
      const auto v = graph_io::parse_single(line, in, "a test index");
      if (v < 0) in.fail("negative test index " + std::to_string(v));
      test_index.push_back(v);
      test_line.push_back(in.line());
    }
    if (test_index.empty()) graph_io::fail(index_path, 1, "no test indices (empty file)");
  }
  const auto num_test = static_cast<std::int64_t>(test_index.size());
  std::vector<std::size_t> order(test_index.size());
  for (std::size_t k = 0; k < order.size(); ++k) order[k] = k;
  std::sort(order.begin(), order.end(), [&](std::size_t a, std::size_t b) {
    return test_index[a] != test_index[b] ? test_index[a] < test_index[b] : a < b;
  });
  std::vector<std::int64_t> sorted_index(test_index.size());
  for (std::size_t k = 0; k < order.size(); ++k) sorted_index[k] = test_index[order[k]];
  for (std::size_t k = 1; k < order.size(); ++k)
    if (sorted_index[k] == sorted_index[k - 1])
      graph_io::fail(index_path, test_line[std::max(order[k], order[k - 1])],
                     "test index " + std::to_string(sorted_index[k]) +
                         " listed twice (also at line " +
                         std::to_string(test_line[std::min(order[k], order[k - 1])]) + ")");

  const auto mismatch = [&](const PlanetoidPickle& a, const std::string& an,
                            const PlanetoidPickle& b, const std::string& bn, bool rows) {
    const auto va = rows ? a.rows : a.cols, vb = rows ? b.rows : b.cols;
    if (va != vb)
      throw std::runtime_error(path(an) + ": " + std::to_string(va) +
                               (rows ? " rows" : " columns") + " but " + path(bn) + " has " +
                               std::to_string(vb));
  };
  mismatch(tx, "tx", allx, "allx", false);
  mismatch(ty, "ty", ally, "ally", false);
  mismatch(ally, "ally", allx, "allx", true);
  mismatch(ty, "ty", tx, "tx", true);
  if (ally.cols < 1) throw std::runtime_error(path("ally") + ": labels with no column");
  const auto width = allx.cols;

  // The test block: tx's rows in order, or for Citeseer the rows min..max of test.index with
  // tx's rows at the sorted indices and zeros elsewhere (PyG's tx_ext / ty_ext).
  std::int64_t block = tx.rows;
  std::vector<std::int64_t> block_row(static_cast<std::size_t>(tx.rows));  // tx row -> block row
  for (std::int64_t r = 0; r < tx.rows; ++r) block_row[static_cast<std::size_t>(r)] = r;
  if (lower == "citeseer") {
    if (tx.rows != num_test)
      throw std::runtime_error(path("tx") + ": " + std::to_string(tx.rows) + " rows but " +
                               index_path + " lists " + std::to_string(num_test) + " test nodes");
    const auto lo = sorted_index.front(), hi = sorted_index.back();
    block = hi - lo + 1;
    if (block > (std::int64_t{1} << 24) ||
        block > (std::int64_t{1} << 30) / std::max<std::int64_t>(width, 1))
      graph_io::fail(index_path, test_line[order.back()],
                     "test indices span " + std::to_string(block) + " rows, too many");
    for (std::size_t k = 0; k < sorted_index.size(); ++k) block_row[k] = sorted_index[k] - lo;
  }
  NodeClassificationDataset ds;
  ds.name = name;
  ds.num_nodes = allx.rows + block;
  ds.num_node_features = width;
  for (std::size_t k = 0; k < test_index.size(); ++k)
    if (test_index[k] >= ds.num_nodes)
      graph_io::fail(index_path, test_line[k],
                     "test index " + std::to_string(test_index[k]) + " outside 0.." +
                         std::to_string(ds.num_nodes - 1));

  // Features and labels in file order (allx, ally then the test block), then the permutation.
  const auto n = static_cast<std::size_t>(ds.num_nodes), w = static_cast<std::size_t>(width);
  std::vector<float> xs(n * w, 0.0f);
  std::vector<std::int64_t> ys(n, 0);
  const auto argmax = [&](const PlanetoidPickle& m, std::int64_t r) {
    const float* row = m.values.data() + r * m.cols;
    return static_cast<std::int64_t>(std::max_element(row, row + m.cols) - row);  // first max
  };
  std::copy(allx.values.begin(), allx.values.end(), xs.begin());
  for (std::int64_t r = 0; r < ally.rows; ++r) ys[static_cast<std::size_t>(r)] = argmax(ally, r);
  for (std::int64_t r = 0; r < tx.rows; ++r) {
    const auto to = static_cast<std::size_t>(allx.rows + block_row[static_cast<std::size_t>(r)]);
    std::copy(tx.values.begin() + r * width, tx.values.begin() + (r + 1) * width,
              xs.begin() + static_cast<std::ptrdiff_t>(to * w));
    ys[to] = argmax(ty, r);
  }
  ds.x = xs;
  ds.labels = ys;
  for (std::size_t k = 0; k < test_index.size(); ++k) {
    const auto to = static_cast<std::size_t>(test_index[k]);
    const auto from = static_cast<std::size_t>(sorted_index[k]);
    std::copy(xs.begin() + static_cast<std::ptrdiff_t>(from * w),
              xs.begin() + static_cast<std::ptrdiff_t>((from + 1) * w),
              ds.x.begin() + static_cast<std::ptrdiff_t>(to * w));
    ds.labels[to] = ys[from];
  }
  ds.num_classes = *std::max_element(ds.labels.begin(), ds.labels.end()) + 1;  // PyG: y.max() + 1

  for (const auto& [key, neighbours] : graph.adjacency) {
    for (const auto v : neighbours) {
      if (key < 0 || key >= ds.num_nodes || v < 0 || v >= ds.num_nodes)
        throw std::runtime_error(graph_path + ": edge (" + std::to_string(key) + ", " +
                                 std::to_string(v) + ") outside the nodes 0.." +
                                 std::to_string(ds.num_nodes - 1));
      if (key != v) ds.edges.push_back({std::min(key, v), std::max(key, v)});
    }
  }
  std::sort(ds.edges.begin(), ds.edges.end());
  ds.edges.erase(std::unique(ds.edges.begin(), ds.edges.end()), ds.edges.end());
  return ds;
}

}  // namespace topos::data
