#pragma once
// The PPO core behind MAPPO and IPPO (Section V, Algorithm alg:mappo_training), in the shape of
// CleanRL's ppo.py: a rollout storage shaped [T, M, N, ...], and three named phases
//
//   collect(...)             T steps of M environments, N agents each, with the current policy
//   compute_advantages(...)  GAE per (environment, agent) with the team reward
//   update(...)              marl.epochs passes of marl.minibatches clipped PPO steps
//
// over a PpoNetworks (actor, critic and their optimiser) that has two backends: "fast", the fused
// float32 forward and backward passes of fast_mlp.hpp (the default), and "torch", LibTorch's
// autograd (the reference, and the path for nn.device = cuda). marl.backend chooses.
#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "common.hpp"
#include "skyloop/core/rng.hpp"
#include "skyloop/env/vec_env.hpp"

namespace skyloop::marl {

/// What the critic reads, resolved once from marl.algo / marl.critic_state / marl.encoder.
/// mlp encoder: the global state (MAPPO, critic_state = global), the agent-specific global state
/// (agent) or the local observation (IPPO). set encoder: the agent's set observation, plus the
/// compact state for MAPPO.
struct CriticReader {
  enum class Input { GlobalState, AgentState, LocalObservation };
  Input input = Input::AgentState;
  Encoder encoder;
  static CriticReader of(const Config& cfg, const Encoder& encoder);
  const char* name() const;  // global | agent | local (the policy header's critic_input)
  int width(const UavEnv& env) const;
  /// The critic's first input columns that are the actor's own input row (its observation), read
  /// from there rather than stored twice: the whole set observation under the set encoder, else 0.
  int observation_width(const UavEnv& env) const;
  /// The critic's columns past observation_width() (its input is agent n's observation, as the
  /// actor reads it, then these): the compact state under the set encoder (nothing for IPPO),
  /// else the whole input.
  void write_own(const UavEnv& env, int n, float* out) const;
  /// Whether write_own writes the same columns for every agent of a step (the compact state
  /// under the set encoder), which marl.minibatch = steps lets a learner compute once per step.
  bool shared_by_step() const;
};

/// One rollout: T steps of M environments with N agents. Per-agent arrays are [T, M, N, ...]
/// row-major (index at(t, e, n)), per-environment ones [T, M].
struct Rollout {
  /// `dims` > 0: continuous actions of that size (the squashed Gaussian policy), `actions` = 0.
  /// The critic reads critic_width columns: the first critic_observation of them (0 or obs_width)
  /// are the row's observation, the rest its critic_inputs.
  Rollout(int steps, int envs, int agents, int obs_width, int critic_width, int actions = kGridActions, int dims = 0,
          int critic_observation = 0);
  int T, M, N, obs_width, critic_width, A;  // A: the mobility model's actions (0 when continuous)
  int C = 0;                           // continuous: the command's size
  int critic_observation = 0;          // the critic's leading columns read from observations
  int critic_own() const { return critic_width - critic_observation; }
  bool critic_shared = false;          // critic_inputs are the same for every agent of a step (CriticReader::shared_by_step)
  std::vector<float> raw_actions;      // [T, M, N, C]: the Gaussian sample z before tanh (continuous)
  std::vector<float> observations;     // [T, M, N, obs_width]: what the actor read
  std::vector<float> critic_inputs;    // [T, M, N, critic_own()]: the critic's own columns
  std::vector<std::int64_t> actions;   // [T, M, N]
  std::vector<float> logprobs;         // [T, M, N]: log pi_old(a | o) among the allowed moves
  std::vector<float> values;           // [T, M, N]: V_old (denormalised)
  std::vector<float> active;           // [T, M, N]: 1 while the UAV has not arrived
  std::vector<float> allowed;          // [T, M, N, A]: 1 for the moves the UAV could take
  std::vector<float> rewards, dones;   // [T, M]: team reward, 1 when the episode ended with the step
  std::vector<float> next_values;      // [M, N]: V of the state after the last step (bootstrap)
  std::vector<float> advantages;       // [T, M, N] (compute_advantages)
  std::vector<float> returns;          // [T, M, N] = advantages + values
  std::size_t at(int t, int e, int n) const {
    return (static_cast<std::size_t>(t) * M + static_cast<std::size_t>(e)) * N + static_cast<std::size_t>(n);
  }
  std::size_t samples() const { return static_cast<std::size_t>(T) * M * N; }
  /// The bytes a rollout of these sizes holds, with one minibatch of it gathered (update's scratch);
  /// critic_own: the critic's columns stored besides the observation.
  static double bytes(int steps, int envs, int agents, int obs_width, int critic_own, int actions, int dims, int minibatches);
};

/// Minibatch rows gathered contiguously from a rollout (advantages normalised, returns and old
/// values in the critic's normalised units).
struct Minibatch {
  int rows = 0, obs_width = 0, critic_width = 0, action_count = kGridActions;
  int dims = 0;  // continuous: the command's size; the actor's output is then [mean (dims), log std (dims)]
  /// The critic's input row: its first critic_observation columns (0 or obs_width) are the row's
  /// observation, the rest the row of critic_inputs [rows x critic_own()].
  int critic_observation = 0;
  int critic_own() const { return critic_width - critic_observation; }
  /// share = s > 1: the rows come in runs of s, the agents of one step, whose critic_inputs rows
  /// are equal (the state they share; marl.minibatch = steps): a backend may compute that part
  /// of the critic once per run. 1: rows independent.
  int share = 1;
  std::vector<float> observations, critic_inputs, logprobs, advantages, returns, values, active, allowed, raw_actions;
  std::vector<std::int64_t> actions;
  /// Rows written on demand (update() sets it): fill(first, last) writes rows [first, last) of
  /// every array above, and active_sum holds the sum of `active` over the rows in row order. A
  /// backend's step fills each range of rows just before it reads them, on the thread that reads
  /// them, so a row goes from the rollout to the forward pass through that core's cache. Rows are
  /// independent: any split writes the same arrays. Unset (empty): every row is already there.
  std::function<void(int first, int last)> fill;
  double active_sum = 0;
  /// Rows [first, last) are there once this returns.
  void ready(int first, int last) {
    if (fill) fill(first, last);
  }
};

struct PpoSettings {
  double clip = 0.2, value_coef = 0.5, entropy_coef = 0.01, grad_clip = 10.0;
};

/// One gradient step's statistics (CleanRL's names: losses/policy_loss, losses/value_loss,
/// losses/entropy, losses/old_approx_kl, losses/approx_kl, losses/clipfrac), and the global
/// gradient norm before clipping. Policy terms are means over active agents.
struct UpdateStats {
  double policy_loss = 0, value_loss = 0, entropy = 0, old_approx_kl = 0, approx_kl = 0, clipfrac = 0, grad_norm = 0;
  void add(const UpdateStats& o, double w);
};

/// The squashed Gaussian policy of continuous actions (the continuous mobility model): the actor
/// outputs a mean mu and a log standard deviation (clamped to [kLogStdMin, kLogStdMax]) per
/// dimension; z ~ N(mu, sigma^2), the command u = tanh(z) in (-1, 1). Its log-probability with
/// the change of variables: log pi(u) = sum_k [log N(z_k; mu_k, sigma_k) - log(1 - tanh(z_k)^2)],
/// log(1 - tanh(z)^2) = 2 (log 2 - z - softplus(-2 z)) (stable for large |z|). PPO's ratio uses z, as
/// stored. The entropy bonus is the squashed distribution's, H = E[-log pi(u)] = sum_k (log sigma_k +
/// (1 + log 2 pi) / 2 + E[log(1 - tanh(z_k)^2)]), estimated at each stored sample written as
/// z = mu + sigma e with e = (z - mu) / sigma held fixed (the reparameterisation of SAC), so its
/// gradient reaches mu and sigma: d/d mu = -2 tanh(z), d/d log sigma = 1 - 2 tanh(z) sigma e. The
/// Gaussian's entropy alone (sum_k log sigma_k + const) grows without bound in sigma and drove log
/// sigma to kLogStdMax, where tanh saturates and the commands turn bang-bang (BENCHMARKS, mobility);
/// the squashed one is largest near sigma = 0.8 (for mu = 0) and falls beyond.
constexpr double kLogStdMin = -5.0, kLogStdMax = 1.0;
/// log pi(tanh(z)) for one dimension given the actor's mu and log sigma (clamped here).
double squashed_gaussian_logprob(double z, double mu, double log_std);
/// log(1 - tanh(z)^2), computed stably.
double tanh_log_jacobian(double z);

/// The loss of eq:total_loss (see PpoNetworks::step) on a minibatch from the networks' outputs
/// (logits [rows x logit_stride], first batch.action_count columns; values [rows x value_stride], first
/// column), and its gradient with respect to them, written into the same places of dlogits and
/// dvalues (other columns untouched). The fast backend's loss; the torch backend differentiates
/// the same loss with autograd. grad_norm is left 0.
UpdateStats ppo_loss(const Minibatch& batch, const PpoSettings& settings, const float* logits, int logit_stride,
                     const float* values, int value_stride, float* dlogits, float* dvalues);

/// Actor, critic and their optimiser (Adam, one learning rate), on one backend.
class PpoNetworks : public Learned {
 public:
  /// logits [rows x actions] of the actor on observations [rows x obs_width]. `lane` in
  /// [0, lanes()): calls on different lanes may run at once (each lane has its own scratch).
  virtual void logits(const float* observations, int rows, float* out, int lane = 0) = 0;
  /// The critic's values [rows] in its normalised units (lanes as logits), on the rows whose
  /// input is their observation's first critic_observation columns (make_ppo_networks; unread
  /// when 0), then their row of critic_inputs [rows x the rest].
  virtual void values(const float* observations, const float* critic_inputs, int rows, float* out, int lane = 0) = 0;
  /// How many logits / values calls may run at once, on lanes 0 .. lanes() - 1.
  virtual int lanes() const { return 1; }
  /// One step on the loss of eq:total_loss over the minibatch: the clipped surrogate (masked
  /// mean over active agents), value_coef x the clipped value loss (eq:critic_loss, mean over
  /// rows), minus entropy_coef x the masked mean entropy of the policy among the allowed moves;
  /// the global gradient norm clipped to grad_clip (0: off).
  /// Rows the batch fills on demand (Minibatch::fill) are filled by the step.
  virtual UpdateStats step(Minibatch& batch, const PpoSettings& settings) = 0;
  /// The optimiser's learning rate from the next step on (marl.lr_schedule).
  virtual void set_learning_rate(double learning_rate) = 0;
  /// marl.average_decay = d > 0: after every step the actor's Polyak average a <- d a + (1 - d) w
  /// (a = w after the first step) is kept beside the trained weights w. save() without the
  /// optimiser (policy.pt, the policy validation scores) then writes a as the actor; with it
  /// (last.pt), w and the optimiser as always, and a beside them, which load() reads back, so a
  /// resumed run continues the same average. logits() and training use w. 0: off.
  virtual void set_average_decay(double decay) = 0;
};

/// Actor obs_width -> hidden -> hidden -> actions (the mobility model's) and critic critic_width -> ... -> 1, both
/// initialised from LibTorch's default initialisation under `seed` (so both backends start from
/// the same weights). backend: "fast" | "torch". `threads` (run.threads; 0 = every core): the fast
/// backend computes each minibatch in two fixed halves, on up to two threads, with the same
/// numbers for any thread count; LibTorch's threads are set by the run.
/// `actions` is the actor's output width: the discrete actions, or 2 x the continuous command's size.
/// `critic_observation` (0 or obs_width): the critic's first input columns are the observation
/// (Minibatch::critic_observation, which each step's batch must match).
std::unique_ptr<PpoNetworks> make_ppo_networks(PpoBackend backend, int obs_width, int critic_width, int hidden,
                                               double learning_rate, const torch::Device& device, std::uint64_t seed,
                                               int threads = 1, int actions = kGridActions, int critic_observation = 0);

/// Fills the rollout with T steps of every environment: each active UAV samples from its policy
/// among the moves its safety settings allow (sequential_safe_actions); arrived UAVs STAY.
/// Continuous (rollout.C > 0): each active UAV samples a command from its squashed Gaussian; the
/// safety layer (safe_velocities) may replace the velocity flown, the sample stays as drawn.
/// Finished episodes go to `stats`. Leaves next_values for the bootstrap.
/// Each environment samples from a stream of its own (seeded from `rng`), and the environments
/// are prepared in kCollectLanes fixed groups (observations, the networks' passes, sampling, the
/// move, and the step's end and reset where the environment's own oracle knows every rate:
/// VecEnv::settle), one per thread up to `threads` (and nets.lanes()); observations that ask a rate
/// oracle the environments share come first, on the calling thread; the rate oracles' batch of the
/// other environments' misses, their steps' ends and resets follow on the calling thread. The
/// rollout is the same floats on any thread count.
constexpr int kCollectLanes = 2;
void collect(VecEnv& envs, const Encoder& encoder, const CriticReader& critic, const SafetyOptions& safety,
             PpoNetworks& nets, const RunningStats& value_norm, Rng& rng, Rollout& rollout, EpisodeStats& stats,
             int threads = 1);

/// GAE (gae() in marl.hpp) per (environment, agent) over the rollout: advantages and returns.
void compute_advantages(Rollout& rollout, double gamma, double lambda);

/// The fraction of the returns' variance the old values explain, over active agents:
/// 1 - Var[returns - values] / Var[returns] (NaN when the returns do not vary).
double explained_variance(const Rollout& rollout);

/// marl.epochs passes over the rollout in marl.minibatches shuffled minibatches (order from
/// `rng`): of agent samples, or (marl.minibatch = steps) of whole steps, the agents of a step in
/// consecutive rows (Minibatch::share when the rollout's critic_inputs are shared); normalises the advantages over active agents and (marl.value_norm) updates
/// `value_norm` with the returns first. Returns the mean statistics over all steps. Each
/// minibatch's rows are gathered by the networks' step as it reaches them (Minibatch::fill), on
/// its threads (the same numbers on any thread count).
/// The entropy bonus is entropy_factor x marl.entropy_coef (marl.entropy_schedule).
UpdateStats update(const Rollout& rollout, PpoNetworks& nets, RunningStats& value_norm, const MarlConfig& m, Rng& rng,
                   Minibatch& scratch, double entropy_factor = 1.0);

}  // namespace skyloop::marl
