// An empty scratch folder for one test: <temp>/topos_test_<name>, removed first if it exists.
#pragma once

#include <filesystem>
#include <string>

namespace topos::testing {

inline std::filesystem::path fresh_dir(const std::string& name) {
  const auto d = std::filesystem::temp_directory_path() / ("topos_test_" + name);
  std::filesystem::remove_all(d);
  std::filesystem::create_directories(d);
  return d;
}

}  // namespace topos::testing
