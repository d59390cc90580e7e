// Tests of topos/data/graph_datasets.hpp. Always: small hand-written TU, DGCNN and Planetoid
// inputs (the pickles spelled out opcode by opcode by a writer here) covering duplicate edges,
// self-loops, isolated nodes, label remapping, Citeseer's missing test nodes, TopoBench's
// features, and each kind of bad input with the file and line its error must name. With
// TOPOS_DATASETS_DIR: every TopoBench dataset loads with the counts of the datasets README, and
// the TU / DGCNN graphs equal a brute-force re-read by a different, simpler parser.
#include <catch2/catch.hpp>

#include "support/fresh_dir.hpp"

#include "support/reference.hpp"
#include "topos/data/graph_datasets.hpp"

#include <chrono>
#include <cstring>
#include <fstream>
#include <iostream>
#include <map>
#include <set>
#include <sstream>

#ifdef TOPOS_WITH_LIBZIP
#include <zip.h>
#endif

using namespace topos::data;
namespace fs = std::filesystem;

namespace {

void write(const fs::path& p, const std::string& text) {
  fs::create_directories(p.parent_path());
  std::ofstream(p, std::ios::binary) << text;
}

/// Runs f, which must throw a std::runtime_error whose message contains every part.
template <class F>
void expect_error(F&& f, const std::vector<std::string>& parts) {
  try {
    f();
  } catch (const std::runtime_error& e) {
    const std::string what = e.what();
    INFO(what);
    for (const auto& p : parts) CHECK(what.find(p) != std::string::npos);
    return;
  }
  FAIL("no error; expected one mentioning " + parts.front());
}

// A small TU set: graph 1 has nodes 1..4 (edge 1-2 three times in both directions, 2-3 both
// ways, a self-loop on 3, node 4 isolated); graph 2 has nodes 5, 6 and the edge 5-6.
struct TuSet {
  std::string A = "1, 2\n2, 1\n1,2\n2, 3\n3, 2\n3, 3\n6, 5\n5, 6\n";
  std::string graph_indicator = "1\n1\n1\n1\n2\n2\n";
  std::string graph_labels = "5\n-1\n";
  std::string node_labels = "3\n4\n3\n6\n3\n5\n";
  // Aligned with A; the self-loop's 7 still counts towards the one-hot width, as in PyG.
  std::string edge_labels = "2\n2\n2\n1\n1\n7\n1\n1\n";

  fs::path write_to(const std::string& dir_name, const std::string& prefix = "TOY") const {
    const auto d = topos::testing::fresh_dir("graph_datasets_" + dir_name);
    write(d / (prefix + "_A.txt"), A);
    write(d / (prefix + "_graph_indicator.txt"), graph_indicator);
    write(d / (prefix + "_graph_labels.txt"), graph_labels);
    if (!node_labels.empty()) write(d / (prefix + "_node_labels.txt"), node_labels);
    if (!edge_labels.empty()) write(d / (prefix + "_edge_labels.txt"), edge_labels);
    return d;
  }
};

using Edges = std::vector<std::array<std::int64_t, 2>>;

// --- A pickle writer: the opcodes of Python 2's pickle.dump(obj, f, 2) of NumPy and SciPy
// objects, spelled out (not the reader's code run backwards).
struct Pickle {
  std::string b;
  Pickle() { b += "\x80\x02"; }  // PROTO 2
  void op(char c) { b += c; }
  void global(const std::string& module, const std::string& name) {
    b += 'c' + module + '\n' + name + '\n';
  }
  void put(int k) { b += 'q', b += static_cast<char>(k); }
  void integer(std::int64_t v) {
    if (v >= 0 && v < 256) {
      b += 'K', b += static_cast<char>(v);
    } else if (v >= 0 && v < 65536) {
      b += 'M', b += static_cast<char>(v & 255), b += static_cast<char>(v >> 8);
    } else {
      b += 'J';
      for (int k = 0; k < 4; ++k)
        b += static_cast<char>((static_cast<std::uint32_t>(v) >> (8 * k)) & 255);
    }
  }
  void str(const std::string& s) {
    if (s.size() < 256) {
      b += 'U', b += static_cast<char>(s.size());
    } else {
      b += 'T';
      for (int k = 0; k < 4; ++k) b += static_cast<char>((s.size() >> (8 * k)) & 255);
    }
    b += s;
  }
  /// numpy.core.multiarray._reconstruct(ndarray, (0,), 'b') then its __setstate__.
  template <class T>
  void ndarray(const std::vector<std::int64_t>& shape, const std::vector<T>& values,
               const std::string& dtype) {
    global("numpy.core.multiarray", "_reconstruct");
    global("numpy", "ndarray");
    integer(0), op('\x85');  // (0,)
    str("b"), op('\x87'), op('R');
    op('(');
    integer(1);
    for (auto s : shape) integer(s);
    op(shape.size() == 1 ? '\x85' : '\x86');
    global("numpy", "dtype");
    str(dtype), integer(0), integer(1), op('\x87'), op('R');
    op('('), integer(3), str("<"), op('N'), op('N'), op('N'), integer(-1), integer(-1), integer(0);
    op('t'), op('b');
    op('\x89');  // NEWFALSE: C order
    std::string raw(values.size() * sizeof(T), '\0');
    std::memcpy(raw.data(), values.data(), raw.size());
    str(raw);
    op('t'), op('b');
  }
  std::string stop() { return b + '.'; }
};

std::string csr_pickle(std::int64_t rows, std::int64_t cols,
                       const std::vector<std::int32_t>& indptr,
                       const std::vector<std::int32_t>& indices, const std::vector<float>& data) {
  Pickle p;
  p.global("scipy.sparse.csr", "csr_matrix"), p.put(1);
  p.op(')'), p.op('\x81'), p.put(2);  // csr_matrix.__new__(csr_matrix)
  p.op('}'), p.put(3), p.op('(');
  p.str("format"), p.str("csr");
  p.str("_shape"), p.integer(rows), p.integer(cols), p.op('\x86');
  p.str("indptr"),
      p.ndarray<std::int32_t>({static_cast<std::int64_t>(indptr.size())}, indptr, "i4");
  p.str("_cs_matrix__has_sorted_indices"), p.op('\x88');
  p.str("indices"),
      p.ndarray<std::int32_t>({static_cast<std::int64_t>(indices.size())}, indices, "i4");
  p.str("maxprint"), p.integer(50);
  p.str("data"), p.ndarray<float>({static_cast<std::int64_t>(data.size())}, data, "f4");
  p.op('u'), p.op('b');
  return p.stop();
}

/// A dense matrix as CSR (zeros left out).
std::string csr_pickle(const std::vector<std::vector<float>>& dense, std::int64_t cols) {
  std::vector<std::int32_t> indptr{0}, indices;
  std::vector<float> data;
  for (const auto& row : dense) {
    for (std::size_t c = 0; c < row.size(); ++c)
      if (row[c] != 0) indices.push_back(static_cast<std::int32_t>(c)), data.push_back(row[c]);
    indptr.push_back(static_cast<std::int32_t>(indices.size()));
  }
  return csr_pickle(static_cast<std::int64_t>(dense.size()), cols, indptr, indices, data);
}

/// One-hot labels as a 2-D int32 ndarray (rows x classes).
std::string one_hot_pickle(const std::vector<int>& labels, int classes) {
  std::vector<std::int32_t> v(labels.size() * static_cast<std::size_t>(classes), 0);
  for (std::size_t r = 0; r < labels.size(); ++r)
    if (labels[r] >= 0)
      v[r * static_cast<std::size_t>(classes) + static_cast<std::size_t>(labels[r])] = 1;
  Pickle p;
  p.ndarray<std::int32_t>({static_cast<std::int64_t>(labels.size()), classes}, v, "i4");
  return p.stop();
}

/// defaultdict(list) of adjacency lists.
std::string graph_pickle(const std::vector<std::pair<int, std::vector<int>>>& adjacency) {
  Pickle p;
  p.global("collections", "defaultdict"), p.put(1);
  p.global("__builtin__", "list"), p.put(2), p.op('\x85'), p.op('R'), p.put(3);
  p.op('(');
  for (const auto& [key, list] : adjacency) {
    p.integer(key), p.op(']');
    if (list.size() == 1) {
      p.integer(list[0]), p.op('a');
    } else if (!list.empty()) {
      p.op('(');
      for (auto v : list) p.integer(v);
      p.op('e');
    }
  }
  p.op('u');
  return p.stop();
}

// A tiny Planetoid set: 3 labelled nodes (allx, ally), a test block, 2 features, 3 classes.
struct PlanetoidSet {
  std::vector<std::vector<float>> allx{{1, 0}, {0, 2}, {3, 3}};
  std::vector<int> ally{2, 0, 1};
  std::vector<std::vector<float>> tx{{5, 0}, {0, 7}};
  std::vector<int> ty{1, 2};
  std::string test_index = "4\n3\n";  // 5 nodes
  std::vector<std::pair<int, std::vector<int>>> graph{
      {0, {1, 1, 0}}, {1, {0, 2}}, {2, {1}}, {3, {4}}, {4, {3, 3}}};

