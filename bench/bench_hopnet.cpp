// HOPNet on MOVi-A scene 8 with the published modela weights (TOPOS_REFERENCE_DIR must point
// at the shared reference folder): one forward pass, one whole rollout step (contacts,
// features, forward, shape matching), and the 102-step rollout, in reference and native modes.
// Issue bars (2 cores): forward <= 3 ms, step <= 5 ms, rollout <= 0.6 s; the Python reference
// takes 8-10 ms, 181 ms and 18.5 s. Threads: 1 intra-op thread (set below), the fastest here.
// And one training step on the whole trajectory (below), for the standard model and for every
// variant preset (BM_train_step_variant, freshly initialised, native mode). Native mode also with
// bfloat16 products (bf16: 1, `hopnet rollout --mode native --matmul-precision medium`). The
// roofline's counters (docs/benchmarks.md): each forward's FLOPs by the network's plan, GFLOP/s,
// the dense kernel alone on HOPNet's shapes (BM_dense_kernel), and one core's peak by precision
// (BM_peak).
#include <benchmark/benchmark.h>
#if defined(__x86_64__)
#include <immintrin.h>
#endif

#include "topos/models/hopnet/training.hpp"
#include "topos/models/hopnet/variants.hpp"
#include "topos/nn/cpu.hpp"
#include "topos/util/malloc.hpp"
#include "topos/util/memory.hpp"

#include <algorithm>
#include <chrono>
#include <cstdlib>
#include <cstring>
#include <iostream>

using namespace topos;
using namespace topos::models::hopnet;

