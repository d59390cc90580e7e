// topos/nn/kernels/epilogue.hpp
// What every CPU kernel (kernels.hpp) builds on: compilation per instruction set (target clones,
// the AVX-512 entry points, cpu_has_v4) and the activations fused into their stores (Epilogue:
// relu, elu with a vectorised expm1, sigmoid with a vectorised exp), also as a pass of their own
// over an array (apply_epilogue).
#pragma once

#include <ATen/Parallel.h>
#include <torch/torch.h>

#include <cmath>
#include <cstdint>
#include <cstring>
#include <type_traits>

namespace topos::nn {

namespace detail {

// The row kernels are compiled for x86-64-v3 (AVX2 + FMA) and the baseline as target clones, on
// 32-byte vectors, and once more for x86-64-v4 (AVX-512) on 64-byte vectors (the `_v4` entry
// points, taken when the CPU has AVX-512: on Zen 5, whose FMA units are 512 bits wide, the dense
// kernel runs 1.9x faster on zmm registers than on ymm). The levels are dispatched by
// instruction set; an "arch=haswell" clone is dispatched by CPU model and never ran on this EPYC.
#if defined(__GNUC__) && !defined(__clang__) && defined(__x86_64__) && __GNUC__ >= 12
#define TOPOS_SIMD_CLONES __attribute__((target_clones("arch=x86-64-v3", "default")))
#define TOPOS_V4 __attribute__((target("arch=x86-64-v4")))
#define TOPOS_HAVE_V4 1
#elif defined(__GNUC__) && !defined(__clang__) && defined(__x86_64__)
#define TOPOS_SIMD_CLONES __attribute__((target_clones("avx2", "default")))
#else
#define TOPOS_SIMD_CLONES
#endif
// The kernels below are inlined into each clone so that they are compiled for its instruction set.
#if defined(__GNUC__)
#define TOPOS_INLINE_KERNEL inline __attribute__((always_inline))
#else
#define TOPOS_INLINE_KERNEL inline
#endif

#if defined(__GNUC__)
// Lanes l and l + w added for w = L/2, ..., 1, each step on the halves of a vector (the tree
// summed through an array in memory cost a store and L - 1 scalar adds).
template <class T, int W, class V>
static TOPOS_INLINE_KERNEL T lane_tree(const V& v) {
  if constexpr (W == 1) {
    return v[0];
  } else if constexpr (W == 2) {
    return v[0] + v[1];
  } else {
    typedef T half __attribute__((vector_size(sizeof(T) * W / 2)));
    half lo, hi;
    std::memcpy(&lo, &v, sizeof lo);
    std::memcpy(&hi, reinterpret_cast<const char*>(&v) + sizeof lo, sizeof hi);
    const half sum = lo + hi;
    return lane_tree<T, W / 2>(sum);
  }
}
// The sum of a row's L-wide vector partial sums and its scalar tail, as a tree (log2 L dependent
// adds, not L: a row of 128 floats is only 8 vectors).
template <class T, class V>
static TOPOS_INLINE_KERNEL T lane_sum(const V& v, T tail) {
  return lane_tree<T, static_cast<int>(sizeof(V) / sizeof(T))>(v) + tail;
}
// p[0, L) += x, for V's L lanes at an unaligned p (a sum kept in memory: a weight's gradient).
template <class T, class V>
static TOPOS_INLINE_KERNEL void add_into(T* p, const V& x) {
  V a;
  std::memcpy(&a, p, sizeof a);
  a += x;
  std::memcpy(p, &a, sizeof a);
}
#endif

#if defined(TOPOS_HAVE_V4)
inline bool cpu_has_v4() {
  static const bool v4 = __builtin_cpu_supports("avx512f") && __builtin_cpu_supports("avx512bw") &&
                         __builtin_cpu_supports("avx512dq") && __builtin_cpu_supports("avx512vl") &&
                         __builtin_cpu_supports("avx512cd");
  return v4;
}
#endif

// The grain at::parallel_for takes for `rows` rows that cost `work` multiply-adds (or element
// operations) in all: the rows of kParallelWork, so that a range splits only where each thread's
// share is at least about kParallelWork / 2. A parallel region costs microseconds to open and tens
// to wake a sleeping thread, so a kernel goes parallel only where each thread gets far more than
// that: split at their own fixed grains (256-512 rows), HOPNet's 500-row products and LayerNorms
// made a two-thread rollout 1.7x slower than one thread.
constexpr std::int64_t kParallelWork = std::int64_t(1) << 20;
inline std::int64_t grain_rows(std::int64_t rows, std::int64_t work) {
  if (rows <= 0 || work <= 0) return std::max<std::int64_t>(rows, 1);
  const std::int64_t per_row = std::max<std::int64_t>(1, work / rows);
  return std::max<std::int64_t>(1, kParallelWork / per_row);
}

// The activation applied to a product's rows before they are stored (a fused epilogue), so an
// activated product is one pass over its output, and its backward needs the output only.
// Every kernel that takes one dispatches on all four (a value it does not know is a logic error,
// never another activation).
enum class Epilogue { none, relu, elu, sigmoid };
// An autograd node saves its Epilogue with flags in one integer: the low two bits.
inline constexpr std::int64_t epilogue_mask = 3;
static_assert(static_cast<std::int64_t>(Epilogue::sigmoid) <= epilogue_mask,
              "an Epilogue takes two bits");

// 1 / (1 + exp(-x)) from t = exp(-|x|) <= 1, which never overflows: 1 / (1 + t) for x >= 0,
// t / (1 + t) below (no cancellation for large negative x).
template <class T>
static TOPOS_INLINE_KERNEL T sigmoid_scalar(T x) {
  const T t = std::exp(-std::abs(x));
  return x >= T(0) ? T(1) / (T(1) + t) : t / (T(1) + t);
}

template <class T>
static TOPOS_INLINE_KERNEL T epilogue_scalar(T x, Epilogue e) {
  if (e == Epilogue::relu) return x > T(0) ? x : T(0);
  if (e == Epilogue::elu) return x > T(0) ? x : std::expm1(x);
  if (e == Epilogue::sigmoid) return sigmoid_scalar(x);
  return x;
}

#if defined(__GNUC__)
// exp(x) = 2^n (1 + p(r)) on a vector of floats (any width), with r = x - n ln2 (two-part ln2),
// |r| <= ln2/2 and p(r) = r + r²(1/2 + ... + r⁵/7!) (truncation < 1e-8); x is clamped at -87 so
// that 2^n stays a normal float. Returns 2^n in `s` and p(r) in `p`: elu_vec and exp_vec combine
// them.
template <class V>
static TOPOS_INLINE_KERNEL void exp_parts(const V& x, V& s, V& p) {
  typedef std::int32_t ivec __attribute__((vector_size(sizeof(V))));
  const V c = x < -87.0f ? V{} - 87.0f : x;
  const V k = (c * 1.44269504088896341f + 12582912.0f) - 12582912.0f;  // round(c / ln2)
  V r = c - k * 0.693359375f;
  r = r - k * -2.12194440e-4f;
  p = r + r * r *
              (0.5f + r * (1.66666672e-1f +
                           r * (4.16666679e-2f +
                                r * (8.33333377e-3f + r * (1.38888892e-3f + r * 1.98412701e-4f)))));
  const ivec bits = (__builtin_convertvector(k, ivec) + 127) << 23;
  std::memcpy(&s, &bits, sizeof s);
}

// elu: x where x > 0, else expm1(x) written as (2^n - 1) + 2^n p(r) so that nothing cancels near
// 0: within 1e-7 of expm1, relative, everywhere. torch 1.13's elu calls libm's scalar expf (19 %
// of CWN's forward); this is a few vector FMAs. In place: no vector type in a function's ABI.
template <class V>
static TOPOS_INLINE_KERNEL void elu_vec(V& x) {
  V s, p;
  exp_parts(x, s, p);
  const V e = (s - 1.0f) + s * p;
  x = x > 0.0f ? x : e;
}

// exp(x) for x <= 0 (a softmax's shifted scores), in place; within 2e-7 relative, and about
// 1e-38 where exp underflows.
template <class V>
static TOPOS_INLINE_KERNEL void exp_vec(V& x) {
  V s, p;
  exp_parts(x, s, p);
  x = s + s * p;
}

// sigmoid as sigmoid_scalar writes it, with exp(-|x|) from exp_parts: within 3e-7 of
// 1 / (1 + exp(-x)), relative, for x >= -87, and 0 below, where exp_parts clamps (the true value
// is under 1.7e-38 there); torch 1.13's CPU sigmoid is a pass of its own (and its backward
// another) wherever a product could have applied it before the store.
template <class V>
static TOPOS_INLINE_KERNEL void sigmoid_vec(V& x) {
  const V neg = x < 0.0f ? x : -x;
  V s, p;
  exp_parts(neg, s, p);
  const V t = s + s * p;
  const V y = (x >= 0.0f ? V{} + 1.0f : t) / (1.0f + t);
  x = x < -87.0f ? V{} : y;
}

template <class T, Epilogue E, class V>
static TOPOS_INLINE_KERNEL void epilogue_vec(V& v) {
  if constexpr (E == Epilogue::relu) {
    v = v > T(0) ? v : V{};
  } else if constexpr (E == Epilogue::elu || E == Epilogue::sigmoid) {
    if constexpr (std::is_same_v<T, float>) {
      if constexpr (E == Epilogue::elu)
        elu_vec(v);
      else
        sigmoid_vec(v);
    } else {
      for (int l = 0; l < static_cast<int>(sizeof(V) / sizeof(T)); ++l)
        v[l] = epilogue_scalar<T>(v[l], E);
    }
  }
}
#endif

// The backward of an epilogue from its output y, in place on g (a scalar or a vector of T, by
// reference: a vector returned by value across instruction sets changes the ABI): g ⊙ act'(y),
// where relu' = [y > 0], elu' = 1 for y > 0, y + 1 below (as torch's elu_backward with
// is_result), and sigmoid' = (1 - y) y (as torch's sigmoid_backward).
template <class T, class V>
static TOPOS_INLINE_KERNEL void epilogue_grad(const V& y, V& g, Epilogue e) {
  if (e == Epilogue::sigmoid)
    g = g * ((T(1) - y) * y);
  else if (e != Epilogue::none)
    g = y > T(0) ? g : e == Epilogue::relu ? V{} : g * (y + T(1));
}

// The epilogue on its own, in place (after a dense product), and its backward (epilogue_grad).
template <class T, int VB = 32>
static TOPOS_INLINE_KERNEL void epilogue_rows(T* y, const T* g, T* out, std::int64_t n,
                                              Epilogue e) {
  std::int64_t i = 0;
#if defined(__GNUC__)
  typedef T vec __attribute__((vector_size(VB)));
  constexpr int L = static_cast<int>(VB / sizeof(T));
  for (; i + L <= n; i += L) {
    vec v;
    std::memcpy(&v, y + i, sizeof v);
    if (!g) {
      if (e == Epilogue::relu) epilogue_vec<T, Epilogue::relu>(v);
      if (e == Epilogue::elu) epilogue_vec<T, Epilogue::elu>(v);
      if (e == Epilogue::sigmoid) epilogue_vec<T, Epilogue::sigmoid>(v);
      std::memcpy(y + i, &v, sizeof v);
    } else {
      vec gv;
      std::memcpy(&gv, g + i, sizeof gv);
      epilogue_grad<T>(v, gv, e);
      std::memcpy(out + i, &gv, sizeof gv);
    }
  }
#endif
  for (; i < n; ++i) {
    if (!g)
      y[i] = epilogue_scalar(y[i], e);
    else {
      T r = g[i];
      epilogue_grad<T>(y[i], r, e);
      out[i] = r;
    }
  }
}
[[maybe_unused]] TOPOS_SIMD_CLONES static void epilogue_rows_float(float* y, const float* g,
                                                                   float* out, std::int64_t n,
                                                                   Epilogue e) {
  epilogue_rows<float>(y, g, out, n, e);
}
#if defined(TOPOS_HAVE_V4)
[[maybe_unused]] TOPOS_V4 static void epilogue_rows_float_v4(float* y, const float* g, float* out,
                                                             std::int64_t n, Epilogue e) {
  epilogue_rows<float, 64>(y, g, out, n, e);
}
#endif
[[maybe_unused]] TOPOS_SIMD_CLONES static void epilogue_rows_double(double* y, const double* g,
                                                                    double* out, std::int64_t n,
                                                                    Epilogue e) {
  epilogue_rows<double>(y, g, out, n, e);
}
#if defined(TOPOS_HAVE_V4)
[[maybe_unused]] TOPOS_V4 static void epilogue_rows_double_v4(double* y, const double* g,
                                                              double* out, std::int64_t n,
                                                              Epilogue e) {
  epilogue_rows<double, 64>(y, g, out, n, e);
}
#endif

// Split at whole blocks of 64 elements, so that each element takes the vector loop or the scalar
// tail (elu: a vectorised expm1 or std::expm1) as on one thread: the same bits on any count.
template <class T>
void epilogue_range(T* y, const T* g, T* out, std::int64_t n, Epilogue e) {
  constexpr std::int64_t kBlock = 64;
  const std::int64_t blocks = (n + kBlock - 1) / kBlock;
  at::parallel_for(0, blocks, grain_rows(blocks, 4 * n), [&](std::int64_t b0, std::int64_t b1) {
    const std::int64_t begin = b0 * kBlock, end = std::min(n, b1 * kBlock);
    T* o = out + begin;
    const T* gb = g ? g + begin : nullptr;
#if defined(TOPOS_HAVE_V4)
    if constexpr (std::is_same_v<T, float>)
      if (cpu_has_v4()) return epilogue_rows_float_v4(y + begin, gb, o, end - begin, e);
    if constexpr (std::is_same_v<T, double>)
      if (cpu_has_v4()) return epilogue_rows_double_v4(y + begin, gb, o, end - begin, e);
#endif
    if constexpr (std::is_same_v<T, float>)
      epilogue_rows_float(y + begin, gb, o, end - begin, e);
    else if constexpr (std::is_same_v<T, double>)
      epilogue_rows_double(y + begin, gb, o, end - begin, e);
    else
      epilogue_rows<T>(y + begin, gb, o, end - begin, e);
  });
}

/// act(y) as torch's own differentiable ops, on any device: where a product is not fused (other
/// devices and dtypes, factored operators, dense maps the kernels do not take).
inline torch::Tensor activate(const torch::Tensor& y, Epilogue e) {
  return e == Epilogue::relu      ? torch::relu(y)
         : e == Epilogue::elu     ? torch::elu(y)
         : e == Epilogue::sigmoid ? torch::sigmoid(y)
                                  : y;
}

/// y = act(y) in place (g undefined), or the gradient g ⊙ act'(y) from the output y.
inline torch::Tensor apply_epilogue(const torch::Tensor& y, const torch::Tensor& g, Epilogue e) {
  if (e == Epilogue::none) return g.defined() ? g : y;
  TORCH_CHECK(y.is_contiguous(), "apply_epilogue: the output must be contiguous");
  const auto gc = g.defined() ? g.contiguous() : g;
  auto out = g.defined() ? torch::empty_like(y) : y;
  AT_DISPATCH_FLOATING_TYPES(y.scalar_type(), "topos_epilogue", [&] {
    epilogue_range<scalar_t>(y.data_ptr<scalar_t>(),
                             gc.defined() ? gc.data_ptr<scalar_t>() : nullptr,
                             out.data_ptr<scalar_t>(), y.numel(), e);
  });
  return out;
}

// ELU (alpha 1) through the vectorised expm1 above, as an autograd node of its own: torch 1.13's
// CPU elu calls libm's scalar expm1f for every entry (a quarter of CWN's MUTAG epoch, where the
// elu of a sum of messages cannot be fused into a product). The backward is g ⊙ elu'(y).
struct EluFunction : public torch::autograd::Function<EluFunction> {
  static torch::Tensor forward(torch::autograd::AutogradContext* ctx, const torch::Tensor& x) {
    auto y = x.clone(at::MemoryFormat::Contiguous);
    apply_epilogue(y, torch::Tensor(), Epilogue::elu);
    ctx->save_for_backward({y});
    return y;
  }
  static torch::autograd::tensor_list backward(torch::autograd::AutogradContext* ctx,
                                               torch::autograd::tensor_list grads) {
    const auto y = ctx->get_saved_variables()[0];
    return {apply_epilogue(y, grads[0].contiguous(), Epilogue::elu)};
  }
};

}  // namespace detail

}  // namespace topos::nn