  fs::path write_to(const std::string& dir_name, const std::string& name) const {
    const auto d = topos::testing::fresh_dir("graph_datasets_" + dir_name);
    const auto f = [&](const std::string& part) { return d / ("ind." + name + "." + part); };
    write(f("x"), csr_pickle({allx[0]}, 2));
    write(f("y"), one_hot_pickle({ally[0]}, 3));
    write(f("allx"), csr_pickle(allx, 2));
    write(f("ally"), one_hot_pickle(ally, 3));
    write(f("tx"), csr_pickle(tx, 2));
    write(f("ty"), one_hot_pickle(ty, 3));
    write(f("graph"), graph_pickle(graph));
    write(f("test.index"), test_index);
    return d;
  }
};

}  // namespace

// --- TU ------------------------------------------------------------------------------------

TEST_CASE("TU reader: duplicates, self-loops, isolated nodes and label remapping as PyG",
          "[graph_datasets]") {
  const auto dir = TuSet{}.write_to("tu_basic");
  const auto ds = read_tu_dataset(dir, "TOY");
  CHECK(ds.name == "TOY");
  REQUIRE(ds.graphs.size() == 2);
  // Graph labels 5, -1 -> sorted classes {-1, 5}.
  CHECK(ds.class_values == std::vector<std::int64_t>{-1, 5});
  CHECK(ds.num_classes == 2);
  CHECK(ds.graphs[0].label == 1);
  CHECK(ds.graphs[1].label == 0);
  // Node labels 3..6 shifted by the minimum 3: width 4 (label 2+3=5 appears, all in range).
  CHECK(ds.num_node_labels == 4);
  CHECK(ds.graphs[0].node_labels == std::vector<std::int64_t>{0, 1, 0, 3});
  CHECK(ds.graphs[1].node_labels == std::vector<std::int64_t>{0, 2});
  // Edge labels 1..7 shifted by 1: width 7 although 7 sits only on the removed self-loop.
  CHECK(ds.num_edge_labels == 7);
  CHECK(ds.graphs[0].num_nodes == 4);  // node 4 is isolated and kept
  CHECK(ds.graphs[0].edges == Edges{{0, 1}, {1, 2}});
  CHECK(ds.graphs[0].edge_labels == std::vector<std::int64_t>{1, 0});
  CHECK(ds.graphs[1].num_nodes == 2);
  CHECK(ds.graphs[1].edges == Edges{{0, 1}});
  CHECK(ds.graphs[1].edge_labels == std::vector<std::int64_t>{0});
  CHECK(ds.num_node_features == 0);
  CHECK(ds.graphs[0].x.empty());
}

TEST_CASE("TU reader: optional label files, CRLF, a last line without newline",
          "[graph_datasets]") {
  TuSet s;
  s.node_labels.clear();
  s.edge_labels.clear();
  s.A = "1, 2\r\n2, 1\r\n5, 6";  // no final newline: still read
  const auto ds = read_tu_dataset(s.write_to("tu_plain"), "TOY");
  CHECK(ds.num_node_labels == 0);
  CHECK(ds.num_edge_labels == 0);
  CHECK(ds.graphs[0].node_labels.empty());
  CHECK(ds.graphs[0].edges == Edges{{0, 1}});
  CHECK(ds.graphs[1].edges == Edges{{0, 1}});
}

