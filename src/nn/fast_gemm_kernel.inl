// One GEMM kernel, included by fast_gemm.cpp once per instruction set inside its own namespace
// SKYLOOP_GEMM_NS, with SKYLOOP_GEMM_TARGET (the function attribute) and SKYLOOP_GEMM_V (floats
// per vector) defined. Vector types are GCC's generic vectors, lowered to the target's registers.
// Everything is static and inside the variant's namespace, so no symbol is shared between
// instruction sets.
namespace SKYLOOP_GEMM_NS {

typedef float vf __attribute__((vector_size(SKYLOOP_GEMM_V * sizeof(float)), aligned(sizeof(float))));
constexpr int V = SKYLOOP_GEMM_V;

SKYLOOP_GEMM_TARGET __attribute__((always_inline)) static inline vf load(const float* p) {
  return *reinterpret_cast<const vf*>(p);
}

/// An MR x 2V block of C, kept in 2 MR vector registers while k sweeps the inner dimension (MR
/// rows, not padded: a block of 2 rows still gives 4 independent accumulation chains).
template <int MR>
SKYLOOP_GEMM_TARGET __attribute__((always_inline)) static inline void block(const float* A, int lda, const float* w,
                                                                            int in, int out_pad, const float* bias,
                                                                            float* C, int ldc, bool accumulate) {
  vf s[MR][2];
  for (int r = 0; r < MR; ++r) {
    if (accumulate) {
      s[r][0] = load(C + r * ldc), s[r][1] = load(C + r * ldc + V);
    } else if (bias) {
      s[r][0] = load(bias), s[r][1] = load(bias + V);
    } else {
      s[r][0] = vf{}, s[r][1] = vf{};
    }
  }
  for (int k = 0; k < in; ++k, w += out_pad) {
    const vf w0 = load(w), w1 = load(w + V);
    for (int r = 0; r < MR; ++r) {
      const float a = A[r * lda + k];
      s[r][0] += a * w0, s[r][1] += a * w1;
    }
  }
  for (int r = 0; r < MR; ++r) *reinterpret_cast<vf*>(C + r * ldc) = s[r][0], *reinterpret_cast<vf*>(C + r * ldc + V) = s[r][1];
}

SKYLOOP_GEMM_TARGET static void gemm(const float* A, int lda, int rows, const float* wt, int in, int out_pad,
                                     const float* bias, float* C, int ldc, bool accumulate) {
  for (int j = 0; j < out_pad; j += 2 * V) {
    const float* b = bias ? bias + j : nullptr;
    int i = 0;
    for (; i + 6 <= rows; i += 6) block<6>(A + static_cast<long>(i) * lda, lda, wt + j, in, out_pad, b, C + static_cast<long>(i) * ldc + j, ldc, accumulate);
    const float* a = A + static_cast<long>(i) * lda;
    float* c = C + static_cast<long>(i) * ldc + j;
    switch (rows - i) {
      case 5: block<5>(a, lda, wt + j, in, out_pad, b, c, ldc, accumulate); break;
      case 4: block<4>(a, lda, wt + j, in, out_pad, b, c, ldc, accumulate); break;
      case 3: block<3>(a, lda, wt + j, in, out_pad, b, c, ldc, accumulate); break;
      case 2: block<2>(a, lda, wt + j, in, out_pad, b, c, ldc, accumulate); break;
      case 1: block<1>(a, lda, wt + j, in, out_pad, b, c, ldc, accumulate); break;
      default: break;
    }
  }
}

}  // namespace SKYLOOP_GEMM_NS
