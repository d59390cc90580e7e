// Model zoo speed: forward and forward+backward of SCN2, SCCNN, SAN, CWN and UniGCNII at 32
// channels, two layers, one thread, on the two complexes of shared/reference/tdl-bench (the
// 2-skeleton of the clique complex of rgg2000_edges.txt, and the triangulated 101 x 101 grid),
// with the operator sets its README lists; each benchmark reports its speed-up over the
// TopoModelX time the README gives for the same work (counter "x_topomodelx").
// Counter "peak_rss_MB" is the process's peak resident memory after the benchmark: run one
// benchmark per process (bench/zoo_memory.sh does) to read a model's own peak.
// Needs TOPOS_REFERENCE_DIR for rgg2000 (grid101 is generated). Run with
//   OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 ./build/bench/bench_zoo --benchmark_repetitions=5
#include "topos/models/zoo.hpp"
#include "topos/nn/cpu.hpp"

#include <benchmark/benchmark.h>

#include <Eigen/SparseCore>

#include <sys/resource.h>

#include <algorithm>
#include <chrono>
#include <cstdlib>
#include <fstream>
#include <iostream>
#include <map>
#include <set>
#include <sstream>

using namespace topos;
using namespace topos::models;
using namespace topos::models::zoo;
using nn::SparseOperator;

namespace {

constexpr std::int64_t C = 32;
using Sp = Eigen::SparseMatrix<double, Eigen::RowMajor, std::int64_t>;
using Triplets = std::vector<Eigen::Triplet<double, std::int64_t>>;

// A 2-dimensional simplicial complex: sorted edges and triangles; signed incidences B1 (n0 × n1:
// -1 at u, +1 at v for edge [u, v]) and B2 (n1 × n2: +1, -1, +1 at faces [b c], [a c], [a b]).
struct Complex {
  std::int64_t n0 = 0;
  std::vector<std::array<std::int64_t, 2>> edges;
  std::vector<std::array<std::int64_t, 3>> triangles;
  Sp B1, B2;

