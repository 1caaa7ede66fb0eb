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
                                                                            int in, int ldb, long vstep,
                                                                            const float* bias, float* C, int ldc,
                                                                            bool accumulate, const float* gate) {
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
  for (int k = 0; k < in; ++k, w += ldb) {
    vf wv[NV];
    for (int v = 0; v < NV; ++v) wv[v] = load(w + v * vstep);
    for (int r = 0; r < MR; ++r) {
      const float a = TA ? A[static_cast<long>(k) * lda + r] : A[r * lda + k];
      for (int v = 0; v < NV; ++v) s[r][v] += a * wv[v];
    }
  }
  if (gate) {  // through tanh backwards: times 1 - h^2, h the layer's output (tanh_backward's arithmetic)
    const vf one = vf{} + 1.0f;
    for (int r = 0; r < MR; ++r)
      for (int v = 0; v < NV; ++v) {
        const vf h = load(gate + r * ldc + v * V);
        s[r][v] = s[r][v] * (one - h * h);
      }
  }
  for (int r = 0; r < MR; ++r)
    for (int v = 0; v < NV; ++v) *reinterpret_cast<vf*>(C + r * ldc + v * V) = s[r][v];
}

/// MR rows of C across the columns [0, live), one panel of 2 V (or a last one of V) columns at a
/// time: the MR rows of A stay in the L1 cache across the panels, and so does B when it is as
/// small as the learners' layers (64 x 64 floats), so A is read from memory once. B is row-major
/// of row stride out_pad, or (panels) in column panels of kColBlock, each [in x kColBlock]
/// contiguous (Dense's layout): a panel is read as one stream, where a row stride of 128 floats
/// puts every row of a panel in the same few sets of the L1 cache.
template <int MR, bool TA>
SKYLOOP_GEMM_TARGET __attribute__((always_inline)) static inline void row_block(const float* A, int lda, const float* wt, int in,
                                                                                int out_pad, bool panels, int live,
                                                                                const float* bias, float* C, bool accumulate,
                                                                                int ldc, const float* gate) {
  const int ldb = panels ? kColBlock : out_pad;
  const long vstep = panels && V >= kColBlock ? static_cast<long>(in) * kColBlock : V;
  for (int j = 0; j < live; j += 2 * V) {
    const float* b = bias ? bias + j : nullptr;
    const float* g = gate ? gate + j : nullptr;
    const float* w = panels ? wt + static_cast<long>(j / kColBlock) * in * kColBlock + j % kColBlock : wt + j;
    if (live - j >= 2 * V) block<MR, 2, TA>(A, lda, w, in, ldb, vstep, b, C + j, ldc, accumulate, g);
    else block<MR, 1, TA>(A, lda, w, in, ldb, vstep, b, C + j, ldc, accumulate, g);
  }
}

/// Every row of C over the columns [0, width), in blocks of 6 rows; a width of one vector (the
/// learners' narrow output layers) in blocks of 12 first. A block's sums are chains of dependent
/// multiply-adds, one per register: 6 chains of one vector would wait on the multiply-add's
/// latency at every k, 12 keep both of its units busy.
template <bool TA>
SKYLOOP_GEMM_TARGET static void gemm_rows(const float* A, int lda, int rows, const float* wt, int in, int out_pad, bool panels,
                                          int width, const float* bias, float* C, int ldc, bool accumulate, const float* gate) {
  auto a_at = [&](int i) { return A + (TA ? static_cast<long>(i) : static_cast<long>(i) * lda); };
  auto g_at = [&](int i) { return gate ? gate + static_cast<long>(i) * ldc : nullptr; };
  int i = 0;
  if (width == V) {
    const long vstep = panels && V >= kColBlock ? static_cast<long>(in) * kColBlock : V;
    for (; i + 12 <= rows; i += 12)
      block<12, 1, TA>(a_at(i), lda, wt, in, panels ? kColBlock : out_pad, vstep, bias, C + static_cast<long>(i) * ldc, ldc, accumulate,
                       g_at(i));
  }
  for (; i + 6 <= rows; i += 6)
    row_block<6, TA>(a_at(i), lda, wt, in, out_pad, panels, width, bias, C + static_cast<long>(i) * ldc, accumulate, ldc,
                     g_at(i));
  const float* a = a_at(i);
  const float* g = g_at(i);
  float* c = C + static_cast<long>(i) * ldc;
  switch (rows - i) {
    case 5: row_block<5, TA>(a, lda, wt, in, out_pad, panels, width, bias, c, accumulate, ldc, g); break;
    case 4: row_block<4, TA>(a, lda, wt, in, out_pad, panels, width, bias, c, accumulate, ldc, g); break;
    case 3: row_block<3, TA>(a, lda, wt, in, out_pad, panels, width, bias, c, accumulate, ldc, g); break;
    case 2: row_block<2, TA>(a, lda, wt, in, out_pad, panels, width, bias, c, accumulate, ldc, g); break;
    case 1: row_block<1, TA>(a, lda, wt, in, out_pad, panels, width, bias, c, accumulate, ldc, g); break;
    default: break;
  }
}

