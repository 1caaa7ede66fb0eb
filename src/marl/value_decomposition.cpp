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
#include "skyloop/core/progress.hpp"
#include "skyloop/marl/learners.hpp"
#include "skyloop/core/rng.hpp"
#include "skyloop/nn/learned.hpp"

namespace skyloop::marl {

namespace {

/// Episodes padded to T_max slots (T_max - 1 transitions).
struct EpisodeBuffer {
  torch::Tensor obs, state, mask, allow, act, rew, done, valid;
  int64_t capacity = 0, size = 0, next = 0;
  EpisodeBuffer(int64_t cap, int64_t tmax, int64_t n, int64_t d, int64_t s) : capacity(cap) {
    obs = torch::zeros({cap, tmax, n, d});
    allow = torch::ones({cap, tmax, n, kActions});
    state = torch::zeros({cap, tmax, s});
    mask = torch::zeros({cap, tmax, n});
    act = torch::full({cap, tmax - 1, n}, static_cast<int64_t>(kStay), torch::kInt64);
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

}  // namespace

MarlTrainResult train_value_decomposition(const Config& cfg, const MarlTrainOptions& opt) {
  namespace fs = std::filesystem;
  using Clock = std::chrono::steady_clock;
  const auto& m = cfg.marl;
  const bool qmix = find_learner(m.algo).mixer == LearnerInfo::Mixer::Qmix;
  Run run(cfg, opt);
  const auto& dir = run.dir;
  const auto& device = run.device;
  VecEnv& vec = run.vec;
  const int N = vec.env(0).uavs(), M = vec.size(), Tm = vec.env(0).t_max();
  const Encoder enc = encoder_of(cfg, true);
  const SafetyOptions safety = safety_of(cfg);
  const int D = enc.width(vec.env(0)), S = vec.env(0).state_size();

  torch::manual_seed(cfg.run.seed);
  Nets nets, target;
  nets.q = MlpNet(D, m.hidden, kActions);
  target.q = MlpNet(D, m.hidden, kActions);
  if (qmix) nets.mixer = QMixer(N, S, m.mixer_embed), target.mixer = QMixer(N, S, m.mixer_embed);
  std::vector<torch::Tensor> params = nets.q->parameters();
  if (qmix)
    for (auto& p : nets.mixer->parameters()) params.push_back(p);
  torch::optim::Adam adam(params, torch::optim::AdamOptions(m.learning_rate));
  TorchLearned learned(nets, adam);
  auto sync_target = [&] {
    torch::NoGradGuard ng;
    auto copy = [](torch::nn::Module& dst, torch::nn::Module& src) {
      auto d = dst.parameters(), s = src.parameters();
      for (std::size_t i = 0; i < d.size(); ++i) d[i].copy_(s[i]);
    };
    copy(*target.q, *nets.q);
    if (qmix) copy(*target.mixer, *nets.mixer);
  };
  std::int64_t steps = 0, grad_steps = 0, episodes = 0;
  std::string metrics = metrics_header();
  auto meta = [&] {
    return nlohmann::json{{"format", kFormat}, {"version", kVersion}, {"algo", m.algo}, {"uavs", N},
                          {"obs_dim", UavEnv::observation_size()}, {"context_dim", D - UavEnv::observation_size()}, {"state_dim", S}, {"hidden", m.hidden}, {"backend", "torch"},
                          {"encoder", m.encoder},
                          {"mixer_embed", m.mixer_embed}, {"env_steps", steps}, {"grad_steps", grad_steps},
                          {"episodes", episodes}, {"config", to_toml(cfg)}};
  };
  if (opt.resume) {
    const auto old = run.resume(cfg, "state_dim", S, learned, metrics);
    steps = old.value("env_steps", std::int64_t{0});
    grad_steps = old.value("grad_steps", std::int64_t{0});
    episodes = old.value("episodes", std::int64_t{0});
    if (opt.progress) *opt.progress << "resuming " << m.algo << " at " << steps << " environment steps (replay buffer restarts empty)\n";
  }
  sync_target();
  write_file_atomic((dir / "config.toml").string(), to_toml(cfg));

  EpisodeBuffer buffer(m.buffer_episodes, Tm, N, D, S);
  std::vector<Recording> rec(static_cast<std::size_t>(M));
  auto record_slot = [&](int e) {
    auto& r = rec[static_cast<std::size_t>(e)];
    UavEnv& env = vec.env(e);
    for (int n = 0; n < N; ++n) {
      r.obs.resize(r.obs.size() + static_cast<std::size_t>(D));
      enc.write(env, n, r.obs.data() + r.obs.size() - static_cast<std::size_t>(D));
      r.mask.push_back(static_cast<float>(env.mask(n)));
      // The moves the target's argmax may pick at this slot: the reachability mask (the shield
      // depends on the other UAVs' choices, unknown to the target).
      const unsigned allowed = allowed_moves(env, n, safety);
      for (int a = 0; a < kActions; ++a) r.allow.push_back((allowed >> a & 1u) ? 1.0f : 0.0f);
    }
    const auto s = env.state();
    r.state.insert(r.state.end(), s.begin(), s.end());
    ++r.slots;
  };
  for (int e = 0; e < M; ++e) record_slot(e);
  auto push_episode = [&](Recording& r) {
    const int64_t i = buffer.next, slots = r.slots, trans = slots - 1;
    buffer.obs[i].zero_();
    buffer.state[i].zero_();
    buffer.mask[i].zero_();
    buffer.allow[i].fill_(1.0);
    buffer.act[i].fill_(static_cast<int64_t>(kStay));
    buffer.rew[i].zero_();
    buffer.done[i].zero_();
    buffer.valid[i].zero_();
    buffer.obs[i].narrow(0, 0, slots).copy_(torch::from_blob(r.obs.data(), {slots, N, D}));
    buffer.state[i].narrow(0, 0, slots).copy_(torch::from_blob(r.state.data(), {slots, S}));
    buffer.mask[i].narrow(0, 0, slots).copy_(torch::from_blob(r.mask.data(), {slots, N}));
    buffer.allow[i].narrow(0, 0, slots).copy_(torch::from_blob(r.allow.data(), {slots, N, kActions}));
    if (trans > 0) {
      buffer.act[i].narrow(0, 0, trans).copy_(torch::from_blob(r.act.data(), {trans, N}, torch::kInt64));
      buffer.rew[i].narrow(0, 0, trans).copy_(torch::from_blob(r.rew.data(), {trans}));
      buffer.done[i].narrow(0, 0, trans).copy_(torch::from_blob(r.done.data(), {trans}));
      buffer.valid[i].narrow(0, 0, trans).fill_(1.0);
    }
    buffer.next = (buffer.next + 1) % buffer.capacity;
    buffer.size = std::min(buffer.size + 1, buffer.capacity);
  };

  auto mix = [&](Nets& net, const torch::Tensor& q, const torch::Tensor& state) {  // q [B, T, N], state [B, T, S]
    if (!qmix) return q.sum(2);
    const auto B = q.size(0), T = q.size(1);
    return net.mixer(q.reshape({B * T, N}), state.reshape({B * T, S})).view({B, T});
  };
  Rng rng(derive_seed(cfg.run.seed, 0x51ULL, static_cast<std::uint64_t>(steps)));
  auto train_step = [&]() -> double {
    const int64_t B = std::min<int64_t>(m.batch_episodes, buffer.size);
    std::vector<int64_t> pick(static_cast<std::size_t>(B));
    for (auto& p : pick) p = static_cast<int64_t>(rng.below(static_cast<std::uint64_t>(buffer.size)));
    const auto idx = torch::tensor(pick, torch::kInt64);
    const auto obs = buffer.obs.index_select(0, idx).to(device);      // [B, Tm, N, D]
    const auto state = buffer.state.index_select(0, idx).to(device);  // [B, Tm, S]
    const auto mask = buffer.mask.index_select(0, idx).to(device);    // [B, Tm, N]
    const auto allow = buffer.allow.index_select(0, idx).to(device);  // [B, Tm, N, 5]
    const auto act = buffer.act.index_select(0, idx).to(device);      // [B, Tm-1, N]
    const auto rew = buffer.rew.index_select(0, idx).to(device);
    const auto done = buffer.done.index_select(0, idx).to(device);
    const auto valid = buffer.valid.index_select(0, idx).to(device);
    const auto q_all = nets.q(obs);                                   // [B, Tm, N, 5]
    const auto q_now = q_all.narrow(1, 0, Tm - 1).gather(3, act.unsqueeze(3)).squeeze(3) * mask.narrow(1, 0, Tm - 1);
    const auto q_tot = mix(nets, q_now, state.narrow(1, 0, Tm - 1));
    torch::Tensor y;
    {
      torch::NoGradGuard ng;
      const auto next_obs = obs.narrow(1, 1, Tm - 1);
      const auto a_star = masked_logits(q_all.detach().narrow(1, 1, Tm - 1), allow.narrow(1, 1, Tm - 1)).argmax(3, true);  // double Q: online argmax over allowed moves
      const auto q_next = target.q(next_obs).gather(3, a_star).squeeze(3) * mask.narrow(1, 1, Tm - 1);
      const auto q_tot_next = mix(target, q_next, state.narrow(1, 1, Tm - 1));
      y = rew + m.gamma * (1 - done) * q_tot_next;
    }
    const auto loss = ((q_tot - y).pow(2) * valid).sum() / torch::clamp_min(valid.sum(), 1.0);
    adam.zero_grad();
    loss.backward();
    if (m.grad_clip > 0) torch::nn::utils::clip_grad_norm_(params, m.grad_clip);
    adam.step();
    if (++grad_steps % m.target_update == 0) sync_target();
    return loss.item<double>();
  };

  const auto t_start = run.start;
  const std::int64_t start_steps = steps;
  std::unique_ptr<Progress> bar;
  const std::int64_t log_every = static_cast<std::int64_t>(M) * 256;
  if (opt.progress)
    bar = std::make_unique<Progress>(fmt::format("{} {} steps", m.algo, m.total_steps),
                                     static_cast<std::size_t>((m.total_steps - steps + log_every - 1) / log_every), *opt.progress, 10.0, 2.0);
  EpisodeStats stats;
  double loss_sum = 0;
  int loss_count = 0, new_episodes = 0;
  std::int64_t next_log = steps + log_every, updates = 0;
  while (steps < m.total_steps) {
    const double frac = std::min(1.0, static_cast<double>(steps) / std::max(1.0, m.epsilon_anneal * static_cast<double>(m.total_steps)));
    const double eps = m.epsilon_start + (m.epsilon_end - m.epsilon_start) * frac;
    std::vector<std::vector<int>> actions(static_cast<std::size_t>(M));
    {
      std::vector<float> in(static_cast<std::size_t>(M * N * D));
      for (int e = 0; e < M; ++e)
        for (int n = 0; n < N; ++n) enc.write(vec.env(e), n, in.data() + static_cast<std::size_t>((e * N + n) * D));
      torch::NoGradGuard ng;
      const auto q = nets.q(torch::from_blob(in.data(), {M * N, D}).to(device)).to(torch::kCPU).contiguous();
      const auto qa = q.accessor<float, 2>();
      for (int e = 0; e < M; ++e)
        // Epsilon-greedy over each UAV's allowed moves (mask and shield); arrived UAVs STAY.
        actions[static_cast<std::size_t>(e)] = sequential_safe_actions(vec.env(e), safety, [&](int n, unsigned allowed) {
          const int i = e * N + n;
          int count = 0, best = -1;
          for (int a = 0; a < kActions; ++a)
            if (allowed >> a & 1u) {
              ++count;
              if (best < 0 || qa[i][a] > qa[i][best]) best = a;
            }
          if (rng.uniform() >= eps) return best;
          int pick = static_cast<int>(rng.below(static_cast<std::uint64_t>(count)));
          for (int a = 0; a < kActions; ++a)
            if ((allowed >> a & 1u) && pick-- == 0) return a;
          return best;
        });
    }
    const auto infos = vec.step(actions);
    steps += M;
    for (int e = 0; e < M; ++e) {
      auto& r = rec[static_cast<std::size_t>(e)];
      for (int n = 0; n < N; ++n) r.act.push_back(actions[static_cast<std::size_t>(e)][static_cast<std::size_t>(n)]);
      r.rew.push_back(static_cast<float>(infos[static_cast<std::size_t>(e)].reward));
      r.done.push_back(infos[static_cast<std::size_t>(e)].done ? 1.0f : 0.0f);
      if (infos[static_cast<std::size_t>(e)].done) {
        // The environment already reset: the terminal slot is the last recorded one + 1; record
        // its observation as zeros (never bootstrapped: done = 1).
        r.obs.resize(r.obs.size() + static_cast<std::size_t>(N * D), 0.0f);
        r.state.resize(r.state.size() + static_cast<std::size_t>(S), 0.0f);
        r.mask.resize(r.mask.size() + static_cast<std::size_t>(N), 0.0f);
        r.allow.resize(r.allow.size() + static_cast<std::size_t>(N * kActions), 1.0f);
        ++r.slots;
        push_episode(r);
        r.clear();
        stats.add(infos[static_cast<std::size_t>(e)], N);
        ++episodes;
        ++new_episodes;
      }
      record_slot(e);
    }
    // One gradient step per M finished episodes once the buffer holds a batch.
    while (new_episodes >= M && buffer.size >= m.batch_episodes) {
      new_episodes -= M;
      loss_sum += train_step();
      ++loss_count;
    }
    if (steps >= next_log || steps >= m.total_steps) {
      next_log += log_every;
      ++updates;
      const double sps = static_cast<double>(steps - start_steps) /
                         std::max(std::chrono::duration<double>(Clock::now() - t_start).count(), 1e-9);
      metrics += metrics_row(cfg.run.seed, steps, stats, vdn_log(loss_count ? loss_sum / loss_count : 0.0, eps), sps);
      stats.clear();
      loss_sum = 0;
      loss_count = 0;
      if (updates % m.checkpoint_every == 0 || steps >= m.total_steps) run.checkpoint(meta(), learned, metrics);
      if (updates % m.checkpoint_every == 0 && steps < m.total_steps) run.validate(cfg, opt, meta(), learned, steps);
      if (bar) bar->advance();
    }
  }
  if (bar) bar->finish();
  return run.finish(cfg, opt, meta(), learned, metrics, steps, start_steps);
}

}  // namespace skyloop::marl
