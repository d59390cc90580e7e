// topos/data/npy.hpp
// NumPy .npy arrays (format 1.0-3.0, little-endian; C or Fortran order, read into C order): read into a typed buffer and
// write atomically. Used for the reference's golden arrays and for exporting results that
// NumPy opens with np.load. std only.
#pragma once

#include "topos/io/atomic_file.hpp"

#include <cstdint>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <stdexcept>
#include <string>
#include <vector>

namespace topos::data {

struct NpyArray {
  std::string dtype;                 ///< "f8", "f4", "i8", "i4", "u1", "b1"
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
    if (dtype == "f8") conv(double{});
    else if (dtype == "f4") conv(float{});
    else if (dtype == "i8") conv(std::int64_t{});
    else if (dtype == "i4") conv(std::int32_t{});
    else if (dtype == "u1" || dtype == "b1") conv(std::uint8_t{});
    else throw std::runtime_error("npy: unsupported dtype " + dtype);
    return out;
  }
};

inline NpyArray read_npy(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw std::runtime_error(path + ": cannot open file");
  char magic[8];
  in.read(magic, 8);
  if (!in || std::memcmp(magic, "\x93NUMPY", 6) != 0) throw std::runtime_error(path + ": not a .npy file");
  std::uint32_t header_len = 0;
  if (magic[6] == 1) {
    std::uint16_t l = 0;
    in.read(reinterpret_cast<char*>(&l), 2);
    header_len = l;
  } else {
    in.read(reinterpret_cast<char*>(&header_len), 4);
  }
  std::string header(header_len, '\0');
  in.read(header.data(), header_len);
  if (!in) throw std::runtime_error(path + ": truncated header");
  NpyArray a;
  const auto value_of = [&](const std::string& key) {
    const auto k = header.find("'" + key + "'");
    if (k == std::string::npos) throw std::runtime_error(path + ": header lacks '" + key + "'");
    return header.find(':', k) + 1;
  };
  {
    auto p = header.find('\'', value_of("descr"));
    const auto q = header.find('\'', p + 1);
    const std::string descr = header.substr(p + 1, q - p - 1);
    if (descr.size() < 3 || (descr[0] != '<' && descr[0] != '|')) throw std::runtime_error(path + ": unsupported dtype '" + descr + "' (little-endian only)");
    a.dtype = descr.substr(1);
  }
  const bool fortran = header.find("'fortran_order': True") != std::string::npos;
  {
    const auto p = header.find('(', value_of("shape")), q = header.find(')', p);
    std::string dims = header.substr(p + 1, q - p - 1);
    std::size_t pos = 0;
    while (pos < dims.size()) {
      const auto c = dims.find(',', pos);
      const std::string tok = dims.substr(pos, c == std::string::npos ? std::string::npos : c - pos);
      if (tok.find_first_not_of(' ') != std::string::npos) a.shape.push_back(std::stoll(tok));
      if (c == std::string::npos) break;
      pos = c + 1;
    }
  }
  const std::size_t item = a.dtype == "f8" || a.dtype == "i8" ? 8 : (a.dtype == "f4" || a.dtype == "i4" ? 4 : 1);
  a.bytes.resize(static_cast<std::size_t>(a.size()) * item);
  in.read(a.bytes.data(), static_cast<std::streamsize>(a.bytes.size()));
  if (!in) throw std::runtime_error(path + ": truncated data");
  if (fortran && a.shape.size() > 1) {
    // NumPy saves a transposed (F-contiguous) array in Fortran order: reorder into C order.
    const std::size_t nd = a.shape.size(), n = static_cast<std::size_t>(a.size());
    std::vector<char> c_order(a.bytes.size());
    std::vector<std::int64_t> idx(nd, 0);
    for (std::size_t k = 0; k < n; ++k) {  // k: C-order position; idx: its multi-index
      std::int64_t f = 0, stride = 1;
      for (std::size_t d = 0; d < nd; ++d) f += idx[d] * stride, stride *= a.shape[d];
      std::memcpy(c_order.data() + k * item, a.bytes.data() + static_cast<std::size_t>(f) * item, item);
      for (std::size_t d = nd; d-- > 0;) {
        if (++idx[d] < a.shape[d]) break;
        idx[d] = 0;
      }
    }
    a.bytes.swap(c_order);
  }
  return a;
}

namespace detail {
inline void write_npy_bytes(const std::string& path, const std::vector<std::int64_t>& shape, const char* descr, const void* data, std::size_t item) {
  std::string dims;
  std::int64_t n = 1;
  for (auto s : shape) dims += std::to_string(s) + ",", n *= s;
  if (shape.size() > 1) dims.pop_back();
  std::string header = std::string("{'descr': '") + descr + "', 'fortran_order': False, 'shape': (" + dims + "), }";
  while ((10 + header.size() + 1) % 64 != 0) header += ' ';
  header += '\n';
  std::string bytes("\x93NUMPY\x01\x00", 8);
  const std::uint16_t len = static_cast<std::uint16_t>(header.size());
  bytes.append(reinterpret_cast<const char*>(&len), 2);
  bytes += header;
  bytes.append(reinterpret_cast<const char*>(data), static_cast<std::size_t>(n) * item);
  write_file_atomic(path, bytes);
}
}  // namespace detail

/// Writes a float64 array (row-major data) atomically: a temporary file, then a rename. An
/// empty shape writes a 0-d array (one value).
inline void write_npy(const std::string& path, const std::vector<std::int64_t>& shape, const double* data) {
  detail::write_npy_bytes(path, shape, "<f8", data, 8);
}
/// Writes a float32 array (row-major data) atomically.
inline void write_npy(const std::string& path, const std::vector<std::int64_t>& shape, const float* data) {
  detail::write_npy_bytes(path, shape, "<f4", data, 4);
}

}  // namespace topos::data
