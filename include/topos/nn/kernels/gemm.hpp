// topos/nn/kernels/gemm.hpp
// Which library multiplies the CPU's float32 products of Linear layers (CpuGemm): BLAS through
// LibTorch's mm; oneDNN's sgemm, which Debian's LibTorch links for its bfloat16 products (libdnnl)
// and which runs HOPNet's 128-wide products 20-30 % faster than OpenBLAS 0.3.21 on an AVX-512
// EPYC (docs/hopnet-training.md); or topos's own register-blocked kernel (kernels/dense.hpp), bias
// and ReLU applied before the store, for where neither is at its best (on HOPNet's 128-wide
// products it is the slowest of the three: docs/benchmarks.md). Process-wide, like
// MatmulPrecision; BLAS unless set.
#pragma once

#include "topos/nn/kernels/epilogue.hpp"

#include <ATen/Parallel.h>
#include <torch/torch.h>

#include <dlfcn.h>

#include <atomic>
#include <cstdint>
#include <stdexcept>
#include <string>

namespace topos::nn {

/// The library of float32 CPU products in nn::linear and Mlp at `highest` precision (and of
/// linear_act's products of more than 64 outputs). oneDNN runs a product on the calling thread's
/// OpenMP threads, which LibTorch sets to its intra-op thread count: choose it where products run
/// one thread each (`hopnet train`'s workers), not where BLAS threads would share the cores.
/// `topos` runs every product that its dense kernel takes (up to 1,024 inputs; 8, 16, 32, 64 or a
/// multiple of 64 outputs up to 1,024 with AVX-512) on one thread, the others on BLAS. Results
/// differ from BLAS's in float32 summation order only.
enum class CpuGemm { blas, onednn, topos };
namespace detail {
inline std::atomic<CpuGemm> cpu_gemm{CpuGemm::blas};

// dnnl_sgemm: row-major C = alpha·op(A)·op(B) + beta·C (oneDNN's C API, found at run time so that
// a LibTorch without oneDNN still links).
using DnnlSgemm = int (*)(char, char, std::int64_t, std::int64_t, std::int64_t, float, const float*,
                          std::int64_t, const float*, std::int64_t, float, float*, std::int64_t);
inline DnnlSgemm onednn_sgemm() {
  static const auto f = reinterpret_cast<DnnlSgemm>(dlsym(RTLD_DEFAULT, "dnnl_sgemm"));
  return f;
}
}  // namespace detail

/// Whether oneDNN's sgemm is in this process (Debian's and PyTorch's LibTorch have it).
inline bool onednn_gemm_available() {
  return detail::onednn_sgemm() != nullptr;
}
/// Sets the library; oneDNN where the process has none is an error naming the way out.
inline void set_cpu_gemm(CpuGemm g) {
  if (g == CpuGemm::onednn && !onednn_gemm_available())
    throw std::invalid_argument(
        "cpu gemm onednn: this LibTorch has no oneDNN (dnnl_sgemm); use blas");
  detail::cpu_gemm.store(g);
}
inline CpuGemm get_cpu_gemm() {
  return detail::cpu_gemm.load();
}
inline CpuGemm cpu_gemm_from_string(const std::string& s) {
  if (s == "blas") return CpuGemm::blas;
  if (s == "onednn") return CpuGemm::onednn;
  if (s == "topos") return CpuGemm::topos;
  throw std::invalid_argument("unknown cpu gemm '" + s + "' (blas, onednn, topos)");
}
inline const char* to_string(CpuGemm g) {
  return g == CpuGemm::blas ? "blas" : g == CpuGemm::onednn ? "onednn" : "topos";
}

/// The library a rollout multiplies on for a --cpu-gemm `name` (blas, onednn, topos or auto).
/// `auto` keeps `current` where the rollout reproduces another implementation's digits (HOPNet's
/// reference mode: BLAS gives the reference's), and otherwise takes oneDNN where LibTorch has it,
/// else topos's dense kernel. oneDNN picks its AVX-512 kernels by itself, where OpenBLAS 0.3.21
/// falls back to SSE3 on CPUs it does not know (HOPNet's rollout 1.8x slower on this project's
/// VM; as fast as oneDNN given OPENBLAS_CORETYPE: docs/benchmarks.md).
inline CpuGemm cpu_gemm_for_rollout(const std::string& name, CpuGemm current, bool reproducing) {
  if (name != "auto") return cpu_gemm_from_string(name);
  if (reproducing) return current;
  return onednn_gemm_available() ? CpuGemm::onednn : CpuGemm::topos;
}

namespace detail {

/// Whether a product of `a` (float32, CPU) goes to oneDNN now.
inline bool use_onednn(const torch::Tensor& a) {
  return get_cpu_gemm() == CpuGemm::onednn && a.device().is_cpu() &&
         a.scalar_type() == torch::kFloat;
}

/// op(a) · op(b) for 2-D float32 CPU tensors through oneDNN's sgemm: a transposed view of a
/// contiguous matrix (a.t(), a column block's .t()) is passed as transposed, not copied.
inline torch::Tensor onednn_mm(const torch::Tensor& a, const torch::Tensor& b) {
  TORCH_CHECK(a.dim() == 2 && b.dim() == 2 && a.size(1) == b.size(0), "onednn_mm: shapes ",
              a.sizes(), " and ", b.sizes(), " do not multiply");
  const auto M = a.size(0), K = a.size(1), N = b.size(1);
  if (M == 0 || N == 0 || K == 0) return torch::zeros({M, N}, a.options());
  // Row-major with unit stride along rows ('N', ld = row stride) or along columns ('T').
  const auto layout = [](const torch::Tensor& t, torch::Tensor& keep) {
    if (t.stride(1) == 1 && t.stride(0) >= t.size(1)) return std::make_pair('N', t.stride(0));
    if (t.stride(0) == 1 && t.stride(1) >= t.size(0)) return std::make_pair('T', t.stride(1));
    keep = t.contiguous();
    return std::make_pair('N', keep.size(1));
  };
  torch::Tensor ka, kb;
  const auto [ta, lda] = layout(a, ka);
  const auto [tb, ldb] = layout(b, kb);
  const float* ap = (ka.defined() ? ka : a).data_ptr<float>();
  const float* bp = (kb.defined() ? kb : b).data_ptr<float>();
  auto c = torch::empty({M, N}, a.options());
  (void)at::get_num_threads();  // LibTorch's thread count reaches this thread's OpenMP first
  const int status =
      onednn_sgemm()(ta, tb, M, N, K, 1.0f, ap, lda, bp, ldb, 0.0f, c.data_ptr<float>(), N);
  if (status != 0)
    throw std::runtime_error("onednn_mm: dnnl_sgemm failed (status " + std::to_string(status) +
                             ") on " + std::to_string(M) + " x " + std::to_string(K) + " by " +
                             std::to_string(K) + " x " + std::to_string(N));
  return c;
}

// y = act(y + b) for a contiguous float32 y (n × N), b of N floats or null: a product's bias and
// activation in one pass over its output (relu or none; elu and sigmoid are applied after the
// bias).
template <bool Bias, bool Relu>
static TOPOS_INLINE_KERNEL void bias_relu_loop(float* y, const float* b, std::int64_t rows,
                                               std::int64_t N) {
  for (std::int64_t i = 0; i < rows; ++i) {
    float* r = y + i * N;
    for (std::int64_t j = 0; j < N; ++j) {
      const float v = Bias ? r[j] + b[j] : r[j];
      r[j] = Relu && v < 0.0f ? 0.0f : v;  // NaN stays NaN, as in torch::relu
    }
  }
}
[[maybe_unused]] TOPOS_SIMD_CLONES static void bias_relu_rows(float* y, const float* b,
                                                              std::int64_t rows, std::int64_t N,
                                                              bool relu) {
  if (b && relu) return bias_relu_loop<true, true>(y, b, rows, N);
  if (b) return bias_relu_loop<true, false>(y, b, rows, N);
  if (relu) bias_relu_loop<false, true>(y, b, rows, N);
}
inline void bias_epilogue(const torch::Tensor& y, const torch::Tensor& b, Epilogue e) {
  TORCH_CHECK(y.is_contiguous() && y.scalar_type() == torch::kFloat,
              "bias_epilogue: a contiguous float32 output");
  const auto N = y.size(1);
  const auto bc = b.defined() ? b.contiguous() : b;
  float* yp = y.data_ptr<float>();
  const float* bp = bc.defined() ? bc.data_ptr<float>() : nullptr;
  const bool relu = e == Epilogue::relu;
  if (bp != nullptr || relu)
    at::parallel_for(0, y.size(0), grain_rows(y.size(0), 4 * y.size(0) * N),
                     [&](std::int64_t begin, std::int64_t end) {
                       bias_relu_rows(yp + begin * N, bp, end - begin, N, relu);
                     });
  if (e == Epilogue::elu || e == Epilogue::sigmoid) apply_epilogue(y, torch::Tensor(), e);
}

}  // namespace detail
}  // namespace topos::nn
