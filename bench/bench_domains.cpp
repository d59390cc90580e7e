// The topological domains at TopoNetX's benchmark sizes (shared/reference/tdl-bench/README.md):
//   BM_rgg2000_clique_ops  clique complex (max rank 3) of rgg2000_edges.txt + signed incidences of
//                          ranks 1-3, Hodge Laplacians 0-3, adjacency 0-2 (TopoNetX: 1.12 s);
//                          needs TOPOS_REFERENCE_DIR, skipped with a message without it
//   BM_grid101_ops         SimplicialComplex of the 101 x 101 grid's 20,000 triangles + signed
//                          incidences 1-2, Hodge Laplacians 0-2 (TopoNetX: 1.17 s)
//   BM_mesh100k_ops        the same on a 100,000-triangle sphere (50,002 nodes)
// plus the pieces of the first two. Counter `x_toponetx` = TopoNetX's time / ours.
// Allocation: glibc returns every freed block above 128 KiB to the OS, so each operator's
// arrays are page-faulted afresh, and on the developers' VM a page fault is expensive (under
// load it dominated: 20x). main() therefore raises M_MMAP_THRESHOLD / M_TRIM_THRESHOLD, as a
// program building many operators should; TOPOS_BENCH_DEFAULT_MALLOC=1 keeps glibc's defaults.
#include <benchmark/benchmark.h>

#include "topos/core/domain_lifting.hpp"
#include "topos/core/simplicial_complex.hpp"
#include "topos/mesh/primitives.hpp"

#include <malloc.h>

#include <chrono>
#include <cstdlib>
#include <fstream>
#include <sstream>
#include <string>

