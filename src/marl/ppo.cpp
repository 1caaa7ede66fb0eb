// MAPPO and IPPO (Section V, Algorithm alg:mappo_training) on one PPO core. They differ only in
// the critic's input: MAPPO's centralised critic sees the global state (or the agent-specific
// global state), IPPO's sees the agent's local observation.
#include <filesystem>
#include <fmt/format.h>
#include <numeric>
#include <ostream>

#include "common.hpp"
#include "skyloop/core/config_io.hpp"
#include "skyloop/core/error.hpp"
#include "skyloop/core/io.hpp"
#include "skyloop/core/progress.hpp"
#include "skyloop/core/rng.hpp"
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

namespace {

/// The critic's input. mlp encoder: the global state (MAPPO, critic_state = global), the
/// agent-specific global state (agent) or the local observation (IPPO). set encoder: the agent's
/// set observation, plus the compact state for MAPPO.
struct CriticInput {
  std::string kind;  // global | agent | local
  Encoder set;       // set.set: the set observation
  int extra(const UavEnv&) const { return set.set && kind != "local" ? UavEnv::compact_state_size() : 0; }
  int size(const UavEnv& e) const {
    if (set.set) return set.width(e) + extra(e);
    return kind == "global" ? e.state_size() : kind == "agent" ? e.agent_state_size() : UavEnv::observation_size();
  }
  void write(const UavEnv& e, int n, float* out) const {
    if (set.set) {
      set.write(e, n, out);
      if (extra(e)) e.write_compact_state(out + set.width(e));
      return;
    }
    if (kind == "global") e.write_state(out);
    else if (kind == "agent") e.write_agent_state(n, out);
    else e.write_observation(n, out);
  }
};

}  // namespace

