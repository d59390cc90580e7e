// topos/nn/kernels/packed_weights.hpp
// The bfloat16 kernels' weights packed into pairs (dense_bf16.hpp), and PackedWeightsScope, inside
// which a thread keeps each weight's pairs between calls: a rollout multiplies the same weights
// at every step, and packing a 128 × 512 weight costs a quarter of its product on a rollout's rows.
#pragma once

#include "topos/nn/kernels/dense_bf16.hpp"

#include <torch/torch.h>

#include <algorithm>
#include <cstdint>
#include <memory>
#include <vector>

namespace topos::nn {
namespace detail {

// A weight's packed pairs: the storage (held weakly, so that a new tensor at a freed address
// cannot match), offset, shape and strides, and the version counter it was packed at.
struct PackedPairs {
  c10::weak_intrusive_ptr<c10::StorageImpl> storage{c10::intrusive_ptr<c10::StorageImpl>()};
  const c10::StorageImpl* key = nullptr;
  std::int64_t offset = 0, R = 0, C = 0, rs = 0, cs = 0, version = -1;
  std::shared_ptr<const std::vector<std::uint32_t>> pairs;
};
struct PackedPairsCache {
  std::vector<PackedPairs> entries;
  std::size_t next = 0;
  int scopes = 0;  // open PackedWeightsScopes on this thread
};
inline PackedPairsCache& packed_pairs_cache() {
  thread_local PackedPairsCache cache;
  return cache;
}

/// pack_bf16_pairs of T (R × C, strides rs and cs), from this thread's cache inside a
/// PackedWeightsScope while T's version counter is the one it was packed at, else packed afresh.
inline std::shared_ptr<const std::vector<std::uint32_t>> packed_pairs(
    const torch::Tensor& T, std::int64_t R, std::int64_t C, std::int64_t rs, std::int64_t cs) {
  const auto pack = [&] {
    return std::make_shared<const std::vector<std::uint32_t>>(
        pack_bf16_pairs(T.data_ptr<float>(), R, C, rs, cs));
  };
  auto& cache = packed_pairs_cache();
  if (cache.scopes == 0 || T.is_inference() || !T.has_storage()) return pack();
  constexpr std::size_t capacity = 512;
  const auto* key = T.storage().unsafeGetStorageImpl();
  const std::int64_t offset = T.storage_offset(), version = T._version();
  for (auto& e : cache.entries)
    if (e.key == key && e.offset == offset && e.R == R && e.C == C && e.rs == rs && e.cs == cs &&
        !e.storage.expired()) {
      if (e.version != version) e.pairs = pack(), e.version = version;
      return e.pairs;
    }
  auto& entries = cache.entries;
  entries.erase(std::remove_if(entries.begin(), entries.end(),
                               [](const PackedPairs& e) { return e.storage.expired(); }),
                entries.end());
  PackedPairs e;
  e.storage = T.storage().getWeakStorageImpl();
  e.key = key, e.offset = offset, e.R = R, e.C = C, e.rs = rs, e.cs = cs, e.version = version;
  e.pairs = pack();
  if (entries.size() < capacity)
    entries.push_back(e);
  else
    entries[cache.next++ % capacity] = e;
  return e.pairs;
}

}  // namespace detail

/// While one is alive, this thread's bfloat16 products (MatmulPrecision::medium) keep each
/// weight's packed pairs between calls instead of packing them every call. The weights must
/// change only through tensor operations while it lives (an in-place op, a copy_ or an
/// optimizer's step on the parameter bumps its version counter, which is checked); a write
/// through `.data()` or a raw pointer is not seen. Scopes nest; the pairs are dropped when the
/// outermost ends. HOPNet's and the simulators' rollouts open one.
class PackedWeightsScope {
 public:
  PackedWeightsScope() { ++detail::packed_pairs_cache().scopes; }
  ~PackedWeightsScope() {
    auto& cache = detail::packed_pairs_cache();
    if (--cache.scopes == 0) cache.entries.clear(), cache.next = 0;
  }
  PackedWeightsScope(const PackedWeightsScope&) = delete;
  PackedWeightsScope& operator=(const PackedWeightsScope&) = delete;
};

}  // namespace topos::nn
