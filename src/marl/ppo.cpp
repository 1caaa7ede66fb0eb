// MAPPO and IPPO (Section V, Algorithm alg:mappo_training) on one PPO core (ppo.hpp). They
// differ only in the critic's input: MAPPO's centralised critic sees the global state (or the
// agent-specific global state), IPPO's sees the agent's local observation.
#include "ppo.hpp"

#include <cmath>
#include <cstdint>
#include <fmt/format.h>
#include <numeric>
#include <ostream>

#include "fast_mlp.hpp"
#include "skyloop/core/config_io.hpp"
#include "skyloop/core/error.hpp"
#include "skyloop/core/parallel.hpp"
#include "skyloop/core/io.hpp"
#include "skyloop/core/memory.hpp"
#include "skyloop/core/progress.hpp"
#include "skyloop/marl/learners.hpp"
#include "skyloop/nn/learned.hpp"

namespace skyloop {

std::vector<double> gae(const std::vector<double>& rewards, const std::vector<double>& values, const std::vector<int>& dones,
                        double gamma, double lambda) {
  const std::size_t T = rewards.size();
  if (values.size() != T + 1 || dones.size() != T) throw std::invalid_argument("gae: need T rewards, T dones and T + 1 values");
  std::vector<double> adv(T);
  double next = 0.0;
  for (std::size_t i = T; i-- > 0;) {
    const double keep = dones[i] ? 0.0 : 1.0;
    const double delta = rewards[i] + gamma * keep * values[i + 1] - values[i];
    next = delta + gamma * lambda * keep * next;
    adv[i] = next;
  }
  return adv;
}

namespace marl {

// ---- the critic's input --------------------------------------------------------------------------

CriticReader CriticReader::of(const Config& cfg, const Encoder& encoder) {
  CriticReader r;
  r.encoder = encoder;
  if (find_learner(cfg.marl.algo).local_critic) r.input = Input::LocalObservation;
  else r.input = cfg.marl.critic_state == "global" ? Input::GlobalState : Input::AgentState;
  return r;
}

const char* CriticReader::name() const {
  switch (input) {
    case Input::GlobalState: return "global";
    case Input::AgentState: return "agent";
    case Input::LocalObservation: break;
  }
  return "local";
}

int CriticReader::width(const UavEnv& e) const {
  if (encoder.set) return encoder.width(e) + (input != Input::LocalObservation ? UavEnv::compact_state_size() : 0);
  switch (input) {
    case Input::GlobalState: return e.state_size();
    case Input::AgentState: return e.agent_state_size();
    case Input::LocalObservation: break;
  }
  return e.observation_size();
}

int CriticReader::observation_width(const UavEnv& e) const { return encoder.set ? encoder.width(e) : 0; }

bool CriticReader::shared_by_step() const { return encoder.set && input != Input::LocalObservation; }

void CriticReader::write_own(const UavEnv& e, int n, float* out) const {
  if (encoder.set) {
    if (input != Input::LocalObservation) e.write_compact_state(out);
    return;
  }
  switch (input) {
    case Input::GlobalState: return e.write_state(out);
    case Input::AgentState: return e.write_agent_state(n, out);
    case Input::LocalObservation: break;
  }
  e.write_observation(n, out);
}

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
constexpr double kHalfLog2Pi = 0.91893853320467274178;  // log(2 pi) / 2
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

/// ppo_loss over the rows [first, last) of the minibatch, with the whole minibatch's normalisers
/// (its active agents and its rows): the rows' share of the loss and of its gradient. The
/// pointers address row `first`.
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

}  // namespace

UpdateStats ppo_loss(const Minibatch& b, const PpoSettings& s, const float* logits, int logit_stride, const float* values,
                     int value_stride, float* dlogits, float* dvalues) {
  return ppo_loss_rows(b, s, 0, b.rows, inverse_active(b), logits, logit_stride, values, value_stride, dlogits, dvalues);
}

// ---- backends ------------------------------------------------------------------------------------

namespace {

/// The actor and critic as LibTorch modules, in MlpNet's default initialisation under `seed`.
Nets initial_nets(int obs_width, int critic_width, int hidden, int actions, std::uint64_t seed) {
  torch::manual_seed(seed);
  Nets nets;
  nets.actor = MlpNet(obs_width, hidden, actions);
  nets.critic = MlpNet(critic_width, hidden, 1);
  return nets;
}

/// The archive entry of the actor's Polyak average in last.pt (PpoNetworks::set_average_decay).
constexpr const char* kActorAverage = "actor_average";

bool read_module(torch::serialize::InputArchive& archive, const char* key, torch::nn::Module& module) {
  torch::serialize::InputArchive sub;
  if (!archive.try_read(key, sub)) return false;
  module.load(sub);
  return true;
}

/// An actor of `like`'s shape (on its device), for the average's archive form.
MlpNet actor_like(MlpNet& like) {
  MlpNet net(like->l1->options.in_features(), like->l1->options.out_features(), like->l3->options.out_features());
  net->to(like->l1->weight.device());
  return net;
}

/// The reference: LibTorch's autograd and Adam.
class TorchPpo final : public PpoNetworks {
 public:
  TorchPpo(Nets nets, double learning_rate, const torch::Device& device, int critic_observation)
      : critic_observation_(critic_observation), nets_(std::move(nets)), device_(device) {
    nets_.actor->to(device);
    nets_.critic->to(device);
    params_ = nets_.actor->parameters();
    for (auto& p : nets_.critic->parameters()) params_.push_back(p);
    adam_ = std::make_unique<torch::optim::Adam>(params_, torch::optim::AdamOptions(learning_rate));
  }

  void set_learning_rate(double learning_rate) override {
    for (auto& group : adam_->param_groups()) static_cast<torch::optim::AdamOptions&>(group.options()).lr(learning_rate);
  }
  void set_average_decay(double decay) override { average_decay_ = decay; }

  void logits(const float* obs, int rows, float* out, int) override { forward(nets_.actor, obs, rows, actions(), out); }
  void values(const float* observations, const float* in, int rows, float* out, int) override {
    torch::NoGradGuard ng;
    copy_rows(nets_.critic(critic_input(observations, in, rows)), rows, 1, out);
  }

