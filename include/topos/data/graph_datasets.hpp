// topos/data/graph_datasets.hpp
// Readers for the raw files of the graph benchmarks TopoBench reports on, into graphs exactly as
// PyTorch Geometric holds them after reading (torch_geometric/io/tu.py, io/planetoid.py):
//  - the TU text format (MUTAG, PROTEINS, NCI1, NCI109, IMDB-BINARY, IMDB-MULTI; a folder or
//    the TU zip): self-loops removed, duplicate edges coalesced, node labels shifted by their
//    minimum, graph labels mapped to 0..C-1 in sorted order, isolated nodes kept;
//  - the DGCNN/GIN text format (our REDDIT-BINARY file);
//  - Planetoid's Python-2 pickles (Cora, Citeseer) through a small, strict pickle reader;
// and the node features TopoBench builds for each dataset (load_topobench_*). docs/datasets.md
// says what each step mirrors. std only; zipped files need libzip (the CMake target topos::data
// defines TOPOS_WITH_LIBZIP and links it). Untrusted input: counts are checked against the
// bytes before use, and bad input is a std::runtime_error naming the file and the 1-based line
// (the byte offset in a pickle); nothing half-read is returned.
//
// This header declares; graph_datasets-inl.hpp implements, compiled once into topos::data
// (src/data.cpp), or inline with TOPOS_HEADER_ONLY (topos/config.hpp).
#pragma once

#include "topos/config.hpp"

#include <array>
#include <cstdint>
#include <filesystem>
#include <optional>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