#ifdef TOPOS_WITH_LIBZIP
TEST_CASE("TU and DGCNN readers: a zip reads as its folder", "[graph_datasets]") {
  const TuSet s;
  const auto dir = topos::testing::fresh_dir("graph_datasets_tu_zip");
  const auto zip_path = dir / "TOY.zip";
  {
    int err = 0;
    zip_t* z = zip_open(zip_path.string().c_str(), ZIP_CREATE | ZIP_TRUNCATE, &err);
    REQUIRE(z != nullptr);
    const std::vector<std::pair<std::string, const std::string*>> entries{
        {"TOY/TOY_A.txt", &s.A},
        {"TOY/TOY_graph_indicator.txt", &s.graph_indicator},
        {"TOY/TOY_graph_labels.txt", &s.graph_labels},
        {"TOY/TOY_node_labels.txt", &s.node_labels},
        {"TOY/TOY_edge_labels.txt", &s.edge_labels}};
    static const std::string dgcnn = "1\n2 0\n0 1 1\n0 1 0\n";
    for (const auto& [name, text] : entries) {
      zip_source_t* src = zip_source_buffer(z, text->data(), text->size(), 0);
      REQUIRE(zip_file_add(z, name.c_str(), src, ZIP_FL_OVERWRITE) >= 0);
    }
    zip_source_t* src = zip_source_buffer(z, dgcnn.data(), dgcnn.size(), 0);
    REQUIRE(zip_file_add(z, "TOY/TOY.txt", src, ZIP_FL_OVERWRITE) >= 0);
    REQUIRE(zip_close(z) == 0);
  }
  const auto a = read_tu_dataset(zip_path, "TOY");
  const auto b = read_tu_dataset(s.write_to("tu_zip_folder"), "TOY");
  REQUIRE(a.graphs.size() == b.graphs.size());
  for (std::size_t g = 0; g < a.graphs.size(); ++g) {
    CHECK(a.graphs[g].edges == b.graphs[g].edges);
    CHECK(a.graphs[g].node_labels == b.graphs[g].node_labels);
    CHECK(a.graphs[g].edge_labels == b.graphs[g].edge_labels);
    CHECK(a.graphs[g].label == b.graphs[g].label);
  }
  const auto d = read_dgcnn_dataset(zip_path, "TOY");
  REQUIRE(d.graphs.size() == 1);
  CHECK(d.graphs[0].edges == Edges{{0, 1}});
  // Errors inside a zip name the zip and the entry.
  expect_error([&] { read_tu_dataset(zip_path, "OTHER"); }, {"TOY.zip", "no entry OTHER_A.txt"});
  write(dir / "bad.zip", "this is not a zip archive");
  expect_error([&] { read_tu_dataset(dir / "bad.zip", "TOY"); }, {"bad.zip"});
}
#endif

TEST_CASE("TU reader: bad input names the file and line", "[graph_datasets]") {
  const auto run = [](const TuSet& s) { return read_tu_dataset(s.write_to("tu_bad"), "TOY"); };
  SECTION("node id out of range") {
    TuSet s;
    s.A = "1, 2\n2, 1\n1, 9\n";
    s.edge_labels.clear();
    expect_error([&] { run(s); }, {"TOY_A.txt:3:", "node id 9 outside 1..6"});
  }
  SECTION("a non-integer token") {
    TuSet s;
    s.A = "1, 2\n2, x\n";
    s.edge_labels.clear();
    expect_error([&] { run(s); }, {"TOY_A.txt:2:", "'x' is not an integer"});
  }
  SECTION("a truncated line") {
    TuSet s;
    s.A = "1, 2\n2,";
    s.edge_labels.clear();
    expect_error([&] { run(s); }, {"TOY_A.txt:2:", "is not an integer"});
  }
  SECTION("a line without a comma") {
    TuSet s;
    s.A = "1, 2\n2 1\n";
    s.edge_labels.clear();
    expect_error([&] { run(s); }, {"TOY_A.txt:2:", "expected an edge"});
  }
  SECTION("an empty line") {
    TuSet s;
    s.graph_indicator = "1\n1\n\n1\n2\n2\n";
    expect_error([&] { run(s); }, {"TOY_graph_indicator.txt:3:", "empty line"});
  }
  SECTION("a graph id beyond the graph labels") {
    TuSet s;
    s.graph_indicator = "1\n1\n1\n1\n2\n3\n";
    expect_error([&] { run(s); }, {"TOY_graph_indicator.txt:6:", "graph id 3 outside 1..2"});
  }
  SECTION("a graph without nodes") {
    TuSet s;
    s.graph_labels = "5\n-1\n0\n";
    expect_error([&] { run(s); }, {"TOY_graph_indicator.txt:6:", "graphs 3..3 have no nodes"});
  }
  SECTION("nodes not grouped by graph") {
    TuSet s;
    s.graph_indicator = "1\n1\n2\n1\n2\n2\n";
    expect_error([&] { run(s); }, {"TOY_graph_indicator.txt:4:", "grouped by graph"});
  }
  SECTION("a missing node label") {
    TuSet s;
    s.node_labels = "3\n4\n3\n6\n3\n";
    expect_error([&] { run(s); }, {"TOY_node_labels.txt:6:", "missing node label"});
  }
  SECTION("more node labels than nodes") {
    TuSet s;
    s.node_labels += "1\n";
    expect_error([&] { run(s); }, {"TOY_node_labels.txt:7:", "more labels than the 6 nodes"});
  }
  SECTION("a missing edge label") {
    TuSet s;
    s.edge_labels = "2\n2\n2\n1\n1\n7\n1\n";
    expect_error([&] { run(s); }, {"TOY_edge_labels.txt:8:", "missing edge label"});
  }
  SECTION("copies of an edge with different labels") {
    TuSet s;
    s.edge_labels = "2\n2\n3\n1\n1\n7\n1\n1\n";
    expect_error([&] { run(s); },
                 {"TOY_edge_labels.txt:3:", "edge (1, 2) has label 3 here but 2 at line 1"});
  }
  SECTION("an edge between two graphs") {
    TuSet s;
    s.A = "1, 5\n";
    s.edge_labels.clear();
    expect_error([&] { run(s); }, {"TOY_A.txt:1:", "joins graph 1 and graph 2"});
  }
  SECTION("an empty graph label file") {
    TuSet s;
    s.graph_labels = "";
    expect_error([&] { run(s); }, {"TOY_graph_labels.txt:1:", "no graph labels"});
  }
  SECTION("a label out of the 64-bit range") {
    TuSet s;
    s.graph_labels = "5\n99999999999999999999\n";
    expect_error([&] { run(s); }, {"TOY_graph_labels.txt:2:", "out of the 64-bit range"});
  }
  SECTION("multi-column labels") {
    TuSet s;
    s.node_labels = "3, 1\n4\n3\n6\n3\n5\n";
    expect_error([&] { run(s); }, {"TOY_node_labels.txt:1:", "multi-column"});
  }
  SECTION("a missing file") {
    const auto d = TuSet{}.write_to("tu_bad");
    fs::remove(d / "TOY_graph_indicator.txt");
    expect_error([&] { read_tu_dataset(d, "TOY"); }, {"TOY_graph_indicator.txt", "no such file"});
  }
}

// --- DGCNN ---------------------------------------------------------------------------------

namespace {
// Graph 1: a duplicate neighbour (0 lists 1 twice) and a self-loop on node 2; graph 2: one
// isolated node with tag 5; graph 3: one edge. Labels 2, 0, 7 -> classes 1, 0, 2.
const std::string kDgcnn =
    "3\n"
    "3 2\n0 2 1 1\n1 2 0 2\n0 2 1 2\n"
    "1 0\n5 0\n"
    "2 7\n0 1 1\n0 1 0\n";
}  // namespace