  UpdateStats step(Minibatch& b, const PpoSettings& s) override {
    b.ready(0, b.rows);
    if (b.critic_observation != critic_observation_) throw std::logic_error("TorchPpo: the batch's critic input is not the network's");
    const int64_t R = b.rows;
    auto blob = [&](const std::vector<float>& v, std::vector<int64_t> shape) {
      return torch::from_blob(const_cast<float*>(v.data()), shape).to(device_);
    };
    const auto active = blob(b.active, {R});
    const auto logp_old = blob(b.logprobs, {R});
    const auto out = nets_.actor(blob(b.observations, {R, b.obs_width}));
    torch::Tensor logp, entropy;
    if (b.dims > 0) {  // the squashed Gaussian (ppo.hpp)
      const int64_t C = b.dims;
      const auto mu = out.narrow(1, 0, C), log_std = out.narrow(1, C, C).clamp(kLogStdMin, kLogStdMax);
      const auto z = blob(b.raw_actions, {R, C});
      const auto jacobian = 2 * (std::log(2.0) - z - torch::nn::functional::softplus(-2 * z));
      const auto sigma = log_std.exp();
      logp = (-0.5 * ((z - mu) / sigma).pow(2) - log_std - kHalfLog2Pi - jacobian).sum(1);
      // The squashed distribution's entropy at the sample, reparameterised (ppo.hpp).
      const auto zr = mu + sigma * ((z - mu) / sigma).detach();
      const auto at = 2 * (std::log(2.0) - zr - torch::nn::functional::softplus(-2 * zr));
      entropy = masked_mean((log_std + 0.5 + kHalfLog2Pi + at).sum(1), active);
    } else {
      const auto logp_all = torch::log_softmax(masked_logits(out, blob(b.allowed, {R, b.action_count})), 1);
      const auto actions = torch::from_blob(const_cast<std::int64_t*>(b.actions.data()), {R}, torch::kInt64).to(device_);
      logp = logp_all.gather(1, actions.unsqueeze(1)).squeeze(1);
      entropy = masked_mean(-(logp_all.exp() * logp_all).sum(1), active);
    }
    const auto policy_loss = -masked_mean(clipped_surrogate(logp, logp_old, blob(b.advantages, {R}), s.clip), active);
    const auto v = nets_.critic(critic_input(b.observations.data(), b.critic_inputs.data(), static_cast<int>(R))).view({R});
    const auto value_loss = clipped_value_loss(v, blob(b.values, {R}), blob(b.returns, {R}), s.clip);
    const auto loss = policy_loss + s.value_coef * value_loss - s.entropy_coef * entropy;  // eq:total_loss
    adam_->zero_grad();
    loss.backward();
    UpdateStats u;
    {
      torch::NoGradGuard ng;
      double sq = 0;
      for (const auto& p : params_)
        if (p.grad().defined()) sq += p.grad().pow(2).sum().item<double>();
      u.grad_norm = std::sqrt(sq);
    }
    if (s.grad_clip > 0) torch::nn::utils::clip_grad_norm_(params_, s.grad_clip);
    adam_->step();
    torch::NoGradGuard ng;
    if (average_decay_ > 0) {
      const bool first = !average_;
      if (first) average_ = actor_like(nets_.actor);
      const auto w = nets_.actor->parameters(), a = average_->parameters();
      const float d = static_cast<float>(average_decay_);
      for (std::size_t i = 0; i < w.size(); ++i)
        if (first) a[i].copy_(w[i]);
        else a[i].mul_(d).add_(w[i], 1.0f - d);
    }
    const auto log_ratio = logp - logp_old;
    const auto ratio = log_ratio.exp();
    u.policy_loss = policy_loss.item<double>();
    u.value_loss = value_loss.item<double>();
    u.entropy = entropy.item<double>();
    u.old_approx_kl = masked_mean(-log_ratio, active).item<double>();
    u.approx_kl = masked_mean((ratio - 1) - log_ratio, active).item<double>();
    u.clipfrac = masked_mean(((ratio - 1).abs() > s.clip).to(torch::kFloat), active).item<double>();
    return u;
  }

  void save(const std::string& path, const nlohmann::json& meta, bool optimiser) override {
    if (optimiser) {
      std::function<void(torch::serialize::OutputArchive&)> extra;
      if (average_) extra = [this](torch::serialize::OutputArchive& a) { write_module(a, kActorAverage, *average_); };
      marl::save(path, meta, nets_, adam_.get(), extra);
      return;
    }
    Nets published = nets_;  // the same modules; the average as the actor
    if (average_) published.actor = average_;
    marl::save(path, meta, published, nullptr);
  }
  void load(const std::string& path, bool optimiser) override {
    if (!optimiser) {  // a published policy: its actor is the weights, no average
      marl::load(path, nets_, nullptr);
      average_ = MlpNet{nullptr};
      return;
    }
    MlpNet average = actor_like(nets_.actor);
    bool found = false;
    marl::load(path, nets_, adam_.get(), [&](torch::serialize::InputArchive& a) { found = read_module(a, kActorAverage, *average); });
    average_ = found ? average : MlpNet{nullptr};
  }

 private:
  int actions() const { return static_cast<int>(nets_.actor->l3->options.out_features()); }
  void forward(MlpNet& net, const float* in, int rows, int width, float* out) {
    torch::NoGradGuard ng;
    copy_rows(net(torch::from_blob(const_cast<float*>(in), {rows, net->l1->options.in_features()}).to(device_)), rows, width, out);
  }
  static void copy_rows(const torch::Tensor& y, int rows, int width, float* out) {
    const auto cpu = y.to(torch::kCPU).contiguous();
    std::copy(cpu.data_ptr<float>(), cpu.data_ptr<float>() + static_cast<std::size_t>(rows) * width, out);
  }
  /// The critic's whole input rows: the observation's columns (when it reads them), then its own.
  torch::Tensor critic_input(const float* observations, const float* own, int rows) const {
    const int64_t width = nets_.critic->l1->options.in_features(), own_width = width - critic_observation_;
    auto rest = torch::from_blob(const_cast<float*>(own), {rows, own_width}).to(device_);
    if (critic_observation_ == 0) return rest;
    const int64_t obs_width = nets_.actor->l1->options.in_features();
    auto head = torch::from_blob(const_cast<float*>(observations), {rows, obs_width}).to(device_);
    return torch::cat({head, rest}, 1);
  }

