// Lifting a closed 50,000-node triangle mesh (MOVi-C scale) to ranks 0-2 and building its
// incidence and adjacency matrices.
#include <benchmark/benchmark.h>

#include "topos/core/mesh_lifting.hpp"
#include "topos/mesh/primitives.hpp"

static void BM_LiftAndOperators50k(benchmark::State& state) {
  const topos::TriangleMesh mesh = topos::uv_sphere(201, 250);  // 50,002 nodes, 100,000 faces
  for (auto _ : state) {
    auto lifted = topos::lift_meshes({mesh});
    auto b01 = lifted.complex.incidence_matrix(0, 1);
    auto b12 = lifted.complex.incidence_matrix(1, 2);
    auto a01 = lifted.complex.adjacency_matrix(0, 1);
    benchmark::DoNotOptimize(b01.nonZeros() + b12.nonZeros() + a01.nonZeros());
  }
  state.counters["nodes"] = static_cast<double>(mesh.num_vertices());
}
BENCHMARK(BM_LiftAndOperators50k)->Unit(benchmark::kMillisecond);

static void BM_Lift50k(benchmark::State& state) {
  const topos::TriangleMesh mesh = topos::uv_sphere(201, 250);
  for (auto _ : state) benchmark::DoNotOptimize(topos::lift_meshes({mesh}).complex.size(1));
}
BENCHMARK(BM_Lift50k)->Unit(benchmark::kMillisecond);

static void BM_Incidence12_50k(benchmark::State& state) {
  const auto lifted = topos::lift_meshes({topos::uv_sphere(201, 250)});
  for (auto _ : state) benchmark::DoNotOptimize(lifted.complex.incidence_matrix(1, 2).nonZeros());
}
BENCHMARK(BM_Incidence12_50k)->Unit(benchmark::kMillisecond);

BENCHMARK_MAIN();
