// topos/data/json.hpp
// DataError, the error of every malformed or missing data file, and reading JSON files with
// errors that name the file: one place for "cannot open file", "malformed JSON" and "not an
// integer". std + nlohmann-json.
#pragma once

#include "topos/data/error.hpp"  // DataError, read_text_file

#include <nlohmann/json.hpp>

#include <cstdint>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <limits>
#include <stdexcept>
#include <string>
#include <type_traits>

namespace topos::data {

/// Whether `v` is a JSON integer that fits an int64 (nlohmann keeps integers above INT64_MAX as
/// unsigned; get<std::int64_t> would wrap them).
template <class Json>
bool is_int64(const Json& v) {
  return v.is_number_integer() &&
         (!v.is_number_unsigned() ||
          v.template get<std::uint64_t>() <=
              static_cast<std::uint64_t>(std::numeric_limits<std::int64_t>::max()));
}

/// The JSON integer `v` as T. Anything else (a string, 1.5, 1e30, a value outside T's range) is a
/// DataError naming `what`: nlohmann's get<T> converts numbers unchecked (a float out of range is
/// undefined behaviour, a large integer wraps).
template <class T = std::int64_t, class Json>
T get_integer(const Json& v, const std::string& what) {
  static_assert(std::is_integral_v<T> && std::is_signed_v<T>, "a signed integer type");
  if (is_int64(v)) {
    const auto x = v.template get<std::int64_t>();
    if (x >= std::numeric_limits<T>::min() && x <= std::numeric_limits<T>::max())
      return static_cast<T>(x);
  }
  throw DataError(what + ": expected an integer in [" +
                  std::to_string(std::numeric_limits<T>::min()) + ", " +
                  std::to_string(std::numeric_limits<T>::max()) + "], got " + v.dump());
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