  int critic_observation_;  // the critic's leading input columns that are the observation (0 or its width)
  Nets nets_;
  torch::Device device_;
  std::vector<torch::Tensor> params_;
  std::unique_ptr<torch::optim::Adam> adam_;
  double average_decay_ = 0;
  MlpNet average_{nullptr};  // the actor's Polyak average, after the first step with average_decay_ > 0
};

/// The default: fused float32 passes (fast_mlp.hpp), the loss's gradient written out.
class FastPpo final : public PpoNetworks {
 public:
  FastPpo(Nets nets, double learning_rate, int threads, int critic_observation)
      : critic_observation_(critic_observation),
        torch_(std::move(nets)),
        actor_(static_cast<int>(torch_.actor->l1->options.in_features()), static_cast<int>(torch_.actor->l1->options.out_features()),
               static_cast<int>(torch_.actor->l3->options.out_features())),
        critic_(static_cast<int>(torch_.critic->l1->options.in_features()), static_cast<int>(torch_.critic->l1->options.out_features()), 1) {
    from_torch();
    actor_adam_.learning_rate = critic_adam_.learning_rate = learning_rate;
    threads_ = std::max(1, std::min<int>(static_cast<int>(kChunks), resolve_threads(threads)));
  }

  void set_learning_rate(double learning_rate) override { actor_adam_.learning_rate = critic_adam_.learning_rate = learning_rate; }
  void set_average_decay(double decay) override { average_decay_ = decay; }

  void logits(const float* obs, int rows, float* out, int lane) override {
    forward(actor_, obs, rows, static_cast<int>(torch_.actor->l3->options.out_features()), out, lane);
  }
  void values(const float* observations, const float* in, int rows, float* out, int lane) override {
    forward(critic_, critic_rows(observations, in), rows, 1, out, lane);
  }
  int lanes() const override { return kLanes; }

  UpdateStats step(Minibatch& b, const PpoSettings& s) override {
    if (b.critic_observation != critic_observation_) throw std::logic_error("FastPpo: the batch's critic input is not the network's");
    const int R = b.rows, as = actor_.out_stride(), vs = critic_.out_stride();
    const std::size_t na = actor_.size(), np = na + critic_.size();
    logits_.resize(static_cast<std::size_t>(R) * as);
    values_.resize(static_cast<std::size_t>(R) * vs);
    dlogits_.assign(logits_.size(), 0.0f);
    dvalues_.assign(values_.size(), 0.0f);
    const double per_active = inverse_active(b);
    // Runs of rows sharing their critic columns (Minibatch::share): the critic's first layer takes
    // them once per run (fast::Mlp::Rows::tail_share), so chunks and pieces hold whole runs.
    const int share = b.share > 1 && critic_observation_ > 0 ? b.share : 1;
    if (R % share != 0) throw std::logic_error("FastPpo: a minibatch of shared rows holds a part of a run");
    const int piece_rows = std::max(share, kPieceRows / share * share);
    // The minibatch in kChunks fixed halves, each forward, loss and backward into its own gradient
    // (on its own thread when run.threads allows), summed in chunk order: the same numbers for
    // any thread count.
    UpdateStats parts[kChunks];
    parallel_for(kChunks, threads_, [&](std::size_t c) {
      const long runs = R / share;
      const int first = static_cast<int>(runs * static_cast<long>(c) / kChunks) * share;
      const int last = static_cast<int>(runs * static_cast<long>(c + 1) / kChunks) * share;
      auto& g = chunk_grad_[c];
      g.assign(np, 0.0f);
      // In pieces of kPieceRows rows, whose activations stay in the core's L2 cache from the
      // forward pass to the backward; each weight's gradient still sums its rows in order, so the
      // pieces change no bit of it.
      for (int lo = first; lo < last; lo += piece_rows) {
        const int hi = std::min(last, lo + piece_rows);
        float* lg = logits_.data() + static_cast<std::size_t>(lo) * as;
        float* vl = values_.data() + static_cast<std::size_t>(lo) * vs;
        float* dl = dlogits_.data() + static_cast<std::size_t>(lo) * as;
        float* dv = dvalues_.data() + static_cast<std::size_t>(lo) * vs;
        b.ready(lo, hi);
        actor_.forward(b.observations.data() + static_cast<std::size_t>(lo) * b.obs_width, hi - lo, lg, &actor_cache_[c]);
        fast::Mlp::Rows critic_in = critic_rows(b.observations.data() + static_cast<std::size_t>(lo) * b.obs_width,
                                                b.critic_inputs.data() + static_cast<std::size_t>(lo) * b.critic_own());
        critic_in.tail_share = share;
        critic_.forward(critic_in, hi - lo, vl, &critic_cache_[c]);
        parts[c].add(ppo_loss_rows(b, s, lo, hi, per_active, lg, as, vl, vs, dl, dv), 1.0);
        actor_.backward(actor_cache_[c], dl, g.data());
        critic_.backward(critic_cache_[c], dv, g.data() + na);
      }
    });
    UpdateStats u;
    for (std::size_t c = 0; c < kChunks; ++c) u.add(parts[c], 1.0);
    // The chunks' gradients summed, each parameter's in chunk order (the parameters in halves, on
    // the threads); then the global norm, clipping (LibTorch's clip_grad_norm_ rule), and Adam
    // and the packed copies for each network on a thread of its own.
    grad_.resize(np);
    parallel_for(2, threads_, [&](std::size_t half) {
      for (std::size_t i = np * half / 2, end = np * (half + 1) / 2; i < end; ++i) {
        float g = 0.0f;
        for (std::size_t c = 0; c < kChunks; ++c) g += chunk_grad_[c][i];
        grad_[i] = g;
      }
    });
    u.grad_norm = fast::norm(grad_);
    const double coef = s.grad_clip > 0 ? s.grad_clip / (u.grad_norm + 1e-6) : 1.0;
    parallel_for(2, threads_, [&](std::size_t net) {
      fast::Mlp& mlp = net == 0 ? actor_ : critic_;
      float* g = grad_.data() + (net == 0 ? 0 : na);
      if (coef < 1)
        for (std::size_t i = 0; i < mlp.size(); ++i) g[i] = static_cast<float>(g[i] * coef);
      (net == 0 ? actor_adam_ : critic_adam_).step(mlp.params().data(), g, mlp.size());
      mlp.refresh();
    });
    if (average_decay_ > 0) {
      const auto& w = actor_.params();
      if (average_.empty()) average_ = w;
      else fast::polyak(average_.data(), w.data(), w.size(), static_cast<float>(average_decay_));
    }
    return u;
  }

