// topos/nn/cpu.hpp
// Deliberate CPU threading and allocation for LibTorch as Debian ships it (OpenBLAS + OpenMP).
// Two thread pools at once oversubscribe the cores (a matmul can run 30x slower), so set them
// together: for HOPNet's large batched training matmuls, BLAS threads and one intra-op thread
// are fastest; for a rollout's small ones, one of each. Freed memory: kept in the heap
// (keep_freed_memory), or cached by size class (use_caching_cpu_allocator), which is as fast and
// does not fragment. Denormal floats: flushed to zero while a ScopedFlushDenormals lives.
#pragma once

#include <torch/torch.h>

#include <ATen/Parallel.h>

#include <dlfcn.h>
#include <malloc.h>
#include <sched.h>
#if defined(__x86_64__) || defined(__i386__)
#include <xmmintrin.h>
#endif

#include <c10/core/Allocator.h>

#include <cstdlib>
#include <cstring>
#include <map>
#include <mutex>
#include <new>
#include <string>
#include <thread>
#include <vector>

namespace topos::nn {

/// Sets OpenBLAS's thread count when the process uses OpenBLAS; false when it does not (another
/// BLAS: then OPENBLAS_NUM_THREADS / OMP_NUM_THREADS in the environment decide).
inline bool set_blas_threads(int n) {
  using Setter = void (*)(int);
  auto set = reinterpret_cast<Setter>(dlsym(RTLD_DEFAULT, "openblas_set_num_threads"));
  if (set == nullptr) return false;
  set(n < 1 ? 1 : n);
  return true;
}

/// The kernel set OpenBLAS multiplies with (its core name: "Haswell", "Cooperlake", ...), or ""
/// when the process's BLAS is not OpenBLAS. OPENBLAS_CORETYPE overrides OpenBLAS's choice, and the
/// choice doubles sgemm's speed or halves it (AVX2 or AVX-512 kernels), so timings name it.
inline std::string blas_kernels() {
  using Name = char* (*)();
  auto name = reinterpret_cast<Name>(dlsym(RTLD_DEFAULT, "openblas_get_corename"));
  return name != nullptr ? std::string(name()) : std::string();
}

/// The cores this process may run on: its CPU affinity (taskset, a container's cpuset), not every
/// core of the host as std::thread::hardware_concurrency counts them.
inline int available_cores() {
  cpu_set_t set;
  CPU_ZERO(&set);
  if (sched_getaffinity(0, sizeof set, &set) == 0) return std::max(1, CPU_COUNT(&set));
  return static_cast<int>(std::max(1u, std::thread::hardware_concurrency()));
}

/// LibTorch's intra-op threads and BLAS threads; 0 means one per available core.
inline void set_cpu_threads(int intra_op, int blas) {
  const int hw = available_cores();
  torch::set_num_threads(intra_op > 0 ? intra_op : hw);
  set_blas_threads(blas > 0 ? blas : hw);
}

/// Keeps freed memory in the process: glibc returns every block above 32 MB to the kernel at
/// free, so each training step re-faults hundreds of MB of fresh zero pages (a third of the step
/// time for a 477-timestep trajectory). Call once, before large tensors are allocated. Threads
/// share the main arena: another arena's heap cannot hold a block of over 64 MB and maps it.
/// Under tcmalloc (topos::tcmalloc), which keeps freed memory itself, the calls change nothing.
inline void keep_freed_memory() {
#ifdef M_MMAP_MAX
  mallopt(M_ARENA_MAX, 1);
  mallopt(M_MMAP_MAX, 0);
  mallopt(M_TRIM_THRESHOLD, 1 << 30);
  mallopt(M_TOP_PAD, 64 << 20);
#endif
}

/// While alive, float arithmetic on the calling thread and on LibTorch's intra-op threads (where
/// its OpenMP is libgomp, as Debian's is: reaches_intra_op_threads) treats
/// denormal inputs as zero and flushes denormal results to zero (x86's MXCSR DAZ and FTZ bits, as
/// torch.set_flush_denormal sets them and TensorFlow's CPU kernels run; elsewhere nothing). A
/// multiply-add that meets a denormal costs a microcode assist, about a hundred cycles: the tiny
/// gradients behind saturated sigmoids (TopoBench's SCCNN) made its backward products 4-5x slower,
/// 23.3 s against 9.2 s for an epoch on REDDIT-BINARY (docs/topobench.md). Values below 1.2e-38
/// become 0; nothing else changes. At destruction the calling thread's previous mode comes back,
/// on it and on the intra-op threads; guards nest.
class ScopedFlushDenormals {
 public:
  explicit ScopedFlushDenormals(bool on = true) : on_(on) {
#if defined(__x86_64__) || defined(__i386__)
    if (!on_) return;
    saved_ = _mm_getcsr();
    set_everywhere(saved_ | kFlush);
#endif
  }
  ~ScopedFlushDenormals() {
#if defined(__x86_64__) || defined(__i386__)
    if (on_) set_everywhere(saved_);
#endif
  }
  ScopedFlushDenormals(const ScopedFlushDenormals&) = delete;
  ScopedFlushDenormals& operator=(const ScopedFlushDenormals&) = delete;

