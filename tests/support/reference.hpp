// Access to the shared data folders for tests: ../shared/reference (TOPOS_REFERENCE_DIR) and
// ../shared/datasets (TOPOS_DATASETS_DIR). When the variable is unset, the test says so and exits
// with TOPOS_SKIP_CODE, which ctest reports as skipped; a variable naming a folder without the
// data's README.md is an error.
#pragma once

#include <cstdlib>
#include <filesystem>
#include <iostream>
#include <string>

namespace topos::test {

/// The folder named by `variable`, which holds `what` and should be `default_place`.
inline std::filesystem::path shared_dir(const char* test_name, const char* variable,
                                        const char* what, const char* default_place) {
  const char* dir = std::getenv(variable);
  if (dir == nullptr || *dir == '\0') {
    std::cout << "SKIPPED: '" << test_name << "' needs " << what << "; set " << variable << " to "
              << default_place << "\n";
    std::exit(TOPOS_SKIP_CODE);
  }
  std::filesystem::path p(dir);
  if (!std::filesystem::exists(p / "README.md")) {
    std::cerr << variable << "=" << dir << " does not hold " << what << " (no README.md)\n";
    std::exit(1);
  }
  return p;
}

inline std::filesystem::path reference_dir(const char* test_name) {
  return shared_dir(test_name, "TOPOS_REFERENCE_DIR", "the reference data", "../shared/reference");
}

/// The raw benchmark datasets.
inline std::filesystem::path datasets_dir(const char* test_name) {
  return shared_dir(test_name, "TOPOS_DATASETS_DIR", "the raw datasets", "../shared/datasets");
}

}  // namespace topos::test