namespace {

using Edges = std::vector<std::array<std::int64_t, 2>>;

// "u v" per line; a leading "# ... N nodes ..." comment gives the node count (isolated nodes).
bool read_edges(Edges& edges, std::int64_t& n, std::string& why) {
  const char* ref = std::getenv("TOPOS_REFERENCE_DIR");
  if (ref == nullptr || *ref == '\0') {
    why = "needs TOPOS_REFERENCE_DIR (tdl-bench/rgg2000_edges.txt)";
    return false;
  }
  const std::string path = std::string(ref) + "/tdl-bench/rgg2000_edges.txt";
  std::ifstream in(path);
  if (!in) {
    why = "cannot open " + path;
    return false;
  }
  std::string line;
  n = 0;
  while (std::getline(in, line)) {
    if (line.empty()) continue;
    if (line[0] == '#') {
      const auto p = line.find(" nodes");
      if (p != std::string::npos) {
        auto b = line.rfind(' ', p - 1);
        std::string num = line.substr(b + 1, p - b - 1);
        num.erase(std::remove(num.begin(), num.end(), ','), num.end());
        n = std::max<std::int64_t>(n, std::stoll(num));
      }
      continue;
    }
    std::istringstream s(line);
    std::int64_t u, v;
    s >> u >> v;
    edges.push_back({u, v});
    n = std::max({n, u + 1, v + 1});
  }
  return true;
}

// The edge list, or the benchmark skipped with the reason.
bool read_edges(benchmark::State& state, Edges& edges, std::int64_t& n) {
  std::string why;
  if (read_edges(edges, n, why)) return true;
  state.SkipWithError(why.c_str());
  return false;
}

std::vector<std::int64_t> grid101_triangles() {
  std::vector<std::int64_t> t;
  for (std::int64_t i = 0; i < 100; ++i)
    for (std::int64_t j = 0; j < 100; ++j) {
      const std::int64_t a = i * 101 + j;
      t.insert(t.end(), {a, a + 1, a + 102, a, a + 102, a + 101});
    }
  return t;
}

std::int64_t rgg_ops(const topos::SimplicialComplex& sc) {
  std::int64_t nnz = 0;
  for (int k = 1; k <= 3; ++k) nnz += sc.incidence_matrix(k).nonZeros();
  for (int k = 0; k <= 3; ++k) nnz += sc.hodge_laplacian_matrix(k).nonZeros();
  for (int k = 0; k <= 2; ++k) nnz += sc.adjacency_matrix(k).nonZeros();
  return nnz;
}
std::int64_t mesh_ops(const topos::SimplicialComplex& sc) {
  std::int64_t nnz = 0;
  for (int k = 1; k <= 2; ++k) nnz += sc.incidence_matrix(k).nonZeros();
  for (int k = 0; k <= 2; ++k) nnz += sc.hodge_laplacian_matrix(k).nonZeros();
  return nnz;
}

// Runs `body` per iteration and reports TopoNetX's seconds / ours.
template <class F>
void timed(benchmark::State& state, double toponetx_seconds, F&& body) {
  double total = 0;
  for (auto _ : state) {
    const auto t0 = std::chrono::steady_clock::now();
    benchmark::DoNotOptimize(body());
    total += std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  }
  if (toponetx_seconds > 0 && state.iterations() > 0) {
    state.counters["x_toponetx"] =
        toponetx_seconds / (total / static_cast<double>(state.iterations()));
    state.SetLabel("TopoNetX " + std::to_string(toponetx_seconds).substr(0, 4) + " s");
  }
}

void BM_rgg2000_clique_ops(benchmark::State& state) {
  Edges edges;
  std::int64_t n = 0;
  if (!read_edges(state, edges, n)) return;
  timed(state, 1.12, [&] {
    const auto sc = topos::clique_complex(n, edges, 3);
    return rgg_ops(sc) + sc.num_cells(3);
  });
  const auto sc = topos::clique_complex(n, edges, 3);
  for (int k = 0; k <= 3; ++k)
    state.counters["n" + std::to_string(k)] = static_cast<double>(sc.num_cells(k));
}
BENCHMARK(BM_rgg2000_clique_ops)->Unit(benchmark::kMillisecond);

void BM_rgg2000_clique_complex(benchmark::State& state) {
  Edges edges;
  std::int64_t n = 0;
  if (!read_edges(state, edges, n)) return;
  timed(state, 0.42, [&] { return topos::clique_complex(n, edges, 3).num_cells(3); });
}
BENCHMARK(BM_rgg2000_clique_complex)->Unit(benchmark::kMillisecond);

void BM_rgg2000_operators(benchmark::State& state) {
  Edges edges;
  std::int64_t n = 0;
  if (!read_edges(state, edges, n)) return;
  const auto sc = topos::clique_complex(n, edges, 3);
  timed(state, 0.70, [&] { return rgg_ops(sc); });
}
BENCHMARK(BM_rgg2000_operators)->Unit(benchmark::kMillisecond);

void BM_grid101_ops(benchmark::State& state) {
  const auto t = grid101_triangles();
  timed(state, 1.17, [&] {
    const auto sc = topos::SimplicialComplex::from_flat(t.data(), t.size() / 3, 3, 101 * 101);
    return mesh_ops(sc) + sc.num_cells(2);
  });
  const auto sc = topos::SimplicialComplex::from_flat(t.data(), t.size() / 3, 3, 101 * 101);
  for (int k = 0; k <= 2; ++k)
    state.counters["n" + std::to_string(k)] = static_cast<double>(sc.num_cells(k));
}
BENCHMARK(BM_grid101_ops)->Unit(benchmark::kMillisecond);

void BM_grid101_complex(benchmark::State& state) {
  const auto t = grid101_triangles();
  timed(state, 0.38, [&] {
    return topos::SimplicialComplex::from_flat(t.data(), t.size() / 3, 3, 101 * 101).num_cells(1);
  });
}
BENCHMARK(BM_grid101_complex)->Unit(benchmark::kMillisecond);

void BM_grid101_operators(benchmark::State& state) {
  const auto t = grid101_triangles();
  const auto sc = topos::SimplicialComplex::from_flat(t.data(), t.size() / 3, 3, 101 * 101);
  timed(state, 0.79, [&] { return mesh_ops(sc); });
}
BENCHMARK(BM_grid101_operators)->Unit(benchmark::kMillisecond);

void BM_mesh100k_ops(benchmark::State& state) {
  const topos::TriangleMesh mesh = topos::uv_sphere(201, 250);  // 50,002 nodes, 100,000 faces
  timed(state, 0, [&] {
    const auto sc = topos::simplicial_complex_from_mesh(mesh);
    return mesh_ops(sc) + sc.num_cells(2);
  });
  state.counters["faces"] = static_cast<double>(mesh.num_faces());
}
BENCHMARK(BM_mesh100k_ops)->Unit(benchmark::kMillisecond);

}  // namespace

int main(int argc, char** argv) {
  const char* keep = std::getenv("TOPOS_BENCH_DEFAULT_MALLOC");
  const bool tuned = keep == nullptr || std::string(keep) != "1";
  if (tuned) {
    mallopt(M_MMAP_THRESHOLD, 1 << 30);
    mallopt(M_TRIM_THRESHOLD, 1 << 30);
  }
  benchmark::AddCustomContext(
      "malloc",
      tuned
          ? "M_MMAP_THRESHOLD=M_TRIM_THRESHOLD=1 GiB (TOPOS_BENCH_DEFAULT_MALLOC=1: glibc defaults)"
          : "glibc defaults");
  benchmark::Initialize(&argc, argv);
  if (benchmark::ReportUnrecognizedArguments(argc, argv)) return 1;
  benchmark::RunSpecifiedBenchmarks();
  benchmark::Shutdown();
  return 0;
}