  void save(const std::string& path, const nlohmann::json& meta, bool optimiser) override {
    to_torch();
    if (!optimiser && !average_.empty()) write_average(torch_.actor);  // the published actor: the average
    std::function<void(torch::serialize::OutputArchive&)> extra;
    if (optimiser)
      extra = [this](torch::serialize::OutputArchive& a) {
        if (!average_.empty()) {
          MlpNet average = actor_like(torch_.actor);
          write_average(average);
          write_module(a, kActorAverage, *average);
        }
        torch::serialize::OutputArchive sub;
        auto put = [&](const char* key, const std::vector<float>& v) {
          sub.write(key, torch::from_blob(const_cast<float*>(v.data()), {static_cast<int64_t>(v.size())}).clone());
        };
        put("actor_m", actor_adam_.m);
        put("actor_v", actor_adam_.v);
        put("critic_m", critic_adam_.m);
        put("critic_v", critic_adam_.v);
        sub.write("steps", torch::tensor(actor_adam_.steps, torch::kInt64));
        a.write("fast_adam", sub);
      };
    marl::save(path, meta, torch_, nullptr, extra);
  }

  void load(const std::string& path, bool optimiser) override {
    if (!optimiser) average_.clear();  // a published policy: its actor is the weights, no average
    std::function<void(torch::serialize::InputArchive&)> extra;
    if (optimiser)
      extra = [&](torch::serialize::InputArchive& a) {
        torch::serialize::InputArchive sub;
        if (!a.try_read("fast_adam", sub)) throw InputError("policy '" + path + "' holds no optimiser state: cannot resume from it");
        auto get = [&](const char* key, std::vector<float>& v) {
          torch::Tensor t;
          sub.read(key, t);
          t = t.to(torch::kFloat).contiguous();
          v.assign(t.data_ptr<float>(), t.data_ptr<float>() + t.numel());
        };
        get("actor_m", actor_adam_.m);
        get("actor_v", actor_adam_.v);
        get("critic_m", critic_adam_.m);
        get("critic_v", critic_adam_.v);
        average_.clear();
        MlpNet average = actor_like(torch_.actor);
        if (read_module(a, kActorAverage, *average)) {
          fast::Mlp packed(actor_.in(), actor_.hidden(), actor_.out());
          packed.set_torch_layout(layout(average));
          average_ = packed.params();
        }
        torch::Tensor steps;
        sub.read("steps", steps);
        actor_adam_.steps = critic_adam_.steps = steps.item<std::int64_t>();
        if (actor_adam_.m.size() != actor_.size() || critic_adam_.m.size() != critic_.size())
          throw InputError("policy '" + path + "': its optimiser state does not match its networks");
      };
    marl::load(path, torch_, nullptr, extra);
    from_torch();
  }

 private:
  static std::array<torch::Tensor, 6> tensors(MlpNet& net) {
    return {net->l1->weight, net->l1->bias, net->l2->weight, net->l2->bias, net->l3->weight, net->l3->bias};
  }
  /// A CPU network's weights in Mlp::set_torch_layout's order (pointers into the tensors).
  static std::array<const float*, 6> layout(MlpNet& net) {
    const auto t = tensors(net);
    std::array<const float*, 6> p{};
    for (std::size_t i = 0; i < 6; ++i) p[i] = t[i].data_ptr<float>();
    return p;
  }
  void from_torch() {
    for (auto [net, fast] : {std::pair<MlpNet*, fast::Mlp*>{&torch_.actor, &actor_}, {&torch_.critic, &critic_}}) fast->set_torch_layout(layout(*net));
  }
  /// The average (in the actor's packed layout) into `net`'s tensors.
  void write_average(MlpNet& net) {
    fast::Mlp packed(actor_.in(), actor_.hidden(), actor_.out());
    packed.params() = average_;
    torch::NoGradGuard ng;
    const auto t = tensors(net);
    std::array<float*, 6> p{};
    for (std::size_t i = 0; i < 6; ++i) p[i] = t[i].data_ptr<float>();
    packed.get_torch_layout(p);
  }
  void to_torch() {
    torch::NoGradGuard ng;
    for (auto [net, fast] : {std::pair<MlpNet*, fast::Mlp*>{&torch_.actor, &actor_}, {&torch_.critic, &critic_}}) {
      const auto t = tensors(*net);
      std::array<float*, 6> p{};
      for (std::size_t i = 0; i < 6; ++i) p[i] = t[i].data_ptr<float>();
      fast->get_torch_layout(p);
    }
  }
  /// Each row's outputs are the same bits whatever the other rows (the kernels sum every element
  /// over its inputs in order), so lanes split a batch without changing a number.
  /// The critic's input rows: the observation's rows (when it reads them), then its own.
  fast::Mlp::Rows critic_rows(const float* observations, const float* own) const {
    const int own_width = critic_.in() - critic_observation_;
    if (critic_observation_ == 0) return critic_.rows_of(own);
    return fast::Mlp::Rows{observations, critic_observation_, actor_.in(), own, own_width};
  }
  void forward(const fast::Mlp& net, const float* in, int rows, int width, float* out, int lane) {
    forward(net, net.rows_of(in), rows, width, out, lane);
  }
  void forward(const fast::Mlp& net, const fast::Mlp::Rows& in, int rows, int width, float* out, int lane) {
    if (lane < 0 || lane >= kLanes) throw std::logic_error("FastPpo: lane " + std::to_string(lane) + " outside 0.." + std::to_string(kLanes - 1));
    auto& scratch = scratch_[lane];
    scratch.resize(static_cast<std::size_t>(rows) * net.out_stride());
    net.forward(in, rows, scratch.data(), &infer_cache_[lane]);
    for (int i = 0; i < rows; ++i)
      std::copy(scratch.data() + static_cast<std::size_t>(i) * net.out_stride(),
                scratch.data() + static_cast<std::size_t>(i) * net.out_stride() + width, out + static_cast<std::size_t>(i) * width);
  }

