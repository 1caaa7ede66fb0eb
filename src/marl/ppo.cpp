// MAPPO and IPPO (Section V, Algorithm alg:mappo_training) on one PPO core (ppo.hpp). They
// differ only in the critic's input: MAPPO's centralised critic sees the global state (or the
// agent-specific global state), IPPO's sees the agent's local observation. Here: the critic's
// input, the three phases (collect, advantages, update) and the learner; the losses are in
// ppo_loss.cpp, the networks in ppo_networks.cpp.
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
#include "skyloop/env/vec_env.hpp"
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
  else r.input = cfg.marl.critic_state == CriticState::Global ? Input::GlobalState : Input::AgentState;
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

/// One rollout's collection (collect, ppo.hpp): what its phases share, each phase a method. A
/// lane touches only its environments' rows, their oracles and their sampling streams.
class Collector {
 public:
  Collector(VecEnv& vec, const Encoder& encoder, const CriticReader& critic, const SafetyOptions& safety, PpoNetworks& nets,
            const RunningStats& value_norm, Rng& rng, Rollout& r, int threads)
      : vec_(vec), encoder_(encoder), critic_(critic), safety_(safety), nets_(nets), value_norm_(value_norm), r_(r),
        M_(r.M), N_(r.N), A_(r.A), C_(r.C), width_(r.C > 0 ? 2 * r.C : r.A),
        // marl.sequential: each agent's observation is written just before it chooses, in its lane; with
        // an oracle the environments share, the lanes then run one after another.
        sequential_(encoder.sequential && r.C == 0),
        // Observations that ask a rate oracle the environments share (its memo) are written on the
        // calling thread first; everything else a lane does touches its own environments and rows.
        encode_in_lanes_(encoder.threads > 1 && !(encoder.asks_oracle && vec.shares_oracle())),
        lane_threads_(sequential_ && encoder.asks_oracle && vec.shares_oracle()
                          ? 1
                          : std::min({resolve_threads(threads), nets.lanes(), kCollectLanes})),
        logits_(static_cast<std::size_t>(M_) * N_ * static_cast<std::size_t>(width_)),
        actions_(static_cast<std::size_t>(M_), std::vector<int>(static_cast<std::size_t>(N_))),
        next_(static_cast<std::size_t>(M_)), infos_(static_cast<std::size_t>(M_)),
        // marl.sequential_passes: each lane's row for the observation and logits of a pass not trained on.
        scratch_rows_(sequential_ && encoder.passes > 1 ? kCollectLanes * (static_cast<std::size_t>(r.obs_width) + r.A) : 0) {
    if (r.critic_observation != critic.observation_width(vec.env(0)) || r.critic_width != critic.width(vec.env(0)))
      throw std::logic_error("collect: the rollout's critic input is not the critic reader's");
    streams_.reserve(static_cast<std::size_t>(M_));  // environment e samples from streams_[e] alone
    for (int e = 0; e < M_; ++e) streams_.emplace_back(rng.next());
  }

  /// Slot t: every environment's observations, the networks' passes, its sampled moves and its
  /// step, then the oracles' batch of the rest and the rewards.
  void slot(int t, EpisodeStats& stats) {
    t_ = t;
    obs_ = r_.observations.data() + r_.at(t, 0, 0) * static_cast<std::size_t>(r_.obs_width);
    crit_ = r_.critic_inputs.data() + r_.at(t, 0, 0) * static_cast<std::size_t>(r_.critic_own());
    values_ = r_.values.data() + r_.at(t, 0, 0);
    if (!encode_in_lanes_)
      for (int e = 0; e < M_; ++e) encode(e);
    parallel_for(kCollectLanes, lane_threads_, [&](std::size_t lane) { run_lane(lane); });
    const auto done = vec_.finish(next_, infos_);
    for (int e = 0; e < M_; ++e) {
      const auto& info = done[static_cast<std::size_t>(e)];
      r_.rewards[static_cast<std::size_t>(t) * M_ + static_cast<std::size_t>(e)] = static_cast<float>(info.reward);
      r_.dones[static_cast<std::size_t>(t) * M_ + static_cast<std::size_t>(e)] = info.done ? 1.0f : 0.0f;
      if (info.done) stats.add(info, N_);
    }
  }

