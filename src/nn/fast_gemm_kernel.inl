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

/// Loads and stores go through the vector type itself (one unaligned vector move), never through
/// __builtin_memcpy: GCC expands a memcpy inside a target-attribute function with the base
/// target's 16-byte pieces, through the stack and general registers (under AVX2 tanh took 4x
/// and its gradient 16x as long; BENCHMARKS.md).
SKYLOOP_GEMM_TARGET __attribute__((always_inline)) static inline void store(float* p, vf x) {
  *reinterpret_cast<vf*>(p) = x;
}

/// An MR x (NV V) block of C, kept in NV MR vector registers while k sweeps the inner dimension
/// (MR rows, not padded: a block of 2 rows still gives 4 independent accumulation chains; NV = 1
/// only for a last block of V columns, the learners' narrow output layers). Each element of C is
/// summed over k in order, whatever the blocking.
template <int MR, int NV, bool TA = false>
SKYLOOP_GEMM_TARGET __attribute__((always_inline)) static inline void block(const float* A, int lda, const float* w,
                                                                            int in, int out_pad, const float* bias,
                                                                            float* C, int ldc, bool accumulate) {
  vf s[MR][NV];
  for (int r = 0; r < MR; ++r)
    for (int v = 0; v < NV; ++v) {
      if (accumulate) {
        s[r][v] = load(C + r * ldc + v * V);
      } else if (bias) {
        s[r][v] = load(bias + v * V);
      } else {
        s[r][v] = vf{};
      }
    }
  for (int k = 0; k < in; ++k, w += out_pad) {
    vf wv[NV];
    for (int v = 0; v < NV; ++v) wv[v] = load(w + v * V);
    for (int r = 0; r < MR; ++r) {
      const float a = TA ? A[static_cast<long>(k) * lda + r] : A[r * lda + k];
      for (int v = 0; v < NV; ++v) s[r][v] += a * wv[v];
    }
  }
  for (int r = 0; r < MR; ++r)
    for (int v = 0; v < NV; ++v) *reinterpret_cast<vf*>(C + r * ldc + v * V) = s[r][v];
}

/// Every row of C over one panel of NV V columns starting at column j.
template <int NV, bool TA>
SKYLOOP_GEMM_TARGET __attribute__((always_inline)) static inline void panel(const float* A, int lda, int rows, const float* wt,
                                                                            int in, int out_pad, const float* b, float* C,
                                                                            int ldc, bool accumulate) {
  int i = 0;
  for (; i + 6 <= rows; i += 6) block<6, NV, TA>(A + (TA ? static_cast<long>(i) : static_cast<long>(i) * lda), lda, wt, in, out_pad, b, C + static_cast<long>(i) * ldc, ldc, accumulate);
  const float* a = A + (TA ? static_cast<long>(i) : static_cast<long>(i) * lda);
  float* c = C + static_cast<long>(i) * ldc;
  switch (rows - i) {
    case 5: block<5, NV, TA>(a, lda, wt, in, out_pad, b, c, ldc, accumulate); break;
    case 4: block<4, NV, TA>(a, lda, wt, in, out_pad, b, c, ldc, accumulate); break;
    case 3: block<3, NV, TA>(a, lda, wt, in, out_pad, b, c, ldc, accumulate); break;
    case 2: block<2, NV, TA>(a, lda, wt, in, out_pad, b, c, ldc, accumulate); break;
    case 1: block<1, NV, TA>(a, lda, wt, in, out_pad, b, c, ldc, accumulate); break;
    default: break;
  }
}

/// The columns [0, cols rounded up to V) of C, B of row stride out_pad: a narrow output layer
/// (5 logits, 1 value) costs one vector of columns, not the whole padded block.
template <bool TA>
SKYLOOP_GEMM_TARGET static void gemm_any(const float* A, int lda, int rows, const float* wt, int in, int out_pad, int cols,
                                         const float* bias, float* C, int ldc, bool accumulate) {
  const int live = (cols + V - 1) / V * V;
  for (int j = 0; j < live; j += 2 * V) {
    const float* b = bias ? bias + j : nullptr;
    if (live - j >= 2 * V) panel<2, TA>(A, lda, rows, wt + j, in, out_pad, b, C + j, ldc, accumulate);
    else panel<1, TA>(A, lda, rows, wt + j, in, out_pad, b, C + j, ldc, accumulate);
  }
}

/// C = A B (+ bias) with A [rows x in] of row stride lda.
SKYLOOP_GEMM_TARGET static void gemm(const float* A, int lda, int rows, const float* wt, int in, int out_pad, int cols,
                                     const float* bias, float* C, int ldc, bool accumulate) {
  gemm_any<false>(A, lda, rows, wt, in, out_pad, cols, bias, C, ldc, accumulate);
}

/// C (+)= A^T B with A [in x rows] of row stride lda (the weight gradient X^T dY, where in is the
/// batch). The batch is swept in chunks whose panel of B and rows of A stay in the L1 cache while
/// every block of C passes over them; each element still sums over k in order.
SKYLOOP_GEMM_TARGET static void gemm_at(const float* A, int lda, int rows, const float* wt, int in, int out_pad, int cols,
                                        const float* bias, float* C, int ldc, bool accumulate) {
  constexpr int kChunk = 128;
  if (in <= kChunk) return gemm_any<true>(A, lda, rows, wt, in, out_pad, cols, bias, C, ldc, accumulate);
  for (int k = 0; k < in; k += kChunk) {
    const int n = in - k < kChunk ? in - k : kChunk;
    gemm_any<true>(A + static_cast<long>(k) * lda, lda, rows, wt + static_cast<long>(k) * out_pad, n, out_pad, cols,
                   k == 0 ? bias : nullptr, C, ldc, k == 0 ? accumulate : true);
  }
}

}  // namespace SKYLOOP_GEMM_NS

