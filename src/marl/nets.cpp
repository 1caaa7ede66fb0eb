#include "nets.hpp"

namespace skyloop::marl {

MlpNetImpl::MlpNetImpl(int64_t in, int64_t hidden, int64_t out) {
  l1 = register_module("l1", torch::nn::Linear(in, hidden));
  l2 = register_module("l2", torch::nn::Linear(hidden, hidden));
  l3 = register_module("l3", torch::nn::Linear(hidden, out));
}

torch::Tensor MlpNetImpl::forward(const torch::Tensor& x) { return l3(torch::tanh(l2(torch::tanh(l1(x))))); }

torch::Tensor masked_logits(const torch::Tensor& logits, const torch::Tensor& allowed) {
  return logits + (allowed - 1.0) * 1e9;
}

torch::Tensor masked_mean(const torch::Tensor& x, const torch::Tensor& mask) {
  return (x * mask).sum() / torch::clamp_min(mask.sum(), 1.0);
}

torch::Tensor clipped_surrogate(const torch::Tensor& logp_new, const torch::Tensor& logp_old,
                                const torch::Tensor& advantages, double eps) {
  const auto ratio = torch::exp(logp_new - logp_old);
  return torch::min(ratio * advantages, torch::clamp(ratio, 1 - eps, 1 + eps) * advantages);
}

torch::Tensor clipped_value_loss(const torch::Tensor& v, const torch::Tensor& v_old, const torch::Tensor& returns, double eps) {
  const auto clipped = v_old + torch::clamp(v - v_old, -eps, eps);
  return torch::max((v - returns).pow(2), (clipped - returns).pow(2)).mean();
}

QMixerImpl::QMixerImpl(int64_t n, int64_t state_dim, int64_t e) : agents(n), embed(e) {
  hyper_w1 = register_module("hyper_w1", torch::nn::Linear(state_dim, n * e));
  hyper_b1 = register_module("hyper_b1", torch::nn::Linear(state_dim, e));
  hyper_w2 = register_module("hyper_w2", torch::nn::Linear(state_dim, e));
  v1 = register_module("v1", torch::nn::Linear(state_dim, e));
  v2 = register_module("v2", torch::nn::Linear(e, 1));
}

torch::Tensor QMixerImpl::forward(const torch::Tensor& q, const torch::Tensor& state) {
  const auto B = q.size(0);
  const auto w1 = torch::abs(hyper_w1(state)).view({B, agents, embed});
  const auto b1 = hyper_b1(state).view({B, 1, embed});
  const auto hidden = torch::elu(torch::bmm(q.view({B, 1, agents}), w1) + b1);  // [B, 1, e]
  const auto w2 = torch::abs(hyper_w2(state)).view({B, embed, 1});
  const auto b2 = v2(torch::relu(v1(state))).view({B, 1, 1});
  return (torch::bmm(hidden, w2) + b2).view({B});
}

}  // namespace skyloop::marl
