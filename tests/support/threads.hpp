// LibTorch's intra-op thread count restored at the end of a scope (also when a check throws), for
// tests that run topos's kernels on two threads.
#pragma once

#include "support/torch_prelude.hpp"

namespace topos::test {

/// Holds the thread count at construction; sets it back at destruction.
struct RestoreThreads {
  int n = at::get_num_threads();
  ~RestoreThreads() { at::set_num_threads(n); }
};

}  // namespace topos::test
