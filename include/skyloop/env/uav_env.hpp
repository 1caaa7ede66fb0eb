#pragma once
// The outer loop's world (Sections III-A and V-B): N UAVs fly from their starts to their
// destinations over fixed ground users, one move of D_fly per slot, and R[t] comes from a
// beamformer behind a RateOracle.
//
// Time: slot t = 1 is the start (positions = starts, R[1] computed at reset); step() applies the
// joint action of slot t and moves to slot t + 1. The episode ends when every UAV has arrived
// (T = that slot) or at t = T_max (T = T_max, mission failed).
//
// Rules (defined here, where the paper is silent):
//  - boundary (eq:range_x, eq:range_y): a move that would leave [0, area_x] x [0, area_y] is
//    cancelled (the UAV stays) and counted as a boundary event (N_bud);
//  - collision (eq:collision_constraint): moves are executed; every UAV closer than D_min to
//    another after the move counts once in N_col (the state is reported, not repaired);
//  - arrival: a UAV on its destination is arrived: locked to STAY and masked (m = 0); N_arr
//    counts the UAVs that arrive in this step;
//  - reward (eq:total_reward): w_rate R-bar[t] + w_arr N_arr - w_bud N_bud - w_col N_col
//    + w_fea sum_n Phi_n, with R-bar[t] = (1/t) sum_{tau <= t} R[tau] and Phi_n exactly as the
//    paper: +1 if T_min[t] <= T_max - t and T_min[t] <= T_min[t-1], else -1, where
//    T_min = ceil(||l_D - l_A|| / D_fly) (Euclidean, as printed).
//    Under env.reward = "objective" (beyond the paper): R-bar[t] - R-bar[t-1] - w_bud N_bud
//    - w_col N_col, so that an episode's rewards sum to its P2.2 objective less R[1];
//  - evaluations report the P2.2 objective (1/T) sum_{t=1}^T R[t], not the shaped reward.
#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "skyloop/env/rate_oracle.hpp"
#include "skyloop/env/spec.hpp"

namespace skyloop {

struct StepInfo {
  double reward = 0;         // r[t] (eq:total_reward)
  double sum_rate = 0;       // R at the new slot
  double avg_rate = 0;       // R-bar at the new slot
  int arrivals = 0, boundary = 0, collisions = 0;
  int feasibility = 0;       // sum_n Phi_n
  bool done = false;
  bool success = false;      // every UAV arrived
  // Episode so far (final values when done): P2.2 objective, slots, UAVs home, totals.
  double objective = 0;
  int T = 0, home = 0, episode_collisions = 0, episode_boundary = 0;
  double episode_reward = 0;
};

/// Users of an environment: from env.users_file if set, else K uniform users from `seed`.
Positions make_users(const Config& cfg, int users, std::uint64_t seed);

class UavEnv {
 public:
  /// `oracle` holds the users; the environment takes the trajectory and reward settings of cfg.
  UavEnv(const Config& cfg, std::shared_ptr<RateOracle> oracle);

  void reset();
  StepInfo step(const std::vector<int>& actions);
  /// Replaces the users (new oracle), e.g. for env.resample_users; then reset().
  void set_oracle(std::shared_ptr<RateOracle> oracle);

  // ---- queries ------------------------------------------------------------------------------
  int uavs() const { return n_; }
  int t() const { return t_; }
  int t_max() const { return t_max_; }
  bool done() const { return done_; }
  const Positions& positions() const { return pos_; }
  const Positions& starts() const { return start_; }
  const Positions& destinations() const { return dest_; }
  bool arrived(int n) const { return arrived_[static_cast<std::size_t>(n)]; }
  /// Active-agent mask m_n (0 once arrived).
  int mask(int n) const { return arrived(n) ? 0 : 1; }
  RateOracle& oracle() { return *oracle_; }
  double d_fly() const { return d_fly_; }
  double d_min() const { return d_min_; }
  double area_x() const { return area_x_; }
  double area_y() const { return area_y_; }

  /// Position after `a` from (x, y), and whether it stays in the area.
  bool move(double x, double y, int a, double& nx, double& ny) const;
  /// Minimum number of moves from (x, y) to UAV n's destination on the D_fly grid (Manhattan).
  int min_moves(int n, double x, double y) const;
  /// True if `a` keeps UAV n in the area and its destination reachable in the moves left after
  /// it (T_max - (t + 1)). An arrived UAV may only STAY.
  bool feasible(int n, int a) const;
  /// Positions after a joint action (boundary moves cancelled), without stepping.
  Positions next_positions(const std::vector<int>& actions) const;
  /// Number of UAVs closer than D_min to another.
  int collisions(const Positions& p) const;

  // ---- observations and states: the layouts are skyloop/env/spec.hpp's ---------------------
  /// Every array this environment exposes, field by field (sizes, offsets, bounds).
  const EnvSpec& spec() const { return *spec_; }
  /// The agents' observation of spec().obs (paper or set, by marl.encoder) into out[0..obs.size-1].
  void write_obs(int n, float* out) const;
  /// o_n[t], the paper's 11 reals (spec().paper_obs): own position / area, mean displacement to
  /// the users / area, displacement to the destination / area, one-hot previous action.
  void write_observation(int n, float* out) const;
  std::vector<float> observation(int n) const;
  static int observation_size() { return paper_observation_spec().size; }
  /// s[t] (spec().state) under env.state = "paper": all UAV positions, all user positions, all
  /// destinations, each / area (4N + 2K reals). Under "compact" (any N and K, 3 G^2 + 2 reals,
  /// G = kStateGrid): the share of users, of UAVs and of not-yet-arrived UAVs' destinations in
  /// each cell of a G x G grid over the area, then t / T_max and the share of UAVs arrived.
  void write_state(float* out) const;
  std::vector<float> state() const;
  int state_size() const { return spec_->state.size; }
  /// Who agent n is (spec().agent_context), for networks shared by all agents: paper: one-hot id
  /// (N reals); compact: displacements / area to its kNeighbours nearest other UAVs, nearest
  /// first (zeros past N - 1).
  void write_agent_context(int n, float* out) const;
  int agent_context_size() const { return spec_->agent_context.size; }
  /// Agent-specific global state (spec().agent_state): s[t], agent n's context, o_n[t].
  void write_agent_state(int n, float* out) const;
  std::vector<float> agent_state(int n) const;
  int agent_state_size() const { return spec_->agent_state.size; }

