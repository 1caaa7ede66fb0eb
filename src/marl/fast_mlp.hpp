#pragma once
// The learners' small networks (in -> hidden -> hidden -> out, tanh; MlpNet in nets.hpp) trained
// outside autograd: float32 forward and backward passes written out by hand over the GEMM kernels
// of the beamformers' fast path (src/nn/fast_gemm.hpp), with no allocation once the buffers have
// grown to the batch. LibTorch's MlpNet stays the reference: marl_test holds this path's outputs,
// losses and gradients to autograd's within float32 rounding on every kernel variant. Torch-free.
//
// Parameters live in one flat float vector, each weight packed as W^T [in x out_pad] (columns
// padded to the kernel's block, kept zero), so the optimiser, the gradient norm and the clipping
// are loops over one array.
#include <array>
#include <cstdint>
#include <cstddef>
#include <vector>

namespace skyloop::marl::fast {

class Mlp {
 public:
  Mlp(int in, int hidden, int out);

  int in() const { return in_; }
  int hidden() const { return hidden_; }
  int out() const { return out_; }
  /// Row stride of forward's output and backward's output gradient (out padded to the block).
  int out_stride() const { return out_pad_; }
  std::size_t size() const { return params_.size(); }

  /// The flat parameter vector. After writing it, call refresh().
  std::vector<float>& params() { return params_; }
  const std::vector<float>& params() const { return params_; }
  void refresh();

  /// Torch's layout, in MlpNet's parameter order: l1.weight [hidden x in], l1.bias, l2.weight
  /// [hidden x hidden], l2.bias, l3.weight [out x hidden], l3.bias.
  void set_torch_layout(const std::array<const float*, 6>& p);
  void get_torch_layout(const std::array<float*, 6>& p) const;

  /// A batch's input rows, in up to two parts side by side: columns [0, head_width) of row r at
  /// head + r head_stride, columns [head_width, in) at tail + r tail_stride (the critic's own
  /// columns beside the actor's observation, which it reads where the actor's pass reads it). The
  /// first layer sums the head's columns, then the tail's, in column order: the same floats as
  /// one input row.
  /// tail_share = s > 1 (with a head; rows a multiple of s): the tail comes in runs of s equal
  /// rows (the state the agents of a step share), read from each run's first row. The first layer
  /// then multiplies it once per run and adds it to the run's rows after the bias and the head
  /// (other floats than one pass over the whole row, within float32 rounding of them), and the
  /// weight gradient sums the run's output gradients first: s times fewer multiply-adds for the
  /// tail's columns, forward and backward.
  struct Rows {
    const float* head = nullptr;
    int head_width = 0, head_stride = 0;
    const float* tail = nullptr;
    int tail_stride = 0;
    int tail_share = 1;
  };
  /// One part: x [rows x in], row-major of stride in.
  Rows rows_of(const float* x) const { return Rows{x, in_, in_, nullptr, 0}; }

  /// The activations a backward pass needs; grows to the largest batch and is then reused.
  /// Holds pointers to forward's input, which must outlive the backward pass.
  struct Cache {
    int rows = 0;
    Rows x;
    std::vector<float> h1, h2, dh, shared;  // shared: the tail's product per run (tail_share)
  };

  /// out [rows x out_stride()] = the network on x [rows x in] (row-major, stride in); only the
  /// first out() columns are defined (the narrow output layer computes one kernel vector, the
  /// rest of the padding is left as it was). With a cache, keeps what backward needs.
  void forward(const float* x, int rows, float* out, Cache* cache) const { forward(rows_of(x), rows, out, cache); }
  void forward(const Rows& x, int rows, float* out, Cache* cache) const;
  /// grad (size() floats) += d loss / d params for the batch of the last forward into `cache`,
  /// given dout = d loss / d out [rows x out_stride()] (padding columns zero).
  void backward(Cache& cache, const float* dout, float* grad) const;

 private:
  int in_, hidden_, out_, hidden_pad_, out_pad_;
  std::size_t w1_, b1_, w2_, b2_, w3_, b3_;  // offsets into params_
  std::vector<float> params_;
  std::vector<float> w2_rows_, w3_rows_;     // W2 [hidden x hidden_pad], W3 [out x hidden_pad] for dX
};

/// Adam (Kingma & Ba; LibTorch's defaults: betas 0.9, 0.999, eps 1e-8, no weight decay) over a
/// flat parameter vector.
struct Adam {
  double learning_rate = 3e-4, beta1 = 0.9, beta2 = 0.999, eps = 1e-8;
  std::int64_t steps = 0;
  std::vector<float> m, v;
  void step(float* params, const float* grad, std::size_t n);
};

/// sqrt(sum g^2) over the vector (accumulated in double).
double norm(const std::vector<float>& g);

/// The Polyak average's step (marl.average_decay): average[i] = decay average[i] + (1 - decay) w[i].
void polyak(float* average, const float* w, std::size_t n, float decay);

}  // namespace skyloop::marl::fast