TEST_CASE("DGCNN reader: duplicates, self-loops, isolated nodes, sorted labels",
          "[graph_datasets]") {
  const auto ds = parse_dgcnn_dataset({"toy.txt", kDgcnn}, "toy");
  REQUIRE(ds.graphs.size() == 3);
  CHECK(ds.class_values == std::vector<std::int64_t>{0, 2, 7});
  CHECK(ds.graphs[0].label == 1);
  CHECK(ds.graphs[1].label == 0);
  CHECK(ds.graphs[2].label == 2);
  CHECK(ds.graphs[0].num_nodes == 3);
  CHECK(ds.graphs[0].edges == Edges{{0, 1}, {1, 2}});
  CHECK(ds.graphs[1].num_nodes == 1);
  CHECK(ds.graphs[1].edges.empty());
  CHECK(ds.graphs[2].edges == Edges{{0, 1}});
  CHECK(ds.num_node_labels == 6);  // tags 0..5
  CHECK(ds.graphs[0].node_labels == std::vector<std::int64_t>{0, 1, 0});
  CHECK(ds.graphs[1].node_labels == std::vector<std::int64_t>{5});
  // From a file: the same.
  const auto dir = topos::testing::fresh_dir("graph_datasets_dgcnn");
  write(dir / "toy.txt", kDgcnn);
  CHECK(read_dgcnn_dataset(dir / "toy.txt", "toy").graphs[0].edges == Edges{{0, 1}, {1, 2}});
}

TEST_CASE("DGCNN reader: bad input names the file and line", "[graph_datasets]") {
  const auto run = [](const std::string& text) {
    return parse_dgcnn_dataset({"toy.txt", text}, "toy");
  };
  expect_error([&] { run("3\n3 2\n0 2 1\n"); }, {"toy.txt:3:", "degree 2 but 1 values follow"});
  expect_error([&] { run("1\n2 0\n0 1 2\n0 1 0\n"); }, {"toy.txt:3:", "neighbour 2 outside 0..1"});
  expect_error([&] { run("2\n2 0\n0 1 1\n0 1 0\n"); },
               {"toy.txt:5:", "unexpected end of file", "graph 2 of 2"});
  expect_error([&] { run("1\n2 0\n0 1 1\n"); }, {"toy.txt:4:", "unexpected end of file", "node 1"});
  expect_error([&] { run("1\n2 zero\n"); }, {"toy.txt:2:", "'zero' is not an integer"});
  expect_error([&] { run("1\n1 0\n0 0\n1 0\n"); },
               {"toy.txt:4:", "unexpected content after the 1 graphs"});
  expect_error([&] { run("1\n1 0 4\n0 0\n"); }, {"toy.txt:2:", "expected 'n label'"});
  expect_error([&] { run("0\n"); }, {"toy.txt:1:", "must be positive"});
  expect_error([&] { run(""); }, {"toy.txt:1:", "unexpected end of file"});
  expect_error([&] { run("1\n1 0\n0 0 0.5\n"); },
               {"toy.txt:3:", "node attributes are not supported"});
}

// --- Planetoid -----------------------------------------------------------------------------

TEST_CASE("Planetoid pickles: CSR, ndarray and graph dict read as Python reads them",
          "[graph_datasets]") {
  // Duplicate CSR entries are summed (scipy's todense).
  const auto m =
      read_planetoid_pickle(csr_pickle(2, 3, {0, 2, 3}, {1, 1, 0}, {0.5f, 2.0f, 4.0f}), "m");
  CHECK(m.kind == PlanetoidPickle::Kind::Matrix);
  CHECK(m.rows == 2);
  CHECK(m.cols == 3);
  CHECK(m.values == std::vector<float>{0, 2.5f, 0, 4, 0, 0});
  const auto y = read_planetoid_pickle(one_hot_pickle({1, 0}, 2), "y");
  CHECK(y.values == std::vector<float>{0, 1, 1, 0});
  const auto g = read_planetoid_pickle(graph_pickle({{0, {1, 2}}, {2, {0}}, {1, {}}}), "g");
  REQUIRE(g.kind == PlanetoidPickle::Kind::Graph);
  REQUIRE(g.adjacency.size() == 3);
  CHECK(g.adjacency[0] == std::pair<std::int64_t, std::vector<std::int64_t>>{0, {1, 2}});
  CHECK(g.adjacency[2] == std::pair<std::int64_t, std::vector<std::int64_t>>{2, {0}});
}

TEST_CASE("Planetoid reader: Citeseer's missing test nodes and the test permutation as PyG",
          "[graph_datasets]") {
  PlanetoidSet s;
  s.test_index = "5\n3\n";  // the block spans 3..5 and node 4 has no test row
  s.graph = {{0, {1, 1, 0}}, {1, {0, 2}}, {2, {1}}, {3, {5}}, {4, {}}, {5, {3, 3}}};
  const auto ds = read_planetoid_dataset(s.write_to("citeseer", "citeseer"), "citeseer");
  CHECK(ds.num_nodes == 6);
  CHECK(ds.num_node_features == 2);
  CHECK(ds.num_classes == 3);
  // Block rows: 3 <- tx[0] (sorted index 3), 4 <- zeros, 5 <- tx[1]; then x[test_index] =
  // x[sorted]: x[5] = tx[0], x[3] = tx[1].
  CHECK(ds.x == std::vector<float>{1, 0, 0, 2, 3, 3, 0, 7, 0, 0, 5, 0});
  CHECK(ds.labels == std::vector<std::int64_t>{2, 0, 1, 2, 0, 1});  // node 4: zero row -> 0
  // Self-loop 0-0 and the duplicates dropped; node 4 isolated.
  CHECK(ds.edges == Edges{{0, 1}, {1, 2}, {3, 5}});
}

TEST_CASE("Planetoid reader: Cora-style test block (no gaps)", "[graph_datasets]") {
  PlanetoidSet s;
  s.tx = {{5, 0}, {0, 7}, {1, 1}};
  s.ty = {1, 2, 0};
  s.test_index = "5\n3\n4\n";  // sorted 3, 4, 5
  s.graph = {{0, {1}}, {3, {5}}};
  const auto ds = read_planetoid_dataset(s.write_to("cora", "cora"), "Cora");
  CHECK(ds.name == "Cora");
  CHECK(ds.num_nodes == 6);
  CHECK(ds.edges == Edges{{0, 1}, {3, 5}});
  // x[5] = tx[0], x[3] = tx[1], x[4] = tx[2].
  CHECK(ds.x == std::vector<float>{1, 0, 0, 2, 3, 3, 0, 7, 1, 1, 5, 0});
  CHECK(ds.labels == std::vector<std::int64_t>{2, 0, 1, 2, 0, 1});
}

