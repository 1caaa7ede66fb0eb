// VDN and QMIX on one value-decomposition core: a parameter-shared agent Q-network on the local
// observation plus a one-hot agent id, epsilon-greedy exploration with linear annealing, an
// episode replay buffer, target networks and double Q-learning. VDN sums the agents' chosen Q
// values; QMIX mixes them with a monotonic hypernetwork conditioned on the global state. Arrived
// agents are masked: they STAY, and their Q values enter the mix as 0.
#include <filesystem>
#include <fmt/format.h>
#include <ostream>

#include "common.hpp"
#include "skyloop/core/config_io.hpp"
#include "skyloop/core/error.hpp"
#include "skyloop/core/io.hpp"
#include "skyloop/core/memory.hpp"
#include "skyloop/core/progress.hpp"
#include "skyloop/env/vec_env.hpp"
#include "skyloop/marl/learners.hpp"
#include "skyloop/core/rng.hpp"
#include "skyloop/nn/learned.hpp"

namespace skyloop::marl {

namespace {

/// Episodes padded to T_max slots (T_max - 1 transitions).
struct EpisodeBuffer {
  torch::Tensor obs, state, mask, allow, act, rew, done, valid;
  int64_t capacity = 0, size = 0, next = 0;
  /// The bytes the tensors below hold.
  static double bytes(int64_t cap, int64_t tmax, int64_t n, int64_t d, int64_t s, int64_t actions) {
    const double slots = static_cast<double>(cap) * static_cast<double>(tmax);
    const double transitions = static_cast<double>(cap) * static_cast<double>(tmax - 1);
    return slots * 4.0 * static_cast<double>(n * d + n * actions + s + n) + transitions * (8.0 * static_cast<double>(n) + 12.0);
  }
  EpisodeBuffer(int64_t cap, int64_t tmax, int64_t n, int64_t d, int64_t s, int64_t actions, int64_t hover) : capacity(cap) {
    obs = torch::zeros({cap, tmax, n, d});
    allow = torch::ones({cap, tmax, n, actions});
    state = torch::zeros({cap, tmax, s});
    mask = torch::zeros({cap, tmax, n});
    act = torch::full({cap, tmax - 1, n}, hover, torch::kInt64);
    rew = torch::zeros({cap, tmax - 1});
    done = torch::zeros({cap, tmax - 1});
    valid = torch::zeros({cap, tmax - 1});
  }
};

/// One environment's episode in progress.
struct Recording {
  std::vector<float> obs, state, mask, allow, rew, done;
  std::vector<int64_t> act;
  int slots = 0;
  void clear() { *this = Recording{}; }
};

LearnerLog vdn_log(double td_loss, double epsilon) {
  LearnerLog log;
  log.value_loss = td_loss;
  log.epsilon = epsilon;
  return log;
}

/// The value-decomposition learner's state and its phases: act (epsilon-greedy over the allowed
/// moves), record (each environment's episode in progress), store (a finished episode into the
/// replay buffer) and update (one double-Q TD step on a batch of episodes, the target networks
/// synced every marl.target_update steps).
class ValueDecompositionCore {
 public:
  ValueDecompositionCore(const Config& cfg, VecEnv& vec)
      : m_(cfg.marl),
        mixer_(find_learner(cfg.marl.algo).mixer),
        N_(vec.env(0).uavs()),
        Tm_(vec.env(0).t_max()),
        encoder_(encoder_of(cfg, true)),
        safety_(training_safety_options(cfg)),
        D_(encoder_.width(vec.env(0))),
        S_(vec.env(0).state_size()),
        A_(vec.env(0).actions()),
        hover_(vec.env(0).hover()),
        buffer_(cfg.marl.buffer_episodes, Tm_, N_, D_, S_, A_, hover_) {
    torch::manual_seed(cfg.run.seed);
    nets_.q = MlpNet(D_, m_.hidden, A_);
    target_.q = MlpNet(D_, m_.hidden, A_);
    if (qmix()) nets_.mixer = QMixer(N_, S_, m_.mixer_embed), target_.mixer = QMixer(N_, S_, m_.mixer_embed);
    params_ = nets_.q->parameters();
    if (qmix())
      for (auto& p : nets_.mixer->parameters()) params_.push_back(p);
    adam_ = std::make_unique<torch::optim::Adam>(params_, torch::optim::AdamOptions(m_.learning_rate));
    learned_ = std::make_unique<TorchLearned>(nets_, *adam_);
  }

