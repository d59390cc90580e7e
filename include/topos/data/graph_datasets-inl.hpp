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

namespace graph_io {

namespace fs = std::filesystem;

[[noreturn]] inline void fail(const std::string& file, std::int64_t line, const std::string& what) {
  throw std::runtime_error(file + ":" + std::to_string(line) + ": " + what);
}

/// A token for an error message: quoted, at most 32 characters, non-printable bytes as '?'.
inline std::string quote(std::string_view s) {
  std::string out = "'";
  for (std::size_t i = 0; i < s.size() && i < 32; ++i) {
    const auto c = static_cast<unsigned char>(s[i]);
    out += (c >= 32 && c < 127) ? static_cast<char>(c) : '?';
  }
  return out + (s.size() > 32 ? "...'" : "'");
}

inline bool is_space(char c) {
  return c == ' ' || c == '\t' || c == '\r' || c == '\v' || c == '\f';
}

inline std::string_view trim(std::string_view s) {
  while (!s.empty() && is_space(s.front())) s.remove_prefix(1);
  while (!s.empty() && is_space(s.back())) s.remove_suffix(1);
  return s;
}

/// Lines of a text with 1-based numbers. A '\r' before the '\n' is dropped; a last line without
/// '\n' is read too (PyG's read_txt_array would silently drop it).
class Lines {
 public:
  Lines(std::string_view text, std::string file) : text_(text), file_(std::move(file)) {}
  bool next(std::string_view& line) {
    if (pos_ >= text_.size()) return false;
    auto end = text_.find('\n', pos_);
    if (end == std::string_view::npos) end = text_.size();
    line = text_.substr(pos_, end - pos_);
    if (!line.empty() && line.back() == '\r') line.remove_suffix(1);
    pos_ = end + 1;
    ++line_;
    return true;
  }
  std::int64_t line() const { return line_; }
  const std::string& file() const { return file_; }
  [[noreturn]] void fail(const std::string& what) const { graph_io::fail(file_, line_, what); }

