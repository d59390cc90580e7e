// A downstream project on the topos::zoo component: writes a TDL golden case's complex.json and
// operators.json (a filled triangle) and builds its operators through the installed golden-case
// runner (topos/models/zoo/golden_case.hpp, whose reader is topos::data's tdl_case.hpp). The
// triangle's L0 is 2 on the diagonal and -1 elsewhere, and B1 has one +1 and one -1 per edge.
#include <torch/torch.h>

#include <topos/models/zoo/golden_case.hpp>
#include <topos/util/malloc.hpp>

#include <filesystem>
#include <fstream>
#include <iostream>

int main() {
  namespace fs = std::filesystem;
  const fs::path dir = fs::temp_directory_path() / "topos_consumer_zoo_case";
  fs::create_directories(dir);
  std::ofstream(dir / "complex.json")
      << R"({"domain": "simplicial", "cells": {"0": [0, 1, 2], "1": [[0, 1], [0, 2], [1, 2]],
             "2": [[0, 1, 2]]}})";
  std::ofstream(dir / "operators.json")
      << R"({"B1": {"op": "incidence_matrix", "args": {"rank": 1}},
             "L0": {"op": "hodge_laplacian_matrix", "args": {"rank": 0}}})";
  const auto ops = topos::models::zoo::case_operators(dir);
  fs::remove_all(dir);
  const auto L0 = ops.at("L0").to_dense();
  const auto B1 = ops.at("B1").to_dense();
  const auto expected = 3 * torch::eye(3) - torch::ones({3, 3});
  const bool ok =
      ops.size() == 2 && torch::equal(L0, expected) && B1.sizes() == torch::IntArrayRef{3, 3} &&
      torch::equal(B1.sum(0), torch::zeros({3})) && B1.abs().sum().item<float>() == 6.0f;
  std::cout << (ok ? "consumer ok" : "consumer FAILED") << " (topos::zoo), malloc "
            << topos::malloc_name() << "\n";
  return ok ? 0 : 1;
}
