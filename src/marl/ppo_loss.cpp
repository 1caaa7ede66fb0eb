// The PPO core's arithmetic (ppo.hpp): the rollout's storage, the clipped surrogate and value
// losses with their gradients by hand (the discrete actor's softmax and the continuous actor's
// tanh-squashed Gaussian), shared by every backend of the networks.
#include "ppo_loss.hpp"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <numeric>

namespace skyloop {
namespace marl {

// ---- storage -------------------------------------------------------------------------------------

Rollout::Rollout(int steps, int envs, int agents, int obs, int critic, int action_count, int dims, int critic_obs)
    : T(steps), M(envs), N(agents), obs_width(obs), critic_width(critic), A(action_count), C(dims), critic_observation(critic_obs) {
  if (critic_obs != 0 && critic_obs != obs)
    throw std::logic_error("Rollout: the critic reads the whole observation or none of it");
  const std::size_t S = samples();
  raw_actions.resize(S * static_cast<std::size_t>(C));
  observations.resize(S * static_cast<std::size_t>(obs));
  critic_inputs.resize(S * static_cast<std::size_t>(critic_own()));
  actions.resize(S);
  logprobs.resize(S);
  values.resize(S);
  active.resize(S);
  allowed.resize(S * static_cast<std::size_t>(A));
  rewards.resize(static_cast<std::size_t>(T) * M);
  dones.resize(rewards.size());
  next_values.resize(static_cast<std::size_t>(M) * N);
  advantages.resize(S);
  returns.resize(S);
}

double Rollout::bytes(int steps, int envs, int agents, int obs, int critic, int action_count, int dims, int minibatches) {
  // Per sample: its floats above (observation, the critic's own columns, raw action, allowed moves, log-prob,
  // value, active, advantage, return) and the action; per environment step: reward and done.
  const double per_sample = 4.0 * (obs + critic + dims + action_count + 6) + 8.0;
  const double samples = static_cast<double>(steps) * envs * agents;
  const double gathered = samples / std::max(minibatches, 1) * (per_sample + 4.0 * 2);
  return samples * per_sample + 8.0 * steps * envs + gathered;
}

void UpdateStats::add(const UpdateStats& o, double w) {
  policy_loss += w * o.policy_loss;
  value_loss += w * o.value_loss;
  entropy += w * o.entropy;
  old_approx_kl += w * o.old_approx_kl;
  approx_kl += w * o.approx_kl;
  clipfrac += w * o.clipfrac;
  grad_norm += w * o.grad_norm;
}

double tanh_log_jacobian(double z) {
  // log(1 - tanh(z)^2) = 2 (log 2 - z - softplus(-2 z)); softplus(x) = max(x, 0) + log1p(exp(-|x|)).
  const double x = -2 * z;
  return 2 * (std::log(2.0) - z - (std::max(x, 0.0) + std::log1p(std::exp(-std::abs(x)))));
}

namespace {
double clamp_log_std(double ls) { return std::min(std::max(ls, kLogStdMin), kLogStdMax); }
}  // namespace

double squashed_gaussian_logprob(double z, double mu, double log_std) {
  const double ls = clamp_log_std(log_std), e = (z - mu) / std::exp(ls);
  return -0.5 * e * e - ls - kHalfLog2Pi - tanh_log_jacobian(z);
}

namespace {

/// The clipped surrogate's derivative with respect to the ratio, ties split as autograd splits
/// them, and the surrogate's statistics for one row of weight w.
double surrogate(double log_ratio, double adv, double clip, double w, UpdateStats& u, double& ratio) {
  ratio = std::exp(log_ratio);
  const double lo = 1 - clip, hi = 1 + clip;
  const double s1 = ratio * adv, s2 = std::min(std::max(ratio, lo), hi) * adv;
  const double in_range = ratio >= lo && ratio <= hi ? 1.0 : 0.0;
  const double dsurr = s1 < s2 ? adv : s1 > s2 ? adv * in_range : 0.5 * adv + 0.5 * adv * in_range;
  u.policy_loss -= w * std::min(s1, s2);
  u.old_approx_kl += w * -log_ratio;
  u.approx_kl += w * ((ratio - 1) - log_ratio);
  u.clipfrac += w * (std::abs(ratio - 1) > clip ? 1.0 : 0.0);
  return dsurr;
}

/// The actor's part of ppo_loss_rows under the squashed Gaussian policy (ppo.hpp).
void gaussian_actor_rows(const Minibatch& b, const PpoSettings& s, int first, int last, double per_active,
                         const float* out, int stride, float* dout, UpdateStats& u) {
  const int C = b.dims;
  for (int i = first; i < last; ++i) {
    const float* o = out + static_cast<std::size_t>(i - first) * stride;
    float* d = dout + static_cast<std::size_t>(i - first) * stride;
    const float* z = b.raw_actions.data() + static_cast<std::size_t>(i) * C;
    double logp = 0, entropy = 0;
    for (int k = 0; k < C; ++k) {
      logp += squashed_gaussian_logprob(z[k], o[k], o[C + k]);
      entropy += clamp_log_std(o[C + k]) + 0.5 + kHalfLog2Pi + tanh_log_jacobian(z[k]);
    }
    const double w = b.active[static_cast<std::size_t>(i)] * per_active;
    double ratio;
    const double dsurr = surrogate(logp - b.logprobs[static_cast<std::size_t>(i)], b.advantages[static_cast<std::size_t>(i)], s.clip, w, u, ratio);
    const double dlogp = -w * dsurr * ratio;
    u.entropy += w * entropy;
    // d log N / d mu = e / sigma, d log N / d log sigma = e^2 - 1 (zero where the clamp holds). The
    // entropy estimate at z = mu + sigma e, e held: d H / d mu = -2 tanh(z), d H / d log sigma =
    // 1 - 2 tanh(z) sigma e (ppo.hpp).
    const double c = s.entropy_coef * w;
    for (int k = 0; k < C; ++k) {
      const double ls = clamp_log_std(o[C + k]), sigma = std::exp(ls), e = (z[k] - o[k]) / sigma, th = std::tanh(static_cast<double>(z[k]));
      const bool free = o[C + k] >= kLogStdMin && o[C + k] <= kLogStdMax;
      d[k] = static_cast<float>(dlogp * e / sigma + 2 * c * th);
      d[C + k] = free ? static_cast<float>(dlogp * (e * e - 1) - c * (1 - 2 * th * sigma * e)) : 0.0f;
    }
  }
}

}  // namespace

UpdateStats ppo_loss_rows(const Minibatch& b, const PpoSettings& s, int first, int last, double per_active,
                          const float* logits, int logit_stride, const float* values, int value_stride, float* dlogits,
                          float* dvalues) {
  const int R = b.rows, A = b.action_count;
  UpdateStats u;
  std::vector<double> p(static_cast<std::size_t>(A)), logp(static_cast<std::size_t>(A));
  // Actor: the clipped surrogate and the entropy over the allowed moves (or the Gaussian's).
  if (b.dims > 0) gaussian_actor_rows(b, s, first, last, per_active, logits, logit_stride, dlogits, u);
  for (int i = first; i < last && b.dims == 0; ++i) {
    const float* z = logits + static_cast<std::size_t>(i - first) * logit_stride;
    const float* allowed = b.allowed.data() + static_cast<std::size_t>(i) * A;
    double mx = -1e300;
    for (int k = 0; k < A; ++k)
      if (allowed[k] > 0) mx = std::max(mx, static_cast<double>(z[k]));
    double sum = 0;
    for (int k = 0; k < A; ++k) {  // p holds exp(z_k - max) until divided by their sum
      p[k] = allowed[k] > 0 ? std::exp(z[k] - mx) : 0.0;
      sum += p[k];
    }
    const double log_sum = mx + std::log(sum);
    double entropy = 0;
    for (int k = 0; k < A; ++k) {
      logp[k] = allowed[k] > 0 ? z[k] - log_sum : 0.0;
      p[k] /= sum;
      entropy -= p[k] * logp[k];
    }
    const auto a = static_cast<std::size_t>(b.actions[static_cast<std::size_t>(i)]);
    const double w = b.active[static_cast<std::size_t>(i)] * per_active;
    double ratio;
    const double dsurr = surrogate(logp[a] - b.logprobs[static_cast<std::size_t>(i)], b.advantages[static_cast<std::size_t>(i)], s.clip, w, u, ratio);
    // d/dz_k: -w dsurr ratio (1[k = a] - p_k) from the surrogate, -c2 w (-p_k (log p_k + H)) from the entropy.
    const double dlogp = -w * dsurr * ratio;
    u.entropy += w * entropy;
    float* dz = dlogits + static_cast<std::size_t>(i - first) * logit_stride;
    for (std::size_t k = 0; k < static_cast<std::size_t>(A); ++k)
      dz[k] = static_cast<float>(dlogp * ((k == a ? 1.0 : 0.0) - p[k]) + s.entropy_coef * w * p[k] * (logp[k] + entropy));
  }
  // Critic: the clipped value loss, a plain mean over the rows.
  for (int i = first; i < last; ++i) {
    const double v = values[static_cast<std::size_t>(i - first) * value_stride], v_old = b.values[static_cast<std::size_t>(i)];
    const double ret = b.returns[static_cast<std::size_t>(i)];
    const double delta = v - v_old;
    const double vc = v_old + std::min(std::max(delta, -s.clip), s.clip);
    const double l1 = (v - ret) * (v - ret), l2 = (vc - ret) * (vc - ret);
    u.value_loss += std::max(l1, l2) / R;
    const double in_range = delta >= -s.clip && delta <= s.clip ? 1.0 : 0.0;
    const double d1 = 2 * (v - ret), d2 = 2 * (vc - ret) * in_range;
    const double dv = l1 > l2 ? d1 : l1 < l2 ? d2 : 0.5 * (d1 + d2);
    dvalues[static_cast<std::size_t>(i - first) * value_stride] = static_cast<float>(s.value_coef * dv / R);
  }
  return u;
}

double inverse_active(const Minibatch& b) {
  if (b.fill) return 1.0 / std::max(b.active_sum, 1.0);  // the rows may not be there yet
  double active = 0;
  for (int i = 0; i < b.rows; ++i) active += b.active[static_cast<std::size_t>(i)];
  return 1.0 / std::max(active, 1.0);
}

UpdateStats ppo_loss(const Minibatch& b, const PpoSettings& s, const float* logits, int logit_stride, const float* values,
                     int value_stride, float* dlogits, float* dvalues) {
  return ppo_loss_rows(b, s, 0, b.rows, inverse_active(b), logits, logit_stride, values, value_stride, dlogits, dvalues);
}

}  // namespace marl
}  // namespace skyloop
