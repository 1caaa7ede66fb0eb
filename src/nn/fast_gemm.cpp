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

using Kernel = void (*)(const float*, int, int, const float*, int, int, const float*, float*, int, bool);
using Elementwise = void (*)(float*, long);

struct Choice {
  Kernel fn, fn_at;
  Elementwise tanh;
  const char* isa;
};

Choice choose() {
  const char* env = std::getenv("ATEN_CPU_CAPABILITY");
  const std::string cap = env ? env : "";
#if defined(__x86_64__) && defined(__GNUC__)
  __builtin_cpu_init();
  const bool avx2 = __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma");
  const bool avx512 = avx2 && __builtin_cpu_supports("avx512f") && __builtin_cpu_supports("avx512vl");
  if (cap == "default") return {generic::gemm, generic::gemm_at, generic::tanh_inplace, "default"};
  if (avx512 && cap != "avx2") return {avx512::gemm, avx512::gemm_at, avx512::tanh_inplace, "avx512"};
  if (avx2) return {avx2::gemm, avx2::gemm_at, avx2::tanh_inplace, "avx2"};
#endif
  return {generic::gemm, generic::gemm_at, generic::tanh_inplace, "default"};
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
      d.wt[static_cast<std::size_t>(i) * d.out_pad + o] = w[static_cast<std::size_t>(o) * in_total + first + i];
  if (bias) {
    d.bias.assign(static_cast<std::size_t>(d.out_pad), 0.0f);
    std::memcpy(d.bias.data(), bias, sizeof(float) * static_cast<std::size_t>(out));
  }
  return d;
}

void gemm(const float* A, int lda, int rows, const Dense& w, float* C, int ldc, bool accumulate) {
  if (ldc < w.out_pad) throw std::logic_error("fast::gemm: unpadded buffers");
  chosen().fn(A, lda, rows, w.wt.data(), w.in, w.out_pad, w.bias.empty() ? nullptr : w.bias.data(), C, ldc, accumulate);
}

void matmul(const float* A, int lda, int rows, const float* B, int inner, int cols_pad, const float* bias, float* C, int ldc,
            bool accumulate) {
  if (cols_pad % kColBlock != 0 || ldc < cols_pad) throw std::logic_error("fast::matmul: unpadded buffers");
  chosen().fn(A, lda, rows, B, inner, cols_pad, bias, C, ldc, accumulate);
}

void matmul_at(const float* A, int lda, int rows, const float* B, int inner, int cols_pad, float* C, int ldc) {
  if (cols_pad % kColBlock != 0 || ldc < cols_pad) throw std::logic_error("fast::matmul_at: unpadded buffers");
  chosen().fn_at(A, lda, rows, B, inner, cols_pad, nullptr, C, ldc, true);
}

void tanh_inplace(float* x, long n) { chosen().tanh(x, n); }

std::string kernel_isa() { return chosen().isa; }

}  // namespace skyloop::nn::fast
