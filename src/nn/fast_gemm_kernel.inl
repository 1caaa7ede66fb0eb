// One micro-kernel body, included by fast_gemm.cpp once per instruction set with
// SKYLOOP_GEMM_NAME, SKYLOOP_GEMM_TARGET and SKYLOOP_GEMM_V (floats per vector) defined.
// A 6 x 2V block of C lives in 12 vector registers while the inner dimension is swept; vector
// types are GCC's generic vectors, lowered to the target's registers. Everything here is local
// to the function, so no inline symbol is shared between the variants.
SKYLOOP_GEMM_TARGET static void SKYLOOP_GEMM_NAME(const float* A, int lda, int rows, const float* wt, int in,
                                                  int out_pad, const float* bias, float* C, int ldc, bool accumulate) {
  typedef float vf __attribute__((vector_size(SKYLOOP_GEMM_V * sizeof(float)), aligned(sizeof(float))));
  constexpr int V = SKYLOOP_GEMM_V;
  for (int j = 0; j < out_pad; j += 2 * V) {
    vf b0 = {}, b1 = {};
    if (bias) b0 = *reinterpret_cast<const vf*>(bias + j), b1 = *reinterpret_cast<const vf*>(bias + j + V);
    for (int i = 0; i < rows; i += 6) {
      // A last block of mr < 6 rows repeats its last row in the spare registers (never stored),
      // so it keeps 12 independent accumulation chains.
      const int mr = rows - i < 6 ? rows - i : 6;
      const int r1 = mr > 1 ? 1 : mr - 1, r2 = mr > 2 ? 2 : mr - 1, r3 = mr > 3 ? 3 : mr - 1, r4 = mr > 4 ? 4 : mr - 1,
                r5 = mr > 5 ? 5 : mr - 1;
      float* c0 = C + static_cast<long>(i) * ldc + j;
      float* c1 = c0 + static_cast<long>(r1) * ldc;
      float* c2 = c0 + static_cast<long>(r2) * ldc;
      float* c3 = c0 + static_cast<long>(r3) * ldc;
      float* c4 = c0 + static_cast<long>(r4) * ldc;
      float* c5 = c0 + static_cast<long>(r5) * ldc;
      vf s00 = b0, s01 = b1, s10 = b0, s11 = b1, s20 = b0, s21 = b1;
      vf s30 = b0, s31 = b1, s40 = b0, s41 = b1, s50 = b0, s51 = b1;
      if (accumulate) {
        s00 = *reinterpret_cast<vf*>(c0), s01 = *reinterpret_cast<vf*>(c0 + V);
        s10 = *reinterpret_cast<vf*>(c1), s11 = *reinterpret_cast<vf*>(c1 + V);
        s20 = *reinterpret_cast<vf*>(c2), s21 = *reinterpret_cast<vf*>(c2 + V);
        s30 = *reinterpret_cast<vf*>(c3), s31 = *reinterpret_cast<vf*>(c3 + V);
        s40 = *reinterpret_cast<vf*>(c4), s41 = *reinterpret_cast<vf*>(c4 + V);
        s50 = *reinterpret_cast<vf*>(c5), s51 = *reinterpret_cast<vf*>(c5 + V);
      }
      const float* a0 = A + static_cast<long>(i) * lda;
      const float* a1 = a0 + static_cast<long>(r1) * lda;
      const float* a2 = a0 + static_cast<long>(r2) * lda;
      const float* a3 = a0 + static_cast<long>(r3) * lda;
      const float* a4 = a0 + static_cast<long>(r4) * lda;
      const float* a5 = a0 + static_cast<long>(r5) * lda;
      const float* w = wt + j;
      for (int k = 0; k < in; ++k, w += out_pad) {
        const vf w0 = *reinterpret_cast<const vf*>(w), w1 = *reinterpret_cast<const vf*>(w + V);
        s00 += a0[k] * w0, s01 += a0[k] * w1;
        s10 += a1[k] * w0, s11 += a1[k] * w1;
        s20 += a2[k] * w0, s21 += a2[k] * w1;
        s30 += a3[k] * w0, s31 += a3[k] * w1;
        s40 += a4[k] * w0, s41 += a4[k] * w1;
        s50 += a5[k] * w0, s51 += a5[k] * w1;
      }
      *reinterpret_cast<vf*>(c0) = s00, *reinterpret_cast<vf*>(c0 + V) = s01;
      if (mr > 1) *reinterpret_cast<vf*>(c1) = s10, *reinterpret_cast<vf*>(c1 + V) = s11;
      if (mr > 2) *reinterpret_cast<vf*>(c2) = s20, *reinterpret_cast<vf*>(c2 + V) = s21;
      if (mr > 3) *reinterpret_cast<vf*>(c3) = s30, *reinterpret_cast<vf*>(c3 + V) = s31;
      if (mr > 4) *reinterpret_cast<vf*>(c4) = s40, *reinterpret_cast<vf*>(c4 + V) = s41;
      if (mr > 5) *reinterpret_cast<vf*>(c5) = s50, *reinterpret_cast<vf*>(c5 + V) = s51;
    }
  }
}
