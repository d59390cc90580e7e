// topos/nn/kernels/precision.hpp
// The process-wide precision of float32 products (MatmulPrecision), which every product topos
// runs reads: its own dense kernels (kernels.hpp), nn::linear and Mlp (mlp.hpp).
#pragma once

#include <dlfcn.h>

#include <atomic>
#include <stdexcept>
#include <string>

namespace topos::nn {

/// How float32 products are multiplied, named after PyTorch's torch.set_float32_matmul_precision:
/// `highest` in float32; `medium` with bfloat16 inputs and float32 sums. On a CPU with AVX-512
/// BF16, the products topos's kernels take (kernels/dense_bf16.hpp: 16 to 1024 inputs and outputs
/// in steps of 16; linear_act, linear_blocks, the schedule's weights, Mlp) round their inputs to
/// bfloat16 as they read them and keep float32 sums, outputs and gradients, at up to twice the
/// float32 rate (on AMX tiles where the CPU has them, several times that: bfloat16_kernels()
/// names the kernels); the 2-D CPU shapes they do not take (inputs or outputs not a multiple of 16,
/// or over 1024: narrow maps, where casts cost more than bfloat16 saves) stay float32. On a GPU,
/// and on a CPU without AVX-512 BF16, only nn::linear and Mlp multiply in bfloat16 (oneDNN's on a
/// CPU, slower than float32 there; its output is rounded to bfloat16 too, as torch.autocast's);
/// the other products stay float32. Values and gradients through a bfloat16 product carry about
/// 8 significant bits. Process-wide, set before training starts; parity with the reference
/// needs `highest`, the default.
enum class MatmulPrecision { highest, medium };
namespace detail {
inline std::atomic<MatmulPrecision> float32_matmul_precision{MatmulPrecision::highest};

/// A cache that holds every padded shape a run meets (a few thousand), so nothing is evicted.
inline void grow_onednn_cache() {
  using Setter = int (*)(int);
  if (auto set = reinterpret_cast<Setter>(dlsym(RTLD_DEFAULT, "dnnl_set_primitive_cache_capacity")))
    set(16384);
}
}  // namespace detail
inline void set_float32_matmul_precision(MatmulPrecision p) {
  if (p == MatmulPrecision::medium) detail::grow_onednn_cache();
  detail::float32_matmul_precision.store(p);
}
inline MatmulPrecision get_float32_matmul_precision() {
  return detail::float32_matmul_precision.load();
}
inline MatmulPrecision matmul_precision_from_string(const std::string& s) {
  if (s == "highest") return MatmulPrecision::highest;
  if (s == "medium") return MatmulPrecision::medium;
  throw std::invalid_argument("unknown matmul precision '" + s + "' (highest, medium)");
}
inline const char* to_string(MatmulPrecision p) {
  return p == MatmulPrecision::highest ? "highest" : "medium";
}

}  // namespace topos::nn
