#include "fast_gemm.hpp"

#include <cstdlib>
#include <cstring>
#include <stdexcept>

namespace skyloop::nn::fast {

namespace {

#define SKYLOOP_GEMM_NS generic
#define SKYLOOP_GEMM_TARGET
#define SKYLOOP_GEMM_V 4
#include "fast_gemm_kernel.inl"
#undef SKYLOOP_GEMM_NS
#undef SKYLOOP_GEMM_TARGET
#undef SKYLOOP_GEMM_V

#if defined(__x86_64__) && defined(__GNUC__)
#define SKYLOOP_GEMM_NS avx2
#define SKYLOOP_GEMM_TARGET __attribute__((target("avx2,fma")))
#define SKYLOOP_GEMM_V 8
#include "fast_gemm_kernel.inl"
#undef SKYLOOP_GEMM_NS
#undef SKYLOOP_GEMM_TARGET
#undef SKYLOOP_GEMM_V

#define SKYLOOP_GEMM_NS avx512
#define SKYLOOP_GEMM_TARGET __attribute__((target("avx512f,avx512vl,avx2,fma")))
#define SKYLOOP_GEMM_V 16
#include "fast_gemm_kernel.inl"
#undef SKYLOOP_GEMM_NS
#undef SKYLOOP_GEMM_TARGET
#undef SKYLOOP_GEMM_V
#endif

using Kernel = void (*)(const float*, int, int, const float*, int, int, int, const float*, float*, int, bool);
using GatedKernel = void (*)(const float*, int, int, const float*, int, int, int, const float*, float*, int);
using Elementwise = void (*)(float*, long);
using Sums = void (*)(const float*, int, int, int, float*);
using TanhGrad = void (*)(const float*, float*, long);
using AdamStep = void (*)(float*, const float*, float*, float*, long, float, float, float, float, float);
using SumSquares = double (*)(const float*, long);
using ColumnAtKernel = void (*)(const float*, int, int, const float*, int, int, float*, int);

struct Choice {
  Kernel fn, fn_at, fn_panels;
  GatedKernel gated;
  Elementwise tanh;
  Sums sums;
  TanhGrad tanh_grad;
  AdamStep adam;
  SumSquares sum_squares;
  ColumnAtKernel column_at;
  const char* isa;
};

#define SKYLOOP_GEMM_CHOICE(ns, name) \
  Choice { ns::gemm, ns::gemm_at, ns::gemm_panels, ns::gemm_gated, ns::tanh_inplace, ns::column_sums, ns::tanh_backward, ns::adam_step, ns::sum_squares, \
         ns::gemm_at_column, name }

Choice choose() {
  const char* env = std::getenv("ATEN_CPU_CAPABILITY");
  const std::string cap = env ? env : "";
#if defined(__x86_64__) && defined(__GNUC__)
  __builtin_cpu_init();
  const bool avx2 = __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma");
  const bool avx512 = avx2 && __builtin_cpu_supports("avx512f") && __builtin_cpu_supports("avx512vl");
  if (cap == "default") return SKYLOOP_GEMM_CHOICE(generic, "default");
  if (avx512 && cap != "avx2") return SKYLOOP_GEMM_CHOICE(avx512, "avx512");
  if (avx2) return SKYLOOP_GEMM_CHOICE(avx2, "avx2");
#endif
  return SKYLOOP_GEMM_CHOICE(generic, "default");
}

const Choice& chosen() {
  static const Choice c = choose();
  return c;
}

}  // namespace

Dense pack(const float* w, int out, int in_total, int first, int count, const float* bias) {
  if (first < 0 || count < 0 || first + count > in_total) throw std::logic_error("fast::pack: input columns out of range");
  Dense d;
  d.in = count;
  d.out = out;
  d.out_pad = pad_cols(out);
  d.wt.assign(static_cast<std::size_t>(count) * d.out_pad, 0.0f);
  for (int o = 0; o < out; ++o)
    for (int i = 0; i < count; ++i)
      d.wt[(static_cast<std::size_t>(o / kColBlock) * count + i) * kColBlock + o % kColBlock] =
          w[static_cast<std::size_t>(o) * in_total + first + i];
  if (bias) {
    d.bias.assign(static_cast<std::size_t>(d.out_pad), 0.0f);
    std::memcpy(d.bias.data(), bias, sizeof(float) * static_cast<std::size_t>(out));
  }
  return d;
}

void gemm(const float* A, int lda, int rows, const Dense& w, float* C, int ldc, bool accumulate) {
  if (ldc < w.out_pad) throw std::logic_error("fast::gemm: unpadded buffers");
  chosen().fn_panels(A, lda, rows, w.wt.data(), w.in, w.out_pad, w.out_pad, w.bias.empty() ? nullptr : w.bias.data(), C, ldc,
                     accumulate);
}

void matmul(const float* A, int lda, int rows, const float* B, int inner, int cols_pad, const float* bias, float* C, int ldc,
            bool accumulate, int cols) {
  if (cols < 0) cols = cols_pad;
  if (cols_pad % kColBlock != 0 || ldc < cols_pad || cols > cols_pad) throw std::logic_error("fast::matmul: unpadded buffers");
  chosen().fn(A, lda, rows, B, inner, cols_pad, cols, bias, C, ldc, accumulate);
}

void matmul_at_column(const float* A, int lda, int cols, const float* B, int ldb, int inner, float* C, int ldc) {
  chosen().column_at(A, lda, cols, B, ldb, inner, C, ldc);
}

void matmul_tanh_backward(const float* A, int lda, int rows, const float* B, int inner, int cols_pad, const float* h, float* C,
                          int ldc) {
  if (cols_pad % kColBlock != 0 || ldc < cols_pad) throw std::logic_error("fast::matmul_tanh_backward: unpadded buffers");
  chosen().gated(A, lda, rows, B, inner, cols_pad, cols_pad, h, C, ldc);
}

void matmul_at(const float* A, int lda, int rows, const float* B, int inner, int cols_pad, float* C, int ldc, int cols) {
  if (cols < 0) cols = cols_pad;
  if (cols_pad % kColBlock != 0 || ldc < cols_pad || cols > cols_pad) throw std::logic_error("fast::matmul_at: unpadded buffers");
  chosen().fn_at(A, lda, rows, B, inner, cols_pad, cols, nullptr, C, ldc, true);
}

void tanh_inplace(float* x, long n) { chosen().tanh(x, n); }

void column_sums(const float* D, int rows, int cols_pad, int ld, float* sums) {
  if (cols_pad % kColBlock != 0 || ld < cols_pad) throw std::logic_error("fast::column_sums: unpadded buffers");
  chosen().sums(D, rows, cols_pad, ld, sums);
}

void tanh_backward(const float* h, float* dh, long n) { chosen().tanh_grad(h, dh, n); }

void adam_step(float* params, const float* grad, float* m, float* v, long n, float beta1, float beta2, float step_size,
               float root_bc2, float eps) {
  chosen().adam(params, grad, m, v, n, beta1, beta2, step_size, root_bc2, eps);
}

double sum_squares(const float* x, long n) { return chosen().sum_squares(x, n); }

std::string kernel_isa() { return chosen().isa; }

}  // namespace skyloop::nn::fast
