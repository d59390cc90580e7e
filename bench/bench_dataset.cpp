// Loading a whole dataset: a synthetic MOVi-A-sized topos dataset (1200 scenes, 3-10 objects,
// 480 frames; about 230 MB of float64 poses) written once to a temporary folder, then opened
// with data::Dataset::open, which reads every pose. Issue bar: "all poses of a 1200-scene
// dataset in seconds". For contrast, the same scenes as Kubric metadata.json are read at about
// 90 scenes/s (13 s for 1200).
#include <benchmark/benchmark.h>

#include "topos/data/dataset.hpp"

#include <random>

using namespace topos::data;

namespace {
std::filesystem::path make_dataset() {
  const auto dir = std::filesystem::temp_directory_path() / "topos_bench_dataset";
  if (std::filesystem::exists(dir / "dataset.json")) return dir;
  std::mt19937 rng(0);
  std::vector<KubricScene> scenes;
  for (int seed = 1; seed <= 1200; ++seed) {
    KubricScene s;
    s.seed = seed;
    s.num_frames = 480;
    const int objects = 3 + static_cast<int>(rng() % 8);
    for (int o = 0; o < objects; ++o) {
      KubricInstance k;
      k.asset_id = k.shape = "cube";
      k.size = 1, k.mass = 1, k.friction = 0.5, k.restitution = 0.5;
      k.positions.setRandom(480, 3);
      k.quaternions.setRandom(480, 4);
      s.instances.push_back(std::move(k));
    }
    scenes.push_back(std::move(s));
  }
  write_topos_dataset(scenes, dir);
  return dir;
}

void BM_open_topos_dataset(benchmark::State& state) {
  const auto dir = make_dataset();
  std::size_t n = 0;
  for (auto _ : state) {
    const auto d = Dataset::open(dir);
    n = d.ids().size();
    benchmark::DoNotOptimize(d.scene(600).instances[0].positions(479, 2));
  }
  state.counters["scenes"] = static_cast<double>(n);
  state.counters["MB"] = static_cast<double>(std::filesystem::file_size(dir / "positions.npy") +
                                             std::filesystem::file_size(dir / "quaternions.npy")) /
                         1e6;
}
BENCHMARK(BM_open_topos_dataset)->Unit(benchmark::kMillisecond)->MinTime(3.0);
}  // namespace

BENCHMARK_MAIN();