 private:
  std::string_view text_;
  std::string file_;
  std::size_t pos_ = 0;
  std::int64_t line_ = 0;
};

/// A decimal integer with optional sign and surrounding blanks (what Python's int() takes,
/// less underscores); anything else is an error at the current line.
inline std::int64_t parse_int(std::string_view token, const Lines& at) {
  const auto t = trim(token);
  std::size_t i = 0;
  bool negative = false;
  if (i < t.size() && (t[i] == '+' || t[i] == '-')) negative = t[i++] == '-';
  if (i == t.size()) at.fail(quote(t) + " is not an integer");
  const std::uint64_t limit =
      negative ? std::uint64_t{1} << 63 : (std::uint64_t{1} << 63) - 1;  // |INT64_MIN|, INT64_MAX
  std::uint64_t v = 0;
  for (; i < t.size(); ++i) {
    if (t[i] < '0' || t[i] > '9') at.fail(quote(t) + " is not an integer");
    const auto d = static_cast<std::uint64_t>(t[i] - '0');
    if (v > (limit - d) / 10) at.fail(quote(t) + " is out of the 64-bit range");
    v = v * 10 + d;
  }
  if (!negative) return static_cast<std::int64_t>(v);
  return v == (std::uint64_t{1} << 63) ? std::numeric_limits<std::int64_t>::min()
                                       : -static_cast<std::int64_t>(v);
}

/// A line holding exactly one integer (one column of a TU file).
inline std::int64_t parse_single(std::string_view line, const Lines& at, const char* what) {
  if (trim(line).empty()) at.fail(std::string("empty line, expected ") + what);
  if (line.find(',') != std::string_view::npos)
    at.fail(std::string("expected one value (") + what +
            "), found several: multi-column label files are not supported");
  return parse_int(line, at);
}

/// One integer per line, every line of the file.
/// A labels file holds one label per line of `source`'s `count` `items` ("node", "edge"): a
/// missing or an extra label is an error naming the labels' file and line.
inline void check_label_count(const TextFile& labels, std::int64_t got, std::int64_t count,
                              const std::string& item, const std::string& source) {
  if (got < count)
    fail(labels.name, got + 1,
         "missing " + item + " label (" + source + " has " + std::to_string(count) + " " + item +
             "s)");
  if (got > count)
    fail(labels.name, count + 1,
         "more labels than the " + std::to_string(count) + " " + item + "s of " + source);
}

inline std::vector<std::int64_t> read_column(const TextFile& f, const char* what) {
  Lines in(f.text, f.name);
  std::string_view line;
  std::vector<std::int64_t> out;
  while (in.next(line)) out.push_back(parse_single(line, in, what));
  return out;
}

/// Blank-separated tokens of a line (Python's str.split()).
inline void split_blanks(std::string_view line, std::vector<std::string_view>& out) {
  out.clear();
  std::size_t i = 0;
  while (i < line.size()) {
    while (i < line.size() && is_space(line[i])) ++i;
    const std::size_t b = i;
    while (i < line.size() && !is_space(line[i])) ++i;
    if (i > b) out.push_back(line.substr(b, i - b));
  }
}

/// The widest label range a one-hot encoding may span.
inline constexpr std::uint64_t kMaxOneHotWidth = std::uint64_t{1} << 20;

/// Shifts labels so that the smallest is 0 (PyG: `label - label.min()`) and returns the one-hot
/// width PyG gives them (max - min + 1; 0 for no labels). Label i is on line i + 1, or on
/// (*lines)[i] when given.
inline std::int64_t shift_labels(std::vector<std::int64_t>& v, const std::string& file,
                                 const std::vector<std::int64_t>* lines = nullptr) {
  if (v.empty()) return 0;
  const auto [lo, hi] = std::minmax_element(v.begin(), v.end());
  const std::int64_t mn = *lo, mx = *hi;
  // Unsigned difference: exact for any pair of int64 values with mx >= mn.
  const std::uint64_t span = static_cast<std::uint64_t>(mx) - static_cast<std::uint64_t>(mn);
  if (span >= kMaxOneHotWidth)
    fail(file, lines ? (*lines)[static_cast<std::size_t>(hi - v.begin())] : 1 + (hi - v.begin()),
         "labels span " + std::to_string(mn) + ".." + std::to_string(mx) +
             ", too wide for a one-hot encoding (at most 2^20 values)");
  for (auto& x : v) x -= mn;  // in range: 0 <= x - mn < 2^20
  return static_cast<std::int64_t>(span) + 1;
}

/// Sorted distinct values and each input's index among them (torch.unique(sorted=True,
/// return_inverse=True)).
inline std::vector<std::int64_t> remap_sorted(std::vector<std::int64_t>& v) {
  std::vector<std::int64_t> values = v;
  std::sort(values.begin(), values.end());
  values.erase(std::unique(values.begin(), values.end()), values.end());
  for (auto& x : v) x = std::lower_bound(values.begin(), values.end(), x) - values.begin();
  return values;
}

/// A whole file. The size is checked against what was read, so a file that shrinks while being
/// read is an error, not a short read.
inline std::string read_bytes(const fs::path& p) {
  std::error_code ec;
  if (!fs::is_regular_file(p, ec))
    throw std::runtime_error("reading " + p.string() + ": no such file");
  std::ifstream in(p, std::ios::binary);
  if (!in) throw std::runtime_error("reading " + p.string() + ": cannot open");
  const auto size = fs::file_size(p, ec);
  if (ec) throw std::runtime_error("reading " + p.string() + ": " + ec.message());
  std::string out(size, '\0');
  in.read(out.data(), static_cast<std::streamsize>(size));
  if (static_cast<std::uintmax_t>(in.gcount()) != size)
    throw std::runtime_error("reading " + p.string() + ": read " + std::to_string(in.gcount()) +
                             " of " + std::to_string(size) + " bytes");
  return out;
}

inline bool is_zip_path(const fs::path& p) {
  std::string ext = p.extension().string();
  for (auto& c : ext) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  return ext == ".zip";
}

#ifdef TOPOS_WITH_LIBZIP
/// A zip archive opened read-only; entries are found by their file name (any folder).
class ZipArchive {
 public:
  /// Entries larger than this are refused (a forged size must not allocate gigabytes).
  static constexpr std::uint64_t kMaxEntryBytes = std::uint64_t{1} << 32;

  explicit ZipArchive(const fs::path& p) : path_(p.string()) {
    int err = 0;
    z_ = zip_open(path_.c_str(), ZIP_RDONLY, &err);
    if (z_ == nullptr) {
      zip_error_t e;
      zip_error_init_with_code(&e, err);
      const std::string msg = zip_error_strerror(&e);
      zip_error_fini(&e);
      throw std::runtime_error("reading " + path_ + ": " + msg);
    }
  }
  ~ZipArchive() { zip_discard(z_); }
  ZipArchive(const ZipArchive&) = delete;
  ZipArchive& operator=(const ZipArchive&) = delete;

