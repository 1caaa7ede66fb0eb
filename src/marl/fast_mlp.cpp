#include "fast_mlp.hpp"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <stdexcept>

#include "../nn/fast_gemm.hpp"

namespace skyloop::marl::fast {

namespace gemm = skyloop::nn::fast;

namespace {

template <typename T>
void grow(std::vector<T>& v, std::size_t n) {
  if (v.size() < n) v.resize(n);
}

}  // namespace

Mlp::Mlp(int in, int hidden, int out)
    : in_(in), hidden_(hidden), out_(out), hidden_pad_(gemm::pad_cols(hidden)), out_pad_(gemm::pad_cols(out)) {
  if (in < 1 || hidden < 1 || out < 1) throw std::invalid_argument("fast::Mlp: sizes must be positive");
  std::size_t at = 0;
  auto take = [&](std::size_t n) {
    const std::size_t here = at;
    at += n;
    return here;
  };
  w1_ = take(static_cast<std::size_t>(in_) * hidden_pad_);
  b1_ = take(static_cast<std::size_t>(hidden_pad_));
  w2_ = take(static_cast<std::size_t>(hidden_) * hidden_pad_);
  b2_ = take(static_cast<std::size_t>(hidden_pad_));
  w3_ = take(static_cast<std::size_t>(hidden_) * out_pad_);
  b3_ = take(static_cast<std::size_t>(out_pad_));
  params_.assign(at, 0.0f);
  refresh();
}

void Mlp::refresh() {
  // W [out x in] from the packed W^T [in x out_pad], rows padded to hidden_pad_ (the padding
  // stays zero), each row of W written in order.
  w2_rows_.resize(static_cast<std::size_t>(hidden_) * hidden_pad_, 0.0f);
  w3_rows_.resize(static_cast<std::size_t>(out_) * hidden_pad_, 0.0f);
  const float* w2 = params_.data() + w2_;
  const float* w3 = params_.data() + w3_;
  for (int o = 0; o < hidden_; ++o) {
    float* row = w2_rows_.data() + static_cast<std::size_t>(o) * hidden_pad_;
    for (int i = 0; i < hidden_; ++i) row[i] = w2[static_cast<std::size_t>(i) * hidden_pad_ + o];
  }
  for (int o = 0; o < out_; ++o) {
    float* row = w3_rows_.data() + static_cast<std::size_t>(o) * hidden_pad_;
    for (int i = 0; i < hidden_; ++i) row[i] = w3[static_cast<std::size_t>(i) * out_pad_ + o];
  }
}

void Mlp::set_torch_layout(const std::array<const float*, 6>& p) {
  std::fill(params_.begin(), params_.end(), 0.0f);
  auto put = [&](std::size_t w, std::size_t b, const float* wsrc, const float* bsrc, int out, int in, int stride) {
    for (int o = 0; o < out; ++o) {
      for (int i = 0; i < in; ++i) params_[w + static_cast<std::size_t>(i) * stride + o] = wsrc[static_cast<std::size_t>(o) * in + i];
      params_[b + static_cast<std::size_t>(o)] = bsrc[o];
    }
  };
  put(w1_, b1_, p[0], p[1], hidden_, in_, hidden_pad_);
  put(w2_, b2_, p[2], p[3], hidden_, hidden_, hidden_pad_);
  put(w3_, b3_, p[4], p[5], out_, hidden_, out_pad_);
  refresh();
}

void Mlp::get_torch_layout(const std::array<float*, 6>& p) const {
  auto get = [&](std::size_t w, std::size_t b, float* wdst, float* bdst, int out, int in, int stride) {
    for (int o = 0; o < out; ++o) {
      for (int i = 0; i < in; ++i) wdst[static_cast<std::size_t>(o) * in + i] = params_[w + static_cast<std::size_t>(i) * stride + o];
      bdst[o] = params_[b + static_cast<std::size_t>(o)];
    }
  };
  get(w1_, b1_, p[0], p[1], hidden_, in_, hidden_pad_);
  get(w2_, b2_, p[2], p[3], hidden_, hidden_, hidden_pad_);
  get(w3_, b3_, p[4], p[5], out_, hidden_, out_pad_);
}

void Mlp::forward(const Rows& x, int rows, float* out, Cache* cache) const {
  if (rows <= 0) return;
  const int tail = in_ - x.head_width;
  if (x.head_width < 0 || tail < 0 || (x.head_width > 0 && !x.head) || (tail > 0 && !x.tail))
    throw std::logic_error("fast::Mlp: the input's parts do not make its width");
  const int share = x.tail_share;
  if (share < 1 || (share > 1 && (x.head_width <= 0 || tail <= 0 || rows % share != 0)))
    throw std::logic_error("fast::Mlp: a shared tail needs a head, a tail and whole runs of rows");
  Cache local;
  Cache& c = cache ? *cache : local;
  const std::size_t hn = static_cast<std::size_t>(rows) * hidden_pad_;
  grow(c.h1, hn);
  grow(c.h2, hn);
  c.rows = rows;
  c.x = x;
  const float* p = params_.data();
  // The first layer over the head's columns from the bias, then on over the tail's (the kernel
  // carries each sum through C in float: the same floats as one pass over the whole row).
  if (x.head_width > 0) gemm::matmul(x.head, x.head_stride, rows, p + w1_, x.head_width, hidden_pad_, p + b1_, c.h1.data(), hidden_pad_, false);
  const float* w_tail = p + w1_ + static_cast<std::size_t>(x.head_width) * hidden_pad_;
  if (tail > 0 && share == 1)
    gemm::matmul(x.tail, x.tail_stride, rows, w_tail, tail, hidden_pad_, x.head_width > 0 ? nullptr : p + b1_, c.h1.data(), hidden_pad_,
                 x.head_width > 0);
  if (share > 1) {  // the runs' tail product once each (from the runs' first rows), added to their rows
    const int runs = rows / share;
    grow(c.shared, static_cast<std::size_t>(runs) * hidden_pad_);
    gemm::matmul(x.tail, x.tail_stride * share, runs, w_tail, tail, hidden_pad_, nullptr, c.shared.data(), hidden_pad_, false);
    for (int r = 0; r < rows; ++r) {
      float* __restrict h = c.h1.data() + static_cast<std::size_t>(r) * hidden_pad_;
      const float* __restrict t = c.shared.data() + static_cast<std::size_t>(r / share) * hidden_pad_;
      for (int j = 0; j < hidden_pad_; ++j) h[j] += t[j];
    }
  }
  gemm::tanh_inplace(c.h1.data(), static_cast<long>(hn));
  gemm::matmul(c.h1.data(), hidden_pad_, rows, p + w2_, hidden_, hidden_pad_, p + b2_, c.h2.data(), hidden_pad_, false);
  gemm::tanh_inplace(c.h2.data(), static_cast<long>(hn));
  gemm::matmul(c.h2.data(), hidden_pad_, rows, p + w3_, hidden_, out_pad_, p + b3_, out, out_pad_, false, out_);
}

void Mlp::backward(Cache& c, const float* dout, float* grad) const {
  const int rows = c.rows;
  if (rows <= 0) return;
  const std::size_t hn = static_cast<std::size_t>(rows) * hidden_pad_;
  grow(c.dh, hn);
  // Layer 3: dW3^T += h2^T dout, db3 += sum dout, dz2 = (dout W3) * (1 - h2^2).
  if (out_ == 1)  // the critic's value: its one column, not the kernel's vector of columns
    gemm::matmul_at_column(c.h2.data(), hidden_pad_, hidden_, dout, out_pad_, rows, grad + w3_, out_pad_);
  else
    gemm::matmul_at(c.h2.data(), hidden_pad_, hidden_, dout, rows, out_pad_, grad + w3_, out_pad_, out_);
  gemm::column_sums(dout, rows, out_pad_, out_pad_, grad + b3_);
  gemm::matmul_tanh_backward(dout, out_pad_, rows, w3_rows_.data(), out_, hidden_pad_, c.h2.data(), c.dh.data(), hidden_pad_);
  // Layer 2 (dh holds dz2).
  gemm::matmul_at(c.h1.data(), hidden_pad_, hidden_, c.dh.data(), rows, hidden_pad_, grad + w2_, hidden_pad_);
  gemm::column_sums(c.dh.data(), rows, hidden_pad_, hidden_pad_, grad + b2_);
  // dz1 = (dz2 W2) * (1 - h1^2) goes into h2's buffer (h2 is no longer needed).
  gemm::matmul_tanh_backward(c.dh.data(), hidden_pad_, rows, w2_rows_.data(), hidden_, hidden_pad_, c.h1.data(), c.h2.data(), hidden_pad_);
  // Layer 1.
  if (c.x.head_width > 0) gemm::matmul_at(c.x.head, c.x.head_stride, c.x.head_width, c.h2.data(), rows, hidden_pad_, grad + w1_, hidden_pad_);
  float* g_tail = grad + w1_ + static_cast<std::size_t>(c.x.head_width) * hidden_pad_;
  const int share = c.x.tail_share;
  if (in_ > c.x.head_width && share == 1)
    gemm::matmul_at(c.x.tail, c.x.tail_stride, in_ - c.x.head_width, c.h2.data(), rows, hidden_pad_, g_tail, hidden_pad_);
  if (share > 1) {  // each run's output gradients summed (in row order), then X_tail^T over the runs
    const int runs = rows / share;
    for (int g = 0; g < runs; ++g) {
      float* __restrict s = c.shared.data() + static_cast<std::size_t>(g) * hidden_pad_;
      const float* __restrict d = c.h2.data() + static_cast<std::size_t>(g) * share * hidden_pad_;
      std::copy(d, d + hidden_pad_, s);
      for (int n = 1; n < share; ++n)
        for (int j = 0; j < hidden_pad_; ++j) s[j] += d[static_cast<std::size_t>(n) * hidden_pad_ + j];
    }
    gemm::matmul_at(c.x.tail, c.x.tail_stride * share, in_ - c.x.head_width, c.shared.data(), runs, hidden_pad_, g_tail, hidden_pad_);
  }
  gemm::column_sums(c.h2.data(), rows, hidden_pad_, hidden_pad_, grad + b1_);
}

void Adam::step(float* params, const float* grad, std::size_t n) {
  if (m.size() != n) m.assign(n, 0.0f), v.assign(n, 0.0f);
  ++steps;
  const double bc1 = 1.0 - std::pow(beta1, static_cast<double>(steps));
  const double bc2 = 1.0 - std::pow(beta2, static_cast<double>(steps));
  const float step_size = static_cast<float>(learning_rate / bc1);
  const float root_bc2 = static_cast<float>(std::sqrt(bc2));
  gemm::adam_step(params, grad, m.data(), v.data(), static_cast<long>(n), static_cast<float>(beta1), static_cast<float>(beta2),
                  step_size, root_bc2, static_cast<float>(eps));
}

double norm(const std::vector<float>& g) { return std::sqrt(gemm::sum_squares(g.data(), static_cast<long>(g.size()))); }

void polyak(float* average, const float* w, std::size_t n, float decay) {
  const float keep = decay, take = 1.0f - decay;
  for (std::size_t i = 0; i < n; ++i) average[i] = keep * average[i] + take * w[i];
}

}  // namespace skyloop::marl::fast
