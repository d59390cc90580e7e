// Contact detection per frame on MOVi-A scene 8 (3 objects + floor, 183 nodes) and on a
// 10-object MOVi-B-like scene of KuBasic meshes, native and reference-compatible modes.
// Set TOPOS_REFERENCE_DIR to the shared reference folder.
#include <benchmark/benchmark.h>

#include "topos/geometry/contacts.hpp"
#include "topos/sim/scene.hpp"

#include <cstdlib>
#include <random>

using namespace topos;

namespace {
std::string ref_dir() {
  const char* d = std::getenv("TOPOS_REFERENCE_DIR");
  return d ? d : "";
}
const sim::Scene& movi_a8() {
  static sim::Scene s = [] {
    sim::MeshLibrary lib(ref_dir() + "/data/kubasic");
    return sim::make_scene(data::read_kubric_metadata(ref_dir() + "/data/movi-a/8"), lib);
  }();
  return s;
}
// Ten KuBasic objects stacked closely above the floor (1.5 m spacing, sizes 0.75-1.5), posed at
// random orientations: many face pairs within d_c, like a settled MOVi-B frame.
std::vector<PosedObject> kubasic_scene(std::vector<TriangleMesh>& keep) {
  sim::MeshLibrary lib(ref_dir() + "/data/kubasic");
  const char* shapes[] = {"cube", "sphere",     "cylinder", "cone", "torus",
                          "gear", "torus_knot", "sponge",   "spot", "teapot"};
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> u(-1, 1);
  keep.clear();
  for (int i = 0; i < 10; ++i) {
    TriangleMesh m = lib.unit_mesh(shapes[i]);
    m.vertices *= 1.0 + 0.4 * u(rng);
    keep.push_back(m);
  }
  keep.push_back(sim::floor_mesh());
  std::vector<PosedObject> objs;
  for (int i = 0; i < 10; ++i) {
    const Eigen::Vector3d p(1.45 * (i % 4) - 2, 1.45 * (i / 4) - 1.5, 0.74);
    objs.push_back(
        {pose_vertices(keep[i].vertices, p, Eigen::Vector4d(u(rng), u(rng), u(rng), u(rng))),
         &keep[i].faces});
  }
  objs.push_back({keep[10].vertices, &keep[10].faces});
  return objs;
}
}  // namespace

static void BM_MoviA8_Reference(benchmark::State& state) {
  if (ref_dir().empty()) return state.SkipWithError("set TOPOS_REFERENCE_DIR");
  const auto& s = movi_a8();
  std::vector<VertexFaceIndex> idx;
  for (auto& o : s.objects) idx.emplace_back(o.mesh.faces, o.mesh.vertices.rows());
  std::vector<std::vector<PosedObject>> frames;
  for (std::int64_t t = 0; t < s.num_frames; ++t) frames.push_back(sim::pose_scene(s, t));
  std::size_t t = 0, pairs = 0;
  for (auto _ : state) {
    auto c = reference_contacts(frames[t++ % frames.size()], 0.1, &idx);
    for (auto& e : c) pairs += e.pairs.size();
  }
  state.counters["pairs/frame"] =
      static_cast<double>(pairs) / static_cast<double>(state.iterations());
}
BENCHMARK(BM_MoviA8_Reference)->Unit(benchmark::kMicrosecond);

static void BM_MoviA8_Native(benchmark::State& state) {
  if (ref_dir().empty()) return state.SkipWithError("set TOPOS_REFERENCE_DIR");
  const auto& s = movi_a8();
  std::vector<std::vector<PosedObject>> frames;
  for (std::int64_t t = 0; t < s.num_frames; ++t) frames.push_back(sim::pose_scene(s, t));
  std::size_t t = 0, pairs = 0;
  for (auto _ : state) pairs += find_contacts(frames[t++ % frames.size()], 0.1).size();
  state.counters["pairs/frame"] =
      static_cast<double>(pairs) / static_cast<double>(state.iterations());
}
BENCHMARK(BM_MoviA8_Native)->Unit(benchmark::kMicrosecond);

static void BM_KuBasic10_Reference(benchmark::State& state) {
  if (ref_dir().empty()) return state.SkipWithError("set TOPOS_REFERENCE_DIR");
  std::vector<TriangleMesh> keep;
  const auto objs = kubasic_scene(keep);
  std::vector<VertexFaceIndex> idx;
  for (auto& o : objs) idx.emplace_back(*o.faces, o.vertices.rows());
  std::size_t pairs = 0, nodes = 0;
  for (auto& o : objs) nodes += static_cast<std::size_t>(o.vertices.rows());
  for (auto _ : state)
    for (auto& e : reference_contacts(objs, 0.1, &idx)) pairs += e.pairs.size();
  state.counters["pairs/frame"] =
      static_cast<double>(pairs) / static_cast<double>(state.iterations());
  state.counters["nodes"] = static_cast<double>(nodes);
}
BENCHMARK(BM_KuBasic10_Reference)->Unit(benchmark::kMicrosecond);

static void BM_KuBasic10_Native(benchmark::State& state) {
  if (ref_dir().empty()) return state.SkipWithError("set TOPOS_REFERENCE_DIR");
  std::vector<TriangleMesh> keep;
  const auto objs = kubasic_scene(keep);
  std::size_t pairs = 0;
  for (auto _ : state) pairs += find_contacts(objs, 0.1).size();
  state.counters["pairs/frame"] =
      static_cast<double>(pairs) / static_cast<double>(state.iterations());
}
BENCHMARK(BM_KuBasic10_Native)->Unit(benchmark::kMicrosecond);

BENCHMARK_MAIN();
