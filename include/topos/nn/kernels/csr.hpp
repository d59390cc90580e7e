// topos/nn/kernels/csr.hpp
// The CSR kernels under spmm (sparse_operator.hpp): Y = act(A X) a target row at a time with
// its channels in vector registers (csr_mm), and the gradient of A's values (csr_value_grad).
#pragma once

#include "topos/nn/kernels/epilogue.hpp"

#include <ATen/Parallel.h>

#include <algorithm>
#include <cstdint>
#include <cstring>
#include <type_traits>

namespace topos::nn {

namespace detail {

// Y[i] = act(Σ_k v[perm k] X[col k]) over the entries k of rows [begin, end); C channels,
// contiguous rows. For a compile-time width the row's sums stay in registers as 32-byte vectors
// (GCC's vector extension, so each clone compiles them for its instruction set; plain arrays let
// -O3 spill them): 2.8x faster than the loop below at 32 channels.
#if defined(__GNUC__)
template <class T, int C, Epilogue E, int VB>
static TOPOS_INLINE_KERNEL void csr_rows_fixed(const std::int64_t* crow, const std::int64_t* col,
                                               const T* val, const std::int64_t* perm, const T* X,
                                               T* Y, std::int64_t begin, std::int64_t end) {
  // A width narrower than the vector (8 floats on 64 bytes) takes vectors of its own size.
  constexpr int VBe = C * static_cast<int>(sizeof(T)) < VB ? C * static_cast<int>(sizeof(T)) : VB;
  typedef T vec __attribute__((vector_size(VBe)));
  constexpr int L = static_cast<int>(VBe / sizeof(T)), V = C / L;
  static_assert(C % L == 0, "the width must be a whole number of vectors");
  for (std::int64_t i = begin; i < end; ++i) {
    vec acc[V] = {};
    for (std::int64_t k = crow[i]; k < crow[i + 1]; ++k) {
      const T v = val[perm ? perm[k] : k];
      const T* x = X + col[k] * C;
      for (int j = 0; j < V; ++j) {
        vec xv;
        std::memcpy(&xv, x + j * L, sizeof(vec));
        acc[j] += v * xv;
      }
    }
    for (int j = 0; j < V; ++j) {
      epilogue_vec<T, E>(acc[j]);
      std::memcpy(Y + i * C + j * L, &acc[j], sizeof(vec));
    }
  }
}

template <class T, Epilogue E, int VB>
static TOPOS_INLINE_KERNEL bool csr_rows_width(const std::int64_t* crow, const std::int64_t* col,
                                               const T* val, const std::int64_t* perm, const T* X,
                                               T* Y, std::int64_t begin, std::int64_t end,
                                               std::int64_t C) {
  switch (C) {
    case 8:
      return csr_rows_fixed<T, 8, E, VB>(crow, col, val, perm, X, Y, begin, end), true;
    case 16:
      return csr_rows_fixed<T, 16, E, VB>(crow, col, val, perm, X, Y, begin, end), true;
    case 32:
      return csr_rows_fixed<T, 32, E, VB>(crow, col, val, perm, X, Y, begin, end), true;
    case 64:
      return csr_rows_fixed<T, 64, E, VB>(crow, col, val, perm, X, Y, begin, end), true;
    case 128:  // CWN's and UniGNN2's width on MUTAG, NCI1, NCI109: 8 zmm accumulators
      return csr_rows_fixed<T, 128, E, VB>(crow, col, val, perm, X, Y, begin, end), true;
    default:
      return false;
  }
}
#endif

template <class T, int VB = 32>
static TOPOS_INLINE_KERNEL void csr_rows(const std::int64_t* crow, const std::int64_t* col,
                                         const T* val, const std::int64_t* perm, const T* X, T* Y,
                                         std::int64_t begin, std::int64_t end, std::int64_t C,
                                         Epilogue e) {
#if defined(__GNUC__)
  if (e == Epilogue::none
          ? csr_rows_width<T, Epilogue::none, VB>(crow, col, val, perm, X, Y, begin, end, C)
      : e == Epilogue::relu
          ? csr_rows_width<T, Epilogue::relu, VB>(crow, col, val, perm, X, Y, begin, end, C)
      : e == Epilogue::elu
          ? csr_rows_width<T, Epilogue::elu, VB>(crow, col, val, perm, X, Y, begin, end, C)
          : csr_rows_width<T, Epilogue::sigmoid, VB>(crow, col, val, perm, X, Y, begin, end, C))
    return;
#endif
  for (std::int64_t i = begin; i < end; ++i) {
    T* __restrict y = Y + i * C;
    std::fill(y, y + C, T(0));
    for (std::int64_t k = crow[i]; k < crow[i + 1]; ++k) {
      const T v = val[perm ? perm[k] : k];
      const T* __restrict x = X + col[k] * C;
      for (std::int64_t c = 0; c < C; ++c) y[c] += v * x[c];
    }
    // The vectorised activation: libm's scalar expm1f per entry was a quarter of CWN's MUTAG
    // epoch at 128 channels, a width with no fixed-width kernel above.
    if (e != Epilogue::none) epilogue_rows<T, VB>(y, nullptr, y, C, e);
  }
}
[[maybe_unused]] TOPOS_SIMD_CLONES static void csr_rows_float(
    const std::int64_t* crow, const std::int64_t* col, const float* val, const std::int64_t* perm,
    const float* X, float* Y, std::int64_t begin, std::int64_t end, std::int64_t C, Epilogue e) {
  csr_rows<float>(crow, col, val, perm, X, Y, begin, end, C, e);
}
#if defined(TOPOS_HAVE_V4)
[[maybe_unused]] TOPOS_V4 static void csr_rows_float_v4(
    const std::int64_t* crow, const std::int64_t* col, const float* val, const std::int64_t* perm,
    const float* X, float* Y, std::int64_t begin, std::int64_t end, std::int64_t C, Epilogue e) {
  csr_rows<float, 64>(crow, col, val, perm, X, Y, begin, end, C, e);
}
#endif
[[maybe_unused]] TOPOS_SIMD_CLONES static void csr_rows_double(
    const std::int64_t* crow, const std::int64_t* col, const double* val, const std::int64_t* perm,
    const double* X, double* Y, std::int64_t begin, std::int64_t end, std::int64_t C, Epilogue e) {
  csr_rows<double>(crow, col, val, perm, X, Y, begin, end, C, e);
}
#if defined(TOPOS_HAVE_V4)
[[maybe_unused]] TOPOS_V4 static void csr_rows_double_v4(
    const std::int64_t* crow, const std::int64_t* col, const double* val, const std::int64_t* perm,
    const double* X, double* Y, std::int64_t begin, std::int64_t end, std::int64_t C, Epilogue e) {
  csr_rows<double, 64>(crow, col, val, perm, X, Y, begin, end, C, e);
}
#endif

template <class T>
void csr_mm(const std::int64_t* crow, const std::int64_t* col, const T* val,
            const std::int64_t* perm, const T* X, T* Y, std::int64_t rows, std::int64_t C,
            Epilogue e = Epilogue::none) {
  const std::int64_t nnz = rows > 0 ? crow[rows] - crow[0] : 0;
  at::parallel_for(0, rows, grain_rows(rows, (nnz + rows) * C),
                   [&](std::int64_t begin, std::int64_t end) {
#if defined(TOPOS_HAVE_V4)
                     if constexpr (std::is_same_v<T, float>)
                       if (cpu_has_v4())
                         return csr_rows_float_v4(crow, col, val, perm, X, Y, begin, end, C, e);
                     if constexpr (std::is_same_v<T, double>)
                       if (cpu_has_v4())
                         return csr_rows_double_v4(crow, col, val, perm, X, Y, begin, end, C, e);
#endif
                     if constexpr (std::is_same_v<T, float>)
                       csr_rows_float(crow, col, val, perm, X, Y, begin, end, C, e);
                     else if constexpr (std::is_same_v<T, double>)
                       csr_rows_double(crow, col, val, perm, X, Y, begin, end, C, e);
                     else
                       csr_rows<T>(crow, col, val, perm, X, Y, begin, end, C, e);
                   });
}

// g[k] = <dY[row k], X[col k]>.
template <class T>
void csr_value_grad(const std::int64_t* row, const std::int64_t* col, const T* dY, const T* X, T* g,
                    std::int64_t nnz, std::int64_t C) {
  at::parallel_for(0, nnz, grain_rows(nnz, nnz * C), [&](std::int64_t begin, std::int64_t end) {
    for (std::int64_t k = begin; k < end; ++k) {
      const T* __restrict a = dY + row[k] * C;
      const T* __restrict b = X + col[k] * C;
      T s = 0;
      for (std::int64_t c = 0; c < C; ++c) s += a[c] * b[c];
      g[k] = s;
    }
  });
}

}  // namespace detail

}  // namespace topos::nn