  int obs_width() const { return D_; }
  int state_width() const { return S_; }
  Learned& learned() { return *learned_; }
  void to(const torch::Device& device) { device_ = device; }

  void sync_target() {
    torch::NoGradGuard ng;
    auto copy = [](torch::nn::Module& dst, torch::nn::Module& src) {
      auto d = dst.parameters(), s = src.parameters();
      for (std::size_t i = 0; i < d.size(); ++i) d[i].copy_(s[i]);
    };
    copy(*target_.q, *nets_.q);
    if (qmix()) copy(*target_.mixer, *nets_.mixer);
  }

  /// Epsilon-greedy joint actions of every environment: each UAV takes the best allowed move by
  /// its Q-values, or with probability epsilon a uniformly random allowed one; arrived UAVs STAY.
  std::vector<std::vector<int>> act(VecEnv& vec, double epsilon, Rng& rng) {
    const int M = vec.size();
    std::vector<std::vector<int>> actions(static_cast<std::size_t>(M));
    in_.resize(static_cast<std::size_t>(M * N_ * D_));
    for (int e = 0; e < M; ++e)
      for (int n = 0; n < N_; ++n) encoder_.write(vec.env(e), n, in_.data() + static_cast<std::size_t>((e * N_ + n) * D_));
    torch::NoGradGuard ng;
    const auto q = nets_.q(torch::from_blob(in_.data(), {M * N_, D_}).to(device_)).to(torch::kCPU).contiguous();
    const auto qa = q.accessor<float, 2>();
    for (int e = 0; e < M; ++e)
      actions[static_cast<std::size_t>(e)] = sequential_safe_actions(vec.env(e), safety_, [&](int n, ActionSet allowed) {
        const int i = e * N_ + n;
        int count = 0, best = -1;
        for (int a = 0; a < A_; ++a)
          if (allowed >> a & 1u) {
            ++count;
            if (best < 0 || qa[i][a] > qa[i][best]) best = a;
          }
        if (rng.uniform() >= epsilon) return best;
        int pick = static_cast<int>(rng.below(static_cast<std::uint64_t>(count)));
        for (int a = 0; a < A_; ++a)
          if ((allowed >> a & 1u) && pick-- == 0) return a;
        return best;
      });
    return actions;
  }

  /// Appends the environment's current slot (observations, active mask, allowed moves, state).
  void record(const UavEnv& env, Recording& r) const {
    for (int n = 0; n < N_; ++n) {
      r.obs.resize(r.obs.size() + static_cast<std::size_t>(D_));
      encoder_.write(env, n, r.obs.data() + r.obs.size() - static_cast<std::size_t>(D_));
      r.mask.push_back(static_cast<float>(env.mask(n)));
      // The moves the target's argmax may pick at this slot: the reachability mask (the shield
      // depends on the other UAVs' choices, unknown to the target).
      const ActionSet allowed = allowed_moves(env, n, safety_);
      for (int a = 0; a < A_; ++a) r.allow.push_back((allowed >> a & 1u) ? 1.0f : 0.0f);
    }
    const auto s = env.state();
    r.state.insert(r.state.end(), s.begin(), s.end());
    ++r.slots;
  }

