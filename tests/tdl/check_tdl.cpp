// The tdl program against the shared golden cases, and on bad input.
//   check_tdl golden TDL WORK   for every case under $TOPOS_REFERENCE_DIR/tdl-golden/cases/, runs
//                               `TDL operators --case CASE --out WORK/CASE` and compares every
//                               operator with CASE/operators/<name>.npy: same shape, float32,
//                               integer-valued references exactly, others within 1e-6. Skips
//                               (exit TOPOS_SKIP_CODE) when TOPOS_REFERENCE_DIR is unset.
//   check_tdl bad TDL WORK      cases with an unknown op, a 2-cell using a missing vertex, an empty
//                               hyperedge: exit status 1, a message naming the problem, no output.
#include "topos/data/json.hpp"
#include "topos/data/npy.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <iostream>
#include <string>
#include <vector>

namespace fs = std::filesystem;

namespace {

std::string quote(const std::string& s) {
  std::string q = "'";
  for (char c : s) q += c == '\'' ? std::string("'\\''") : std::string(1, c);
  return q + "'";
}

int run(const std::string& cmd) {
  const int status = std::system(cmd.c_str());
  return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
}

int check_golden(const std::string& tdl, const fs::path& work) {
  const char* ref = std::getenv("TOPOS_REFERENCE_DIR");
  if (ref == nullptr || *ref == '\0') {
    std::cout << "SKIPPED: tdl_golden needs the reference data; set TOPOS_REFERENCE_DIR to "
                 "../shared/reference\n";
    return TOPOS_SKIP_CODE;
  }
  const fs::path cases = fs::path(ref) / "tdl-golden" / "cases";
  if (!fs::is_directory(cases)) {
    std::cerr << cases << " is not a folder\n";
    return 1;
  }
  std::vector<fs::path> dirs;
  for (const auto& e : fs::directory_iterator(cases))
    if (e.is_directory() && fs::exists(e.path() / "operators.json")) dirs.push_back(e.path());
  std::sort(dirs.begin(), dirs.end());
  if (dirs.empty()) {
    std::cerr << "no case with operators.json under " << cases << "\n";
    return 1;
  }
  int failures = 0;
  std::size_t compared = 0;
  for (const fs::path& dir : dirs) {
    const std::string name = dir.filename().string();
    const fs::path out = work / name;
    fs::remove_all(out);
    if (run(quote(tdl) + " operators --case " + quote(dir.string()) + " --out " +
            quote(out.string()) + " > /dev/null") != 0) {
      std::cout << name << ": tdl operators FAILED\n";
      ++failures;
      continue;
    }
    const auto ops = topos::data::read_ordered_json_file(dir / "operators.json");
    int case_fail = 0;
    double worst = 0;
    for (auto it = ops.begin(); it != ops.end(); ++it) {
      const std::string op = it.key();
      try {
        const auto golden = topos::data::read_npy((dir / "operators" / (op + ".npy")).string());
        const auto ours = topos::data::read_npy((out / (op + ".npy")).string());
        if (ours.dtype != "f4")
          throw std::runtime_error("written as " + ours.dtype + ", not float32");
        if (ours.shape != golden.shape)
          throw std::runtime_error("shape differs from the reference");
        const auto g = golden.as<double>(), o = ours.as<double>();
        const bool integral = std::all_of(
            g.begin(), g.end(), [](double v) { return std::isfinite(v) && v == std::round(v); });
        for (std::size_t k = 0; k < g.size(); ++k) {
          const double d = std::abs(g[k] - o[k]);
          worst = std::max(worst, d);
          if (!(integral ? g[k] == o[k] : d <= 1e-6)) {
            throw std::runtime_error(
                "entry " + std::to_string(k) + ": reference " + std::to_string(g[k]) + ", tdl " +
                std::to_string(o[k]) +
                (integral ? " (integer operator: must be exact)" : " (tolerance 1e-6)"));
          }
        }
        ++compared;
      } catch (const std::exception& e) {
        std::cout << name << "/" << op << ": MISMATCH: " << e.what() << "\n";
        ++case_fail;
      }
    }
    std::printf("%-26s %3zu operators  max |diff| %.3g  %s\n", name.c_str(), ops.size(), worst,
                case_fail ? "FAILED" : "ok");
    failures += case_fail;
  }
  std::printf("%zu cases, %zu operators matched, %d failures\n", dirs.size(), compared, failures);
  return failures == 0 && compared > 0 ? 0 : 1;
}

// Writes a case, runs tdl on it, expects exit 1, every `needles` in stderr and no .npy written.
bool expect_failure(const std::string& tdl, const fs::path& work, const std::string& name,
                    const std::string& complex_json, const std::string& operators_json,
                    const std::vector<std::string>& needles) {
  const fs::path dir = work / name, out = work / (name + "-out");
  fs::remove_all(dir);
  fs::remove_all(out);
  fs::create_directories(dir);
  topos::io::write_file_atomic((dir / "complex.json").string(), complex_json);
  topos::io::write_file_atomic((dir / "operators.json").string(), operators_json);
  const fs::path err = work / (name + ".stderr");
  const int rc = run(quote(tdl) + " operators --case " + quote(dir.string()) + " --out " +
                     quote(out.string()) + " > /dev/null 2> " + quote(err.string()));
  const std::string msg = topos::data::read_text_file(err);
  bool ok = rc == 1;
  for (const auto& n : needles) ok = ok && msg.find(n) != std::string::npos;
  bool wrote = false;
  if (fs::exists(out))
    for (const auto& e : fs::directory_iterator(out)) wrote = true, (void)e;
  ok = ok && !wrote;
  std::printf("%-22s exit %d, %s: %s", name.c_str(), rc, ok ? "ok" : "FAILED", msg.c_str());
  return ok;
}

int check_bad(const std::string& tdl, const fs::path& work) {
  const std::string sc =
      R"({"domain": "simplicial", "cells": {"0": [[0], [1], [2]], "1": [[0, 1], [1, 2]]}})";
  bool ok = true;
  ok &= expect_failure(
      tdl, work, "unknown-op", sc,
      R"({"incidence_1": {"op": "incidence_matrix", "args": {"rank": 1, "signed": true}}, )"
      R"("weird": {"op": "frobnicate_matrix", "args": {"rank": 1}}})",
      {"'weird'", "frobnicate_matrix", "unknown op"});
  ok &= expect_failure(tdl, work, "missing-argument", sc,
                       R"({"L": {"op": "hodge_laplacian_matrix", "args": {"signed": true}}})",
                       {"'L'", "missing argument 'rank'"});
  ok &= expect_failure(
      tdl, work, "cell-missing-vertex",
      R"({"domain": "cell", "nodes": [0, 1, 2], "edges": [[0, 1], [1, 2], [0, 2]], )"
      R"("cells": [[0, 1, 5]]})",
      R"({"incidence_2": {"op": "incidence_matrix", "args": {"rank": 2, "signed": true}}})",
      {"2-cell 0", "node 5"});
  ok &= expect_failure(
      tdl, work, "cell-not-closed",
      R"({"domain": "cell", "nodes": [0, 1, 2, 3], "edges": [[0, 1], [1, 2], [2, 3]], )"
      R"("cells": [[0, 1, 2, 3]]})",
      R"({"incidence_2": {"op": "incidence_matrix", "args": {"rank": 2, "signed": true}}})",
      {"not a closed cycle", "[3, 0]"});
  ok &= expect_failure(
      tdl, work, "empty-hyperedge",
      R"({"domain": "hypergraph", "nodes": [0, 1], "hyperedges": [[0, 1], []]})",
      R"({"incidence_1": {"op": "incidence_matrix", "args": {"rank": 0, "to_rank": 1}}})",
      {"hyperedge 1", "empty"});
  ok &= expect_failure(tdl, work, "repeated-vertex",
                       R"({"domain": "simplicial", "cells": {"0": [[0], [1]], "1": [[0, 0]]}})",
                       R"({"incidence_1": {"op": "incidence_matrix", "args": {"rank": 1}}})",
                       {"repeats node 0"});
  ok &= expect_failure(
      tdl, work, "wrong-domain-op",
      R"({"domain": "hypergraph", "nodes": [0, 1], "hyperedges": [[0, 1]]})",
      R"({"L": {"op": "hodge_laplacian_matrix", "args": {"rank": 0, "signed": true}}})",
      {"'L'", "not defined on a hypergraph"});
  return ok ? 0 : 1;
}

}  // namespace

int main(int argc, char** argv) {
  if (argc != 4 || (std::string(argv[1]) != "golden" && std::string(argv[1]) != "bad")) {
    std::cerr << "usage: check_tdl golden|bad TDL WORKDIR\n";
    return 2;
  }
  try {
    fs::create_directories(argv[3]);
    return std::string(argv[1]) == "golden" ? check_golden(argv[2], argv[3])
                                            : check_bad(argv[2], argv[3]);
  } catch (const std::exception& e) {
    std::cerr << "check_tdl: " << e.what() << "\n";
    return 1;
  }
}