TEST_CASE("Planetoid reader: bad input names the file", "[graph_datasets]") {
  const auto write_set = [](const PlanetoidSet& s) { return s.write_to("planetoid_bad", "cora"); };
  SECTION("an opcode outside the subset") {
    const auto d = write_set(PlanetoidSet{});
    // Protocol 3's BINUNICODE 'X' where Python 2 wrote SHORT_BINSTRING.
    write(d / "ind.cora.tx", std::string("\x80\x02X\x01\x00\x00\x00"
                                         "a.",
                                         10));
    expect_error([&] { read_planetoid_dataset(d, "cora"); },
                 {"ind.cora.tx: offset 2:", "unsupported pickle opcode 0x58"});
  }
  SECTION("a truncated pickle") {
    const auto d = write_set(PlanetoidSet{});
    const auto full = csr_pickle({{1, 0}, {0, 2}, {3, 3}}, 2);
    write(d / "ind.cora.allx", full.substr(0, full.size() - 20));
    expect_error([&] { read_planetoid_dataset(d, "cora"); },
                 {"ind.cora.allx: offset", "truncated"});
  }
  SECTION("an ndarray whose data does not match its shape") {
    const auto d = write_set(PlanetoidSet{});
    Pickle p;
    p.ndarray<std::int32_t>({3, 3}, {1, 0, 0, 0, 1, 0, 0, 0}, "i4");
    write(d / "ind.cora.ally", p.stop());
    expect_error([&] { read_planetoid_dataset(d, "cora"); },
                 {"ind.cora.ally: offset", "needs 36 bytes"});
  }
  SECTION("a CSR column out of range") {
    const auto d = write_set(PlanetoidSet{});
    write(d / "ind.cora.tx", csr_pickle(2, 2, {0, 1, 2}, {0, 2}, {1, 1}));
    expect_error([&] { read_planetoid_dataset(d, "cora"); },
                 {"ind.cora.tx", "column 2 outside 0..1"});
  }
  SECTION("a test index listed twice") {
    PlanetoidSet s;
    s.test_index = "3\n4\n3\n";
    s.tx.push_back({1, 1});
    s.ty.push_back(0);
    expect_error([&] { read_planetoid_dataset(write_set(s), "cora"); },
                 {"ind.cora.test.index:3:", "test index 3 listed twice (also at line 1)"});
  }
  SECTION("a test index out of range") {
    PlanetoidSet s;
    s.test_index = "3\n9\n";
    expect_error([&] { read_planetoid_dataset(write_set(s), "cora"); },
                 {"ind.cora.test.index:2:", "test index 9 outside 0..4"});
  }
  SECTION("a non-integer test index") {
    PlanetoidSet s;
    s.test_index = "3\nfour\n";
    expect_error([&] { read_planetoid_dataset(write_set(s), "cora"); },
                 {"ind.cora.test.index:2:", "'four' is not an integer"});
  }
  SECTION("tx and ty disagree") {
    PlanetoidSet s;
    s.ty.push_back(0);
    expect_error([&] { read_planetoid_dataset(write_set(s), "cora"); },
                 {"ind.cora.ty", "3 rows", "ind.cora.tx has 2"});
  }
  SECTION("Citeseer: tx and test.index disagree") {
    PlanetoidSet s;
    s.test_index = "5\n3\n4\n";
    expect_error(
        [&] { read_planetoid_dataset(s.write_to("planetoid_bad", "citeseer"), "citeseer"); },
        {"ind.citeseer.tx", "2 rows", "lists 3 test nodes"});
  }
  SECTION("Citeseer: test indices spanning too many rows") {
    PlanetoidSet s;
    s.test_index = "3\n100000000\n";
    expect_error(
        [&] { read_planetoid_dataset(s.write_to("planetoid_bad", "citeseer"), "citeseer"); },
        {"ind.citeseer.test.index:2:", "test indices span 99999998 rows, too many"});
  }
  SECTION("a matrix over the entry limit") {
    expect_error(
        [&] {
          read_planetoid_pickle(csr_pickle({{1, 2, 3}, {4, 5, 6}}, 3), "m.pkl", 5);
        },
        {"m.pkl", "a 2 x 3 matrix is over the limit of 5 entries"});
  }
  SECTION("a graph entry outside the nodes") {
    PlanetoidSet s;
    s.graph.push_back({7, {2}});
    expect_error([&] { read_planetoid_dataset(write_set(s), "cora"); },
                 {"ind.cora.graph", "edge (7, 2) outside the nodes 0..4"});
  }
  SECTION("the graph where a matrix belongs") {
    const auto d = write_set(PlanetoidSet{});
    write(d / "ind.cora.x", graph_pickle({{0, {1}}}));
    expect_error([&] { read_planetoid_dataset(d, "cora"); }, {"ind.cora.x", "expected a matrix"});
  }
  SECTION("a missing file") {
    const auto d = write_set(PlanetoidSet{});
    fs::remove(d / "ind.cora.ally");
    expect_error([&] { read_planetoid_dataset(d, "cora"); }, {"ind.cora.ally", "no such file"});
  }
  SECTION("pickle machine errors") {
    const auto bad = [](const std::string& bytes, const std::string& what) {
      expect_error([&] { read_planetoid_pickle(bytes, "p.pkl"); }, {"p.pkl: offset", what});
    };
    bad(std::string("\x80\x02N", 3), "no STOP");
    bad(std::string("\x80\x02t.", 4), "no MARK");
    bad(std::string("\x80\x02\x85.", 4), "stack underflow");
    bad(std::string("\x80\x02h\x05.", 5), "never stored");
    bad(std::string("\x80\x02"
                    "cos\nsystem\n.",
                    14),
        "unsupported global");
    bad("\x80\x02N" + std::string(20, '\x85') + ".", "nested too deeply");
    bad(std::string("\x80\x02]K\x01K\x02.", 8), "STOP with 3 stack items");
    bad(std::string("\x80\x02N.N", 5), "bytes after the STOP");
    bad(std::string("\x80\x03N.", 4), "expected PROTO 2");
    bad(std::string("N.", 2), "not a protocol-2 pickle");
    bad(std::string("\x80\x02]]a.", 6), "a list item is a list");
    bad(std::string("\x80\x02}(]K\x01u.", 9), "dict key that is a list");
    bad(std::string("\x80\x02T\xff\xff\xff\xff", 7), "negative string length");
    bad(std::string("\x80\x02T\x00\x00\x01\x00"
                    "ab",
                    9),
        "truncated pickle");
  }
}

// --- TopoBench features --------------------------------------------------------------------