  /// Closes a finished episode (the terminal slot recorded as zeros: never bootstrapped, done = 1)
  /// and stores it in the replay buffer, replacing the oldest when full.
  void store(Recording& r) {
    r.obs.resize(r.obs.size() + static_cast<std::size_t>(N_ * D_), 0.0f);
    r.state.resize(r.state.size() + static_cast<std::size_t>(S_), 0.0f);
    r.mask.resize(r.mask.size() + static_cast<std::size_t>(N_), 0.0f);
    r.allow.resize(r.allow.size() + static_cast<std::size_t>(N_ * A_), 1.0f);
    ++r.slots;
    auto& b = buffer_;
    const int64_t i = b.next, slots = r.slots, trans = slots - 1;
    b.obs[i].zero_();
    b.state[i].zero_();
    b.mask[i].zero_();
    b.allow[i].fill_(1.0);
    b.act[i].fill_(static_cast<int64_t>(hover_));
    b.rew[i].zero_();
    b.done[i].zero_();
    b.valid[i].zero_();
    b.obs[i].narrow(0, 0, slots).copy_(torch::from_blob(r.obs.data(), {slots, N_, D_}));
    b.state[i].narrow(0, 0, slots).copy_(torch::from_blob(r.state.data(), {slots, S_}));
    b.mask[i].narrow(0, 0, slots).copy_(torch::from_blob(r.mask.data(), {slots, N_}));
    b.allow[i].narrow(0, 0, slots).copy_(torch::from_blob(r.allow.data(), {slots, N_, A_}));
    if (trans > 0) {
      b.act[i].narrow(0, 0, trans).copy_(torch::from_blob(r.act.data(), {trans, N_}, torch::kInt64));
      b.rew[i].narrow(0, 0, trans).copy_(torch::from_blob(r.rew.data(), {trans}));
      b.done[i].narrow(0, 0, trans).copy_(torch::from_blob(r.done.data(), {trans}));
      b.valid[i].narrow(0, 0, trans).fill_(1.0);
    }
    b.next = (b.next + 1) % b.capacity;
    b.size = std::min(b.size + 1, b.capacity);
    r.clear();
  }

  bool ready() const { return buffer_.size >= m_.batch_episodes; }

  /// One TD step on marl.batch_episodes episodes drawn with replacement: y = r + gamma (1 - done)
  /// Q_tot'(s', argmax_a Q(o', a) among the allowed moves) (double Q), the squared error over the
  /// valid transitions; returns the loss.
  double update(Rng& rng) {
    const int64_t B = std::min<int64_t>(m_.batch_episodes, buffer_.size);
    std::vector<int64_t> pick(static_cast<std::size_t>(B));
    for (auto& p : pick) p = static_cast<int64_t>(rng.below(static_cast<std::uint64_t>(buffer_.size)));
    const auto idx = torch::tensor(pick, torch::kInt64);
    const auto obs = buffer_.obs.index_select(0, idx).to(device_);      // [B, Tm, N, D]
    const auto state = buffer_.state.index_select(0, idx).to(device_);  // [B, Tm, S]
    const auto mask = buffer_.mask.index_select(0, idx).to(device_);    // [B, Tm, N]
    const auto allow = buffer_.allow.index_select(0, idx).to(device_);  // [B, Tm, N, 5]
    const auto act = buffer_.act.index_select(0, idx).to(device_);      // [B, Tm-1, N]
    const auto rew = buffer_.rew.index_select(0, idx).to(device_);
    const auto done = buffer_.done.index_select(0, idx).to(device_);
    const auto valid = buffer_.valid.index_select(0, idx).to(device_);
    const auto q_all = nets_.q(obs);                                    // [B, Tm, N, 5]
    const auto q_now = q_all.narrow(1, 0, Tm_ - 1).gather(3, act.unsqueeze(3)).squeeze(3) * mask.narrow(1, 0, Tm_ - 1);
    const auto q_tot = mix(nets_, q_now, state.narrow(1, 0, Tm_ - 1));
    torch::Tensor y;
    {
      torch::NoGradGuard ng;
      const auto next_obs = obs.narrow(1, 1, Tm_ - 1);
      const auto a_star = masked_logits(q_all.detach().narrow(1, 1, Tm_ - 1), allow.narrow(1, 1, Tm_ - 1)).argmax(3, true);
      const auto q_next = target_.q(next_obs).gather(3, a_star).squeeze(3) * mask.narrow(1, 1, Tm_ - 1);
      const auto q_tot_next = mix(target_, q_next, state.narrow(1, 1, Tm_ - 1));
      y = rew + m_.gamma * (1 - done) * q_tot_next;
    }
    const auto loss = ((q_tot - y).pow(2) * valid).sum() / torch::clamp_min(valid.sum(), 1.0);
    adam_->zero_grad();
    loss.backward();
    if (m_.grad_clip > 0) torch::nn::utils::clip_grad_norm_(params_, m_.grad_clip);
    adam_->step();
    if (++grad_steps % m_.target_update == 0) sync_target();
    return loss.item<double>();
  }

