#pragma once
// Dense layers for the fast inference path (fast_model.hpp): y = x W^T + b in float32, with a
// register-blocked kernel compiled for several instruction sets (generic SSE2, AVX2+FMA,
// AVX-512) and chosen once at run time from the CPU. ATEN_CPU_CAPABILITY (default | avx2 |
// avx512), the variable LibTorch reads, caps the choice here too, so one test matrix covers the
// kernels of both paths. Torch-free.
#include <string>
#include <vector>

namespace skyloop::nn::fast {

constexpr int kColBlock = 16;   // weights pad their output width to a multiple of this (a 16-float AVX-512 vector)

inline int pad_cols(int cols) { return (cols + kColBlock - 1) / kColBlock * kColBlock; }

/// A linear map packed for the kernel: W^T [in x out_pad] (columns >= out are zero) in column
/// panels of kColBlock, each panel [in x kColBlock] row-major and contiguous (element (i, o) at
/// wt[((o / kColBlock) * in + i) * kColBlock + o % kColBlock]), the bias padded the same way
/// (empty: no bias).
struct Dense {
  int in = 0, out = 0, out_pad = 0;
  std::vector<float> wt, bias;
};

/// Packs the input columns [first, first + count) of a row-major weight W [out x in_total]
/// (torch's Linear layout) with an optional bias [out].
Dense pack(const float* w, int out, int in_total, int first, int count, const float* bias);

/// C[i, :] (+)= A[i, :in] W^T (+ bias) for i < rows (any count; in blocks of 6 rows);
/// A has row stride lda, C row stride ldc >= w.out_pad (columns out..out_pad are written too).
/// accumulate = false overwrites C (with the bias, if any); true adds to it.
void gemm(const float* A, int lda, int rows, const Dense& w, float* C, int ldc, bool accumulate);

/// The same kernel on any row-major B [inner x cols_pad] (cols_pad a multiple of kColBlock):
/// C[i, :cols_pad] (+)= A[i, :inner] B (+ bias) for i < rows. The training path (the learners'
/// fused MLPs, src/marl/fast_mlp.hpp) builds its forward and backward passes from it.
/// cols >= 0: only the columns [0, cols) are asked for; those up to the next whole vector of the
/// kernel in use are written too, the rest of C's row is left as it was (a narrow output layer).
void matmul(const float* A, int lda, int rows, const float* B, int inner, int cols_pad, const float* bias, float* C, int ldc,
            bool accumulate, int cols = -1);

/// The weight gradient of a layer of one output: C[j * ldc] += sum_k A[k, j] B[k * ldb] for j < cols,
/// A [inner x cols] of row stride lda, B's column of row stride ldb. The floats of matmul_at's
/// column 0, without the kernel vector of columns matmul_at computes for it.
void matmul_at_column(const float* A, int lda, int cols, const float* B, int ldb, int inner, float* C, int ldc);

/// C[i, :cols_pad] = (A[i, :inner] B) * (1 - h[i, :cols_pad]^2) element-wise, h of C's row stride
/// ldc: the gradient into a tanh layer from the gradient at the next layer's input, in one pass
/// (the same floats as matmul, then tanh_backward).
void matmul_tanh_backward(const float* A, int lda, int rows, const float* B, int inner, int cols_pad, const float* h, float* C,
                          int ldc);

/// C[:rows, :cols_pad] += A^T B for A [inner x rows] of row stride lda: a weight's gradient
/// X^T dY straight from the activations X [batch x in] (rows = in, inner = batch). cols as matmul's.
void matmul_at(const float* A, int lda, int rows, const float* B, int inner, int cols_pad, float* C, int ldc, int cols = -1);

/// x[i] = tanh(x[i]) for i < n, vectorised (absolute error within a few float32 ulps of 1).
void tanh_inplace(float* x, long n);

/// sums[c] += sum_r D[r, c] for c < cols_pad (a multiple of kColBlock; D of row stride ld), each
/// column summed over the rows in order: a bias's gradient.
void column_sums(const float* D, int rows, int cols_pad, int ld, float* sums);

/// dh[i] *= 1 - h[i]^2 for i < n: the gradient through tanh, from its output h.
void tanh_backward(const float* h, float* dh, long n);

/// One Adam step over n parameters: m = b1 m + (1 - b1) g, v = b2 v + (1 - b2) g^2,
/// p -= step_size m / (sqrt(v) / root_bc2 + eps), with step_size = lr / (1 - b1^t) and
/// root_bc2 = sqrt(1 - b2^t).
void adam_step(float* params, const float* grad, float* m, float* v, long n, float beta1, float beta2, float step_size,
               float root_bc2, float eps);

/// sum x[i]^2, accumulated in double (in a fixed order for each kernel).
double sum_squares(const float* x, long n);

/// The kernel in use: "avx512", "avx2" or "default".
std::string kernel_isa();

}  // namespace skyloop::nn::fast