  static constexpr std::size_t kChunks = 2;
  static constexpr int kLanes = kCollectLanes;
  static constexpr int kPieceRows = 192;
  int critic_observation_;  // the critic's leading input columns that are the observation (0 or its width)
  Nets torch_;  // the archive's form of the weights (written on save, read on load)
  fast::Mlp actor_, critic_;
  fast::Adam actor_adam_, critic_adam_;
  double average_decay_ = 0;
  std::vector<float> average_;  // the actor's Polyak average in its packed layout (empty before the first step)
  int threads_ = 1;
  fast::Mlp::Cache actor_cache_[kChunks], critic_cache_[kChunks], infer_cache_[kLanes];
  std::vector<float> chunk_grad_[kChunks];
  std::vector<float> grad_, logits_, values_, dlogits_, dvalues_, scratch_[kLanes];
};

}  // namespace

std::unique_ptr<PpoNetworks> make_ppo_networks(const std::string& backend, int obs_width, int critic_width, int hidden,
                                               double learning_rate, const torch::Device& device, std::uint64_t seed,
                                               int threads, int actions, int critic_observation) {
  if (critic_observation != 0 && (critic_observation != obs_width || critic_width < obs_width))
    throw std::logic_error("make_ppo_networks: the critic reads the whole observation or none of it");
  auto nets = initial_nets(obs_width, critic_width, hidden, actions, seed);
  if (backend == "torch") return std::make_unique<TorchPpo>(std::move(nets), learning_rate, device, critic_observation);
  if (backend != "fast") throw InputError("marl.backend = \"" + backend + "\" is not allowed: allowed one of fast, torch");
  if (device.is_cuda())
    throw InputError("marl.backend = \"fast\" runs on the CPU: with nn.device = \"cuda\" set marl.backend = \"torch\"");
  return std::make_unique<FastPpo>(std::move(nets), learning_rate, threads, critic_observation);
}

// ---- the three phases ----------------------------------------------------------------------------

namespace {
/// A move drawn from the softmax of the logits z over the allowed moves; `logp` its log-probability.
int sample_allowed(const float* z, ActionSet allowed, int A, Rng& draw, double& logp) {
  double mx = -1e30;
  for (int k = 0; k < A; ++k)
    if (allowed >> k & 1u) mx = std::max(mx, static_cast<double>(z[k]));
  double sum = 0;
  for (int k = 0; k < A; ++k)
    if (allowed >> k & 1u) sum += std::exp(static_cast<double>(z[k]) - mx);
  const double u = draw.uniform() * sum;
  double acc = 0;
  int a = -1;
  for (int k = 0; k < A; ++k) {
    if (!(allowed >> k & 1u)) continue;
    acc += std::exp(static_cast<double>(z[k]) - mx);
    if (a < 0 && u < acc) a = k;
  }
  if (a < 0)
    for (int k = A; k-- > 0;)
      if (allowed >> k & 1u) {
        a = k;
        break;
      }
  logp = static_cast<double>(z[a]) - mx - std::log(sum);
  return a;
}
}  // namespace


void collect(VecEnv& vec, const Encoder& encoder, const CriticReader& critic, const SafetyOptions& safety, PpoNetworks& nets,
             const RunningStats& value_norm, Rng& rng, Rollout& r, EpisodeStats& stats, int threads) {
  const int M = r.M, N = r.N, A = r.A, C = r.C;
  const int width = C > 0 ? 2 * C : A;  // the actor's output: logits, or mean and log std
  if (r.critic_observation != critic.observation_width(vec.env(0)) || r.critic_width != critic.width(vec.env(0)))
    throw std::logic_error("collect: the rollout's critic input is not the critic reader's");
  const std::size_t step_rows = static_cast<std::size_t>(M) * N;
  std::vector<float> logits(step_rows * static_cast<std::size_t>(width));
  std::vector<Rng> streams;  // environment e samples from streams[e] alone: the same draws on any thread count
  streams.reserve(static_cast<std::size_t>(M));
  for (int e = 0; e < M; ++e) streams.emplace_back(rng.next());
  std::vector<std::vector<int>> actions(static_cast<std::size_t>(M), std::vector<int>(static_cast<std::size_t>(N)));
  std::vector<Positions> next(static_cast<std::size_t>(M));
  std::vector<StepInfo> infos(static_cast<std::size_t>(M));
  // The lanes: kCollectLanes fixed, contiguous groups of environments. Observations that ask a
  // rate oracle the environments share (its memo) are written on the calling thread first;
  // everything else a lane does touches its own environments (and their own oracles) and rows.
  const bool encode_in_lanes = encoder.threads > 1 && !(encoder.asks_oracle && vec.shares_oracle());
  // marl.sequential: each agent's observation is written just before it chooses, in its lane; with
  // an oracle the environments share, the lanes then run one after another.
  const bool sequential = encoder.sequential && C == 0;
  const bool serial_lanes = sequential && encoder.asks_oracle && vec.shares_oracle();
  const int lane_threads = serial_lanes ? 1 : std::min({resolve_threads(threads), nets.lanes(), kCollectLanes});
  // marl.sequential_passes: each lane's row for the observation and logits of a pass not trained on.
  std::vector<float> scratch_rows(sequential && encoder.passes > 1 ? kCollectLanes * (static_cast<std::size_t>(r.obs_width) + A) : 0);
  auto env_range = [&](std::size_t lane) {
    return std::pair<int, int>{static_cast<int>(static_cast<std::size_t>(M) * lane / kCollectLanes),
                               static_cast<int>(static_cast<std::size_t>(M) * (lane + 1) / kCollectLanes)};
  };

  for (int t = 0; t < r.T; ++t) {
    float* obs = r.observations.data() + r.at(t, 0, 0) * static_cast<std::size_t>(r.obs_width);
    float* crit = r.critic_inputs.data() + r.at(t, 0, 0) * static_cast<std::size_t>(r.critic_own());
    float* values = r.values.data() + r.at(t, 0, 0);
    auto encode = [&](int e) {
      for (int n = 0; n < N; ++n) {
        const auto i = static_cast<std::size_t>(e * N + n);
        if (!sequential) {
          encoder.write(vec.env(e), n, obs + i * static_cast<std::size_t>(r.obs_width));
          critic.write_own(vec.env(e), n, crit + i * static_cast<std::size_t>(r.critic_own()));
        }
        r.active[r.at(t, e, n)] = static_cast<float>(vec.env(e).mask(n));
        r.logprobs[r.at(t, e, n)] = 0.0f;  // agents that STAY without sampling (arrived) keep these
        std::fill_n(r.allowed.data() + r.at(t, e, n) * A, A, 1.0f);
      }
    };
    if (!encode_in_lanes)
      for (int e = 0; e < M; ++e) encode(e);
    parallel_for(kCollectLanes, lane_threads, [&](std::size_t lane) {
      const auto [first, last] = env_range(lane);
      if (first == last) return;
      if (encode_in_lanes)
        for (int e = first; e < last; ++e) encode(e);
      const std::size_t row = static_cast<std::size_t>(first) * N;
      const int rows = (last - first) * N;
      auto critic_values = [&] {
        nets.values(obs + row * static_cast<std::size_t>(r.obs_width), crit + row * static_cast<std::size_t>(r.critic_own()), rows,
                    values + row, static_cast<int>(lane));
        for (std::size_t i = row; i < row + static_cast<std::size_t>(rows); ++i)
          values[i] = static_cast<float>(value_norm.denormalise(values[i]));
      };
      if (!sequential) {
        nets.logits(obs + row * static_cast<std::size_t>(r.obs_width), rows, logits.data() + row * static_cast<std::size_t>(width),
                    static_cast<int>(lane));
        critic_values();
      }
      for (int e = first; e < last; ++e) {
        const auto ee = static_cast<std::size_t>(e);
        Rng& draw = streams[ee];
        UavEnv& env = vec.env(e);
        infos[ee] = StepInfo{};
        if (C > 0) {
          // Each active UAV draws z ~ N(mu, sigma^2) per dimension and commands u = tanh(z) (ppo.hpp);
          // the safety layer may fly another velocity. Arrived UAVs hover (inactive rows).
          Positions wanted = Positions::Zero(N, 2);
          for (int n = 0; n < N; ++n) {
            const std::size_t i = r.at(t, e, n);
            float* raw = r.raw_actions.data() + i * static_cast<std::size_t>(C);
            std::fill_n(raw, C, 0.0f);
            if (env.arrived(n)) continue;
            const float* o = logits.data() + static_cast<std::size_t>(e * N + n) * width;
            double logp = 0, u[2] = {0, 0};
            for (int k = 0; k < C; ++k) {
              const double ls = std::min(std::max(static_cast<double>(o[C + k]), kLogStdMin), kLogStdMax);
              const float z = static_cast<float>(o[k] + std::exp(ls) * draw.normal());
              raw[k] = z;
              logp += squashed_gaussian_logprob(z, o[k], o[C + k]);
              u[k] = std::tanh(static_cast<double>(z));
            }
            r.logprobs[i] = static_cast<float>(logp);
            env.command_velocity(n, u[0], u[1], wanted(n, 0), wanted(n, 1));
          }
          next[ee] = vec.begin_velocities(e, safe_velocities(env, safety, wanted), infos[ee]);
          vec.settle(e, next[ee], infos[ee]);
          continue;
        }
        // Each UAV samples from its policy restricted to its allowed moves (the reachability
        // mask and the shield against the UAVs already placed); arrived agents STAY.
        auto record = [&](int n, ActionSet allowed, const float* z) {
          const std::size_t i = r.at(t, e, n);
          for (int k = 0; k < A; ++k) r.allowed[i * A + static_cast<std::size_t>(k)] = (allowed >> k & 1u) ? 1.0f : 0.0f;
          double logp = 0;
          const int a = sample_allowed(z, allowed, A, draw, logp);
          r.logprobs[i] = static_cast<float>(logp);
          return a;
        };
        if (sequential) {
          // Each agent's observation now, with the landings chosen before it (and with
          // marl.sequential_passes, the others' moves of the pass before); the last pass is trained on.
          float* intention = scratch_rows.empty() ? nullptr : scratch_rows.data() + lane * (static_cast<std::size_t>(r.obs_width) + A);
          actions[ee] = take_turns(env, safety, encoder.passes, [&](int n, ActionSet allowed, bool flown) {
            float* o = flown ? obs + static_cast<std::size_t>(e * N + n) * static_cast<std::size_t>(r.obs_width) : intention;
            float* z = flown ? logits.data() + static_cast<std::size_t>(e * N + n) * A : intention + r.obs_width;
            encoder.write(env, n, o);
            nets.logits(o, 1, z, static_cast<int>(lane));
            if (flown) return record(n, allowed, z);
            double logp = 0;
            return sample_allowed(z, allowed, A, draw, logp);
          });
        } else {
          actions[ee] = sequential_safe_actions(env, safety, [&](int n, ActionSet allowed) {
            return record(n, allowed, logits.data() + static_cast<std::size_t>(e * N + n) * A);
          });
        }
        if (sequential) {  // the rows no agent chose from (arrived UAVs), then the critic's inputs
          for (int n = 0; n < N; ++n) {
            const std::size_t i = static_cast<std::size_t>(e * N + n);
            if (env.arrived(n)) encoder.write(env, n, obs + i * static_cast<std::size_t>(r.obs_width));
          }
          env.clear_decided();
          for (int n = 0; n < N; ++n) {
            const std::size_t i = static_cast<std::size_t>(e * N + n);
            critic.write_own(env, n, crit + i * static_cast<std::size_t>(r.critic_own()));
          }
        }
        for (int n = 0; n < N; ++n) r.actions[r.at(t, e, n)] = actions[ee][static_cast<std::size_t>(n)];
        next[ee] = vec.begin(e, actions[ee], infos[ee]);
        vec.settle(e, next[ee], infos[ee]);  // its step ends here when its oracle knows every rate
      }
      if (sequential) critic_values();
    });
    const auto done = vec.finish(next, infos);
    for (int e = 0; e < M; ++e) {
      const auto& info = done[static_cast<std::size_t>(e)];
      r.rewards[static_cast<std::size_t>(t) * M + static_cast<std::size_t>(e)] = static_cast<float>(info.reward);
      r.dones[static_cast<std::size_t>(t) * M + static_cast<std::size_t>(e)] = info.done ? 1.0f : 0.0f;
      if (info.done) stats.add(info, N);
    }
  }
  // Bootstrap values of the states after the rollout.
  std::vector<float> last_obs(step_rows * static_cast<std::size_t>(r.critic_observation)), crit(step_rows * static_cast<std::size_t>(r.critic_own()));
  for (int e = 0; e < M; ++e)
    for (int n = 0; n < N; ++n) {
      const auto i = static_cast<std::size_t>(e * N + n);
      if (r.critic_observation > 0) encoder.write(vec.env(e), n, last_obs.data() + i * static_cast<std::size_t>(r.critic_observation));
      critic.write_own(vec.env(e), n, crit.data() + i * static_cast<std::size_t>(r.critic_own()));
    }
  nets.values(last_obs.data(), crit.data(), static_cast<int>(step_rows), r.next_values.data());
  for (auto& v : r.next_values) v = static_cast<float>(value_norm.denormalise(v));
}

void compute_advantages(Rollout& r, double gamma, double lambda) {
  for (int e = 0; e < r.M; ++e)
    for (int n = 0; n < r.N; ++n) {
      double next_advantage = 0, next_value = r.next_values[static_cast<std::size_t>(e * r.N + n)];
      for (int t = r.T; t-- > 0;) {
        const std::size_t i = r.at(t, e, n), j = static_cast<std::size_t>(t) * r.M + static_cast<std::size_t>(e);
        const double keep = r.dones[j] > 0 ? 0.0 : 1.0;
        const double delta = r.rewards[j] + gamma * keep * next_value - r.values[i];
        next_advantage = delta + gamma * lambda * keep * next_advantage;
        next_value = r.values[i];
        r.advantages[i] = static_cast<float>(next_advantage);
        r.returns[i] = static_cast<float>(next_advantage + r.values[i]);
      }
    }
}

double explained_variance(const Rollout& r) {
  double w = 0, my = 0, md = 0;
  for (std::size_t i = 0; i < r.samples(); ++i) {
    w += r.active[i];
    my += r.active[i] * r.returns[i];
    md += r.active[i] * (r.returns[i] - r.values[i]);
  }
  if (w <= 0) return NAN;
  my /= w, md /= w;
  double vy = 0, vd = 0;
  for (std::size_t i = 0; i < r.samples(); ++i) {
    const double d = r.returns[i] - r.values[i];
    vy += r.active[i] * (r.returns[i] - my) * (r.returns[i] - my);
    vd += r.active[i] * (d - md) * (d - md);
  }
  return vy > 0 ? 1.0 - vd / vy : NAN;
}

/// Asks for every cache line of the floats [p, p + n).
inline void prefetch_span(const float* p, int n) {
  if (n <= 0) return;
  const auto first = reinterpret_cast<std::uintptr_t>(p) & ~std::uintptr_t{63};
  const auto last = reinterpret_cast<std::uintptr_t>(p + n - 1);
  for (std::uintptr_t a = first; a <= last; a += 64) __builtin_prefetch(reinterpret_cast<const void*>(a));
}

UpdateStats update(const Rollout& r, PpoNetworks& nets, RunningStats& value_norm, const MarlConfig& m, Rng& rng, Minibatch& b,
                   double entropy_factor) {
  const std::size_t S = r.samples();
  // Advantages normalised over the active agents; value targets in normalised units.
  double w = 0, mean = 0, var = 0;
  for (std::size_t i = 0; i < S; ++i) w += r.active[i], mean += r.active[i] * r.advantages[i];
  mean /= std::max(w, 1.0);
  for (std::size_t i = 0; i < S; ++i) var += r.active[i] * (r.advantages[i] - mean) * (r.advantages[i] - mean);
  var /= std::max(w, 1.0);
  const double scale = 1.0 / std::sqrt(var + 1e-8);
  if (m.value_norm) value_norm.update(r.returns.data(), S);
  auto norm = [&](float x) { return static_cast<float>(m.value_norm ? value_norm.normalise(x) : x); };

  const PpoSettings settings{m.clip, m.value_coef, m.entropy_coef * entropy_factor, m.grad_clip};
  // marl.minibatch = steps: minibatches of whole steps, a step's N agents in consecutive rows.
  const int group = m.minibatch == "steps" ? r.N : 1;
  const std::size_t units = S / static_cast<std::size_t>(group);  // agent samples or steps
  const int rows = group * static_cast<int>(std::max<std::size_t>(1, units / static_cast<std::size_t>(m.minibatches)));
  b.share = group > 1 && r.critic_shared ? group : 1;
  b.rows = rows, b.obs_width = r.obs_width, b.critic_width = r.critic_width, b.action_count = r.A, b.dims = r.C;
  b.critic_observation = r.critic_observation;
  const int own = r.critic_own();
  b.raw_actions.resize(static_cast<std::size_t>(rows) * r.C);
  b.observations.resize(static_cast<std::size_t>(rows) * r.obs_width);
  b.critic_inputs.resize(static_cast<std::size_t>(rows) * own);
  b.allowed.resize(static_cast<std::size_t>(rows) * r.A);
  for (auto* v : {&b.logprobs, &b.advantages, &b.returns, &b.values, &b.active}) v->resize(static_cast<std::size_t>(rows));
  b.actions.resize(static_cast<std::size_t>(rows));

  UpdateStats mean_stats;
  int steps = 0;
  constexpr int kAhead = 8;  // rows the gather prefetches ahead
  std::vector<std::size_t> order(S), unit_order(group > 1 ? units : 0);
  std::vector<UpdateStats> all;
  std::size_t first = 0;  // the minibatch's first index into `order`
  // The networks' step gathers each range of rows as it reaches it (Minibatch::fill).
  b.fill = [&](int lo, int hi) {
    for (int k = lo; k < hi; ++k) {
      const std::size_t i = order[first + static_cast<std::size_t>(k)], kk = static_cast<std::size_t>(k);
      if (k + kAhead < hi) {  // the rows are scattered over the rollout: ask for a later one's now
        const std::size_t ahead = order[first + static_cast<std::size_t>(k + kAhead)];
        prefetch_span(r.observations.data() + ahead * r.obs_width, r.obs_width);
        prefetch_span(r.critic_inputs.data() + ahead * own, own);
        prefetch_span(r.allowed.data() + ahead * r.A, r.A);
      }
      std::copy_n(r.observations.data() + i * r.obs_width, r.obs_width, b.observations.data() + kk * r.obs_width);
      std::copy_n(r.critic_inputs.data() + i * own, own, b.critic_inputs.data() + kk * own);
      std::copy_n(r.allowed.data() + i * r.A, r.A, b.allowed.data() + kk * r.A);
      std::copy_n(r.raw_actions.data() + i * r.C, r.C, b.raw_actions.data() + kk * r.C);
      b.actions[kk] = r.actions[i];
      b.logprobs[kk] = r.logprobs[i];
      b.active[kk] = r.active[i];
      b.advantages[kk] = static_cast<float>((r.advantages[i] - mean) * scale);
      b.returns[kk] = norm(r.returns[i]);
      b.values[kk] = norm(r.values[i]);
    }
  };
  struct Unset {  // the gather refers to this call's locals: never leave it in the scratch
    Minibatch& b;
    ~Unset() { b.fill = nullptr; }
  } unset{b};
  for (int epoch = 0; epoch < m.epochs; ++epoch) {
    if (group == 1) {
      std::iota(order.begin(), order.end(), std::size_t{0});
      shuffle(order, rng);
    } else {  // the steps shuffled, each step's agents kept together in order (index = step * N + n)
      std::iota(unit_order.begin(), unit_order.end(), std::size_t{0});
      shuffle(unit_order, rng);
      for (std::size_t u = 0; u < units; ++u)
        for (int n = 0; n < group; ++n) order[u * group + static_cast<std::size_t>(n)] = unit_order[u] * group + static_cast<std::size_t>(n);
    }
    for (first = 0; first + static_cast<std::size_t>(rows) <= S; first += static_cast<std::size_t>(rows)) {
      double active = 0;  // in row order, as a gathered batch's sum
      for (int k = 0; k < rows; ++k) active += r.active[order[first + static_cast<std::size_t>(k)]];
      b.active_sum = active;
      all.push_back(nets.step(b, settings));
      ++steps;
    }
  }
  for (const auto& u : all) mean_stats.add(u, 1.0 / std::max(steps, 1));
  return mean_stats;
}

// ---- the learner ---------------------------------------------------------------------------------

MarlTrainResult train_ppo(const Config& cfg, const MarlTrainOptions& opt) {
  const auto& m = cfg.marl;
  const Encoder encoder = encoder_of(cfg, false);
  const CriticReader critic = CriticReader::of(cfg, encoder);
  // The sizes, read from the environments before the run directory is touched (the rollout's
  // memory is checked there). The continuous model: a squashed Gaussian over its command (C
  // dimensions), else a softmax over the A actions.
  int N = 0, M = 0, obs_width = 0, critic_width = 0, critic_observation = 0, C = 0, A = 0;
  Run run(cfg, opt, [&](const VecEnv& v) {
    N = v.env(0).uavs(), M = v.size(), obs_width = encoder.width(v.env(0)), critic_width = critic.width(v.env(0));
    critic_observation = critic.observation_width(v.env(0));
    C = v.env(0).mobility().actions().dims, A = C > 0 ? 0 : v.env(0).actions();
    const double bytes = Rollout::bytes(m.rollout, M, N, obs_width, critic_width - critic_observation, A, C, m.minibatches);
    require_memory(bytes,
                   fmt::format("the PPO rollout of marl.rollout = {} steps x marl.envs = {} environments x {} UAVs ({} + {} "
                               "floats an agent step)", m.rollout, M, N, obs_width, critic_width - critic_observation),
                   fmt::format("allowed marl.rollout x marl.envs <= {:.0f} for this scenario",
                               std::floor(memory_limit_bytes() / (bytes / (static_cast<double>(m.rollout) * M)))));
  });
  VecEnv& vec = run.vec;
  const SafetyOptions safety = training_safety_options(cfg);
  auto nets = make_ppo_networks(m.backend, obs_width, critic_width, m.hidden, m.learning_rate, run.device, cfg.run.seed,
                                cfg.run.threads, C > 0 ? 2 * C : A, critic_observation);
  nets->set_average_decay(m.average_decay);
  RunningStats value_norm;

  std::int64_t steps = 0, updates = 0;
  std::string metrics = metrics_header();
  auto meta = [&] {
    return nlohmann::json{{"format", kFormat}, {"version", kVersion}, {"algo", m.algo}, {"uavs", N},
                          {"obs_dim", obs_width}, {"encoder", m.encoder}, {"backend", m.backend},
                          {"mobility", cfg.trajectory.mobility}, {"actions", vec.env(0).mobility().actions().names},
                          {"hover", vec.env(0).hover()}, {"dims", C},
                          {"critic_input", critic.name()}, {"critic_dim", critic_width},
                          {"hidden", m.hidden}, {"env_steps", steps}, {"updates", updates},
                          {"value_mean", value_norm.mean}, {"value_var", value_norm.var}, {"value_count", value_norm.count},
                          {"config", to_toml(cfg)}};
  };
  if (opt.resume) {
    const auto old = run.resume(cfg, "critic_dim", critic_width, *nets, metrics);
    steps = old.value("env_steps", std::int64_t{0});
    updates = old.value("updates", std::int64_t{0});
    value_norm.mean = old.value("value_mean", 0.0);
    value_norm.var = old.value("value_var", 1.0);
    value_norm.count = old.value("value_count", 1e-4);
    if (opt.progress) *opt.progress << "resuming " << m.algo << " at " << steps << " environment steps\n";
  }
  write_file_atomic((run.dir / "config.toml").string(), to_toml(cfg));

  const std::int64_t per_update = static_cast<std::int64_t>(m.rollout) * M;
  const std::int64_t start_steps = steps;
  std::unique_ptr<Progress> bar;
  if (opt.progress)
    bar = std::make_unique<Progress>(fmt::format("{} {} steps", m.algo, m.total_steps),
                                     static_cast<std::size_t>((m.total_steps - steps + per_update - 1) / per_update), *opt.progress, 10.0, 2.0);
  Rollout rollout(m.rollout, M, N, obs_width, critic_width, A, C, critic_observation);
  rollout.critic_shared = critic.shared_by_step();
  Minibatch scratch;
  EpisodeStats stats;
  const Schedule lr_schedule = Schedule::of(m.lr_schedule), entropy_schedule = Schedule::of(m.entropy_schedule);
  while (steps < m.total_steps) {
    Rng rng(derive_seed(cfg.run.seed, 0x50504fULL, static_cast<std::uint64_t>(updates)));
    if (lr_schedule.linear) nets->set_learning_rate(m.learning_rate * lr_schedule.factor(steps, m.total_steps));
    const double entropy_factor = entropy_schedule.factor(steps, m.total_steps);
    collect(vec, encoder, critic, safety, *nets, value_norm, rng, rollout, stats, cfg.run.threads);
    steps += per_update;
    compute_advantages(rollout, m.gamma, m.gae_lambda);
    const double explained = explained_variance(rollout);
    const UpdateStats u = update(rollout, *nets, value_norm, m, rng, scratch, entropy_factor);
    ++updates;
    const double elapsed = std::chrono::duration<double>(std::chrono::steady_clock::now() - run.start).count();
    if (stats.episodes > 0 || steps >= m.total_steps) {
      LearnerLog log;
      log.policy_loss = u.policy_loss, log.value_loss = u.value_loss, log.entropy = u.entropy;
      log.old_approx_kl = u.old_approx_kl, log.approx_kl = u.approx_kl, log.clipfrac = u.clipfrac;
      log.explained_variance = explained, log.grad_norm = u.grad_norm;
      metrics += metrics_row(cfg.run.seed, steps, stats, log, static_cast<double>(steps - start_steps) / std::max(elapsed, 1e-9));
      stats.clear();
    }
    if (updates % m.checkpoint_every == 0 || steps >= m.total_steps) run.checkpoint(meta(), *nets, metrics);
    if (updates % m.checkpoint_every == 0 && steps < m.total_steps) run.validate(cfg, opt, meta(), *nets, steps);
    if (bar) bar->advance();
  }
  if (bar) bar->finish();
  return run.finish(cfg, opt, meta(), *nets, metrics, steps, start_steps);
}

}  // namespace marl
}  // namespace skyloop