  /// The optimiser's learning rate from the next step on (marl.lr_schedule).
  void set_learning_rate(double learning_rate) {
    for (auto& group : adam_->param_groups()) static_cast<torch::optim::AdamOptions&>(group.options()).lr(learning_rate);
  }

  std::int64_t grad_steps = 0;

 private:
  bool qmix() const { return mixer_ == LearnerInfo::Mixer::Qmix; }
  /// The team Q from the agents' Q [B, T, N] and the state [B, T, S] (VDN: the sum).
  torch::Tensor mix(Nets& net, const torch::Tensor& q, const torch::Tensor& state) const {
    if (!qmix()) return q.sum(2);
    const auto B = q.size(0), T = q.size(1);
    return net.mixer(q.reshape({B * T, N_}), state.reshape({B * T, S_})).view({B, T});
  }

  const MarlConfig& m_;
  LearnerInfo::Mixer mixer_;
  int N_, Tm_;
  Encoder encoder_;
  SafetyOptions safety_;
  int D_, S_, A_, hover_;
  EpisodeBuffer buffer_;
  Nets nets_, target_;
  std::vector<torch::Tensor> params_;
  std::unique_ptr<torch::optim::Adam> adam_;
  std::unique_ptr<TorchLearned> learned_;
  torch::Device device_{torch::kCPU};
  std::vector<float> in_;
};

}  // namespace

MarlTrainResult train_value_decomposition(const Config& cfg, const MarlTrainOptions& opt) {
  using Clock = std::chrono::steady_clock;
  const auto& m = cfg.marl;
  Run run(cfg, opt, [&](const VecEnv& v) {
    const UavEnv& e = v.env(0);
    const int n = e.uavs(), d = encoder_of(cfg, true).width(e);
    const double per_episode = EpisodeBuffer::bytes(1, e.t_max(), n, d, e.state_size(), e.actions());
    require_memory(per_episode * static_cast<double>(m.buffer_episodes),
                   fmt::format("the {} replay buffer of marl.buffer_episodes = {} episodes of trajectory.t_max = {} slots x {} UAVs",
                               m.algo, m.buffer_episodes, e.t_max(), n),
                   fmt::format("allowed marl.buffer_episodes <= {:.0f} for this scenario",
                               std::floor(memory_limit_bytes() / per_episode)));
  });
  VecEnv& vec = run.vec;  // the learner's tensors on one torch thread (Run): the TD loss's sums
  const int N = vec.env(0).uavs(), M = vec.size();
  ValueDecompositionCore core(cfg, vec);
  core.to(run.device);
  const int D = core.obs_width(), S = core.state_width();
  std::int64_t steps = 0, episodes = 0;
  std::string metrics = metrics_header();
  auto meta = [&] {
    return nlohmann::json{{"format", kFormat}, {"version", kVersion}, {"algo", m.algo}, {"uavs", N},
                          {"obs_dim", vec.env(0).observation_size()}, {"context_dim", D - vec.env(0).observation_size()},
                          {"mobility", cfg.trajectory.mobility}, {"actions", vec.env(0).dynamics().actions().names},
                          {"hover", vec.env(0).hover()},
                          {"state_dim", S}, {"hidden", m.hidden}, {"backend", "torch"}, {"encoder", name_of(m.encoder)},
                          {"mixer_embed", m.mixer_embed}, {"env_steps", steps}, {"grad_steps", core.grad_steps},
                          {"episodes", episodes}, {"config", to_toml(cfg)}};
  };
  if (opt.resume) {
    const auto old = run.resume(cfg, "state_dim", S, core.learned(), metrics);
    steps = old.value("env_steps", std::int64_t{0});
    core.grad_steps = old.value("grad_steps", std::int64_t{0});
    episodes = old.value("episodes", std::int64_t{0});
    if (opt.progress) *opt.progress << "resuming " << m.algo << " at " << steps << " environment steps (replay buffer restarts empty)\n";
  }
  core.sync_target();
  write_file_atomic((run.dir / "config.toml").string(), to_toml(cfg));

  std::vector<Recording> recording(static_cast<std::size_t>(M));
  for (int e = 0; e < M; ++e) core.record(vec.env(e), recording[static_cast<std::size_t>(e)]);
  Rng rng(derive_seed(cfg.run.seed, 0x51ULL, static_cast<std::uint64_t>(steps)));
  const std::int64_t start_steps = steps;
  std::unique_ptr<Progress> bar;
  const std::int64_t log_every = static_cast<std::int64_t>(M) * 256;
  if (opt.progress)
    bar = std::make_unique<Progress>(fmt::format("{} {} steps", m.algo, m.total_steps),
                                     static_cast<std::size_t>((m.total_steps - steps + log_every - 1) / log_every), *opt.progress, 10.0, 2.0);
  EpisodeStats stats;
  double loss_sum = 0;
  int loss_count = 0, new_episodes = 0;
  std::int64_t next_log = steps + log_every, logs = 0;
  const Schedule lr_schedule = Schedule::of(m.lr_schedule);
  while (steps < m.total_steps) {
    if (lr_schedule.linear) core.set_learning_rate(m.learning_rate * lr_schedule.factor(steps, m.total_steps));
    // Epsilon anneals linearly over the first marl.epsilon_anneal of the steps.
    const double frac = std::min(1.0, static_cast<double>(steps) / std::max(1.0, m.epsilon_anneal * static_cast<double>(m.total_steps)));
    const double epsilon = m.epsilon_start + (m.epsilon_end - m.epsilon_start) * frac;
    const auto actions = core.act(vec, epsilon, rng);
    const auto infos = vec.step(actions);
    steps += M;
    for (int e = 0; e < M; ++e) {
      auto& r = recording[static_cast<std::size_t>(e)];
      const auto& info = infos[static_cast<std::size_t>(e)];
      for (int n = 0; n < N; ++n) r.act.push_back(actions[static_cast<std::size_t>(e)][static_cast<std::size_t>(n)]);
      r.rew.push_back(static_cast<float>(info.reward));
      r.done.push_back(info.done ? 1.0f : 0.0f);
      if (info.done) {  // the environment already reset: its next slot starts a new episode
        core.store(r);
        stats.add(info, N);
        ++episodes;
        ++new_episodes;
      }
      core.record(vec.env(e), r);
    }
    // One gradient step per M finished episodes once the buffer holds a batch.
    while (new_episodes >= M && core.ready()) {
      new_episodes -= M;
      loss_sum += core.update(rng);
      ++loss_count;
    }
    if (steps >= next_log || steps >= m.total_steps) {
      next_log += log_every;
      ++logs;
      const double sps = static_cast<double>(steps - start_steps) /
                         std::max(std::chrono::duration<double>(Clock::now() - run.start).count(), 1e-9);
      metrics += metrics_row(cfg.run.seed, steps, stats, vdn_log(loss_count ? loss_sum / loss_count : 0.0, epsilon), sps);
      stats.clear();
      loss_sum = 0;
      loss_count = 0;
      if (logs % m.checkpoint_every == 0 || steps >= m.total_steps) run.checkpoint(meta(), core.learned(), metrics);
      if (logs % m.checkpoint_every == 0 && steps < m.total_steps) run.validate(cfg, opt, meta(), core.learned(), steps);
      if (bar) bar->advance();
    }
  }
  if (bar) bar->finish();
  return run.finish(cfg, opt, meta(), core.learned(), metrics, steps, start_steps);
}

}  // namespace skyloop::marl
