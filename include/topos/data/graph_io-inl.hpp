// topos/data/graph_io-inl.hpp
// Part of graph_datasets-inl.hpp (included by it and by planetoid_pickle-inl.hpp, not by users):
// the readers' shared helpers in namespace graph_io: errors naming the file and line, tokens,
// whole files from a folder or a zip (libzip), and torch's CPU normal draws.
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

}  // namespace topos::data
