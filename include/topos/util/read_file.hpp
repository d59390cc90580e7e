// topos/util/read_file.hpp
// Reading a whole stream or file into memory in large blocks (std only). Building a string from
// istreambuf_iterator goes one character at a time, about 40 instructions a byte: 0.15 G
// instructions for one MOVi-A scene's 3.6 MB metadata.json, and as much again for a 3 MB
// checkpoint, before either is parsed.
#pragma once

#include <filesystem>
#include <fstream>
#include <ios>
#include <istream>
#include <string>

namespace topos {

/// The rest of `in`, from its position to its end, read in 64 KiB blocks (the string reserved to
/// the stream's size where it can seek; a stream that cannot, such as /proc's files, is read
/// until it ends). A read error sets `in.bad()`: check it before trusting the bytes.
inline std::string read_all(std::istream& in) {
  std::string out;
  const auto start = in.tellg();
  if (start != std::streampos(-1) && in.seekg(0, std::ios::end)) {
    const auto end = in.tellg();
    // Only a hint: a directory's stream seeks to an end of 2^63 - 1 bytes.
    if (end != std::streampos(-1) && end > start) try {
        out.reserve(static_cast<std::size_t>(end - start));
      } catch (const std::exception&) {
      }
  }
  in.clear();
  if (start != std::streampos(-1)) in.seekg(start);
  char block[1 << 16];
  while (in.read(block, sizeof block) || in.gcount() > 0)
    out.append(block, static_cast<std::size_t>(in.gcount()));
  return out;
}

/// The whole file at `path` as bytes; false, `out` untouched, where it cannot be opened or read
/// (a directory, a read error).
inline bool read_file(const std::string& path, std::string& out) {
  std::error_code ec;
  if (std::filesystem::is_directory(path, ec)) return false;
  std::ifstream in(path, std::ios::binary);
  if (!in) return false;
  std::string bytes = read_all(in);
  if (in.bad()) return false;
  out = std::move(bytes);
  return true;
}

}  // namespace topos
