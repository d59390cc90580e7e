// Access to ../shared/reference for tests: the folder named by TOPOS_REFERENCE_DIR. When it is
// unset, the test says so and exits with TOPOS_SKIP_CODE, which ctest reports as skipped.
#pragma once

#include <cstdlib>
#include <filesystem>
#include <iostream>
#include <string>

namespace topos::test {

inline std::filesystem::path reference_dir(const char* test_name) {
  const char* dir = std::getenv("TOPOS_REFERENCE_DIR");
  if (dir == nullptr || *dir == '\0') {
    std::cout << "SKIPPED: '" << test_name
              << "' needs the reference data; set TOPOS_REFERENCE_DIR to ../shared/reference\n";
    std::exit(TOPOS_SKIP_CODE);
  }
  std::filesystem::path p(dir);
  if (!std::filesystem::exists(p / "README.md")) {
    std::cerr << "TOPOS_REFERENCE_DIR=" << dir
              << " does not hold the reference data (no README.md)\n";
    std::exit(1);
  }
  return p;
}

/// The raw benchmark datasets (../shared/datasets): the folder named by TOPOS_DATASETS_DIR, or
/// skip as reference_dir does.
inline std::filesystem::path datasets_dir(const char* test_name) {
  const char* dir = std::getenv("TOPOS_DATASETS_DIR");
  if (dir == nullptr || *dir == '\0') {
    std::cout << "SKIPPED: '" << test_name
              << "' needs the raw datasets; set TOPOS_DATASETS_DIR to ../shared/datasets\n";
    std::exit(TOPOS_SKIP_CODE);
  }
  std::filesystem::path p(dir);
  if (!std::filesystem::exists(p / "README.md")) {
    std::cerr << "TOPOS_DATASETS_DIR=" << dir << " does not hold the datasets (no README.md)\n";
    std::exit(1);
  }
  return p;
}

}  // namespace topos::test