  /// Whether the guard reaches LibTorch's intra-op threads too (its OpenMP is libgomp's).
  static bool reaches_intra_op_threads() {
    return gomp_parallel() != nullptr;
  }
  /// Whether denormals are flushed on the calling thread now.
  static bool active() {
#if defined(__x86_64__) || defined(__i386__)
    return (_mm_getcsr() & kFlush) == kFlush;
#else
    return false;
#endif
  }

 private:
  static constexpr unsigned kFlush = 0x8040;  // FTZ (bit 15) and DAZ (bit 6)
  using Parallel = void (*)(void (*)(void*), void*, unsigned, unsigned);
  // libgomp's entry point for a parallel region, looked up once; null without libgomp.
  static Parallel gomp_parallel() {
    static const auto parallel = reinterpret_cast<Parallel>(dlsym(RTLD_DEFAULT, "GOMP_parallel"));
    return parallel;
  }
  // The calling thread, then every thread of its OpenMP team, the one LibTorch's operations run
  // on. The region is opened through libgomp's entry point (GOMP_parallel, which `#pragma omp
  // parallel` compiles to; LibTorch links libgomp), found at run time, so that this works in a
  // translation unit compiled without -fopenmp too. Inside a parallel region, or without
  // libgomp, only the calling thread changes.
  static void set_everywhere(unsigned csr) {
#if defined(__x86_64__) || defined(__i386__)
    _mm_setcsr(csr);
    const auto parallel = gomp_parallel();
    const int n = at::get_num_threads();
    if (parallel != nullptr && n > 1 && !at::in_parallel_region())
      parallel([](void* c) { _mm_setcsr(*static_cast<unsigned*>(c)); }, &csr,
               static_cast<unsigned>(n), 0);
#else
    (void)csr;
#endif
  }
  bool on_;
  unsigned saved_ = 0;
};

namespace detail {

// LibTorch's CPU allocator with a cache: a freed block of 1 MB or more goes on the free list of
// its size class (sizes rounded up to an eighth of their power of two: at most 12.5 % over) and
// is handed out again for the next request of that class. Its pages are never returned and
// faulted in again (keep_freed_memory's speed), and it is never split for a request of another
// size, which is what fragments a kept heap: SAN's forward+backward on a 20k-triangle grid holds
// some 125 MB at once, and the kept heap grew by 250 MB around it. Smaller blocks are malloc's.
// Every block carries its class in a 64-byte header, so raw_deleter() frees any of them.
class CachingCPUAllocator final : public c10::Allocator {
 public:
  static constexpr std::size_t min_cached = std::size_t(1) << 20, header = 64;