  void build() {
    std::sort(edges.begin(), edges.end());
    edges.erase(std::unique(edges.begin(), edges.end()), edges.end());
    std::sort(triangles.begin(), triangles.end());
    std::map<std::array<std::int64_t, 2>, std::int64_t> id;
    for (std::size_t e = 0; e < edges.size(); ++e) id[edges[e]] = static_cast<std::int64_t>(e);
    Triplets t1, t2;
    for (std::size_t e = 0; e < edges.size(); ++e) {
      t1.emplace_back(edges[e][0], static_cast<std::int64_t>(e), -1.0);
      t1.emplace_back(edges[e][1], static_cast<std::int64_t>(e), 1.0);
    }
    for (std::size_t f = 0; f < triangles.size(); ++f) {
      const auto [a, b, c] = triangles[f];
      t2.emplace_back(id.at({b, c}), static_cast<std::int64_t>(f), 1.0);
      t2.emplace_back(id.at({a, c}), static_cast<std::int64_t>(f), -1.0);
      t2.emplace_back(id.at({a, b}), static_cast<std::int64_t>(f), 1.0);
    }
    B1.resize(n0, static_cast<std::int64_t>(edges.size()));
    B1.setFromTriplets(t1.begin(), t1.end());
    B2.resize(static_cast<std::int64_t>(edges.size()), static_cast<std::int64_t>(triangles.size()));
    B2.setFromTriplets(t2.begin(), t2.end());
  }
  std::array<std::int64_t, 3> shape() const {
    return {n0, static_cast<std::int64_t>(edges.size()),
            static_cast<std::int64_t>(triangles.size())};
  }
};

Complex rgg2000() {
  const char* ref = std::getenv("TOPOS_REFERENCE_DIR");
  if (ref == nullptr)
    throw std::runtime_error("rgg2000 needs TOPOS_REFERENCE_DIR (shared/reference)");
  std::ifstream in(std::string(ref) + "/tdl-bench/rgg2000_edges.txt");
  if (!in) throw std::runtime_error("cannot open tdl-bench/rgg2000_edges.txt");
  Complex c;
  c.n0 = 2000;
  std::vector<std::set<std::int64_t>> adj(2000);
  std::string line;
  while (std::getline(in, line)) {
    if (line.empty() || line[0] == '#') continue;
    std::istringstream s(line);
    std::int64_t u, v;
    s >> u >> v;
    c.edges.push_back({std::min(u, v), std::max(u, v)});
    adj[static_cast<std::size_t>(u)].insert(v);
    adj[static_cast<std::size_t>(v)].insert(u);
  }
  for (const auto& [u, v] : c.edges)  // 3-cliques, each once (w > v > u)
    for (auto w : adj[static_cast<std::size_t>(v)])
      if (w > v && adj[static_cast<std::size_t>(u)].count(w)) c.triangles.push_back({u, v, w});
  c.build();
  return c;
}

Complex grid101() {
  Complex c;
  c.n0 = 101 * 101;
  for (std::int64_t i = 0; i < 100; ++i)
    for (std::int64_t j = 0; j < 100; ++j) {
      const auto a = i * 101 + j;
      for (std::array<std::int64_t, 3> t : {std::array<std::int64_t, 3>{a, a + 1, a + 102},
                                            std::array<std::int64_t, 3>{a, a + 101, a + 102}}) {
        std::sort(t.begin(), t.end());
        c.triangles.push_back(t);
        c.edges.push_back({t[0], t[1]});
        c.edges.push_back({t[0], t[2]});
        c.edges.push_back({t[1], t[2]});
      }
    }
  c.build();
  return c;
}

SparseOperator op(const Sp& m) {
  std::vector<std::int64_t> r, c;
  std::vector<double> v;
  for (std::int64_t i = 0; i < m.outerSize(); ++i)
    for (Sp::InnerIterator it(m, i); it; ++it)
      r.push_back(it.row()), c.push_back(it.col()), v.push_back(it.value());
  return SparseOperator::from_triplets(m.rows(), m.cols(), r, c, v);
}
Sp product(const Sp& a, const Sp& b) {
  return Sp(a * b);
}
Sp transpose(const Sp& a) {
  return Sp(a.transpose());
}
// D^-1/2 |L| D^-1/2-style rescale: the values differ from TopoNetX's normalised Laplacian, the
// pattern (what the time depends on) is the same.
Sp normalized(const Sp& L) {
  Eigen::VectorXd d = Eigen::VectorXd::Zero(L.rows());
  for (std::int64_t i = 0; i < L.outerSize(); ++i)
    for (Sp::InnerIterator it(L, i); it; ++it) d(i) += std::abs(it.value());
  Sp out = L;
  for (std::int64_t i = 0; i < out.outerSize(); ++i)
    for (Sp::InnerIterator it(out, i); it; ++it)
      it.valueRef() /= std::sqrt(std::max(d(i), 1.0) * std::max(d(it.col()), 1.0));
  return out;
}
Sp off_diagonal_pattern(const Sp& A) {  // |A| with the diagonal removed, entries set to 1
  Triplets t;
  for (std::int64_t i = 0; i < A.outerSize(); ++i)
    for (Sp::InnerIterator it(A, i); it; ++it)
      if (it.col() != i && it.value() != 0) t.emplace_back(i, it.col(), 1.0);
  Sp out(A.rows(), A.cols());
  out.setFromTriplets(t.begin(), t.end());
  return out;
}
Sp absolute(const Sp& A) {
  return Sp(A.cwiseAbs());
}

// One model on one complex: its module and TopoModelX's positional arguments.
ZooModel build(const std::string& model, const Complex& c, std::vector<ZooArg>& args) {
  const auto n = c.shape();
  torch::manual_seed(0);
  const auto x = [&](int r) {
    return ZooArg::of(torch::randn({n[static_cast<std::size_t>(r)], C}), "x");
  };
  const auto& B1 = c.B1;
  const auto& B2 = c.B2;
  const Sp B1t = transpose(B1), B2t = transpose(B2);
  const Sp L0 = product(B1, B1t), Ld1 = product(B1t, B1), Lu1 = product(B2, B2t),
           L2 = product(B2t, B2);
  const auto O = [](const Sp& m) { return ZooArg::of(op(m), "op"); };
  nlohmann::json cfg;
  if (model == "SCN2") {
    cfg = {{"in_channels_0", C}, {"in_channels_1", C}, {"in_channels_2", C}, {"n_layers", 2}};
    args = {x(0), x(1), x(2), O(normalized(L0)), O(normalized(Sp(Ld1 + Lu1))), O(normalized(L2))};
  } else if (model == "SCCNN") {
    cfg = {{"in_channels_all", {C, C, C}},
           {"hidden_channels_all", {C, C, C}},
           {"conv_order", 1},
           {"sc_order", 2},
           {"n_layers", 2}};
    args = {ZooArg::list({x(0), x(1), x(2)}), ZooArg::list({O(L0), O(Ld1), O(Lu1), O(L2)}),
            ZooArg::list({O(B1), O(B2)})};
  } else if (model == "SAN") {
    cfg = {{"in_channels", C}, {"hidden_channels", C}, {"out_channels", C}, {"n_layers", 2}};
    args = {x(1), O(Lu1), O(Ld1)};
  } else if (model == "CWN") {
    cfg = {{"in_channels_0", C},
           {"in_channels_1", C},
           {"in_channels_2", C},
           {"hid_channels", C},
           {"n_layers", 2}};
    args = {x(0),  x(1),
            x(2),  O(off_diagonal_pattern(product(absolute(B2), transpose(absolute(B2))))),
            O(B2), O(B1t)};
  } else if (model == "UniGCNII") {
    Triplets t;
    for (std::int64_t v = 0; v < n[0]; ++v) t.emplace_back(v, v, 1.0);
    for (std::size_t f = 0; f < c.triangles.size(); ++f)
      for (auto v : c.triangles[f]) t.emplace_back(v, n[0] + static_cast<std::int64_t>(f), 1.0);
    Sp H(n[0], n[0] + n[2]);
    H.setFromTriplets(t.begin(), t.end());
    cfg = {{"in_channels", C}, {"hidden_channels", C}, {"n_layers", 2}};
    args = {x(0), O(H)};
  }
  auto z = make_zoo_model(model, cfg);
  z.module->eval();
  return z;
}

// TopoModelX's times from tdl-bench/README.md (seconds), forward and forward+backward.
const std::map<std::string, std::array<double, 2>> kTopoModelX = {
    {"scn2/rgg2000", {8.3e-3, 19.8e-3}}, {"scn2/grid101", {15.5e-3, 38.4e-3}},
    {"cwn/rgg2000", {7.5e-3, 19.3e-3}},  {"cwn/grid101", {22.4e-3, 56.6e-3}},
    {"sccnn/rgg2000", {4.36, 5.53}},     {"sccnn/grid101", {43.9, 63.3}},
    {"san/rgg2000", {68.2, 147.1}},      {"unigcnii/rgg2000", {18.1, 18.1}},
    {"unigcnii/grid101", {519.0, 522.0}}};

// The process's resident anonymous memory (RssAnon), MB: the heap and tensors without the
// mapped library code. With the cache or the kept heap nothing is given back, so its value after
// a benchmark is the most anonymous memory the benchmark held at once.
double rss_anon_mb() {
  std::ifstream in("/proc/self/status");
  std::string line;
  while (std::getline(in, line))
    if (line.rfind("RssAnon:", 0) == 0) return std::stod(line.substr(8)) / 1024.0;  // kB
  return 0;
}

void run(benchmark::State& state, const std::string& model, const std::string& cname,
         const Complex* complex, bool backward) {
  rusage usage{};
  getrusage(RUSAGE_SELF, &usage);
  const auto rss_before = static_cast<double>(usage.ru_maxrss) / 1024.0;  // KiB on Linux
  const auto anon_before = rss_anon_mb();
  std::vector<ZooArg> args;
  auto z = build(model, *complex, args);
  std::vector<torch::Tensor> R;
  {
    torch::NoGradGuard g;  // the shapes only: a forward with autograd would raise the peak
    for (const auto& y : z.forward(args)) R.push_back(torch::randn_like(y));
  }
  auto once = [&] {
    if (!backward) {
      torch::NoGradGuard g;
      benchmark::DoNotOptimize(z.forward(args));
      return;
    }
    z.module->zero_grad();
    const auto out = z.forward(args);
    torch::Tensor loss = (out[0] * R[0]).sum();
    for (std::size_t i = 1; i < out.size(); ++i) loss = loss + (out[i] * R[i]).sum();
    loss.backward();
  };
  double total = 0;
  for (auto _ : state) {
    const auto t0 = std::chrono::steady_clock::now();
    once();
    total += std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  }
  std::string lower = model;
  std::transform(lower.begin(), lower.end(), lower.begin(),
                 [](unsigned char ch) { return static_cast<char>(std::tolower(ch)); });
  auto it = kTopoModelX.find(lower + "/" + cname);
  if (it != kTopoModelX.end() && state.iterations() > 0)
    state.counters["x_topomodelx"] =
        it->second[backward ? 1 : 0] / (total / static_cast<double>(state.iterations()));
  getrusage(RUSAGE_SELF, &usage);
  state.counters["peak_rss_MB"] = static_cast<double>(usage.ru_maxrss) / 1024.0;
  // The peak before this benchmark built its model: LibTorch and the complexes (one benchmark
  // per process, bench/zoo_memory.sh, so that it is not an earlier benchmark's peak).
  state.counters["rss_before_MB"] = rss_before;
  state.counters["anon_above_MB"] = rss_anon_mb() - anon_before;
}

// The sparse-dense product alone, side by side with torch's COO kernel (what TopoModelX calls) on
// the same operator and features: a same-machine ratio that a busy machine disturbs less.
void spmm_pair(benchmark::State& state, const SparseOperator* A, bool torch_coo) {
  torch::NoGradGuard g;
  const auto X = torch::randn({A->cols, C});
  const auto coo =
      torch::sparse_coo_tensor(torch::stack({A->row, A->col}), A->values, {A->rows, A->cols})
          .coalesce();
  for (auto _ : state) benchmark::DoNotOptimize(torch_coo ? torch::mm(coo, X) : nn::spmm(*A, X));
}

}  // namespace