  // ---- set observation (marl.encoder = "set"; beyond the paper) ----------------------------
  /// A permutation-invariant encoding of the users and the other UAVs around agent n, sized
  /// independently of K and N (a kernel mean embedding: DeepSets with fixed Gaussian features,
  /// pooled by mean over the users and by sum over the UAVs), spec().set_obs:
  ///  - own (11): position / area, displacement to its destination / area, slack (moves left
  ///    minus moves needed) / T_max, t / T_max, one-hot previous action;
  ///  - users (kWideGrid^2): at each point c of a kWideGrid x kWideGrid grid centred on the UAV
  ///    with spacing 2 D_fly, (4 / K) sum_k exp(-|u_k - x - c|^2 / (2 (2 D_fly)^2));
  ///  - UAVs, wide (kWideGrid^2): the same sum over the other UAVs (not divided by anything);
  ///  - UAVs, near (kNearGrid^2): spacing D_fly, width D_fly / 2: who is one move away.
  /// Reordering the users or the other UAVs leaves it unchanged (tests/unit/env_test.cpp).
  void write_set_observation(int n, float* out) const;
  int set_observation_size() const { return spec_->set_obs.size; }
  int users() const;
  /// The compact state (spec().compact_state, whatever env.state says).
  static int compact_state_size() { return compact_state_spec().size; }
  void write_compact_state(float* out) const;

  // ---- episode record -----------------------------------------------------------------------
  const std::vector<double>& rates() const { return rates_; }  // R[1..t]
  /// (1/T) sum R[t] over the episode so far (T = current slot).
  double objective() const;
  int total_arrivals() const { return tot_arr_; }
  int total_boundary() const { return tot_bud_; }
  int total_collisions() const { return tot_col_; }

 private:
  friend class VecEnv;
  /// Phase 1 of step(): moves, boundary and collision counts; returns the new positions.
  Positions begin_step(const std::vector<int>& actions, StepInfo& info);
  /// Phase 2: arrival, R, reward, termination, given R at the new positions.
  void end_step(const Positions& next, double rate, StepInfo& info);
  /// Phi_n at slot t for UAV n at (x, y); updates T_min[t-1].
  int feasibility_indicator(int n, double x, double y, int t);

  int n_, t_max_;
  double d_fly_, d_min_, area_x_, area_y_;
  double w_rate_, w_arr_, w_bud_, w_col_, w_fea_;
  bool compact_ = false;  // env.state = "compact"
  bool objective_reward_ = false;  // env.reward = "objective"
  SpecParams spec_params_;  // what spec_ is made from (N, K, area, horizon, env.state, marl.encoder)
  std::shared_ptr<const EnvSpec> spec_;
  Positions start_, dest_, pos_;
  std::shared_ptr<RateOracle> oracle_;
  std::vector<bool> arrived_;
  std::vector<int> prev_action_, prev_tmin_;
  std::vector<double> rates_;
  double rate_sum_ = 0;
  int t_ = 1;
  bool done_ = false;
  int tot_arr_ = 0, tot_bud_ = 0, tot_col_ = 0;
  double tot_reward_ = 0;
};

/// M environments stepped as one batch: every environment's R[t] in one batched oracle call.
/// Environment i's users come from derive_seed(seed, i) (env.users_file overrides); with
/// env.resample_users every episode of environment i is a new training layout
/// (skyloop/env/layouts.hpp: training_layout_seed(seed, i, episode), K in env.users_min..max).
class VecEnv {
 public:
  VecEnv(const Config& cfg, std::shared_ptr<const Beamformer> beamformer, int count, std::uint64_t seed);
  /// M environments on one scenario: they share `oracle` (its users and its cache).
  VecEnv(const Config& cfg, std::shared_ptr<RateOracle> oracle, int count);
  int size() const { return static_cast<int>(envs_.size()); }
  UavEnv& env(int i) { return *envs_[static_cast<std::size_t>(i)]; }
  /// actions[i] = joint action of environment i. Finished environments are reset automatically
  /// after their final step (the returned info is the final step's); `before_reset(i)`, when
  /// given, sees environment i in its final state first (e.g. to record its last observation).
  std::vector<StepInfo> step(const std::vector<std::vector<int>>& actions,
                             const std::function<void(std::size_t)>& before_reset = {});
  void reset();

 private:
  void reset_env(std::size_t i);
  bool sampling() const;                 // a new training layout every episode
  Positions users_of(std::size_t i) const;  // environment i's users in its current episode
  Config cfg_;
  std::shared_ptr<const Beamformer> beamformer_;
  std::uint64_t seed_;
  std::vector<std::unique_ptr<UavEnv>> envs_;
  std::vector<std::uint64_t> episodes_;
  bool shared_ = false;
};

}  // namespace skyloop
