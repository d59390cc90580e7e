// Fuzz harness: the Planetoid pickle reader (data/graph_datasets.hpp, read_planetoid_pickle):
// a strict protocol-2 machine for scipy CSR matrices, NumPy arrays and dicts of lists. A matrix
// may claim any shape: one over the 2^20-entry limit given here must be refused before it is
// allocated (libFuzzer's -malloc_limit_mb catches it otherwise).
#include "fuzz_target.hpp"

#include "topos/data/graph_datasets.hpp"

#include <string_view>

TOPOS_FUZZ_TARGET(planetoid) {
  using namespace topos_fuzz;
  try {
    const auto p = topos::data::read_planetoid_pickle(
        std::string_view(reinterpret_cast<const char*>(data), size), source(), 1 << 20);
    if (p.kind == topos::data::PlanetoidPickle::Kind::Matrix) {
      check(p.rows >= 0 && p.cols >= 0 && p.rows * p.cols <= (1 << 20), "shape within limit");
      check(p.values.size() == static_cast<std::size_t>(p.rows * p.cols), "dense values");
    } else {
      for (std::size_t k = 1; k < p.adjacency.size(); ++k)
        check(p.adjacency[k - 1].first < p.adjacency[k].first, "keys unique and ordered");
    }
  } catch (const std::runtime_error& e) {
    expect_error(e.what());
  }
  return 0;
}
