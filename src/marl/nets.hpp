#pragma once
// Networks and losses shared by the learners (torch).
#include <torch/torch.h>

namespace skyloop::marl {

/// in -> hidden -> hidden -> out, tanh activations.
struct MlpNetImpl : torch::nn::Module {
  MlpNetImpl(int64_t in, int64_t hidden, int64_t out);
  torch::Tensor forward(const torch::Tensor& x);
  torch::nn::Linear l1{nullptr}, l2{nullptr}, l3{nullptr};
};
TORCH_MODULE(MlpNet);

/// Masked mean: sum(x * m) / max(sum(m), 1).
torch::Tensor masked_mean(const torch::Tensor& x, const torch::Tensor& mask);

/// Logits with the actions outside `allowed` (0/1 per action, same shape) pushed to -1e9.
torch::Tensor masked_logits(const torch::Tensor& logits, const torch::Tensor& allowed);

/// PPO clipped surrogate (per sample): min(rho A, clip(rho, 1 - eps, 1 + eps) A).
torch::Tensor clipped_surrogate(const torch::Tensor& logp_new, const torch::Tensor& logp_old,
                                const torch::Tensor& advantages, double eps);

/// Clipped value loss (eq:critic_loss), mean over samples:
/// max[(V - R)^2, (V_old + clip(V - V_old, -eps, eps) - R)^2].
torch::Tensor clipped_value_loss(const torch::Tensor& v, const torch::Tensor& v_old, const torch::Tensor& returns, double eps);

/// QMIX's monotonic mixer (Rashid et al. 2018): Q_tot = w2^T elu(W1^T q + b1) + b2 with
/// W1 = |hyper_w1(s)|, w2 = |hyper_w2(s)|, b1 = hyper_b1(s), b2 = V(s) (two layers).
struct QMixerImpl : torch::nn::Module {
  QMixerImpl(int64_t agents, int64_t state_dim, int64_t embed);
  /// q [B, N], state [B, S] -> [B]
  torch::Tensor forward(const torch::Tensor& q, const torch::Tensor& state);
  int64_t agents, embed;
  torch::nn::Linear hyper_w1{nullptr}, hyper_b1{nullptr}, hyper_w2{nullptr}, v1{nullptr}, v2{nullptr};
};
TORCH_MODULE(QMixer);

}  // namespace skyloop::marl