int main(int argc, char** argv) {
  nn::set_cpu_threads(1, 1);
  torch::set_num_interop_threads(1);
  // Freed tensors are kept for reuse instead of going back to the kernel: without it every
  // grid101-sized temporary is a fresh mmap whose pages fault in again (SCN2's grid101
  // forward+backward took twice as long). TOPOS_BENCH_ALLOCATOR picks how: "cache" (default,
  // nn::use_caching_cpu_allocator: freed blocks by size class), "heap" (nn::keep_freed_memory:
  // the heap is never trimmed, as the hopnet trainer does; it fragments) or "system" (glibc's
  // defaults, as TOPOS_BENCH_SYSTEM_MALLOC=1 did).
  const char* env = std::getenv("TOPOS_BENCH_ALLOCATOR");
  const std::string allocator = env                                        ? env
                                : std::getenv("TOPOS_BENCH_SYSTEM_MALLOC") ? "system"
                                                                           : "cache";
  if (allocator == "cache") {
    nn::use_caching_cpu_allocator();
  } else if (allocator == "heap") {
    nn::keep_freed_memory();
  } else if (allocator != "system") {
    std::cerr << "TOPOS_BENCH_ALLOCATOR: expected cache, heap or system, not '" << allocator
              << "'\n";
    return 2;
  }
  benchmark::AddCustomContext("allocator", allocator);
  benchmark::Initialize(&argc, argv);
  std::map<std::string, Complex> complexes;
  try {
    complexes["rgg2000"] = rgg2000();
  } catch (const std::exception& e) {
    std::cerr << "skipping rgg2000: " << e.what() << "\n";
  }
  complexes["grid101"] = grid101();
  for (const auto& [name, c] : complexes) {
    const auto s = c.shape();
    std::cerr << name << ": shape (" << s[0] << ", " << s[1] << ", " << s[2] << ")\n";
  }
  for (const std::string model : {"SCN2", "SCCNN", "SAN", "CWN", "UniGCNII"})
    for (const auto& [cname, c] : complexes)
      for (bool bwd : {false, true}) {
        std::string lower = model;
        std::transform(lower.begin(), lower.end(), lower.begin(),
                       [](unsigned char ch) { return static_cast<char>(std::tolower(ch)); });
        const Complex* cp = &c;
        const std::string cn = cname;
        benchmark::RegisterBenchmark(
            ("BM_zoo/" + lower + "/" + cname + (bwd ? "/forward_backward" : "/forward")).c_str(),
            [model, cn, cp, bwd](benchmark::State& st) { run(st, model, cn, cp, bwd); })
            ->Unit(benchmark::kMillisecond);
      }
  static std::map<std::string, SparseOperator> laplacians;
  for (const auto& [cname, c] : complexes) {
    const Sp B1t = transpose(c.B1), B2t = transpose(c.B2);
    laplacians[cname + "/L0"] = op(normalized(product(c.B1, B1t)));
    laplacians[cname + "/L1"] = op(normalized(Sp(product(B1t, c.B1) + product(c.B2, B2t))));
    laplacians[cname + "/L2"] = op(normalized(product(B2t, c.B2)));
  }
  for (const auto& [name, A] : laplacians)
    for (bool coo : {false, true})
      benchmark::RegisterBenchmark(("BM_zoo_spmm/" + name + (coo ? "/torch_coo" : "/csr")).c_str(),
                                   [p = &A, coo](benchmark::State& st) { spmm_pair(st, p, coo); })
          ->Unit(benchmark::kMicrosecond);
  benchmark::RunSpecifiedBenchmarks();
  benchmark::Shutdown();
  return 0;
}
