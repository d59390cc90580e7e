// topos/nn/tensor_cache.hpp
// What a kernel derives from tensors and would otherwise derive again on every call (a weight's
// bfloat16 pairs, a neighbourhood's operator in CSR form), kept per thread while those tensors
// live: keys that hold a tensor's storage weakly, so that a new tensor at a freed address cannot
// match, and its version counter, so that an in-place change is seen; a bounded list of entries.
#pragma once

#include <torch/torch.h>

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <utility>
#include <vector>

namespace topos::nn::detail {

/// A tensor as a cache key: its storage (held weakly), offset, size, strides, dtype and version
/// counter. An undefined tensor (or one without storage) is the empty key, which matches those.
struct TensorKey {
  c10::weak_intrusive_ptr<c10::StorageImpl> storage{c10::intrusive_ptr<c10::StorageImpl>()};
  const c10::StorageImpl* key = nullptr;
  std::int64_t offset = 0, numel = 0, version = -1;
  std::vector<std::int64_t> strides;
  torch::Dtype dtype = torch::kLong;

  /// Whether t can be a key: inference tensors have no version counter (`_version()` throws), so
  /// nothing derived from them is kept; nor from a tensor without storage.
  static bool keyable(const torch::Tensor& t) {
    return !t.defined() || (!t.is_inference() && t.has_storage());
  }
  static TensorKey of(const torch::Tensor& t) {
    TensorKey k;
    if (!t.defined() || !t.has_storage()) return k;
    k.storage = t.storage().getWeakStorageImpl();
    k.key = t.storage().unsafeGetStorageImpl();
    k.offset = t.storage_offset(), k.numel = t.numel(), k.version = t._version();
    k.strides = t.strides().vec(), k.dtype = t.scalar_type();
    return k;
  }
  /// The same storage (alive), offset and dtype, at any version: for a caller that says itself
  /// which elements it reads from there (a shape and strides of its own).
  bool same_storage(const torch::Tensor& t) const {
    if (!t.defined() || !t.has_storage()) return key == nullptr;
    return key == t.storage().unsafeGetStorageImpl() && !storage.expired() &&
           offset == t.storage_offset() && dtype == t.scalar_type();
  }
  /// The same tensor's elements (storage alive, offset, size, strides, dtype), at any version.
  bool same_tensor(const torch::Tensor& t) const {
    return same_storage(t) &&
           (key == nullptr || (numel == t.numel() && t.strides() == c10::IntArrayRef(strides)));
  }
  /// The same tensor at the version the key was taken at.
  bool matches(const torch::Tensor& t) const {
    return same_tensor(t) && (key == nullptr || version == t._version());
  }
  /// Whether the tensor is gone (never for the empty key).
  bool expired() const { return key != nullptr && storage.expired(); }
};

/// At most `capacity` entries (each with `bool expired() const`, true once a tensor it was derived
/// from is freed), one list per thread where the caller declares it thread_local. A new entry
/// first drops the expired ones, then the oldest when the list is full.
template <class Entry>
struct TensorCache {
  explicit TensorCache(std::size_t capacity) : capacity(capacity) {}
  template <class Match>
  Entry* find(Match&& match) {
    for (auto& e : entries)
      if (match(e)) return &e;
    return nullptr;
  }
  Entry& insert(Entry e) {
    entries.erase(std::remove_if(entries.begin(), entries.end(),
                                 [](const Entry& old) { return old.expired(); }),
                  entries.end());
    if (entries.size() >= capacity) entries.erase(entries.begin());
    return entries.emplace_back(std::move(e));
  }
  void clear() { entries.clear(); }

  std::vector<Entry> entries;  // oldest first
  std::size_t capacity;
};

}  // namespace topos::nn::detail
