// topos/nn/kernels/packed_weights.hpp
// The bfloat16 kernels' weights packed into pairs (dense_bf16.hpp), and PackedWeightsScope, inside
// which a thread keeps each weight's pairs between calls: a rollout multiplies the same weights
// at every step, and packing a 128 × 512 weight costs a quarter of its product on a rollout's rows.
#pragma once

#include "topos/nn/kernels/dense_bf16.hpp"
#include "topos/nn/tensor_cache.hpp"

#include <torch/torch.h>

#include <cstdint>
#include <memory>
#include <vector>

namespace topos::nn {
namespace detail {

// A weight's packed pairs: the tensor (its key's version the one it was packed at) and how it was
// read (R × C, strides rs and cs).
struct PackedPairs {
  TensorKey tensor;
  std::int64_t R = 0, C = 0, rs = 0, cs = 0;
  std::shared_ptr<const std::vector<std::uint32_t>> pairs;
  bool expired() const { return tensor.expired(); }
};
struct PackedPairsCache {
  TensorCache<PackedPairs> entries{512};
  int scopes = 0;  // open PackedWeightsScopes on this thread
};
inline PackedPairsCache& packed_pairs_cache() {
  thread_local PackedPairsCache cache;
  return cache;
}

/// pack_bf16_pairs of T (R × C, strides rs and cs), from this thread's cache inside a
/// PackedWeightsScope while T's version counter is the one it was packed at (packed again in
/// place when it changed), else packed afresh.
inline std::shared_ptr<const std::vector<std::uint32_t>> packed_pairs(
    const torch::Tensor& T, std::int64_t R, std::int64_t C, std::int64_t rs, std::int64_t cs) {
  const auto pack = [&] {
    return std::make_shared<const std::vector<std::uint32_t>>(
        pack_bf16_pairs(T.data_ptr<float>(), R, C, rs, cs));
  };
  auto& cache = packed_pairs_cache();
  if (cache.scopes == 0 || !TensorKey::keyable(T) || !T.has_storage()) return pack();
  if (auto* e = cache.entries.find([&](const PackedPairs& e) {
        return e.R == R && e.C == C && e.rs == rs && e.cs == cs && e.tensor.same_storage(T);
      })) {
    if (e->tensor.version != T._version()) e->pairs = pack(), e->tensor.version = T._version();
    return e->pairs;
  }
  PackedPairs e;
  e.tensor = TensorKey::of(T);
  e.R = R, e.C = C, e.rs = rs, e.cs = cs;
  e.pairs = pack();
  return cache.entries.insert(std::move(e)).pairs;
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
    if (--cache.scopes == 0) cache.entries.clear();
  }
  PackedWeightsScope(const PackedWeightsScope&) = delete;
  PackedWeightsScope& operator=(const PackedWeightsScope&) = delete;
};

}  // namespace topos::nn