namespace topos::data {

/// One graph of a graph-classification set as PyG holds it after reading: nodes 0..n-1,
/// undirected edges (u < v), sorted lexicographically, unique, no self-loops.
struct LabeledGraph {
  std::int64_t num_nodes = 0;
  std::vector<std::array<std::int64_t, 2>> edges;
  std::vector<std::int64_t>
      node_labels;  ///< per node, 0-based (as PyG one-hots them); empty if none
  std::vector<std::int64_t> edge_labels;  ///< per edge of `edges`, 0-based; empty if none
  std::int64_t label = 0;                 ///< graph class, 0-based contiguous
  std::vector<float> x;  ///< node features, row-major num_nodes x num_node_features
  std::vector<float>
      edge_attr;  ///< edge features, row-major edges x num_edge_features; may be empty
};

struct GraphClassificationDataset {
  std::string name;
  std::vector<LabeledGraph> graphs;
  std::int64_t num_classes = 0, num_node_features = 0;
  std::int64_t num_edge_features = 0;  ///< width of edge_attr rows (0: none)
  /// One-hot widths of node_labels / edge_labels as PyG builds them (max - min + 1; 0: none).
  std::int64_t num_node_labels = 0, num_edge_labels = 0;
  std::vector<std::int64_t> class_values;  ///< the file's label of each class, ascending
};

struct NodeClassificationDataset {
  std::string name;
  std::int64_t num_nodes = 0, num_node_features = 0, num_classes = 0;
  std::vector<std::array<std::int64_t, 2>>
      edges;             ///< undirected, u < v, sorted, unique, no self-loops
  std::vector<float> x;  ///< row-major num_nodes x num_node_features
  std::vector<std::int64_t> labels;
};

/// A text file's name (as errors show it) and contents.
struct TextFile {
  std::string name;
  std::string text;
};

/// The files of one TU dataset (<prefix>_A.txt, ...); node and edge labels are optional.
struct TuFiles {
  TextFile A, graph_indicator, graph_labels;
  std::optional<TextFile> node_labels, edge_labels;
};

/// What one Planetoid pickle holds: a matrix (a scipy CSR matrix or a 2-D NumPy array, dense
/// here as PyG densifies it) or the graph (a dict of adjacency lists).
struct PlanetoidPickle {
  enum class Kind { Matrix, Graph };
  Kind kind = Kind::Matrix;
  std::int64_t rows = 0, cols = 0;
  std::vector<float> values;  ///< Matrix: row-major rows x cols
  std::vector<std::pair<std::int64_t, std::vector<std::int64_t>>> adjacency;  ///< Graph, by key
};

struct TopoBenchOptions {
  /// TopoBench's `seed` (configs/run.yaml: 42). REDDIT-BINARY's node features are the one
  /// vector `torch.manual_seed(seed); torch.normal(0, 0.1, size=(1, 10))` on every node.
  std::uint64_t seed = 42;
};

namespace graph_io {
/// PyTorch's CPU `torch.manual_seed(seed); torch.normal(mean, std, size=(n,))` for n < 16, as
/// float: its serial path draws each value with at::normal_distribution<double> (Box-Muller on
/// two 53-bit uniforms from mt19937, each made of two 32-bit outputs, high word first; the sine
/// of each pair is cached for the next value). From 16 values on PyTorch uses another path.
std::vector<float> torch_cpu_normal(std::uint64_t seed, int n, double mean, double std);
}  // namespace graph_io

/// Parses a TU dataset held in memory (read_tu_dataset reads the files). Semantics of PyG's
/// read_tu_data with use_node_attr=False: 1-based ids in _A.txt; self-loops removed; duplicate
/// edges (either direction) coalesced into one undirected edge u < v; node and edge labels
/// shifted by their minimum; graph labels mapped to 0..C-1 in sorted order. Stricter than PyG:
/// nodes must be grouped by graph in order with no graph empty, an edge must stay inside one
/// graph, and the copies of an edge must carry the same edge label (PyG would add their one-hot
/// vectors). x is left empty (num_node_features 0).
GraphClassificationDataset parse_tu_dataset(const TuFiles& f, const std::string& name);

/// Reads TU dataset `name` (the files' prefix, e.g. "MUTAG" for MUTAG_A.txt) from a folder or
/// a zip (the TU download). x is left empty; see parse_tu_dataset.
GraphClassificationDataset read_tu_dataset(const std::filesystem::path& folder_or_zip,
                                           const std::string& name);

/// Parses the DGCNN/GIN text format: a line with the number of graphs, then per graph a line
/// `n label` and n lines `tag degree neighbours...` (0-based neighbours in the graph). As for
/// TU: self-loops removed, duplicates coalesced, graph labels mapped to 0..C-1 in sorted order
/// (REDDIT-BINARY's {0, 2} become {0, 1}), tags shifted by their minimum into node_labels.
/// A line with more values than 2 + degree (node attributes) is an error.
GraphClassificationDataset parse_dgcnn_dataset(const TextFile& file, const std::string& name);

/// Reads a DGCNN-format dataset from its .txt file or from a zip holding `<name>.txt` (in any
/// folder of the zip).
GraphClassificationDataset read_dgcnn_dataset(const std::filesystem::path& txt_or_zip,
                                              const std::string& name);

/// Reads one Planetoid pickle (`source` names it in errors). Matrices are densified as PyG's
/// `out.todense()` does (duplicate CSR entries summed); one with more than `max_elements`
/// entries is refused before anything is allocated.
PlanetoidPickle read_planetoid_pickle(std::string_view bytes, const std::string& source,
                                      std::int64_t max_elements = std::int64_t{1} << 30);

/// Reads Planetoid dataset `name` ("cora", "citeseer", any case) from the ind.<name>.* files in
/// `folder`, as PyG's read_planetoid_data builds it: features allx then tx and labels ally then
/// ty (argmax of each one-hot row, 0 for an all-zero row), the test rows moved to the positions
/// test.index lists (x[test_index] = x[sorted(test_index)]); for Citeseer the test block spans
/// min..max of test.index and the 15 indices missing from it get zero features and label 0.
/// Edges from the graph dict, self-loops removed and both directions coalesced into u < v.
/// Stricter than PyG: a test index listed twice, out of range or negative, a graph entry
/// outside 0..n-1, or tx / ty / test.index disagreeing on the number of test nodes is an error.
NodeClassificationDataset read_planetoid_dataset(const std::filesystem::path& folder,
                                                 const std::string& name);

/// The graph-classification sets by TopoBench's names (MUTAG, PROTEINS, NCI1, NCI109,
/// IMDB-BINARY, IMDB-MULTI, REDDIT-BINARY) from a ../shared/datasets-like root, with x (and
/// MUTAG's edge_attr) as TopoBench builds them (configs/dataset/graph/<name>.yaml and
/// configs/transforms/dataset_defaults/<name>.yaml at 671074ab):
///  - MUTAG: x = one-hot atom type (7), edge_attr = one-hot bond type (4; PyG's edge_attr,
///    which TopoBench's clique and cycle liftings keep: preserve_edge_attr_if_lifted: True);
///  - PROTEINS (tu/PROTEINS_full/ stands in; use_node_attr=False), NCI1, NCI109: one-hot node
///    labels (3, 37, 38);
///  - IMDB-BINARY, IMDB-MULTI: one-hot degree over 0..max_node_degree (135, 88): 136, 89;
///  - REDDIT-BINARY: EqualGausFeatures, one N(0, 0.1) vector of 10 values on every node (see
///    TopoBenchOptions::seed). Read from tu/REDDIT-BINARY(.zip) when present, else from the
///    DGCNN file dgcnn/REDDIT-BINARY.zip (labels {0, 2} -> classes {0, 1}; its tags dropped, as
///    TU's REDDIT-BINARY has no node labels).
GraphClassificationDataset load_topobench_graph_dataset(const std::filesystem::path& datasets_root,
                                                        const std::string& name,
                                                        const TopoBenchOptions& options);

GraphClassificationDataset load_topobench_graph_dataset(const std::filesystem::path& datasets_root,
                                                        const std::string& name);

/// Cora / Citeseer (and PubMed, whose features are not available offline) by TopoBench's name
/// (cocitation_cora, cocitation_citeseer, cocitation_pubmed) or the plain one (Cora, CiteSeer,
/// ...; any case), from <datasets_root>/planetoid/. TopoBench applies no feature transform to
/// them: x is the raw bag-of-words matrix.
NodeClassificationDataset load_topobench_node_dataset(const std::filesystem::path& datasets_root,
                                                      const std::string& name);

}  // namespace topos::data

#ifdef TOPOS_HEADER_ONLY
#include "topos/data/graph_datasets-inl.hpp"
#endif