  const std::string& path() const { return path_; }

  /// The one entry whose file name (after the last '/') is `base`; nullopt when there is none.
  std::optional<zip_uint64_t> find(const std::string& base) const {
    const zip_int64_t n = zip_get_num_entries(z_, 0);
    std::optional<zip_uint64_t> found;
    for (zip_int64_t i = 0; i < n; ++i) {
      const char* name = zip_get_name(z_, static_cast<zip_uint64_t>(i), 0);
      if (name == nullptr) continue;
      const std::string_view s(name);
      const auto slash = s.rfind('/');
      if ((slash == std::string_view::npos ? s : s.substr(slash + 1)) != base) continue;
      if (found) throw std::runtime_error("reading " + path_ + ": two entries named " + base);
      found = static_cast<zip_uint64_t>(i);
    }
    return found;
  }

  /// "<zip>:<entry>", as errors name an entry.
  std::string entry_name(zip_uint64_t i) const {
    const char* name = zip_get_name(z_, i, 0);
    return path_ + ":" + (name ? name : "?");
  }

  TextFile read(zip_uint64_t i) const {
    TextFile out{entry_name(i), {}};
    zip_stat_t st;
    zip_stat_init(&st);
    if (zip_stat_index(z_, i, 0, &st) != 0 || !(st.valid & ZIP_STAT_SIZE))
      throw std::runtime_error("reading " + out.name + ": " + zip_strerror(z_));
    if (st.size > kMaxEntryBytes)
      throw std::runtime_error("reading " + out.name + ": " + std::to_string(st.size) +
                               " bytes, over the 4 GiB limit");
    zip_file_t* f = zip_fopen_index(z_, i, 0);
    if (f == nullptr) throw std::runtime_error("reading " + out.name + ": " + zip_strerror(z_));
    out.text.resize(st.size);
    zip_uint64_t got = 0;
    while (got < st.size) {
      const zip_int64_t r = zip_fread(f, out.text.data() + got, st.size - got);
      if (r < 0) {
        const std::string msg = zip_file_strerror(f);
        zip_fclose(f);
        throw std::runtime_error("reading " + out.name + ": " + msg);
      }
      if (r == 0) break;
      got += static_cast<zip_uint64_t>(r);
    }
    zip_fclose(f);
    if (got != st.size)
      throw std::runtime_error("reading " + out.name + ": truncated entry (" + std::to_string(got) +
                               " of " + std::to_string(st.size) + " bytes)");
    return out;
  }

 private:
  std::string path_;
  zip_t* z_ = nullptr;
};
#endif

[[noreturn]] inline void no_libzip(const fs::path& p) {
  throw std::runtime_error("reading " + p.string() + ": built without libzip");
}

TOPOS_INLINE std::vector<float> torch_cpu_normal(std::uint64_t seed, int n, double mean,
                                                 double std) {
  if (n < 0 || n >= 16) throw std::invalid_argument("torch_cpu_normal: only n < 16 is modelled");
  std::mt19937 engine(static_cast<std::uint32_t>(seed));  // at::mt19937 keeps the low 32 bits
  const auto uniform = [&] {
    const std::uint64_t hi = engine(), lo = engine();
    const std::uint64_t v = (hi << 32) | lo;
    return static_cast<double>(v & ((std::uint64_t{1} << 53) - 1)) *
           (1.0 / (std::uint64_t{1} << 53));
  };
  std::vector<float> out;
  bool cached = false;
  double next = 0;
  const double pi = 3.14159265358979323846;
  for (int i = 0; i < n; ++i) {
    double z;
    if (cached) {
      z = next;
      cached = false;
    } else {
      const double u1 = uniform(), u2 = uniform();
      const double r = std::sqrt(-2.0 * std::log1p(-u2));
      const double theta = 2.0 * pi * u1;
      next = r * std::sin(theta);
      cached = true;
      z = r * std::cos(theta);
    }
    out.push_back(static_cast<float>(z * std + mean));
  }
  return out;
}

}  // namespace graph_io

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

// --- Planetoid: Python-2 pickles ------------------------------------------------------------

}  // namespace topos::data

// The object reader (namespace pickle), which uses graph_io above.
#include "topos/data/planetoid_pickle-inl.hpp"

namespace topos::data {

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
