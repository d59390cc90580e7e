// topos/data/error.hpp
// DataError, the error of every malformed or missing data file, and reading a whole file with an
// error that names it (std only; topos/data/json.hpp adds the JSON readers).
#pragma once

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

}  // namespace topos::data