TEST_CASE("torch_cpu_normal reproduces torch.normal on the CPU", "[graph_datasets]") {
  // /usr/bin/python3 -c "import torch; torch.manual_seed(42);
  //   print([float(a) for a in torch.normal(mean=0, std=0.1, size=(1, 10))[0]])"  (torch 1.13)
  const std::vector<float> seed42{
      0.033669035881757736f, 0.012880940921604633f,  0.023446235805749893f, 0.023033302277326584f,
      -0.11228563636541367f, -0.018632829189300537f, 0.2208201289176941f,   -0.06379970908164978f,
      0.046165723353624344f, 0.026735085994005203f};
  CHECK(topos::data::graph_io::torch_cpu_normal(42, 10, 0.0, 0.1) == seed42);
  const std::vector<float> seed0{
      0.15409961342811584f,  -0.0293428897857666f,  -0.21787893772125244f, 0.05684312805533409f,
      -0.10845223069190979f, -0.13985954225063324f, 0.040334682911634445f, 0.08380263298749924f,
      -0.07192575931549072f, -0.04033435136079788f};
  CHECK(topos::data::graph_io::torch_cpu_normal(0, 10, 0.0, 0.1) == seed0);
}

TEST_CASE("TopoBench features on hand-written datasets", "[graph_datasets]") {
  const auto root = topos::testing::fresh_dir("graph_datasets_topobench_root");
  SECTION("IMDB: one-hot degree over 0..135, every edge listed four times") {
    // A star: node 1 joined to 2, 3, 4 (degree 3), each edge as IMDB lists it.
    std::string a;
    for (int leaf = 2; leaf <= 4; ++leaf)
      for (int k = 0; k < 2; ++k)
        a += "1, " + std::to_string(leaf) + "\n" + std::to_string(leaf) + ", 1\n";
    write(root / "tu/IMDB-BINARY/IMDB-BINARY_A.txt", a);
    write(root / "tu/IMDB-BINARY/IMDB-BINARY_graph_indicator.txt", "1\n1\n1\n1\n1\n");
    write(root / "tu/IMDB-BINARY/IMDB-BINARY_graph_labels.txt", "1\n");
    const auto ds = load_topobench_graph_dataset(root, "IMDB-BINARY");
    CHECK(ds.num_node_features == 136);
    const auto& g = ds.graphs[0];
    CHECK(g.edges == Edges{{0, 1}, {0, 2}, {0, 3}});
    REQUIRE(g.x.size() == 5 * 136);
    const std::vector<int> degree{3, 1, 1, 1, 0};  // node 5 isolated
    for (int v = 0; v < 5; ++v)
      for (int d = 0; d < 136; ++d)
        CHECK(g.x[static_cast<std::size_t>(v * 136 + d)] ==
              (d == degree[static_cast<std::size_t>(v)] ? 1.0f : 0.0f));
  }
  SECTION("IMDB: a degree above TopoBench's max_degree is an error") {
    std::string a, gi = "1\n";
    for (int leaf = 2; leaf <= 90; ++leaf) a += "1, " + std::to_string(leaf) + "\n", gi += "1\n";
    write(root / "tu/IMDB-MULTI/IMDB-MULTI_A.txt", a);
    write(root / "tu/IMDB-MULTI/IMDB-MULTI_graph_indicator.txt", gi);
    write(root / "tu/IMDB-MULTI/IMDB-MULTI_graph_labels.txt", "1\n");
    expect_error([&] { load_topobench_graph_dataset(root, "IMDB-MULTI"); },
                 {"IMDB-MULTI", "degree 89, above TopoBench's max_degree 88"});
  }
  SECTION("MUTAG: one-hot node labels and edge labels") {
    write(root / "tu/MUTAG/MUTAG_A.txt", "1, 2\n2, 1\n2, 3\n3, 2\n");
    write(root / "tu/MUTAG/MUTAG_graph_indicator.txt", "1\n1\n1\n");
    write(root / "tu/MUTAG/MUTAG_graph_labels.txt", "-1\n");
    write(root / "tu/MUTAG/MUTAG_node_labels.txt", "0\n2\n1\n");
    write(root / "tu/MUTAG/MUTAG_edge_labels.txt", "3\n3\n0\n0\n");
    const auto ds = load_topobench_graph_dataset(root, "mutag");
    CHECK(ds.name == "MUTAG");
    CHECK(ds.num_node_features == 3);
    CHECK(ds.graphs[0].x == std::vector<float>{1, 0, 0, 0, 0, 1, 0, 1, 0});
    CHECK(ds.num_edge_features == 4);
    CHECK(ds.graphs[0].edge_attr == std::vector<float>{0, 0, 0, 1, 1, 0, 0, 0});
  }
  SECTION("PROTEINS from PROTEINS_full") {
    write(root / "tu/PROTEINS_full/PROTEINS_full_A.txt", "1, 2\n2, 1\n");
    write(root / "tu/PROTEINS_full/PROTEINS_full_graph_indicator.txt", "1\n1\n");
    write(root / "tu/PROTEINS_full/PROTEINS_full_graph_labels.txt", "2\n");
    write(root / "tu/PROTEINS_full/PROTEINS_full_node_labels.txt", "2\n0\n");
    const auto ds = load_topobench_graph_dataset(root, "PROTEINS");
    CHECK(ds.name == "PROTEINS");
    CHECK(ds.graphs[0].x == std::vector<float>{0, 0, 1, 1, 0, 0});
  }
  SECTION("REDDIT-BINARY from the DGCNN file: one Gaussian vector on every node") {
    write(root / "dgcnn/REDDIT-BINARY.txt", "2\n2 2\n0 1 1\n0 1 0\n1 0\n0 0\n");
    const auto ds = load_topobench_graph_dataset(root, "REDDIT-BINARY");
    CHECK(ds.class_values == std::vector<std::int64_t>{0, 2});
    CHECK(ds.graphs[0].label == 1);
    CHECK(ds.graphs[1].label == 0);
    CHECK(ds.num_node_features == 10);
    CHECK(ds.num_node_labels == 0);
    CHECK(ds.graphs[0].node_labels.empty());
    const auto v = topos::data::graph_io::torch_cpu_normal(42, 10, 0.0, 0.1);
    std::vector<float> two = v;
    two.insert(two.end(), v.begin(), v.end());
    CHECK(ds.graphs[0].x == two);
    CHECK(ds.graphs[1].x == v);
    TopoBenchOptions o;
    o.seed = 0;
    CHECK(load_topobench_graph_dataset(root, "REDDIT-BINARY", o).graphs[1].x ==
          topos::data::graph_io::torch_cpu_normal(0, 10, 0.0, 0.1));
  }
  SECTION("unknown names and missing files") {
    try {
      load_topobench_graph_dataset(root, "ENZYMES");
      FAIL("no error");
    } catch (const std::invalid_argument& e) {
      const std::string what = e.what();
      CHECK(what.find("ENZYMES") != std::string::npos);
      for (const char* k :
           {"MUTAG", "PROTEINS", "NCI1", "NCI109", "IMDB-BINARY", "IMDB-MULTI", "REDDIT-BINARY"})
        CHECK(what.find(k) != std::string::npos);
    }
    CHECK_THROWS_WITH(load_topobench_node_dataset(root, "ogbn-arxiv"),
                      Catch::Contains("cocitation_cora") && Catch::Contains("cocitation_citeseer"));
    expect_error([&] { load_topobench_graph_dataset(root, "NCI1"); },
                 {"NCI1 not found", "tu/NCI1"});
  }
}