  static CachingCPUAllocator& instance() {
    static auto* a = new CachingCPUAllocator();  // never destroyed: tensors may outlive main
    return *a;
  }
  static std::size_t size_class(std::size_t n) {
    if (n < min_cached) return n;
    std::size_t p = min_cached;
    while (p <= n / 2) p *= 2;
    const std::size_t step = p / 8;
    return (n + step - 1) / step * step;
  }
  c10::DataPtr allocate(std::size_t n) const override {
    const auto cpu = c10::Device(c10::DeviceType::CPU);
    if (n == 0) return {nullptr, nullptr, &release, cpu};
    const auto cls = size_class(n);
    char* base = nullptr;
    if (cls >= min_cached) {
      std::lock_guard<std::mutex> lock(mutex_);
      auto it = free_.find(cls);
      if (it != free_.end() && !it->second.empty()) {
        base = it->second.back();
        it->second.pop_back();
        cached_ -= cls;
      }
    }
    if (base == nullptr) {
      void* p = nullptr;
      if (posix_memalign(&p, header, cls + header) != 0 || p == nullptr) {
        release_cached();  // the cache may hold what the request needs
        if (posix_memalign(&p, header, cls + header) != 0 || p == nullptr) throw std::bad_alloc();
      }
      base = static_cast<char*>(p);
      std::memcpy(base, &cls, sizeof cls);
    }
    return {base + header, base + header, &release, cpu};
  }
  c10::DeleterFnPtr raw_deleter() const override { return &release; }

  static void release(void* data) {
    if (data == nullptr) return;
    char* base = static_cast<char*>(data) - header;
    std::size_t cls;
    std::memcpy(&cls, base, sizeof cls);
    auto& a = instance();
    if (cls >= min_cached) {
      std::lock_guard<std::mutex> lock(a.mutex_);
      if (a.cached_ + cls <= a.limit_) {
        a.free_[cls].push_back(base);
        a.cached_ += cls;
        return;
      }
    }
    std::free(base);
  }
  /// Frees every cached block (they are returned to malloc, and large ones to the system).
  void release_cached() const {
    std::lock_guard<std::mutex> lock(mutex_);
    for (auto& [cls, blocks] : free_)
      for (char* b : blocks) std::free(b);
    free_.clear();
    cached_ = 0;
  }
  void set_limit(std::size_t bytes) {
    std::lock_guard<std::mutex> lock(mutex_);
    limit_ = bytes;
  }
  std::size_t cached_bytes() const {
    std::lock_guard<std::mutex> lock(mutex_);
    return cached_;
  }

 private:
  CachingCPUAllocator() = default;
  mutable std::mutex mutex_;
  mutable std::map<std::size_t, std::vector<char*>> free_;
  mutable std::size_t cached_ = 0;
  std::size_t limit_ = std::size_t(1) << 30;
};

}  // namespace detail

/// Makes LibTorch allocate CPU tensors through a size-class cache (detail::CachingCPUAllocator):
/// freed blocks of 1 MB or more are kept, at most `max_cached_bytes` of them, and reused for
/// requests of their class. As fast as keep_freed_memory for repeated forward and backward
/// passes, with a peak near what is live at once. Tensors allocated before keep their allocator.
inline void use_caching_cpu_allocator(std::size_t max_cached_bytes = std::size_t(1) << 30) {
  auto& a = detail::CachingCPUAllocator::instance();
  a.set_limit(max_cached_bytes);
  c10::SetAllocator(c10::DeviceType::CPU, &a, /*priority=*/1);
}

/// Bytes held by the CPU cache's free lists, and a way to give them back.
inline std::size_t cached_cpu_bytes() {
  return detail::CachingCPUAllocator::instance().cached_bytes();
}
inline void release_cached_cpu_memory() {
  detail::CachingCPUAllocator::instance().release_cached();
}

}  // namespace topos::nn
