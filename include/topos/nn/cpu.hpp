// topos/nn/cpu.hpp
// Deliberate CPU threading and allocation for LibTorch as Debian ships it (OpenBLAS + OpenMP).
// Two thread pools at once oversubscribe the cores (a matmul can run 30x slower), so set them
// together: for HOPNet's large batched training matmuls, BLAS threads and one intra-op thread
// are fastest; for a rollout's small ones, one of each.
#pragma once

#include <torch/torch.h>

#include <dlfcn.h>
#include <malloc.h>
#include <sched.h>

#include <thread>

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
/// time for a 477-timestep trajectory). Call once, before large tensors are allocated.
inline void keep_freed_memory() {
#ifdef M_MMAP_MAX
  mallopt(M_MMAP_MAX, 0);
  mallopt(M_TRIM_THRESHOLD, 1 << 30);
  mallopt(M_TOP_PAD, 64 << 20);
#endif
}

}  // namespace topos::nn