namespace SKYLOOP_GEMM_NS {

typedef int vi __attribute__((vector_size(SKYLOOP_GEMM_V * sizeof(int)), aligned(sizeof(int))));

SKYLOOP_GEMM_TARGET __attribute__((always_inline)) static inline vf splat(float x) { return vf{} + x; }

/// The same bits read as the other type (no aliasing of one object through two types).
template <typename To, typename From>
SKYLOOP_GEMM_TARGET __attribute__((always_inline)) static inline To bits_as(const From& x) {
  static_assert(sizeof(To) == sizeof(From), "bits_as: sizes differ");
  return (To)x;  // GCC's cast between vector types of one size reinterprets the bits, in registers
}

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
  return p * bits_as<vf>(bits);
}

/// tanh of V floats: the odd Taylor series to x^13 below |x| = 0.4 (truncation < 1e-8
/// relative), (1 - e) / (1 + e) with e = exp(-2|x|) above it (no cancellation there).
SKYLOOP_GEMM_TARGET __attribute__((always_inline)) static inline vf tanh_v(vf x) {
  const vi sign_mask = vi{} + static_cast<int>(0x80000000u);
  const vi xi = bits_as<vi>(x);
  const vi ai = xi & ~sign_mask;
  const vf a = bits_as<vf>(ai);
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
  const vi out = bits_as<vi>(r) | (xi & sign_mask);
  return bits_as<vf>(out);
}

SKYLOOP_GEMM_TARGET static void tanh_inplace(float* x, long n) {
  long i = 0;
  for (; i + V <= n; i += V) {
    store(x + i, tanh_v(load(x + i)));
  }
  if (i < n) {
    vf v = vf{};
    __builtin_memcpy(&v, x + i, sizeof(float) * static_cast<unsigned long>(n - i));
    v = tanh_v(v);
    __builtin_memcpy(x + i, &v, sizeof(float) * static_cast<unsigned long>(n - i));
  }
}

/// sums[c] += sum_r D[r, c] for c < cols_pad (a multiple of V), rows summed in order.
SKYLOOP_GEMM_TARGET static void column_sums(const float* D, int rows, int cols_pad, int ld, float* sums) {
  for (int c = 0; c < cols_pad; c += V) {
    vf s = load(sums + c);
    for (int r = 0; r < rows; ++r) s += load(D + static_cast<long>(r) * ld + c);
    *reinterpret_cast<vf*>(sums + c) = s;
  }
}

/// dh[i] *= 1 - h[i]^2 (tanh's derivative from its output) for i < n.
SKYLOOP_GEMM_TARGET static void tanh_backward(const float* h, float* dh, long n) {
  long i = 0;
  for (; i + V <= n; i += V) {
    const vf x = load(h + i);
    store(dh + i, load(dh + i) * (splat(1.0f) - x * x));
  }
  for (; i < n; ++i) dh[i] *= 1.0f - h[i] * h[i];
}

/// One Adam step over n floats (fast_mlp.hpp's Adam: the bias corrections folded into step_size
/// and root_bc2 by the caller).
SKYLOOP_GEMM_TARGET static void adam_step(float* p, const float* g, float* m, float* v, long n, float b1, float b2,
                                          float step_size, float root_bc2, float eps) {
  long i = 0;
  const vf vb1 = splat(b1), vb2 = splat(b2), c1 = splat(1.0f - b1), c2 = splat(1.0f - b2), vs = splat(step_size),
           vr = splat(root_bc2), ve = splat(eps);
  for (; i + V <= n; i += V) {
    vf pv = load(p + i);
    const vf gv = load(g + i);
    vf mv = load(m + i), vv = load(v + i);
    mv = vb1 * mv + c1 * gv;
    vv = vb2 * vv + c2 * gv * gv;
    vf root;
    for (int k = 0; k < V; ++k) root[k] = __builtin_sqrtf(vv[k]);
    pv -= vs * mv / (root / vr + ve);
    store(p + i, pv);
    store(m + i, mv);
    store(v + i, vv);
  }
  for (; i < n; ++i) {
    m[i] = b1 * m[i] + (1.0f - b1) * g[i];
    v[i] = b2 * v[i] + (1.0f - b2) * g[i] * g[i];
    p[i] -= step_size * m[i] / (__builtin_sqrtf(v[i]) / root_bc2 + eps);
  }
}

/// sum x[i]^2 in double, V partial sums (then added in order).
SKYLOOP_GEMM_TARGET static double sum_squares(const float* x, long n) {
  typedef double vd __attribute__((vector_size(SKYLOOP_GEMM_V * sizeof(double)), aligned(sizeof(double))));
  vd s{};
  long i = 0;
  for (; i + V <= n; i += V) {
    const vd d = __builtin_convertvector(load(x + i), vd);
    s += d * d;
  }
  double total = 0;
  for (int k = 0; k < V; ++k) total += s[k];
  for (; i < n; ++i) total += static_cast<double>(x[i]) * x[i];
  return total;
}

}  // namespace SKYLOOP_GEMM_NS