// --- The real datasets ---------------------------------------------------------------------

namespace {

/// A different, simpler TU parser: istream extraction, a std::set per graph.
struct BruteTu {
  std::vector<std::int64_t> graph_of;  // per node, 1-based graph id
  std::vector<std::int64_t> graph_label, node_label;
  std::map<std::int64_t, std::set<std::pair<std::int64_t, std::int64_t>>> edges;  // global 0-based
};

std::vector<std::int64_t> ints(const std::string& text) {
  std::istringstream in(text);
  std::vector<std::int64_t> v;
  std::int64_t x;
  while (in >> x) v.push_back(x);
  return v;
}

BruteTu brute_tu(const std::string& a, const std::string& gi, const std::string& gl,
                 const std::string& nl) {
  BruteTu b;
  b.graph_of = ints(gi);
  b.graph_label = ints(gl);
  b.node_label = ints(nl);
  std::istringstream in(a);
  std::int64_t u, v;
  char comma;
  while (in >> u >> comma >> v)
    if (u != v)
      b.edges[b.graph_of[static_cast<std::size_t>(u - 1)]].insert(
          {std::min(u, v) - 1, std::max(u, v) - 1});
  return b;
}

std::string slurp(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  std::ostringstream s;
  s << in.rdbuf();
  return s.str();
}

#ifdef TOPOS_WITH_LIBZIP
std::string zip_entry(const fs::path& zip, const std::string& entry) {
  int err = 0;
  zip_t* z = zip_open(zip.string().c_str(), ZIP_RDONLY, &err);
  REQUIRE(z != nullptr);
  zip_stat_t st;
  REQUIRE(zip_stat(z, entry.c_str(), 0, &st) == 0);
  std::string out(st.size, '\0');
  zip_file_t* f = zip_fopen(z, entry.c_str(), 0);
  REQUIRE(f != nullptr);
  REQUIRE(zip_fread(f, out.data(), st.size) == static_cast<zip_int64_t>(st.size));
  zip_fclose(f);
  zip_discard(z);
  return out;
}
#endif

/// The loader's graphs equal the brute-force ones: nodes, edges, labels, node labels.
void compare(const GraphClassificationDataset& ds, const BruteTu& b) {
  REQUIRE(ds.graphs.size() == b.graph_label.size());
  std::int64_t start = 0;
  const auto min_label =
      b.node_label.empty() ? 0 : *std::min_element(b.node_label.begin(), b.node_label.end());
  for (std::size_t g = 0; g < ds.graphs.size(); ++g) {
    const auto& gr = ds.graphs[g];
    const auto n =
        std::count(b.graph_of.begin(), b.graph_of.end(), static_cast<std::int64_t>(g + 1));
    REQUIRE(gr.num_nodes == n);
    CHECK(ds.class_values[static_cast<std::size_t>(gr.label)] == b.graph_label[g]);
    Edges expected;
    const auto it = b.edges.find(static_cast<std::int64_t>(g + 1));
    if (it != b.edges.end())
      for (const auto& [u, v] : it->second) expected.push_back({u - start, v - start});
    REQUIRE(gr.edges == expected);
    for (std::int64_t i = 0; i < n && !b.node_label.empty(); ++i)
      REQUIRE(gr.node_labels[static_cast<std::size_t>(i)] + min_label ==
              b.node_label[static_cast<std::size_t>(start + i)]);
    start += n;
  }
}

struct Expected {
  const char* name;
  std::int64_t graphs, nodes, edges, features, classes;
};

}  // namespace

TEST_CASE("every TopoBench graph dataset loads with the README's counts",
          "[graph_datasets][datasets]") {
  const auto root = topos::test::datasets_dir("every TopoBench graph dataset loads");
  // ../shared/datasets/README.md (the publishers' figures) and TopoBench's configs
  // (configs/dataset/graph/<name>.yaml: num_features, num_classes).
  const Expected table[] = {{"MUTAG", 188, 3371, 3721, 7, 2},
                            {"PROTEINS", 1113, 43471, 81044, 3, 2},
                            {"NCI1", 4110, 122747, 132753, 37, 2},
                            {"NCI109", 4127, 122494, 132604, 38, 2},
                            {"IMDB-BINARY", 1000, 19773, 96531, 136, 2},
                            {"IMDB-MULTI", 1500, 19502, 98903, 89, 3},
                            {"REDDIT-BINARY", 2000, 859254, 995508, 10, 2}};
  for (const auto& e : table) {
    INFO(e.name);
    const auto t0 = std::chrono::steady_clock::now();
    const auto ds = load_topobench_graph_dataset(root, e.name);
    const double ms =
        std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
    std::cout << "  " << e.name << ": loaded in " << ms << " ms\n";
    std::int64_t nodes = 0, edges = 0;
    for (const auto& g : ds.graphs) {
      nodes += g.num_nodes, edges += static_cast<std::int64_t>(g.edges.size());
      REQUIRE(g.x.size() == static_cast<std::size_t>(g.num_nodes * ds.num_node_features));
      REQUIRE(std::is_sorted(g.edges.begin(), g.edges.end()));
    }
    CHECK(static_cast<std::int64_t>(ds.graphs.size()) == e.graphs);
    CHECK(nodes == e.nodes);
    CHECK(edges == e.edges);
    CHECK(ds.num_node_features == e.features);
    CHECK(ds.num_classes == e.classes);
    if (std::string(e.name) == "MUTAG") {
      CHECK(ds.num_edge_features == 4);  // configs/dataset/graph/MUTAG.yaml: num_features [7, 4]
      CHECK(ds.class_values == std::vector<std::int64_t>{-1, 1});
    }
    if (std::string(e.name) == "REDDIT-BINARY")
      CHECK(ds.class_values == std::vector<std::int64_t>{0, 2});
  }
}

