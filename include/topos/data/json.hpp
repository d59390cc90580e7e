// topos/data/json.hpp
// DataError, the error of every malformed or missing data file, and reading JSON files with
// errors that name the file: one place for "cannot open file" and "malformed JSON". std +
// nlohmann-json.
#pragma once

#include <nlohmann/json.hpp>

#include <filesystem>
#include <fstream>
#include <iterator>
#include <stdexcept>
#include <string>

namespace topos::data {

class DataError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

/// The whole file as text; a file that cannot be opened is a DataError naming it.
inline std::string read_text_file(const std::filesystem::path& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw DataError(path.string() + ": cannot open file");
  return std::string((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
}

/// Parses JSON text; a syntax error is a DataError naming `source`.
inline nlohmann::json parse_json(const std::string& text, const std::string& source) {
  try {
    return nlohmann::json::parse(text);
  } catch (const nlohmann::json::exception& e) {
    throw DataError(source + ": malformed JSON: " + e.what());
  }
}

inline nlohmann::json read_json_file(const std::filesystem::path& path) {
  return parse_json(read_text_file(path), path.string());
}

/// As parse_json, keeping objects' keys in text order (where the order means something, e.g.
/// operators listed in creation order).
inline nlohmann::ordered_json parse_ordered_json(const std::string& text,
                                                 const std::string& source) {
  try {
    return nlohmann::ordered_json::parse(text);
  } catch (const nlohmann::json::exception& e) {
    throw DataError(source + ": malformed JSON: " + e.what());
  }
}

/// As read_json_file, keeping objects' keys in file order.
inline nlohmann::ordered_json read_ordered_json_file(const std::filesystem::path& path) {
  return parse_ordered_json(read_text_file(path), path.string());
}

}  // namespace topos::data