namespace {
struct Setup {
  std::string ref;
  Scene scene;
  Normalizer norm;
  std::vector<ContactCandidate> first;
  explicit Setup() {
    const char* d = std::getenv("TOPOS_REFERENCE_DIR");
    if (!d) throw std::runtime_error("set TOPOS_REFERENCE_DIR to the shared reference folder");
    ref = d;
    MeshLibrary lib(ref + "/data/kubasic");
    scene = make_scene(data::read_kubric_metadata(ref + "/data/movi-a/8"), lib);
    norm = Normalizer(read_stats_json(ref + "/data/normalization/movia.json"));
    first = read_collisions_json(ref + "/data/movi-a/8/collisions.json").at(3);
  }
  Hopnet model(FeatureMode m) const {
    auto net = load_hopnet(ref + "/data/checkpoints/modela_seed2_e39.pt", m);
    net->eval();
    return net;
  }
};
const Setup& setup() {
  static Setup s;
  return s;
}

// What every benchmark below starts from: the mode of its argument, the published model in that
// mode, and the scene's geometry; one intra-op and one BLAS thread unless a benchmark says else.
struct Case {
  FeatureMode mode;
  Hopnet net;
  HopnetGeometry g;
};
Case make_case(const benchmark::State& state) {
  nn::set_cpu_threads(1, 1);
  const auto mode = static_cast<FeatureMode>(state.range(0));
  return {mode, setup().model(mode), make_geometry(setup().scene, mode)};
}

// The matmul precision of a benchmark's second argument (bf16: 1, medium) while it runs;
// highest again afterwards, for the benchmarks that follow in the process.
struct Precision {
  explicit Precision(bool bf16) {
    nn::set_float32_matmul_precision(bf16 ? nn::MatmulPrecision::medium
                                          : nn::MatmulPrecision::highest);
  }
  ~Precision() { nn::set_float32_matmul_precision(nn::MatmulPrecision::highest); }
};

// The library of float32 products (gemm: 0 BLAS, 1 oneDNN, 2 topos's dense kernel; nn::CpuGemm)
// while a benchmark runs; BLAS again afterwards.
struct Gemm {
  explicit Gemm(std::int64_t g) { nn::set_cpu_gemm(static_cast<nn::CpuGemm>(g)); }
  ~Gemm() { nn::set_cpu_gemm(nn::CpuGemm::blas); }
};

// The FLOPs of one forward over `b` as the network's plan counts them (OperatorNetwork::plan over
// the batch: dense products 2·rows·in·out, sparse ones 2·pairs·width; in the plain order, so
// messages for every source cell, where the fast paths compute only those with a receiver).
std::int64_t plan_flops(const Hopnet& net, const HopnetBatch& b, bool print = false) {
  auto inputs = b.inputs;
  if (net->options.mode() != FeatureMode::native) inputs.erase("x3_plus");
  const auto plan = net->plan(inputs, b.complex);
  if (print) std::cerr << plan.str();
  return plan.total_flops;
}

// The frame at t = 100 (47 faces, 49 contacts in reference mode) as one batch.
HopnetBatch frame_100(const HopnetGeometry& g) {
  const auto& S = setup();
  const auto frame =
      build_frame(g, scene_poses(S.scene, 0), scene_poses(S.scene, 98), scene_poses(S.scene, 99),
                  scene_poses(S.scene, 100),
                  detect_contacts(g, pose_objects(g, scene_poses(S.scene, 100)), 0.1));
  return make_batch({{&g, &frame}}, S.norm);
}

void BM_forward(benchmark::State& state) {
  auto [mode, net, g] = make_case(state);
  const Precision precision(state.range(1) != 0);
  const Gemm gemm(state.range(3));
  const auto& S = setup();
  const auto batch = frame_100(g);
  // TOPOS_PRINT_PLAN=1: the plan, operation by operation with its FLOPs, on stderr (once).
  static bool printed = false;
  const bool print = std::getenv("TOPOS_PRINT_PLAN") && !printed;
  printed = printed || print;
  const auto flops = static_cast<double>(plan_flops(net, batch, print));
  // plain: 1 runs the plan as printed, every fast path off (messages from every source cell),
  // so its GFLOP/s is the rate reached on the plan's FLOPs.
  if (state.range(2)) net->set_fast_paths(false);
  torch::NoGradGuard ng;
  for (auto _ : state) benchmark::DoNotOptimize(net->forward(batch, S.norm).a0);
  state.counters["faces"] = static_cast<double>(batch.complex.size(2));
  state.counters["contacts"] = static_cast<double>(batch.complex.size(3));
  state.counters["MFLOP"] = flops / 1e6;
  state.counters["GFLOP/s"] =
      benchmark::Counter(flops / 1e9, benchmark::Counter::kIsIterationInvariantRate);
}
// Native mode with float32 products (BLAS, oneDNN, topos's kernel) and bfloat16 ones; reference
// mode in float32 only.
void precision_args(benchmark::internal::Benchmark* b) {
  b->Args({0, 0, 0})
      ->Args({0, 0, 1})
      ->Args({0, 0, 2})
      ->Args({1, 0, 0})
      ->Args({1, 0, 1})
      ->Args({1, 0, 2})
      ->Args({1, 1, 0})
      ->ArgNames({"native", "bf16", "gemm"});
}
BENCHMARK(BM_forward)
    ->Args({0, 0, 0, 0})
    ->Args({0, 0, 0, 1})
    ->Args({0, 0, 0, 2})
    ->Args({1, 0, 0, 0})
    ->Args({1, 0, 0, 1})
    ->Args({1, 0, 0, 2})
    ->Args({1, 1, 0, 0})
    ->Args({0, 0, 1, 0})
    ->Args({1, 0, 1, 0})
    ->ArgNames({"native", "bf16", "plain", "gemm"})
    ->Unit(benchmark::kMillisecond);

void BM_rollout_step(benchmark::State& state) {
  auto [mode, net, g] = make_case(state);
  const Precision precision(state.range(1) != 0);
  const Gemm gemm(state.range(2));
  const auto& S = setup();
  const Poses p0 = scene_poses(S.scene, 0), p98 = scene_poses(S.scene, 98),
              p99 = scene_poses(S.scene, 99), p100 = scene_poses(S.scene, 100);
  for (auto _ : state) {
    const auto contacts = detect_contacts(g, pose_objects(g, p100), 0.1);
    benchmark::DoNotOptimize(
        predict_next(*net, S.norm, g, p0, p98, p99, p100, contacts).positions.data());
  }
  const auto flops = static_cast<double>(plan_flops(net, frame_100(g)));
  state.counters["MFLOP"] = flops / 1e6;
  state.counters["GFLOP/s"] =
      benchmark::Counter(flops / 1e9, benchmark::Counter::kIsIterationInvariantRate);
}
BENCHMARK(BM_rollout_step)->Apply(precision_args)->Unit(benchmark::kMillisecond);

void BM_rollout_102(benchmark::State& state) {
  auto [mode, net, g] = make_case(state);
  // threads: LibTorch's intra-op threads, which topos's kernels and oneDNN's products share;
  // steps: the threads a parallel group's steps share (OperatorNetworkImpl::step_threads).
  if (state.range(3) > 1) nn::set_cpu_threads(static_cast<int>(state.range(3)), 1);
  net->step_threads(static_cast<int>(state.range(4)));
  const Precision precision(state.range(1) != 0);
  const Gemm gemm(state.range(2));
  const auto& S = setup();
  RolloutOptions opt;
  if (mode == FeatureMode::reference) opt.first_contacts = S.first;
  double pos100 = 0;
  for (auto _ : state)
    pos100 = rollout_metrics(rollout(*net, S.norm, S.scene, g, opt).poses, S.scene).pos_rmse[100];
  state.counters["pos_rmse_100"] = pos100;
}
// precision_args on one thread, then both float32 modes on two intra-op threads (oneDNN's
// products and topos's kernel), then oneDNN's float32 and native bfloat16 on two step threads.
void rollout_args(benchmark::internal::Benchmark* b) {
  for (const auto& a : std::vector<std::vector<std::int64_t>>{
           {0, 0, 0}, {0, 0, 1}, {0, 0, 2}, {1, 0, 0}, {1, 0, 1}, {1, 0, 2}, {1, 1, 0}})
    b->Args({a[0], a[1], a[2], 1, 1});
  for (std::int64_t native : {0, 1})
    for (std::int64_t gemm : {1, 2}) b->Args({native, 0, gemm, 2, 1});
  for (const auto& a : std::vector<std::vector<std::int64_t>>{{0, 0, 1}, {1, 0, 1}, {1, 1, 0}})
    b->Args({a[0], a[1], a[2], 1, 2});
  b->ArgNames({"native", "bf16", "gemm", "threads", "steps"});
}
BENCHMARK(BM_rollout_102)->Apply(rollout_args)->Unit(benchmark::kMillisecond)->MinTime(2.0);

// The dense kernel alone on HOPNet's shapes, one thread: x Wᵀ + b, as the MLPs' Linear layers
// run (rows × in -> 128). Rows as in scene 8's forward at frame 100: 64 (its 47-50 faces and
// 49-119 contacts; bfloat16 pads to 64 rows anyway), 192 (its 183 nodes), 512 (its 524 edges),
// and 87,296 (a whole training trajectory's nodes, 477 timesteps); in: 128 (a message MLP's
// layers), 256 and 512 (the updates' first layers over concatenated states). bf16: 0 is
// nn::linear_act, the float32 path of a rollout; 1 the bfloat16 product of nn::linear at medium
// precision (the casts, oneDNN's bfloat16 kernel) as the MLPs run it.
void BM_dense_kernel(benchmark::State& state) {
  nn::set_cpu_threads(1, 1);
  // As training runs: without it each 87,296-row output (45 MB, above glibc's 32 MB mmap bound)
  // is fresh zero pages, and the figure measures the VM's page faults (16 against 158 GFLOP/s on
  // 2026-11-30's AMD VM).
  nn::keep_freed_memory();
  const std::int64_t rows = state.range(0), in = state.range(1), out = 128;
  const bool bf16 = state.range(2) != 0;
  torch::manual_seed(0);
  const auto x = torch::randn({rows, in}), W = torch::randn({out, in}) / 16,
             b = torch::randn({out});
  const Precision precision(bf16);
  torch::NoGradGuard ng;
  for (auto _ : state)
    benchmark::DoNotOptimize(bf16 ? nn::linear(x, W, b) : nn::linear_act(x, W, b));
  state.counters["GFLOP/s"] = benchmark::Counter(2.0 * static_cast<double>(rows * in * out) / 1e9,
                                                 benchmark::Counter::kIsIterationInvariantRate);
}
BENCHMARK(BM_dense_kernel)
    ->ArgsProduct({{64, 192, 512, 87296}, {128, 256, 512}, {0, 1}})
    ->ArgNames({"rows", "in", "bf16"})
    ->Unit(benchmark::kMicrosecond)
    ->MinTime(0.5);

#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__)
// One core's arithmetic ceiling by precision, the roofline's top: twelve independent vector
// accumulators (more than latency × ports need) kept in registers, each updated n times by
// STEP(a) (a macro: vector arguments between functions of other targets would change the ABI).
#define TOPOS_PEAK_LOOP(V, acc, n, STEP)                                                \
  {                                                                                     \
    V a0 = acc[0], a1 = acc[1], a2 = acc[2], a3 = acc[3], a4 = acc[4], a5 = acc[5];     \
    V a6 = acc[6], a7 = acc[7], a8 = acc[8], a9 = acc[9], a10 = acc[10], a11 = acc[11]; \
    for (long i = 0; i < (n); ++i) {                                                    \
      a0 = STEP(a0), a1 = STEP(a1), a2 = STEP(a2), a3 = STEP(a3), a4 = STEP(a4);        \
      a5 = STEP(a5), a6 = STEP(a6), a7 = STEP(a7), a8 = STEP(a8), a9 = STEP(a9);        \
      a10 = STEP(a10), a11 = STEP(a11);                                                 \
    }                                                                                   \
    acc[0] = a0, acc[1] = a1, acc[2] = a2, acc[3] = a3, acc[4] = a4, acc[5] = a5;       \
    acc[6] = a6, acc[7] = a7, acc[8] = a8, acc[9] = a9, acc[10] = a10, acc[11] = a11;   \
  }
// The sum of the accumulators' lanes (so that none of them is dead code), read as bytes.
template <class T>
float lanes_sum(const void* acc, std::size_t bytes) {
  float sum = 0;
  for (std::size_t i = 0; i < bytes / sizeof(T); ++i) {
    T v;
    std::memcpy(&v, static_cast<const char*>(acc) + i * sizeof(T), sizeof(T));
    sum += static_cast<float>(v);
  }
  return sum;
}
// float32 FMA (vfmadd231ps: 16 multiply-adds, 32 FLOP).
__attribute__((noinline, target("avx512f"))) float peak_fma_f32(long n) {
  __m512 acc[12];
  for (auto& a : acc) a = _mm512_set1_ps(0.0f);
  const __m512 x = _mm512_set1_ps(1.0001f), y = _mm512_set1_ps(0.9999f);
#define TOPOS_STEP(a) _mm512_fmadd_ps(x, y, a)
  TOPOS_PEAK_LOOP(__m512, acc, n, TOPOS_STEP)
#undef TOPOS_STEP
  return lanes_sum<float>(acc, sizeof acc);
}
// bfloat16 pairs into float32 (vdpbf16ps: 32 multiply-adds, 64 FLOP), what bfloat16 products
// run on where there is no AMX.
__attribute__((noinline, target("avx512f,avx512bf16"))) float peak_dot_bf16(long n) {
  __m512 acc[12];
  for (auto& a : acc) a = _mm512_set1_ps(0.0f);
  const __m512bh x = (__m512bh)_mm512_set1_epi16(0x3f80);  // bfloat16 ones
#define TOPOS_STEP(a) _mm512_dpbf16_ps(a, x, x)
  TOPOS_PEAK_LOOP(__m512, acc, n, TOPOS_STEP)
#undef TOPOS_STEP
  return lanes_sum<float>(acc, sizeof acc);
}
// float16 FMA (vfmadd231ph: 32 multiply-adds, 64 FLOP; float16 accumulators, which stop growing
// at float16's precision: normal numbers throughout, nothing denormal).
__attribute__((noinline, target("avx512f,avx512fp16"))) float peak_fma_f16(long n) {
  __m512h acc[12];
  for (auto& a : acc) a = _mm512_set1_ph(static_cast<_Float16>(0.0f));
  const __m512h x = _mm512_set1_ph(static_cast<_Float16>(1.0f)),
                y = _mm512_set1_ph(static_cast<_Float16>(0.5f));
#define TOPOS_STEP(a) _mm512_fmadd_ph(x, y, a)
  TOPOS_PEAK_LOOP(__m512h, acc, n, TOPOS_STEP)
#undef TOPOS_STEP
  return lanes_sum<_Float16>(acc, sizeof acc);
}
#undef TOPOS_PEAK_LOOP
#endif

// One core's peak FLOP rate per instruction kind (kind 0: float32 FMA, 1: bfloat16 dot
// products, 2: float16 FMA), the ceiling of docs/benchmarks.md's roofline: on a CPU whose
// bfloat16 dot products reach half the float32 FMAs' FLOP rate, bfloat16 products cannot be
// faster than float32 ones, whatever the kernel. A kind the CPU lacks is skipped with its name.
void BM_peak(benchmark::State& state) {
#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__)
  const int kind = static_cast<int>(state.range(0));
  const char* names[] = {"avx512f", "avx512bf16", "avx512fp16"};
  const char* labels[] = {"float32 FMA", "bfloat16 dot product", "float16 FMA"};
  state.SetLabel(labels[kind]);
  const bool has = kind == 0   ? __builtin_cpu_supports("avx512f")
                   : kind == 1 ? __builtin_cpu_supports("avx512bf16")
                               : __builtin_cpu_supports("avx512fp16");
  if (!has) {
    state.SkipWithError((std::string("this CPU has no ") + names[kind]).c_str());
    return;
  }
  long n = 1'000'000;
  for (auto _ : state) {
    benchmark::DoNotOptimize(n);  // not hoisted: each iteration computes
    benchmark::DoNotOptimize(kind == 0   ? peak_fma_f32(n)
                             : kind == 1 ? peak_dot_bf16(n)
                                         : peak_fma_f16(n));
  }
  state.counters["GFLOP/s"] = benchmark::Counter(12.0 * n * (kind == 0 ? 32 : 64) / 1e9,
                                                 benchmark::Counter::kIsIterationInvariantRate);
#else
  state.SkipWithError("x86-64 with GCC only");
#endif
}
BENCHMARK(BM_peak)->ArgName("kind")->DenseRange(0, 2)->Unit(benchmark::kMillisecond)->MinTime(0.5);

// LayerNorm over 128 channels, as every HOPNet MLP ends, one thread: torch's layer_norm
// (topos: 0) against nn::layer_norm (topos: 1), forward alone or forward and backward (backward:
// 1). Rows as BM_dense_kernel's. Freed memory is kept (nn::keep_freed_memory), as in training.
void BM_layer_norm(benchmark::State& state) {
  nn::set_cpu_threads(1, 1);
  nn::keep_freed_memory();  // as training runs: a trajectory's fresh pages are not the kernel's
  const std::int64_t rows = state.range(0), channels = 128;
  const bool topos = state.range(1) != 0, backward = state.range(2) != 0;
  torch::manual_seed(0);
  const auto x = torch::randn({rows, channels}).requires_grad_(backward);
  const auto w = torch::randn({channels}).requires_grad_(backward),
             b = torch::randn({channels}).requires_grad_(backward);
  const auto dy = torch::randn({rows, channels});
  const auto run = [&] {
    return topos ? nn::layer_norm(x, w, b, 1e-5) : torch::layer_norm(x, {channels}, w, b, 1e-5);
  };
  for (auto _ : state) {
    if (backward) {
      run().backward(dy);
    } else {
      torch::NoGradGuard ng;
      benchmark::DoNotOptimize(run());
    }
  }
  state.counters["GB/s"] =
      benchmark::Counter((backward ? 5.0 : 2.0) * 4.0 * static_cast<double>(rows * channels) / 1e9,
                         benchmark::Counter::kIsIterationInvariantRate);
}
BENCHMARK(BM_layer_norm)
    ->ArgsProduct({{64, 192, 512, 87296}, {0, 1}, {0, 1}})
    ->ArgNames({"rows", "topos", "backward"})
    ->Unit(benchmark::kMicrosecond);

// One optimizer step on the whole trajectory (t = 2..478: 477 timesteps), forward, backward and
// Adam (train_step, as `hopnet train`). Arguments: chunk, timesteps per forward/backward (0: the
// whole trajectory in one batch); workers, chunks run at once on their own threads (1: one after
// the other, with BLAS threads on every core and one intra-op thread; more: one BLAS thread each).
// bf16: 1 multiplies in bfloat16 (nn::MatmulPrecision::medium, `hopnet train --matmul-precision
// medium`). Reference mode trains on collisions.json's contacts, as the reference does.
// Issue bar: 0.8 s on 2 cores (goal 0.5 s); the Python reference takes 7 s (plus preprocessing).
void BM_train_step(benchmark::State& state) {
  auto [mode, net, g] = make_case(state);
  const int workers = static_cast<int>(state.range(2));
  nn::set_cpu_threads(1, workers > 1 ? 1 : 0);
  nn::keep_freed_memory();
  nn::set_float32_matmul_precision(state.range(3) ? nn::MatmulPrecision::medium
                                                  : nn::MatmulPrecision::highest);
  const auto& S = setup();
  const auto contacts = read_collisions_json(S.ref + "/data/movi-a/8/collisions.json");
  const auto tf = trajectory_frames(S.scene, g, 0.1, 0.0, 2, -1,
                                    mode == FeatureMode::reference ? &contacts : nullptr);
  const auto chunks = make_training_chunks(g, tf, S.norm, state.range(1));
  net->train();
  torch::optim::Adam opt(net->parameters(), torch::optim::AdamOptions(1e-4));
  // The first step also grows the heap to its working size (~1 s more); measure the steady state.
  const auto t0 = std::chrono::steady_clock::now();
  train_step(*net, opt, chunks, S.norm, nullptr, workers);
  state.counters["first_step_s"] =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  reset_peak_rss();
  for (auto _ : state) train_step(*net, opt, chunks, S.norm, nullptr, workers);
  nn::set_cpu_threads(1, 1);
  nn::set_float32_matmul_precision(nn::MatmulPrecision::highest);
  state.counters["peak_rss_mb"] = peak_rss_mb();
  // The step's FLOPs: the forward's by the plan, chunk by chunk, and the backward's twice that
  // (each product's input and weight gradients; the encoders' inputs need none, a few per cent
  // less).
  double forward = 0;
  for (const auto& c : chunks) forward += static_cast<double>(plan_flops(net, c.batch));
  state.counters["GFLOP"] = 3 * forward / 1e9;
  state.counters["GFLOP/s"] =
      benchmark::Counter(3 * forward / 1e9, benchmark::Counter::kIsIterationInvariantRate);
  state.counters["timesteps"] = static_cast<double>(tf.frames.size());
  state.counters["timesteps_per_s"] = benchmark::Counter(
      static_cast<double>(tf.frames.size()), benchmark::Counter::kIsIterationInvariantRate);
}
BENCHMARK(BM_train_step)
    ->Args({0, 0, 1, 0})
    ->Args({1, 0, 1, 0})
    ->Args({0, 120, 1, 0})
    ->Args({0, 60, 2, 0})
    ->Args({1, 60, 2, 0})
    ->Args({0, 30, 2, 0})
    ->Args({0, 60, 2, 1})
    ->Args({1, 60, 2, 1})
    ->Args({0, 30, 2, 1})
    ->ArgNames({"native", "chunk", "workers", "bf16"})
    ->Unit(benchmark::kMillisecond)
    ->MinTime(5.0)
    ->UseRealTime();

// One training step of each variant (the presets of models/hopnet/variants.hpp) on the same
// trajectory, native mode, fresh weights (seed 0), as BM_train_step. Statistics: movia.json,
// movia-nox4.json for nox4, and movia.json's first 8 x0 columns without centre-mass distances.
const std::vector<std::string> kVariants{"standard", "nox4", "noseq",   "no-cm-distance",
                                         "mlp3",     "mp2",  "hidden64"};
void BM_train_step_variant(benchmark::State& state) {
  const auto& S = setup();
  const std::string config = kVariants.at(static_cast<std::size_t>(state.range(0)));
  state.SetLabel(config);
  nn::set_cpu_threads(1, 0);
  nn::keep_freed_memory();
  torch::manual_seed(0);
  const auto o = parse_config(config, HopnetOptions().mode(FeatureMode::native));
  Hopnet net(o);
  auto stats = read_stats_json(S.ref + (o.architecture() == Architecture::no_object_cells
                                            ? "/data/normalization/movia-nox4.json"
                                            : "/data/normalization/movia.json"));
  if (!o.center_mass_distance()) stats.mean["x0"].resize(8), stats.std["x0"].resize(8);
  const Normalizer norm(stats);
  const auto g = make_geometry(S.scene, o.lifting());
  const auto item =
      make_training_item(g, trajectory_frames(S.scene, g, o.collision_radius()), norm);
  net->train();
  torch::optim::Adam opt(net->parameters(), torch::optim::AdamOptions(1e-4));
  const auto step = [&] {
    opt.zero_grad();
    auto loss = trajectory_loss(*net, item, norm);
    loss.backward();
    opt.step();
  };
  step();
  for (auto _ : state) step();
  nn::set_cpu_threads(1, 1);
  state.counters["parameters"] = static_cast<double>(net->num_parameters());
  state.counters["timesteps_per_s"] = benchmark::Counter(
      static_cast<double>(item.timesteps), benchmark::Counter::kIsIterationInvariantRate);
}
BENCHMARK(BM_train_step_variant)
    ->DenseRange(0, 6)
    ->Unit(benchmark::kMillisecond)
    ->MinTime(3.0)
    ->UseRealTime();

// hopnet's malloc (topos::tcmalloc), named in the output's context.
const int malloc_context = [] {
  benchmark::AddCustomContext("malloc", topos::malloc_name());
  return 0;
}();
}  // namespace

BENCHMARK_MAIN();