MarlTrainResult train_ppo(const Config& cfg, const MarlTrainOptions& opt) {
  namespace fs = std::filesystem;
  using Clock = std::chrono::steady_clock;
  const auto& m = cfg.marl;
  Run run(cfg, opt);
  const auto& dir = run.dir;
  const auto& device = run.device;
  VecEnv& vec = run.vec;
  const Encoder enc = encoder_of(cfg, false);
  const SafetyOptions safety = safety_of(cfg);
  const int N = vec.env(0).uavs(), M = vec.size(), obs_dim = enc.width(vec.env(0));
  const CriticInput critic_in{m.algo == "ippo" ? "local" : m.critic_state, enc};
  const int cin = critic_in.size(vec.env(0));

  torch::manual_seed(cfg.run.seed);
  Nets nets;
  nets.actor = MlpNet(obs_dim, m.hidden, kActions);
  nets.critic = MlpNet(cin, m.hidden, 1);
  nets.actor->to(device);
  nets.critic->to(device);
  std::vector<torch::Tensor> params = nets.actor->parameters();
  for (auto& p : nets.critic->parameters()) params.push_back(p);
  torch::optim::Adam adam(params, torch::optim::AdamOptions(m.learning_rate));
  RunningStats vnorm;

  std::int64_t steps = 0, updates = 0;
  std::string metrics = metrics_header();
  auto meta = [&] {
    return nlohmann::json{{"format", kFormat}, {"version", kVersion}, {"algo", m.algo}, {"uavs", N},
                          {"obs_dim", obs_dim}, {"encoder", m.encoder},
                          {"critic_input", critic_in.kind}, {"critic_dim", cin},
                          {"hidden", m.hidden}, {"env_steps", steps}, {"updates", updates},
                          {"value_mean", vnorm.mean}, {"value_var", vnorm.var}, {"value_count", vnorm.count},
                          {"config", to_toml(cfg)}};
  };
  if (opt.resume) {
    const auto old = run.resume(cfg, "critic_dim", cin, nets, adam, metrics);
    steps = old.value("env_steps", std::int64_t{0});
    updates = old.value("updates", std::int64_t{0});
    vnorm.mean = old.value("value_mean", 0.0);
    vnorm.var = old.value("value_var", 1.0);
    vnorm.count = old.value("value_count", 1e-4);
    if (opt.progress) *opt.progress << "resuming " << m.algo << " at " << steps << " environment steps\n";
  }
  write_file_atomic((dir / "config.toml").string(), to_toml(cfg));

  const int T = m.rollout;
  const std::int64_t per_update = static_cast<std::int64_t>(T) * M;
  const auto t_start = run.start;
  const std::int64_t start_steps = steps;
  std::unique_ptr<Progress> bar;
  if (opt.progress)
    bar = std::make_unique<Progress>(fmt::format("{} {} steps", m.algo, m.total_steps),
                                     static_cast<std::size_t>((m.total_steps - steps + per_update - 1) / per_update), *opt.progress, 10.0, 2.0);
  EpisodeStats stats;
  double last_pl = 0, last_vl = 0, last_ent = 0;

  while (steps < m.total_steps) {
    Rng rng(derive_seed(cfg.run.seed, 0x50504fULL, static_cast<std::uint64_t>(updates)));
    // ---- rollout -----------------------------------------------------------------------------
    std::vector<float> obs_buf, crit_buf;
    obs_buf.reserve(static_cast<std::size_t>(T * M * N * obs_dim));
    crit_buf.reserve(static_cast<std::size_t>(T * M * N * cin));
    std::vector<int64_t> act_buf;
    std::vector<float> logp_buf, mask_buf, allow_buf, val_buf, rew_buf, done_buf;
    std::vector<float> obs(static_cast<std::size_t>(M * N * obs_dim)), crit(static_cast<std::size_t>(M * N * cin));
    for (int t = 0; t < T; ++t) {
      std::vector<float> mask;
      for (int e = 0; e < M; ++e)
        for (int n = 0; n < N; ++n) {
          const auto i = static_cast<std::size_t>(e * N + n);
          enc.write(vec.env(e), n, obs.data() + i * static_cast<std::size_t>(obs_dim));
          critic_in.write(vec.env(e), n, crit.data() + i * static_cast<std::size_t>(cin));
          mask.push_back(static_cast<float>(vec.env(e).mask(n)));
        }
      torch::Tensor logits, values;
      {
        torch::NoGradGuard ng;
        logits = nets.actor(torch::from_blob(obs.data(), {M * N, obs_dim}).to(device)).to(torch::kCPU).contiguous();
        values = vnorm.denormalise(nets.critic(torch::from_blob(crit.data(), {M * N, cin}).to(device)).to(torch::kCPU)).view({M * N});
      }
      auto la = logits.accessor<float, 2>();
      const auto values_c = values.contiguous();
      auto va = values_c.accessor<float, 1>();  // not values[i].item(): one tensor per agent and step
      std::vector<std::vector<int>> actions(static_cast<std::size_t>(M));
      std::vector<float> allow(static_cast<std::size_t>(M * N * kActions), 1.0f), logp(static_cast<std::size_t>(M * N), 0.0f);
      for (int e = 0; e < M; ++e) {
        // Each UAV samples from its policy restricted to its allowed moves (the reachability
        // mask and the shield against the UAVs already placed); arrived agents STAY.
        actions[static_cast<std::size_t>(e)] = sequential_safe_actions(vec.env(e), safety, [&](int n, unsigned allowed) {
          const int i = e * N + n;
          double mx = -1e30;
          for (int k = 0; k < kActions; ++k)
            if (allowed >> k & 1u) mx = std::max(mx, static_cast<double>(la[i][k]));
          double z = 0;
          for (int k = 0; k < kActions; ++k)
            if (allowed >> k & 1u) z += std::exp(static_cast<double>(la[i][k]) - mx);
          double u = rng.uniform() * z, acc = 0;
          int a = -1;
          for (int k = 0; k < kActions; ++k) {
            allow[static_cast<std::size_t>(i * kActions + k)] = (allowed >> k & 1u) ? 1.0f : 0.0f;
            if (!(allowed >> k & 1u)) continue;
            acc += std::exp(static_cast<double>(la[i][k]) - mx);
            if (a < 0 && u < acc) a = k;
          }
          if (a < 0)
            for (int k = kActions; k-- > 0;)
              if (allowed >> k & 1u) { a = k; break; }
          logp[static_cast<std::size_t>(i)] = static_cast<float>(static_cast<double>(la[i][a]) - mx - std::log(z));
          return a;
        });
      }
      for (int i = 0; i < M * N; ++i) {
        const int a = actions[static_cast<std::size_t>(i / N)][static_cast<std::size_t>(i % N)];
        act_buf.push_back(a);
        logp_buf.push_back(logp[static_cast<std::size_t>(i)]);
        val_buf.push_back(va[i]);
      }
      obs_buf.insert(obs_buf.end(), obs.begin(), obs.end());
      crit_buf.insert(crit_buf.end(), crit.begin(), crit.end());
      mask_buf.insert(mask_buf.end(), mask.begin(), mask.end());
      allow_buf.insert(allow_buf.end(), allow.begin(), allow.end());
      const auto infos = vec.step(actions);
      for (int e = 0; e < M; ++e) {
        rew_buf.push_back(static_cast<float>(infos[static_cast<std::size_t>(e)].reward));
        done_buf.push_back(infos[static_cast<std::size_t>(e)].done ? 1.0f : 0.0f);
        if (infos[static_cast<std::size_t>(e)].done) stats.add(infos[static_cast<std::size_t>(e)], N);
      }
    }
    steps += per_update;
    // Bootstrap values of the states after the rollout.
    std::vector<float> crit_last(static_cast<std::size_t>(M * N * cin));
    for (int e = 0; e < M; ++e)
      for (int n = 0; n < N; ++n) critic_in.write(vec.env(e), n, crit_last.data() + static_cast<std::size_t>((e * N + n) * cin));
    torch::Tensor v_last;
    {
      torch::NoGradGuard ng;
      v_last = vnorm.denormalise(nets.critic(torch::from_blob(crit_last.data(), {M * N, cin}).to(device)).to(torch::kCPU)).view({M * N});
    }
    const auto v_last_c = v_last.contiguous();
    const auto v_last_a = v_last_c.accessor<float, 1>();
    // ---- GAE per (environment, agent), with the team reward ------------------------------------
    std::vector<float> adv_buf(static_cast<std::size_t>(T * M * N)), ret_buf(adv_buf.size());
    for (int e = 0; e < M; ++e)
      for (int n = 0; n < N; ++n) {
        std::vector<double> r(static_cast<std::size_t>(T)), v(static_cast<std::size_t>(T + 1));
        std::vector<int> d(static_cast<std::size_t>(T));
        for (int t = 0; t < T; ++t) {
          r[static_cast<std::size_t>(t)] = rew_buf[static_cast<std::size_t>(t * M + e)];
          d[static_cast<std::size_t>(t)] = done_buf[static_cast<std::size_t>(t * M + e)] > 0;
          v[static_cast<std::size_t>(t)] = val_buf[static_cast<std::size_t>((t * M + e) * N + n)];
        }
        v[static_cast<std::size_t>(T)] = v_last_a[e * N + n];
        const auto a = gae(r, v, d, m.gamma, m.gae_lambda);
        for (int t = 0; t < T; ++t) {
          const auto i = static_cast<std::size_t>((t * M + e) * N + n);
          adv_buf[i] = static_cast<float>(a[static_cast<std::size_t>(t)]);
          ret_buf[i] = static_cast<float>(a[static_cast<std::size_t>(t)] + v[static_cast<std::size_t>(t)]);
        }
      }
    const int64_t B = static_cast<int64_t>(T) * M * N;
    const auto obs_t = torch::from_blob(obs_buf.data(), {B, obs_dim}).clone().to(device);
    const auto crit_t = torch::from_blob(crit_buf.data(), {B, cin}).clone().to(device);
    const auto act_t = torch::tensor(act_buf, torch::kInt64).to(device);
    const auto logp_t = torch::from_blob(logp_buf.data(), {B}).clone().to(device);
    const auto mask_t = torch::from_blob(mask_buf.data(), {B}).clone().to(device);
    const auto allow_t = torch::from_blob(allow_buf.data(), {B, kActions}).clone().to(device);
    auto adv_t = torch::from_blob(adv_buf.data(), {B}).clone().to(device);
    auto ret_t = torch::from_blob(ret_buf.data(), {B}).clone().to(device);
    auto vold_t = torch::from_blob(val_buf.data(), {B}).clone().to(device);
    // Advantages normalised over the active agents; value targets in normalised units.
    {
      const auto mean = masked_mean(adv_t, mask_t);
      const auto var = masked_mean((adv_t - mean).pow(2), mask_t);
      adv_t = (adv_t - mean) / torch::sqrt(var + 1e-8);
    }
    if (m.value_norm) vnorm.update(ret_t.to(torch::kCPU));
    const auto ret_n = m.value_norm ? vnorm.normalise(ret_t) : ret_t;
    const auto vold_n = m.value_norm ? vnorm.normalise(vold_t) : vold_t;
    // ---- PPO epochs ----------------------------------------------------------------------------
    double pl = 0, vl = 0, ent = 0;
    int count = 0;
    const int64_t mb = std::max<int64_t>(1, B / m.minibatches);
    for (int epoch = 0; epoch < m.epochs; ++epoch) {
      std::vector<int64_t> perm(static_cast<std::size_t>(B));
      std::iota(perm.begin(), perm.end(), 0);
      for (std::size_t i = perm.size(); i > 1; --i) std::swap(perm[i - 1], perm[rng.below(i)]);
      const auto perm_t = torch::tensor(perm, torch::kInt64).to(device);
      for (int64_t first = 0; first + mb <= B; first += mb) {
        const auto idx = perm_t.narrow(0, first, mb);
        const auto logp_all = torch::log_softmax(masked_logits(nets.actor(obs_t.index_select(0, idx)), allow_t.index_select(0, idx)), 1);
        const auto logp = logp_all.gather(1, act_t.index_select(0, idx).unsqueeze(1)).squeeze(1);
        const auto entropy = -(logp_all.exp() * logp_all).sum(1);
        const auto mk = mask_t.index_select(0, idx);
        const auto actor_loss = -masked_mean(clipped_surrogate(logp, logp_t.index_select(0, idx), adv_t.index_select(0, idx), m.clip), mk);
        const auto v = nets.critic(crit_t.index_select(0, idx)).view({mb});
        const auto critic_loss = clipped_value_loss(v, vold_n.index_select(0, idx), ret_n.index_select(0, idx), m.clip);
        const auto ent_mean = masked_mean(entropy, mk);
        const auto loss = actor_loss + m.value_coef * critic_loss - m.entropy_coef * ent_mean;  // eq:total_loss
        adam.zero_grad();
        loss.backward();
        if (m.grad_clip > 0) torch::nn::utils::clip_grad_norm_(params, m.grad_clip);
        adam.step();
        pl += actor_loss.item<double>();
        vl += critic_loss.item<double>();
        ent += ent_mean.item<double>();
        ++count;
      }
    }
    ++updates;
    last_pl = pl / std::max(1, count), last_vl = vl / std::max(1, count), last_ent = ent / std::max(1, count);
    const double elapsed = std::chrono::duration<double>(Clock::now() - t_start).count();
    const double sps = static_cast<double>(steps - start_steps) / std::max(elapsed, 1e-9);
    if (stats.episodes > 0 || steps >= m.total_steps) {
      metrics += metrics_row(cfg.run.seed, steps, stats, last_pl, last_vl, last_ent, 0.0, sps);
      stats.clear();
    }
    if (updates % m.checkpoint_every == 0 || steps >= m.total_steps) run.checkpoint(meta(), nets, adam, metrics);
    if (updates % m.checkpoint_every == 0 && steps < m.total_steps) run.validate(cfg, opt, meta(), nets, steps);
    if (bar) bar->advance();
  }
  if (bar) bar->finish();
  return run.finish(cfg, opt, meta(), nets, adam, metrics, steps, start_steps);
}

}  // namespace marl
}  // namespace skyloop
