// topos/data/error.hpp
// DataError, the error of every malformed or missing data file, and reading a whole file with an
// error that names it (std only; topos/data/json.hpp adds the JSON readers).
#pragma once

#include "topos/util/read_file.hpp"

#include <filesystem>
#include <stdexcept>
#include <string>

namespace topos::data {

class DataError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

/// The whole file as text; a file that cannot be opened is a DataError naming it.
inline std::string read_text_file(const std::filesystem::path& path) {
  std::string text;
  if (!read_file(path.string(), text)) throw DataError(path.string() + ": cannot open file");
  return text;
}

}  // namespace topos::data
