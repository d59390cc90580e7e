// topos/data/npy.hpp
// NumPy .npy arrays (format 1.0-3.0, little-endian; C or Fortran order, read into C order): read
// into a typed buffer and
// write atomically. Used for the reference's golden arrays and for exporting results that
// NumPy opens with np.load. std only.
#pragma once

#include "topos/io/atomic_file.hpp"

#include <cstdint>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <istream>
#include <limits>
#include <stdexcept>
#include <string>
#include <vector>

namespace topos::data {

struct NpyArray {
  std::string dtype;  ///< "f8", "f4", "i8", "i4", "u1", "b1"
  std::vector<std::int64_t> shape;
  std::vector<char> bytes;

  std::int64_t size() const {
    std::int64_t n = 1;
    for (auto s : shape) n *= s;
    return n;
  }
  /// All elements converted to T (row-major order).
  template <class T>
  std::vector<T> as() const {
    std::vector<T> out(static_cast<std::size_t>(size()));
    const auto conv = [&](auto tag) {
      using S = decltype(tag);
      for (std::size_t i = 0; i < out.size(); ++i) {
        S v;
        std::memcpy(&v, bytes.data() + i * sizeof(S), sizeof(S));
        out[i] = static_cast<T>(v);
      }
    };
    if (dtype == "f8")
      conv(double{});
    else if (dtype == "f4")
      conv(float{});
    else if (dtype == "i8")
      conv(std::int64_t{});
    else if (dtype == "i4")
      conv(std::int32_t{});
    else if (dtype == "u1" || dtype == "b1")
      conv(std::uint8_t{});
    else
      throw std::runtime_error("npy: unsupported dtype " + dtype);
    return out;
  }
};

/// Bytes per element of a supported dtype, or 0.
inline std::size_t npy_item_size(const std::string& dtype) {
  if (dtype == "f8" || dtype == "i8") return 8;
  if (dtype == "f4" || dtype == "i4") return 4;
  if (dtype == "u1" || dtype == "b1") return 1;
  return 0;
}

/// Parses a .npy stream; `source` names it in errors. Untrusted input: the header is checked
/// field by field, and the data size it implies is checked (without overflow) against the bytes
/// the stream still holds before anything is allocated, so a header claiming a 10 GB shape is a
/// "truncated data" error, not an out-of-memory kill.
inline NpyArray read_npy(std::istream& in, const std::string& source) {
  const auto fail = [&](const std::string& why) -> void {
    throw std::runtime_error(source + ": " + why);
  };
  char magic[8];
  in.read(magic, 8);
  if (!in || std::memcmp(magic, "\x93NUMPY", 6) != 0) fail("not a .npy file");
  if (magic[6] < 1 || magic[6] > 3)
    fail("unsupported .npy format version " + std::to_string(static_cast<int>(magic[6])));
  std::uint32_t header_len = 0;
  unsigned char len_bytes[4] = {0, 0, 0, 0};
  in.read(reinterpret_cast<char*>(len_bytes), magic[6] == 1 ? 2 : 4);
  for (int i = 3; i >= 0; --i) header_len = (header_len << 8) | len_bytes[i];  // little-endian
  if (!in) fail("truncated header");
  // NumPy writes headers of a few hundred bytes; refuse absurd lengths before allocating.
  if (header_len > (1u << 20))
    fail("header of " + std::to_string(header_len) + " bytes is too long");
  std::string header(header_len, '\0');
  in.read(header.data(), header_len);
  if (!in) fail("truncated header");
  NpyArray a;
  // The text after `'key':`, spaces skipped.
  const auto value_of = [&](const std::string& key) {
    const auto k = header.find("'" + key + "'");
    if (k == std::string::npos) fail("header lacks '" + key + "'");
    auto p = header.find(':', k);
    if (p == std::string::npos) fail("header lacks a value for '" + key + "'");
    p = header.find_first_not_of(' ', p + 1);
    if (p == std::string::npos) fail("header lacks a value for '" + key + "'");
    return p;
  };
  {
    const auto p = value_of("descr");
    const auto q = header[p] == '\'' ? header.find('\'', p + 1) : std::string::npos;
    if (q == std::string::npos) fail("malformed 'descr' in the header");
    const std::string descr = header.substr(p + 1, q - p - 1);
    if (descr.size() < 3 || (descr[0] != '<' && descr[0] != '|'))
      fail("unsupported dtype '" + descr + "' (little-endian only)");
    a.dtype = descr.substr(1);
    if (npy_item_size(a.dtype) == 0) fail("unsupported dtype '" + descr + "'");
  }
  bool fortran = false;
  {
    const auto p = value_of("fortran_order");
    fortran = header.compare(p, 4, "True") == 0;
    if (!fortran && header.compare(p, 5, "False") != 0)
      fail("malformed 'fortran_order' in the header");
  }
  {
    const auto p = value_of("shape");
    const auto q = header[p] == '(' ? header.find(')', p) : std::string::npos;
    if (q == std::string::npos) fail("malformed 'shape' in the header");
    const std::string dims = header.substr(p + 1, q - p - 1);
    std::size_t pos = 0;
    while (pos < dims.size()) {
      const auto c = dims.find(',', pos);
      const std::string tok =
          dims.substr(pos, c == std::string::npos ? std::string::npos : c - pos);
      const auto b = tok.find_first_not_of(' ');
      if (b != std::string::npos) {
        const auto e = tok.find_last_not_of(' ');
        const std::string digits = tok.substr(b, e - b + 1);
        if (digits.empty() || digits.size() > 18 ||
            digits.find_first_not_of("0123456789") != std::string::npos)
          fail("bad dimension '" + tok + "' in 'shape'");
        a.shape.push_back(std::stoll(digits));
        if (a.shape.size() > 32) fail("more than 32 dimensions");
      } else if (c != std::string::npos) {
        fail("empty dimension in 'shape'");
      }
      if (c == std::string::npos) break;
      pos = c + 1;
    }
  }
  // Element and byte counts without overflow, then against what the stream holds.
  const std::size_t item = npy_item_size(a.dtype);
  std::uint64_t bytes = item;
  for (auto s : a.shape) {
    if (s != 0 &&
        bytes > std::numeric_limits<std::uint64_t>::max() / static_cast<std::uint64_t>(s)) {
      bytes = std::numeric_limits<std::uint64_t>::max();
      break;
    }
    bytes *= static_cast<std::uint64_t>(s);
  }
  const auto here = in.tellg();
  in.seekg(0, std::ios::end);
  const auto end = in.tellg();
  in.seekg(here);
  if (here < 0 || end < 0 || !in) fail("cannot determine the data size");
  const auto available = static_cast<std::uint64_t>(end - here);
  if (bytes > available)
    fail("truncated data (the header's shape needs " + std::to_string(bytes) +
         " bytes, the file holds " + std::to_string(available) + ")");
  a.bytes.resize(static_cast<std::size_t>(bytes));
  in.read(a.bytes.data(), static_cast<std::streamsize>(a.bytes.size()));
  if (!in) fail("truncated data");
  if (fortran && a.shape.size() > 1) {
    // NumPy saves a transposed (F-contiguous) array in Fortran order: reorder into C order.
    const std::size_t nd = a.shape.size(), n = static_cast<std::size_t>(a.size());
    std::vector<char> c_order(a.bytes.size());
    std::vector<std::int64_t> idx(nd, 0);
    for (std::size_t k = 0; k < n; ++k) {  // k: C-order position; idx: its multi-index
      std::int64_t f = 0, stride = 1;
      for (std::size_t d = 0; d < nd; ++d) f += idx[d] * stride, stride *= a.shape[d];
      std::memcpy(c_order.data() + k * item, a.bytes.data() + static_cast<std::size_t>(f) * item,
                  item);
      for (std::size_t d = nd; d-- > 0;) {
        if (++idx[d] < a.shape[d]) break;
        idx[d] = 0;
      }
    }
    a.bytes.swap(c_order);
  }
  return a;
}

inline NpyArray read_npy(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw std::runtime_error(path + ": cannot open file");
  return read_npy(in, path);
}

namespace detail {
inline void write_npy_bytes(const std::string& path, const std::vector<std::int64_t>& shape,
                            const char* descr, const void* data, std::size_t item) {
  std::string dims;
  std::int64_t n = 1;
  for (auto s : shape) dims += std::to_string(s) + ",", n *= s;
  if (shape.size() > 1) dims.pop_back();
  std::string header =
      std::string("{'descr': '") + descr + "', 'fortran_order': False, 'shape': (" + dims + "), }";
  while ((10 + header.size() + 1) % 64 != 0) header += ' ';
  header += '\n';
  std::string bytes("\x93NUMPY\x01\x00", 8);
  const std::uint16_t len = static_cast<std::uint16_t>(header.size());
  bytes.append(reinterpret_cast<const char*>(&len), 2);
  bytes += header;
  bytes.append(reinterpret_cast<const char*>(data), static_cast<std::size_t>(n) * item);
  io::write_file_atomic(path, bytes);
}
}  // namespace detail

/// Writes a float64 array (row-major data) atomically: a temporary file, then a rename. An
/// empty shape writes a 0-d array (one value).
inline void write_npy(const std::string& path, const std::vector<std::int64_t>& shape,
                      const double* data) {
  detail::write_npy_bytes(path, shape, "<f8", data, 8);
}
/// Writes a float32 array (row-major data) atomically.
inline void write_npy(const std::string& path, const std::vector<std::int64_t>& shape,
                      const float* data) {
  detail::write_npy_bytes(path, shape, "<f4", data, 4);
}

}  // namespace topos::data