  /// The bootstrap values of the states after the rollout.
  void bootstrap() {
    const std::size_t step_rows = static_cast<std::size_t>(M_) * N_;
    std::vector<float> last_obs(step_rows * static_cast<std::size_t>(r_.critic_observation)),
        crit(step_rows * static_cast<std::size_t>(r_.critic_own()));
    for (int e = 0; e < M_; ++e)
      for (int n = 0; n < N_; ++n) {
        const auto i = static_cast<std::size_t>(e * N_ + n);
        if (r_.critic_observation > 0)
          encoder_.write(vec_.env(e), n, last_obs.data() + i * static_cast<std::size_t>(r_.critic_observation));
        critic_.write_own(vec_.env(e), n, crit.data() + i * static_cast<std::size_t>(r_.critic_own()));
      }
    nets_.values(last_obs.data(), crit.data(), static_cast<int>(step_rows), r_.next_values.data());
    for (auto& v : r_.next_values) v = static_cast<float>(value_norm_.denormalise(v));
  }

 private:
  float* obs_row(int e, int n) const { return obs_ + static_cast<std::size_t>(e * N_ + n) * static_cast<std::size_t>(r_.obs_width); }
  float* crit_row(int e, int n) const { return crit_ + static_cast<std::size_t>(e * N_ + n) * static_cast<std::size_t>(r_.critic_own()); }
  float* logits_row(int e, int n) { return logits_.data() + static_cast<std::size_t>(e * N_ + n) * static_cast<std::size_t>(width_); }

  /// Environment e's rows of the slot before its agents choose (all of them unless sequential).
  void encode(int e) {
    for (int n = 0; n < N_; ++n) {
      if (!sequential_) {
        encoder_.write(vec_.env(e), n, obs_row(e, n));
        critic_.write_own(vec_.env(e), n, crit_row(e, n));
      }
      r_.active[r_.at(t_, e, n)] = static_cast<float>(vec_.env(e).mask(n));
      r_.logprobs[r_.at(t_, e, n)] = 0.0f;  // agents that STAY without sampling (arrived) keep these
      std::fill_n(r_.allowed.data() + r_.at(t_, e, n) * A_, A_, 1.0f);
    }
  }

  /// The critic's values of rows [row, row + rows), denormalised.
  void critic_values(std::size_t row, int rows, int lane) {
    nets_.values(obs_ + row * static_cast<std::size_t>(r_.obs_width), crit_ + row * static_cast<std::size_t>(r_.critic_own()), rows,
                 values_ + row, lane);
    for (std::size_t i = row; i < row + static_cast<std::size_t>(rows); ++i)
      values_[i] = static_cast<float>(value_norm_.denormalise(values_[i]));
  }

  /// Lane `lane`: its fixed, contiguous group of environments, observed, sampled and moved.
  void run_lane(std::size_t lane) {
    const int first = static_cast<int>(static_cast<std::size_t>(M_) * lane / kCollectLanes);
    const int last = static_cast<int>(static_cast<std::size_t>(M_) * (lane + 1) / kCollectLanes);
    if (first == last) return;
    if (encode_in_lanes_)
      for (int e = first; e < last; ++e) encode(e);
    const std::size_t row = static_cast<std::size_t>(first) * N_;
    const int rows = (last - first) * N_;
    if (!sequential_) {
      nets_.logits(obs_ + row * static_cast<std::size_t>(r_.obs_width), rows, logits_.data() + row * static_cast<std::size_t>(width_),
                   static_cast<int>(lane));
      critic_values(row, rows, static_cast<int>(lane));
    }
    for (int e = first; e < last; ++e) {
      infos_[static_cast<std::size_t>(e)] = StepInfo{};
      if (C_ > 0) fly_commands(e);
      else fly_moves(e, lane);
    }
    if (sequential_) critic_values(row, rows, static_cast<int>(lane));
  }

  /// Continuous mobility: each active UAV draws z ~ N(mu, sigma^2) per dimension and commands
  /// u = tanh(z) (ppo.hpp); the safety layer may fly another velocity. Arrived UAVs hover.
  void fly_commands(int e) {
    const auto ee = static_cast<std::size_t>(e);
    Rng& draw = streams_[ee];
    UavEnv& env = vec_.env(e);
    Positions wanted = Positions::Zero(N_, 2);
    for (int n = 0; n < N_; ++n) {
      const std::size_t i = r_.at(t_, e, n);
      float* raw = r_.raw_actions.data() + i * static_cast<std::size_t>(C_);
      std::fill_n(raw, C_, 0.0f);
      if (env.arrived(n)) continue;
      const float* o = logits_row(e, n);
      double logp = 0, u[2] = {0, 0};
      for (int k = 0; k < C_; ++k) {
        const double ls = std::min(std::max(static_cast<double>(o[C_ + k]), kLogStdMin), kLogStdMax);
        const float z = static_cast<float>(o[k] + std::exp(ls) * draw.normal());
        raw[k] = z;
        logp += squashed_gaussian_logprob(z, o[k], o[C_ + k]);
        u[k] = std::tanh(static_cast<double>(z));
      }
      r_.logprobs[i] = static_cast<float>(logp);
      env.command_velocity(n, u[0], u[1], wanted(n, 0), wanted(n, 1));
    }
    next_[ee] = vec_.begin_velocities(e, safe_velocities(env, safety_, wanted), infos_[ee]);
    vec_.settle(e, next_[ee], infos_[ee]);
  }