/// The columns [0, cols rounded up to V) of C, B of row stride out_pad: a narrow output layer
/// (5 logits, 1 value) costs one vector of columns, not the whole padded block. A B sweeps the
/// row blocks once, each across every panel (A read once); A^T B, over a chunk of the batch,
/// sweeps the panels once, each across every row block (B's panel stays in the L1 cache).
template <bool TA>
SKYLOOP_GEMM_TARGET static void gemm_any(const float* A, int lda, int rows, const float* wt, int in, int out_pad, int cols,
                                         const float* bias, float* C, int ldc, bool accumulate, const float* gate = nullptr,
                                         bool panels = false) {
  const int live = (cols + V - 1) / V * V;
  if (!TA) return gemm_rows<TA>(A, lda, rows, wt, in, out_pad, panels, live, bias, C, ldc, accumulate, gate);
  for (int j = 0; j < live; j += 2 * V)
    gemm_rows<TA>(A, lda, rows, wt + j, in, out_pad, false, live - j >= 2 * V ? 2 * V : V, bias ? bias + j : nullptr, C + j,
                  ldc, accumulate, nullptr);
}

/// C = A B (+ bias) with A [rows x in] of row stride lda.
SKYLOOP_GEMM_TARGET static void gemm(const float* A, int lda, int rows, const float* wt, int in, int out_pad, int cols,
                                     const float* bias, float* C, int ldc, bool accumulate) {
  gemm_any<false>(A, lda, rows, wt, in, out_pad, cols, bias, C, ldc, accumulate);
}

/// C = A B (+ bias) with B in column panels of kColBlock (Dense's layout, fast_gemm.hpp).
SKYLOOP_GEMM_TARGET static void gemm_panels(const float* A, int lda, int rows, const float* wt, int in, int out_pad, int cols,
                                            const float* bias, float* C, int ldc, bool accumulate) {
  gemm_any<false>(A, lda, rows, wt, in, out_pad, cols, bias, C, ldc, accumulate, nullptr, true);
}

/// C[j * ldc] += sum_k A[k, j] B[k * ldb] for j < cols: gemm_at's arithmetic for one output
/// column (the weight gradient X^T dY of a layer of one output, the critic's value; each sum over
/// the batch k in order, one multiply-add at a time in vector lanes, as the block kernel's),
/// without the vector of columns the block kernel computes for it: the columns j of A in vectors.
SKYLOOP_GEMM_TARGET static void gemm_at_column(const float* A, int lda, int cols, const float* B, int ldb, int inner, float* C,
                                               int ldc) {
  constexpr int kVectors = 8;
  int j = 0;
  for (; j + V <= cols; j += kVectors * V) {
    const int nv = (cols - j) / V < kVectors ? (cols - j) / V : kVectors;
    vf s[kVectors];
    for (int v = 0; v < nv; ++v)
      for (int l = 0; l < V; ++l) s[v][l] = C[static_cast<long>(j + v * V + l) * ldc];
    for (int k = 0; k < inner; ++k) {
      const vf b = vf{} + B[static_cast<long>(k) * ldb];
      const float* a = A + static_cast<long>(k) * lda + j;
      for (int v = 0; v < nv; ++v) s[v] += load(a + v * V) * b;
    }
    for (int v = 0; v < nv; ++v)
      for (int l = 0; l < V; ++l) C[static_cast<long>(j + v * V + l) * ldc] = s[v][l];
    if (nv < kVectors) {
      j += nv * V;
      break;
    }
  }
  if (j < cols) {  // the last columns, in the lanes of one vector
    const int n = cols - j;
    vf s = vf{};
    for (int l = 0; l < n; ++l) s[l] = C[static_cast<long>(j + l) * ldc];
    for (int k = 0; k < inner; ++k) {
      vf a = vf{};
      for (int l = 0; l < n; ++l) a[l] = A[static_cast<long>(k) * lda + j + l];
      s += a * (vf{} + B[static_cast<long>(k) * ldb]);
    }
    for (int l = 0; l < n; ++l) C[static_cast<long>(j + l) * ldc] = s[l];
  }
}

