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
template <int MR, bool TA = false>
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
      const float a = TA ? A[static_cast<long>(k) * lda + r] : A[r * lda + k];
      s[r][0] += a * w0, s[r][1] += a * w1;
    }
  }
  for (int r = 0; r < MR; ++r) *reinterpret_cast<vf*>(C + r * ldc) = s[r][0], *reinterpret_cast<vf*>(C + r * ldc + V) = s[r][1];
}

template <bool TA>
SKYLOOP_GEMM_TARGET static void gemm_any(const float* A, int lda, int rows, const float* wt, int in, int out_pad,
                                     const float* bias, float* C, int ldc, bool accumulate) {
  for (int j = 0; j < out_pad; j += 2 * V) {
    const float* b = bias ? bias + j : nullptr;
    int i = 0;
    for (; i + 6 <= rows; i += 6) block<6, TA>(A + (TA ? static_cast<long>(i) : static_cast<long>(i) * lda), lda, wt + j, in, out_pad, b, C + static_cast<long>(i) * ldc + j, ldc, accumulate);
    const float* a = A + (TA ? static_cast<long>(i) : static_cast<long>(i) * lda);
    float* c = C + static_cast<long>(i) * ldc + j;
    switch (rows - i) {
      case 5: block<5, TA>(a, lda, wt + j, in, out_pad, b, c, ldc, accumulate); break;
      case 4: block<4, TA>(a, lda, wt + j, in, out_pad, b, c, ldc, accumulate); break;
      case 3: block<3, TA>(a, lda, wt + j, in, out_pad, b, c, ldc, accumulate); break;
      case 2: block<2, TA>(a, lda, wt + j, in, out_pad, b, c, ldc, accumulate); break;
      case 1: block<1, TA>(a, lda, wt + j, in, out_pad, b, c, ldc, accumulate); break;
      default: break;
    }
  }
}

/// C = A B (+ bias) with A [rows x in] of row stride lda.
SKYLOOP_GEMM_TARGET static void gemm(const float* A, int lda, int rows, const float* wt, int in, int out_pad,
                                     const float* bias, float* C, int ldc, bool accumulate) {
  gemm_any<false>(A, lda, rows, wt, in, out_pad, bias, C, ldc, accumulate);
}

/// C = A^T B (+ bias) with A [in x rows] of row stride lda (the weight gradient X^T dY).
SKYLOOP_GEMM_TARGET static void gemm_at(const float* A, int lda, int rows, const float* wt, int in, int out_pad,
                                        const float* bias, float* C, int ldc, bool accumulate) {
  gemm_any<true>(A, lda, rows, wt, in, out_pad, bias, C, ldc, accumulate);
}

}  // namespace SKYLOOP_GEMM_NS

namespace SKYLOOP_GEMM_NS {

typedef int vi __attribute__((vector_size(SKYLOOP_GEMM_V * sizeof(int)), aligned(sizeof(int))));

SKYLOOP_GEMM_TARGET __attribute__((always_inline)) static inline vf splat(float x) { return vf{} + x; }

/// exp(y) for y in [-87, 0]: y = n ln2 + r (Cody-Waite, |r| <= ln2 / 2), e^r by its Taylor
/// polynomial to r^7 (relative error below 2^-24 on that interval), 2^n built in the exponent bits.
SKYLOOP_GEMM_TARGET __attribute__((always_inline)) static inline vf exp_nonpositive(vf y) {
  const vf magic = splat(12582912.0f);  // 1.5 * 2^23: adding it rounds to an integer
  const vf n = (y * splat(1.44269504088896341f) + magic) - magic;
  const vf r = (y - n * splat(0.693359375f)) - n * splat(-2.12194440e-4f);
  vf p = splat(1.0f / 5040.0f);
  p = p * r + splat(1.0f / 720.0f);
  p = p * r + splat(1.0f / 120.0f);
  p = p * r + splat(1.0f / 24.0f);
  p = p * r + splat(1.0f / 6.0f);
  p = p * r + splat(0.5f);
  p = p * r + splat(1.0f);
  p = p * r + splat(1.0f);
  const vi bits = (__builtin_convertvector(n, vi) + 127) << 23;
  return p * reinterpret_cast<const vf&>(bits);
}

/// tanh of V floats: the odd Taylor series to x^13 below |x| = 0.4 (truncation < 1e-8
/// relative), (1 - e) / (1 + e) with e = exp(-2|x|) above it (no cancellation there).
SKYLOOP_GEMM_TARGET __attribute__((always_inline)) static inline vf tanh_v(vf x) {
  const vi sign_mask = vi{} + static_cast<int>(0x80000000u);
  const vi xi = reinterpret_cast<const vi&>(x);
  const vi ai = xi & ~sign_mask;
  const vf a = reinterpret_cast<const vf&>(ai);
  const vf a2 = a * a;
  vf s = splat(21844.0f / 6081075.0f);
  s = s * a2 + splat(-1382.0f / 155925.0f);
  s = s * a2 + splat(62.0f / 2835.0f);
  s = s * a2 + splat(-17.0f / 315.0f);
  s = s * a2 + splat(2.0f / 15.0f);
  s = s * a2 + splat(-1.0f / 3.0f);
  const vf small = a + a * a2 * s;
  vf y = splat(-2.0f) * a;
  y = y < splat(-87.0f) ? splat(-87.0f) : y;  // e below 2^-125: tanh rounds to 1 there
  const vf e = exp_nonpositive(y);
  const vf big = (splat(1.0f) - e) / (splat(1.0f) + e);
  const vf r = a < splat(0.4f) ? small : big;
  const vi out = reinterpret_cast<const vi&>(r) | (xi & sign_mask);
  return reinterpret_cast<const vf&>(out);
}

SKYLOOP_GEMM_TARGET static void tanh_inplace(float* x, long n) {
  long i = 0;
  for (; i + V <= n; i += V) {
    vf v;
    __builtin_memcpy(&v, x + i, sizeof(vf));
    v = tanh_v(v);
    __builtin_memcpy(x + i, &v, sizeof(vf));
  }
  if (i < n) {
    vf v = vf{};
    __builtin_memcpy(&v, x + i, sizeof(float) * static_cast<unsigned long>(n - i));
    v = tanh_v(v);
    __builtin_memcpy(x + i, &v, sizeof(float) * static_cast<unsigned long>(n - i));
  }
}

}  // namespace SKYLOOP_GEMM_NS