  /// Agent n's move drawn from its policy restricted to `allowed`, recorded for training.
  int record(int e, int n, ActionSet allowed, const float* z) {
    const std::size_t i = r_.at(t_, e, n);
    for (int k = 0; k < A_; ++k) r_.allowed[i * A_ + static_cast<std::size_t>(k)] = (allowed >> k & 1u) ? 1.0f : 0.0f;
    double logp = 0;
    const int a = sample_allowed(z, allowed, A_, streams_[static_cast<std::size_t>(e)], logp);
    r_.logprobs[i] = static_cast<float>(logp);
    return a;
  }

  /// Lattice moves: each UAV samples among its allowed moves (the reachability mask and the shield
  /// against the UAVs already placed); arrived agents STAY. Under marl.sequential each agent is
  /// observed just before it chooses, with the landings chosen before it (and with
  /// marl.sequential_passes, the others' moves of the pass before); the last pass is trained on.
  void fly_moves(int e, std::size_t lane) {
    const auto ee = static_cast<std::size_t>(e);
    UavEnv& env = vec_.env(e);
    if (sequential_) {
      float* intention = scratch_rows_.empty() ? nullptr : scratch_rows_.data() + lane * (static_cast<std::size_t>(r_.obs_width) + A_);
      actions_[ee] = take_turns(env, safety_, encoder_.passes, [&](int n, ActionSet allowed, bool flown) {
        float* o = flown ? obs_row(e, n) : intention;
        float* z = flown ? logits_.data() + static_cast<std::size_t>(e * N_ + n) * A_ : intention + r_.obs_width;
        encoder_.write(env, n, o);
        nets_.logits(o, 1, z, static_cast<int>(lane));
        if (flown) return record(e, n, allowed, z);
        double logp = 0;
        return sample_allowed(z, allowed, A_, streams_[ee], logp);
      });
      // the rows no agent chose from (arrived UAVs), then the critic's inputs
      for (int n = 0; n < N_; ++n)
        if (env.arrived(n)) encoder_.write(env, n, obs_row(e, n));
      env.clear_decided();
      for (int n = 0; n < N_; ++n) critic_.write_own(env, n, crit_row(e, n));
    } else {
      actions_[ee] = sequential_safe_actions(env, safety_, [&](int n, ActionSet allowed) {
        return record(e, n, allowed, logits_.data() + static_cast<std::size_t>(e * N_ + n) * A_);
      });
    }
    for (int n = 0; n < N_; ++n) r_.actions[r_.at(t_, e, n)] = actions_[ee][static_cast<std::size_t>(n)];
    next_[ee] = vec_.begin(e, actions_[ee], infos_[ee]);
    vec_.settle(e, next_[ee], infos_[ee]);  // its step ends here when its oracle knows every rate
  }

  VecEnv& vec_;
  const Encoder& encoder_;
  const CriticReader& critic_;
  const SafetyOptions& safety_;
  PpoNetworks& nets_;
  const RunningStats& value_norm_;
  Rollout& r_;
  const int M_, N_, A_, C_, width_;  // environments, agents, actions, command dimensions, actor outputs
  const bool sequential_, encode_in_lanes_;
  const int lane_threads_;
  std::vector<float> logits_;
  std::vector<Rng> streams_;
  std::vector<std::vector<int>> actions_;
  std::vector<Positions> next_;
  std::vector<StepInfo> infos_;
  std::vector<float> scratch_rows_;
  int t_ = 0;  // the slot, and its rows of the rollout
  float* obs_ = nullptr;
  float* crit_ = nullptr;
  float* values_ = nullptr;
};

}  // namespace

void collect(VecEnv& vec, const Encoder& encoder, const CriticReader& critic, const SafetyOptions& safety, PpoNetworks& nets,
             const RunningStats& value_norm, Rng& rng, Rollout& r, EpisodeStats& stats, int threads) {
  Collector c(vec, encoder, critic, safety, nets, value_norm, rng, r, threads);
  for (int t = 0; t < r.T; ++t) c.slot(t, stats);
  c.bootstrap();
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
  const int group = m.minibatch == MinibatchLayout::Steps ? r.N : 1;
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
    C = v.env(0).dynamics().actions().dims, A = C > 0 ? 0 : v.env(0).actions();
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
                          {"obs_dim", obs_width}, {"encoder", name_of(m.encoder)}, {"backend", name_of(m.backend)},
                          {"mobility", cfg.trajectory.mobility}, {"actions", vec.env(0).dynamics().actions().names},
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