/// C = (A B) * (1 - H^2) element-wise, H of C's shape and row stride: the gradient into a tanh
/// layer's input from the gradient at its output (tanh_backward fused into the GEMM's store).
SKYLOOP_GEMM_TARGET static void gemm_gated(const float* A, int lda, int rows, const float* wt, int in, int out_pad, int cols,
                                           const float* H, float* C, int ldc) {
  gemm_any<false>(A, lda, rows, wt, in, out_pad, cols, nullptr, C, ldc, false, H);
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

/// tanh of V floats: tanh(a) = a P(a^2) / Q(a^2) on a = |x| clamped to 9, the sign put back,
/// 1 from a = 9 on (tanh(9) is 3.1e-8 below 1, within one float32 ulp). P (degree 5) and Q
/// (degree 4) are the minimax rational fit of tanh(x) / x in relative error on [0, 9] (a linear
/// program over 6,500 points, iterated on the denominator; relative error 9.4e-9), rounded to
/// float: evaluated in float32 with FMA the result is within 1.5 ulps relative below |x| = 0.4
/// and 2 ulps absolute above (a float32 emulation over every multiple of 1/1024 in [0, 20]).
/// Nine FMAs and one division: about twice as fast as the Taylor series and exp it replaced
/// (BENCHMARKS.md).
SKYLOOP_GEMM_TARGET __attribute__((always_inline)) static inline vf tanh_v(vf x) {
  const vi sign_mask = vi{} + static_cast<int>(0x80000000u);
  const vi xi = bits_as<vi>(x);
  const vf a = bits_as<vf>(xi & ~sign_mask);
  const vf ac = a > splat(9.0f) ? splat(9.0f) : a;  // +inf to 9; a NaN stays NaN
  const vf t = ac * ac;
  vf p = splat(-1.0738933180209909e-11f);
  p = p * t + splat(2.852411817855227e-08f);
  p = p * t + splat(2.7128233341500163e-05f);
  p = p * t + splat(0.003824284067377448f);
  p = p * t + splat(0.13644681870937347f);
  p = p * t + splat(1.0f);
  vf q = splat(1.2265865052540903e-06f);
  q = q * t + splat(0.0003861276200041175f);
  q = q * t + splat(0.027084356173872948f);
  q = q * t + splat(0.4697801470756531f);
  q = q * t + splat(1.0f);
  const vf r = a >= splat(9.0f) ? splat(1.0f) : ac * p / q;
  return bits_as<vf>(bits_as<vi>(r) | (xi & sign_mask));
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

/// sums[c] += sum_r D[r, c] for c < cols_pad (a multiple of V), rows summed in order. Up to
/// kSumVectors column vectors at a time, each its own chain of additions down the rows: one chain
/// alone waits on the adder's latency at every row.
SKYLOOP_GEMM_TARGET static void column_sums(const float* D, int rows, int cols_pad, int ld, float* sums) {
  constexpr int kSumVectors = 8;
  for (int c = 0; c < cols_pad; c += kSumVectors * V) {
    const int nv = (cols_pad - c) / V < kSumVectors ? (cols_pad - c) / V : kSumVectors;
    vf s[kSumVectors];
    for (int v = 0; v < nv; ++v) s[v] = load(sums + c + v * V);
    for (int r = 0; r < rows; ++r) {
      const float* d = D + static_cast<long>(r) * ld + c;
      for (int v = 0; v < nv; ++v) s[v] += load(d + v * V);
    }
    for (int v = 0; v < nv; ++v) store(sums + c + v * V, s[v]);
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

/// sum x[i]^2 in double, V partial sums (partial k over x[k], x[k + V], ...; then added in order).
/// The partial sums live in V / 4 vectors of 4 doubles, a width every variant keeps in registers
/// (one vector of V doubles went through the stack at every step under AVX2).
SKYLOOP_GEMM_TARGET static double sum_squares(const float* x, long n) {
  typedef double vd4 __attribute__((vector_size(4 * sizeof(double)), aligned(sizeof(double))));
  typedef float vf4 __attribute__((vector_size(4 * sizeof(float)), aligned(sizeof(float))));
  constexpr int kParts = V / 4;
  vd4 s[kParts];
  for (int p = 0; p < kParts; ++p) s[p] = vd4{};
  long i = 0;
  for (; i + V <= n; i += V)
    for (int p = 0; p < kParts; ++p) {
      const vd4 d = __builtin_convertvector(*reinterpret_cast<const vf4*>(x + i + 4 * p), vd4);
      s[p] += d * d;
    }
  double total = 0;
  for (int p = 0; p < kParts; ++p)
    for (int k = 0; k < 4; ++k) total += s[p][k];
  for (; i < n; ++i) total += static_cast<double>(x[i]) * x[i];
  return total;
}

}  // namespace SKYLOOP_GEMM_NS