TEST_CASE("TU and DGCNN graphs equal a brute-force re-read", "[graph_datasets][datasets]") {
  const auto root = topos::test::datasets_dir("TU and DGCNN graphs equal a brute-force re-read");
  for (const auto& [name, prefix] :
       std::vector<std::pair<std::string, std::string>>{{"MUTAG", "MUTAG"},
                                                        {"PROTEINS", "PROTEINS_full"},
                                                        {"NCI1", "NCI1"},
                                                        {"NCI109", "NCI109"}}) {
    INFO(name);
    const auto dir = root / "tu" / prefix;
    const auto f = [&](const char* part) { return slurp(dir / (prefix + "_" + part + ".txt")); };
    const auto b = brute_tu(f("A"), f("graph_indicator"), f("graph_labels"), f("node_labels"));
    const auto ds = load_topobench_graph_dataset(root, name);
    compare(ds, b);
    // x is the one-hot node label.
    for (const auto& g : ds.graphs)
      for (std::int64_t v = 0; v < g.num_nodes; ++v)
        for (std::int64_t c = 0; c < ds.num_node_features; ++c)
          REQUIRE(g.x[static_cast<std::size_t>(v * ds.num_node_features + c)] ==
                  (c == g.node_labels[static_cast<std::size_t>(v)] ? 1.0f : 0.0f));
  }
#ifdef TOPOS_WITH_LIBZIP
  for (const auto& [name, max_degree] :
       std::vector<std::pair<std::string, int>>{{"IMDB-BINARY", 135}, {"IMDB-MULTI", 88}}) {
    INFO(name);
    const auto zip = root / "tu" / (name + ".zip");
    const auto e = [&](const char* part) {
      return zip_entry(zip, name + "/" + name + "_" + part + ".txt");
    };
    const auto ds = load_topobench_graph_dataset(root, name);
    compare(ds, brute_tu(e("A"), e("graph_indicator"), e("graph_labels"), ""));
    // x is the one-hot degree; the widest degree is TopoBench's max_degree (its width - 1).
    std::int64_t widest = 0;
    for (const auto& g : ds.graphs) {
      std::vector<std::int64_t> degree(static_cast<std::size_t>(g.num_nodes), 0);
      for (const auto& edge : g.edges)
        ++degree[static_cast<std::size_t>(edge[0])], ++degree[static_cast<std::size_t>(edge[1])];
      for (std::int64_t v = 0; v < g.num_nodes; ++v) {
        const auto d = degree[static_cast<std::size_t>(v)];
        widest = std::max(widest, d);
        const float* row = g.x.data() + v * ds.num_node_features;
        REQUIRE(row[d] == 1.0f);
        REQUIRE(std::count(row, row + ds.num_node_features, 0.0f) == ds.num_node_features - 1);
      }
    }
    CHECK(widest == max_degree);
  }
  {
    // REDDIT-BINARY: `n label` then `tag degree neighbours...`, read with istream extraction.
    std::istringstream in(
        zip_entry(root / "dgcnn" / "REDDIT-BINARY.zip", "REDDIT-BINARY/REDDIT-BINARY.txt"));
    const auto ds = load_topobench_graph_dataset(root, "REDDIT-BINARY");
    std::int64_t num_graphs;
    in >> num_graphs;
    REQUIRE(static_cast<std::int64_t>(ds.graphs.size()) == num_graphs);
    const auto v = topos::data::graph_io::torch_cpu_normal(42, 10, 0.0, 0.1);
    for (const auto& g : ds.graphs) {
      std::int64_t n, label;
      in >> n >> label;
      REQUIRE(g.num_nodes == n);
      REQUIRE(ds.class_values[static_cast<std::size_t>(g.label)] == label);
      std::set<std::pair<std::int64_t, std::int64_t>> edges;
      for (std::int64_t u = 0; u < n; ++u) {
        std::int64_t tag, degree, w;
        in >> tag >> degree;
        for (std::int64_t k = 0; k < degree; ++k) {
          in >> w;
          if (w != u) edges.insert({std::min(u, w), std::max(u, w)});
        }
      }
      Edges expected;
      for (const auto& [a, b] : edges) expected.push_back({a, b});
      REQUIRE(g.edges == expected);
      for (std::int64_t u = 0; u < n; ++u)
        REQUIRE(std::equal(v.begin(), v.end(), g.x.begin() + u * 10));
    }
  }
#endif
}

TEST_CASE("Cora and Citeseer load as PyG reads them", "[graph_datasets][datasets]") {
  const auto root = topos::test::datasets_dir("Cora and Citeseer load as PyG reads them");
  struct Node {
    const char* name;
    std::int64_t nodes, edges, features, classes, nonzeros;
    std::vector<std::int64_t> class_sizes;
  };
  // Nodes, edges, features, classes: the datasets README. Nonzeros and class sizes: PyG's
  // Planetoid('Cora') x.count_nonzero() and y.bincount(), re-derived here by a Python
  // re-implementation of read_planetoid_data on numpy/scipy (pickle.load(encoding='latin1')).
  const Node table[] = {
      {"cocitation_cora", 2708, 5278, 1433, 7, 49216, {351, 217, 418, 818, 426, 298, 180}},
      {"cocitation_citeseer", 3327, 4552, 3703, 6, 105165, {264, 590, 668, 701, 596, 508}}};
  for (const auto& e : table) {
    INFO(e.name);
    const auto t0 = std::chrono::steady_clock::now();
    const auto ds = load_topobench_node_dataset(root, e.name);
    const double ms =
        std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
    std::cout << "  " << e.name << ": loaded in " << ms << " ms\n";
    CHECK(ds.num_nodes == e.nodes);
    CHECK(static_cast<std::int64_t>(ds.edges.size()) == e.edges);
    CHECK(ds.num_node_features == e.features);
    CHECK(ds.num_classes == e.classes);
    REQUIRE(ds.x.size() == static_cast<std::size_t>(e.nodes * e.features));
    CHECK(std::count_if(ds.x.begin(), ds.x.end(), [](float v) { return v != 0; }) == e.nonzeros);
    std::vector<std::int64_t> sizes(static_cast<std::size_t>(e.classes), 0);
    for (auto l : ds.labels) ++sizes[static_cast<std::size_t>(l)];
    CHECK(sizes == e.class_sizes);
    for (const auto& edge : ds.edges) REQUIRE((edge[0] < edge[1] && edge[1] < ds.num_nodes));
    CHECK(std::adjacent_find(ds.edges.begin(), ds.edges.end()) == ds.edges.end());
    // The rows without any feature are exactly the indices missing from the test range (README:
    // Citeseer's 15 isolated test nodes; none for Cora), with label 0 as PyG gives them.
    const auto test = ints(
        slurp(root / "planetoid" /
              (std::string("ind.") + (e.nodes == 2708 ? "cora" : "citeseer") + ".test.index")));
    const std::set<std::int64_t> listed(test.begin(), test.end());
    std::set<std::int64_t> missing;
    for (auto i = *listed.begin(); i <= *listed.rbegin(); ++i)
      if (!listed.count(i)) missing.insert(i);
    CHECK(missing.size() == (e.nodes == 2708 ? 0u : 15u));
    std::set<std::int64_t> zero_rows;
    for (std::int64_t v = 0; v < ds.num_nodes; ++v) {
      const auto row = ds.x.begin() + v * ds.num_node_features;
      if (std::all_of(row, row + ds.num_node_features, [](float x) { return x == 0; }))
        zero_rows.insert(v);
    }
    CHECK(zero_rows == missing);
    for (auto v : missing) CHECK(ds.labels[static_cast<std::size_t>(v)] == 0);
  }
}
