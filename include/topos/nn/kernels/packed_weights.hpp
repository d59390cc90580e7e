// topos/nn/kernels/packed_weights.hpp
// The weights as the kernels read them: bfloat16 pairs (dense_bf16.hpp), float32 or double
// transposes, contiguous or in panels (dense_operand, dense.hpp), and slices of a weight that a
// step reads (selected_weight); and PackedWeightsScope, inside
// which a thread keeps each weight's layout between calls: a rollout multiplies the same weights
// at every step, and packing a 128 × 512 weight costs a quarter of its product on a rollout's
// rows (copying the float32 transposes was a fifth of a rollout step on topos's kernels). A
// forward's helper threads (step_threads) keep theirs within the scope of the thread they help.
#pragma once

#include "topos/nn/kernels/dense.hpp"
#include "topos/nn/kernels/dense_bf16.hpp"
#include "topos/nn/tensor_cache.hpp"

#include <torch/torch.h>

#include <atomic>
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
// A weight laid out by dense_operand: M's key (sizes K × N, panels or not) and the copy.
struct LaidOutWeight {
  TensorKey tensor;
  std::int64_t K = 0, N = 0;
  bool panels = false;
  torch::Tensor operand;
  bool expired() const { return tensor.expired(); }
};
// Slices of a weight along one dimension, as W.index_select(dim, index) gives them: W's key and
// the copy.
struct SelectedWeight {
  TensorKey tensor;
  std::int64_t dim = 0;
  std::vector<std::int64_t> index;
  torch::Tensor selected;
  bool expired() const { return tensor.expired(); }
};
struct PackedPairsCache {
  TensorCache<PackedPairs> entries{512};
  TensorCache<LaidOutWeight> operands{512};
  TensorCache<SelectedWeight> selections{256};
  int scopes = 0;             // open PackedWeightsScopes on this thread (an adopted one counts)
  std::uint64_t scope = 0;    // the outermost one's id (0: none), which helper threads adopt
  std::uint64_t adopted = 0;  // the id of another thread's scope this one keeps pairs within
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

/// dense_operand(M, panels), from this thread's cache inside a PackedWeightsScope while M is the
/// tensor it was laid out from at the same version (laid out again in place when it changed),
/// else laid out afresh.
inline torch::Tensor weight_operand(const torch::Tensor& M, bool panels) {
  auto& cache = packed_pairs_cache();
  if (cache.scopes == 0 || (!panels && M.is_contiguous()) || !TensorKey::keyable(M) ||
      !M.has_storage())
    return dense_operand(M, panels);
  const auto K = M.size(0), N = M.size(1);
  if (auto* e = cache.operands.find([&](const LaidOutWeight& e) {
        return e.K == K && e.N == N && e.panels == panels && e.tensor.same_tensor(M);
      })) {
    if (e->tensor.version != M._version())
      e->operand = dense_operand(M, panels), e->tensor.version = M._version();
    return e->operand;
  }
  LaidOutWeight e;
  e.tensor = TensorKey::of(M);
  e.K = K, e.N = N, e.panels = panels;
  e.operand = dense_operand(M, panels);
  return cache.operands.insert(std::move(e)).operand;
}

/// W.index_select(dim, index): inside a PackedWeightsScope, while no gradient is recorded through
/// W, the one tensor kept for W at its version (selected again in place when W changed), so that
/// the products' caches above keep its layout too; else selected afresh. A step whose terms are
/// split reads a slice of its weight's columns at every call: a fresh copy each time, laid out
/// again by every product (3 % of a rollout on topos's kernels).
inline torch::Tensor selected_weight(const torch::Tensor& W, std::int64_t dim,
                                     const std::vector<std::int64_t>& index) {
  const auto select = [&] {
    const c10::InferenceMode normal_tensors(false);  // an inference tensor could not be a key
    return W.index_select(dim, torch::tensor(index, torch::kLong).to(W.device()));
  };
  auto& cache = packed_pairs_cache();
  if (cache.scopes == 0 || (torch::GradMode::is_enabled() && W.requires_grad()) ||
      !TensorKey::keyable(W) || !W.has_storage())
    return select();
  if (auto* e = cache.selections.find([&](const SelectedWeight& e) {
        return e.dim == dim && e.index == index && e.tensor.same_tensor(W);
      })) {
    if (e->tensor.version != W._version()) {
      e->selected.copy_(select());  // bumps its version: the layouts kept of it are redone
      e->tensor.version = W._version();
    }
    return e->selected;
  }
  SelectedWeight e;
  e.tensor = TensorKey::of(W);
  e.dim = dim, e.index = index;
  e.selected = select();
  return cache.selections.insert(std::move(e)).selected;
}

// Drops what a thread's ended scope kept.
inline void clear_packed_weights(PackedPairsCache& cache) {
  cache.entries.clear(), cache.operands.clear(), cache.selections.clear(), cache.scope = 0;
}

inline std::uint64_t new_packed_scope_id() {
  static std::atomic<std::uint64_t> last{0};
  return ++last;
}

/// This thread's outermost open PackedWeightsScope (0: none), for the threads that help it.
inline std::uint64_t packed_weights_scope() {
  return packed_pairs_cache().scope;
}

/// A helper thread starting a job for a thread whose packed_weights_scope() is `id` keeps pairs
/// as if inside that scope: from one job to the next of the same scope it keeps them (a rollout's
/// helpers pack each weight once, not at every step), and it drops them once a job comes from
/// outside that scope (another scope, or none). Between the two it holds them, unused: scope ids
/// are never reused, so pairs kept for an ended scope are never read.
inline void adopt_packed_weights_scope(std::uint64_t id) {
  auto& cache = packed_pairs_cache();
  if (cache.adopted == id) return;
  if (cache.adopted != 0 && --cache.scopes == 0) clear_packed_weights(cache);
  cache.adopted = id;
  if (id != 0 && cache.scopes++ == 0) cache.scope = id;
}

}  // namespace detail

/// While one is alive, this thread's products on topos's kernels keep each weight as they read it
/// between calls (bfloat16 pairs at MatmulPrecision::medium, a float32 transpose otherwise)
/// instead of laying it out at every call. The weights must change only through tensor
/// operations while it lives (an in-place op, a copy_ or an optimizer's step on the parameter
/// bumps its version counter, which is checked); a write through `.data()` or a raw pointer is
/// not seen. Scopes nest; what they kept is dropped when the outermost ends. HOPNet's and the
/// simulators' rollouts open one. The helper threads of an OperatorNetwork's forward
/// (step_threads) keep theirs within the calling thread's scope.
class PackedWeightsScope {
 public:
  PackedWeightsScope() {
    auto& cache = detail::packed_pairs_cache();
    if (cache.scopes++ == 0) cache.scope = detail::new_packed_scope_id();
  }
  ~PackedWeightsScope() {
    auto& cache = detail::packed_pairs_cache();
    if (--cache.scopes == 0) detail::clear_packed_weights(cache);
  }
  PackedWeightsScope(const PackedWeightsScope&) = delete;
  PackedWeightsScope& operator=(const PackedWeightsScope&) = delete;
};

}  // namespace topos::nn
