#pragma once
// The outer loop's world (Sections III-A and V-B): N UAVs fly from their starts to their
// destinations over fixed ground users, one move per slot of the dynamics
// (skyloop/env/dynamics.hpp; the paper's: D_fly along x or y, or stay), and R[t] comes from a
// beamformer behind a RateOracle. Every slot each UAV spends propulsion energy at its ground speed
// (skyloop/env/energy.hpp); arrived UAVs hover until the mission ends.
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
//    Under env.objective other than sum-rate the objective reward is J[t+1] - J[t] (less the
//    same penalties) with J the mission objective so far (below; J[1] = 0 for energy-efficiency and energy);
//  - evaluations report the objective J, not the shaped reward. J by env.objective (E = propulsion
//    energy of every UAV over slots 1..T-1, slot t's move lasting delta_t; B = channel.bandwidth_hz):
//      sum-rate (P2.2):   J = (1/T) sum_{t=1}^T R[t]
//      energy-efficiency: J = B delta_t sum_{t=1}^T R[t] / E / 1000   (kbit/J)
//      weighted:          J = (1/T) sum_{t=1}^T (R[t] - w P_fleet[t]), P_fleet[t] = E[t] / delta_t, P_fleet[T] = 0
//      energy:            J = -E / 1000 (kJ; the rate term off: the least-energy mission)
//  - energy budget (energy.budget_j > 0): a UAV whose energy passes it fails the mission (success
//    needs every UAV home within T_max and within its budget); moves are not masked by it.
#include <cstdint>
#include <functional>
#include <cmath>
#include <memory>
#include <mutex>
#include <string>
#include <unordered_map>
#include <vector>

#include "skyloop/core/choices.hpp"
#include "skyloop/env/energy.hpp"
#include "skyloop/env/dynamics.hpp"
#include "skyloop/env/rate_oracle.hpp"
#include "skyloop/env/spec.hpp"

namespace skyloop {


/// Users of an environment: from env.users_file if set, else K uniform users from `seed`.
Positions make_users(const Config& cfg, int users, std::uint64_t seed);

/// The environment's world: what a step changes, and nothing else (the mission, the users and the
/// models are fixed for an episode). Plain data; UavEnv::world() reads it.
struct World {
  Positions positions;                 // N x 3: x, y and altitude (m)
  Positions velocity;                  // N x 2: each UAV's ground velocity in the last slot (m/s)
  int slot = 1;                        // t: the slot about to be flown, 1 .. T_max
  std::vector<bool> arrived;           // per UAV: at its destination (it hovers there from then on)
  std::vector<int> previous_action;    // per UAV: its last action (the observations' previous action)
  std::vector<double> energy_j;        // per UAV: propulsion energy so far (J)
  std::vector<double> speed_mps;       // per UAV: ground speed in the last slot (m/s)
  std::vector<double> power_w;         // per UAV: propulsion power in the last slot (W)
  double energy_total_j = 0;           // the fleet's energy so far (J)
  std::vector<double> rates;           // R[1 .. t], R[1] at the starts (UavEnv::rates())
  double rate_sum = 0;                 // their sum
};

class UavEnv {
 public:
  /// `oracle` holds the users; the environment takes the trajectory and reward settings of cfg.
  UavEnv(const Config& cfg, std::shared_ptr<RateOracle> oracle);
  /// The same flying `dynamics` in place of cfg's trajectory.mobility (a model of your own:
  /// docs/extending/mobility-model.md); cfg's other trajectory settings stay.
  UavEnv(const Config& cfg, std::shared_ptr<RateOracle> oracle, std::shared_ptr<const Dynamics> dynamics);
  /// An environment of `like`'s configuration over the users of `oracle`, reset: the same as one
  /// made from that configuration, without making its lattice tables again (it shares like's).
  UavEnv(const UavEnv& like, std::shared_ptr<RateOracle> oracle);

  void reset();
  StepInfo step(const std::vector<int>& actions);
  /// Replaces the users (new oracle), e.g. for env.resample_users; then reset().
  void set_oracle(std::shared_ptr<RateOracle> oracle);

  // ---- queries ------------------------------------------------------------------------------
  /// What a step changes: positions, velocities, the slot, arrivals, energy, the rates so far.
  const World& world() const { return world_; }
  int uavs() const { return n_; }
  int t() const { return world_.slot; }
  int t_max() const { return t_max_; }
  bool done() const { return done_; }
  const Positions& positions() const { return world_.positions; }
  const Positions& starts() const { return mission_.starts; }
  const Positions& destinations() const { return mission_.destinations; }
  bool arrived(int n) const { return world_.arrived[static_cast<std::size_t>(n)]; }
  /// The dynamics (trajectory.mobility): the action space (actions().count()), what a move does,
  /// reachability. Ask it, never which model it is.
  const Dynamics& dynamics() const { return *dynamics_; }
  /// The mission the dynamics flies: the area, starts, destinations, T_max.
  const Mission& mission() const { return mission_; }
  int actions() const { return dynamics_->count(); }
  int hover() const { return dynamics_->hover(); }
  const PropulsionModel& propulsion() const { return propulsion_; }
  Objective objective_kind() const { return objective_kind_; }
  /// Active-agent mask m_n (0 once arrived).
  int mask(int n) const { return arrived(n) ? 0 : 1; }
  RateOracle& oracle() { return *oracle_; }
  double d_fly() const { return d_fly_; }
  double d_min() const { return d_min_; }
  double area_x() const { return mission_.area_x; }
  double area_y() const { return mission_.area_y; }

  /// Where a UAV ends a slot: position, velocity (m/s), ground speed and whether the move stayed
  /// in the area (skyloop/env/dynamics.hpp's Flight).
  using Landing = Flight;
  /// UAV n as it is now: its position and its velocity (and speed) in the last slot.
  Landing current(int n) const;
  /// Where UAV n ends this slot under action a (Dynamics::fly; a commanding model: primitive a);
  /// arrived UAVs hover where they are.
  Landing landing(int n, int a) const;
  /// Where UAV n ends this slot under velocity command (vx, vy) m/s (models that take commands:
  /// Dynamics::fly_command).
  Landing landing_velocity(int n, double vx, double vy) const;
  /// Fewest slots from (x, y) at altitude z to UAV n's destination under the dynamics
  /// (Reachability::slots, at UAV n's current velocity); more than t_max when out of reach.
  int min_moves(int n, double x, double y, double z) const;
  /// The same from a landing (its velocity too).
  int min_moves(int n, const Landing& l) const;
  /// What min_moves_around keeps clear of: the lattice points within D_min of every other UAV's
  /// destination (where each will hover once it arrives, until the mission ends), or of the UAVs
  /// that have arrived (parked) so far.
  enum class ClearOf { Destinations, Parked };
  /// min_moves over the lattice points clear of `what` (UAV n's own destination stays open), for
  /// the safety layer (skyloop/planning/safety.hpp); t_max + 1 where (x, y) is not clear or cut off.
  /// Equal to min_moves off the lattice and while nothing is to be kept clear of.
  /// Breadth-first over UAV n's lattice: once per environment (Destinations) or once per arrival
  /// (Parked), made when first asked.
  int min_moves_around(int n, const Landing& l, ClearOf what) const;
  /// Refuses (InputError, one line naming the fields) `envs` environments of `cfg` whose
  /// distance tables would not fit in memory (skyloop/core/memory.hpp): the dynamics' reachability
  /// tables and the Destinations tables once (copies share them), a Parked table per UAV per
  /// environment where marl.mask_clearance asks for them, and one breadth-first search's scratch
  /// per copy.
  static void require_table_memory(const Config& cfg, int envs);
  static void require_table_memory(const Config& cfg, const Dynamics& dynamics, int envs);
  /// True if `a` keeps UAV n in the area and its destination reachable in the moves left after
  /// it (T_max - (t + 1)). An arrived UAV may only hover (STAY).
  bool feasible(int n, int a) const;
  /// Positions after a joint action (boundary moves cancelled), without stepping.
  Positions next_positions(const std::vector<int>& actions) const;
  /// Models that take commands: one slot under velocity commands v (row n: UAV n's, m/s; arrived
  /// UAVs hover whatever their row says). The discrete step() above flies the primitives' commands.
  StepInfo step_velocities(const Positions& v);
  /// Models that take commands: the velocity commands (m/s) of a joint action of primitives.
  Positions primitive_velocities(const std::vector<int>& actions) const;
  /// Models that take commands: the velocity (m/s) UAV n's command u in [-1, 1]^2 asks for
  /// (trajectory.command; Dynamics::command_velocity from its last velocity).
  void command_velocity(int n, double u0, double u1, double& vx, double& vy) const;
  /// Models that take commands: UAV n's velocity command (m/s) for primitive a.
  void primitive_velocity(int n, int a, double& vx, double& vy) const;
  /// UAV n's velocity in the last slot (m/s; 0 before the first step).
  double velocity_x(int n) const { return world_.velocity(n, 0); }
  double velocity_y(int n) const { return world_.velocity(n, 1); }
  /// Number of UAVs closer than D_min to another (separation).
  int collisions(const Positions& p) const;
  /// The distance between UAVs n and m of `p`: horizontal where they fly at one altitude, 3-D where
  /// their altitudes differ (positions with a third column).
  static double separation(const Positions& p, Eigen::Index n, Eigen::Index m);
  /// The same for an offset (dx, dy, dz): hypot(dx, dy) where dz = 0.
  static double separation(double dx, double dy, double dz) {
    return dz == 0 ? std::hypot(dx, dy) : std::sqrt(dx * dx + dy * dy + dz * dz);
  }
  /// UAV n's altitude (m).
  double altitude(int n) const { return world_.positions(n, 2); }

  // ---- observations and states: the layouts are skyloop/env/spec.hpp's ---------------------
  /// Every array this environment exposes, field by field (sizes, offsets, bounds).
  const EnvSpec& spec() const { return *spec_; }
  /// The agents' observation of spec().obs (paper or set, by marl.encoder) into out[0..obs.size-1].
  void write_obs(int n, float* out) const;
  /// o_n[t], the paper's 11 reals (spec().paper_obs): own position / area, mean displacement to
  /// the users / area, displacement to the destination / area, one-hot previous action (as wide
  /// as the action space: 5 under the grid model).
  void write_observation(int n, float* out) const;
  std::vector<float> observation(int n) const;
  int observation_size() const { return spec_->paper_obs.size; }
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
  ///  - UAVs, near (kNearGrid^2): spacing D_fly, width D_fly / 2: who is one move away;
  ///  - with marl.lookahead, move gains (one per action): write_move_gains;
  ///  - with marl.rate_map = r, the radio map within r lattice steps: write_rate_map.
  /// Each field is a row of observation_fields() (src/env/observations.cpp).
  /// Reordering the users or the other UAVs leaves it unchanged (tests/unit/env_test.cpp).
  void write_set_observation(int n, float* out) const;
  /// Sequential decisions (marl.sequential): the landing UAV m has chosen this slot, which the set
  /// observations of the agents written after it show in place of where m is (its kernels in the
  /// UAV grids, and its position in the move gains' and the radio map's position sets), so an agent
  /// choosing later sees the slot's joint rate with the earlier choices made. Cleared by
  /// clear_decided, reset and every step; nothing else reads it.
  void show_decided(int m, double x, double y, double z);
  void clear_decided();
  /// Where the set observation sees the UAVs: positions(), with the decided landings in place.
  const Positions& seen_positions() const { return any_decided_ ? seen_ : world_.positions; }
  int set_observation_size() const { return spec_->set_obs.size; }
  int users() const;
  /// The compact state (spec().compact_state, whatever env.state says).
  static int compact_state_size() { return compact_state_spec().size; }
  void write_compact_state(float* out) const;

  // ---- episode record -----------------------------------------------------------------------
  const std::vector<double>& rates() const { return world_.rates; }  // R[1..t]
  /// J of env.objective over the episode so far (T = current slot); sum-rate: (1/T) sum R[t].
  double objective() const;
  /// (1/T) sum R[t] (P2.2), whatever env.objective is.
  double sum_rate_objective() const;
  /// Propulsion energy (J) of UAV n and of the fleet so far; speed (m/s) and power (W) of UAV n
  /// in the last slot (0 and hover power before the first step).
  double energy_j(int n) const { return world_.energy_j[static_cast<std::size_t>(n)]; }
  double energy_j() const { return world_.energy_total_j; }
  double last_speed(int n) const { return world_.speed_mps[static_cast<std::size_t>(n)]; }
  double last_power(int n) const { return world_.power_w[static_cast<std::size_t>(n)]; }
  /// Bits delivered so far per joule spent (bit/J): B delta_t sum R[t] / E; 0 before any energy.
  double bits_per_joule() const;
  /// UAVs whose energy passed energy.budget_j (0 without a budget).
  int over_budget() const;
  /// J of env.objective for a mission of T slots with sum_{t<=T} R[t] = rate_sum and fleet energy
  /// energy_j over slots 1..T-1: the one formula the environment, the DP and the reports use.
  double objective_of(double rate_sum, int T, double energy_j) const;
  /// J one slot from now if that slot's sum rate is `rate` and the move costs `energy_j` (the
  /// one-step look-ahead the greedy planners rank moves by).
  double objective_after(double rate, double energy_j) const { return objective_of(world_.rate_sum + rate, world_.slot + 1, world_.energy_total_j + energy_j); }
  /// Fleet energy (J) of a joint action from the current slot (arrived UAVs and cancelled moves hover).
  double step_energy(const std::vector<int>& actions) const;
  double budget_j() const { return budget_j_; }
  double energy_weight() const { return w_energy_; }
  double bandwidth_hz() const { return bandwidth_hz_; }
  int total_arrivals() const { return tot_arr_; }
  int total_boundary() const { return tot_bud_; }
  int total_collisions() const { return tot_col_; }

 // ---- the two-phase step (VecEnv's protocol; envpool's send / recv) -------------------------
  // step() is begin_step, the oracle's R at the new positions, then end_step. A batch of
  // environments (VecEnv) runs phase 1 in each, asks the oracle for every environment's rates in
  // one call, then runs phase 2 in each.
  /// reset() given R at the start (what the oracle says there).
  void reset(double start_rate);
  /// set_oracle() given R at the start under the new oracle.
  void set_oracle(std::shared_ptr<RateOracle> oracle, double start_rate);
  /// Phase 1 of step(): moves, boundary and collision counts; returns the new positions.
  Positions begin_step(const std::vector<int>& actions, StepInfo& info);
  /// The same for velocity commands (continuous model).
  Positions begin_step_velocities(const Positions& v, StepInfo& info);
  /// Phase 2: arrival, R, reward, termination, given R at the new positions.
  void end_step(const Positions& next, double rate, StepInfo& info);
  /// Whether end_step(next, ...) ends the episode (every UAV home, or T_max reached), without
  /// ending it: VecEnv prepares the next episode's oracle alongside the step's rates.
  bool ends_episode(const Positions& next) const;

 private:
  /// Phase 1's bookkeeping of UAV n landing at l (its energy, speed, velocity).
  void land(int n, const Landing& l, StepInfo& info);
  void check_step(std::size_t count) const;
  /// Whether UAV n at `p` is at its destination (end_step's arrival rule).
  bool at_destination(const Positions& p, int n) const;
  /// Phi_n at slot t for UAV n at (x, y); updates T_min[t-1].
  int feasibility_indicator(int n, double x, double y, int t);

  /// J after the rates and energy so far (the objective reward's J[t]).
  double objective_at() const;

  int n_, t_max_;
  double d_fly_, d_min_;
  // A lattice (origin, size) and the fewest slots from each of its points to a UAV's destination
  // with the points of min_moves_around's `what` closed, and the version it was made for (-1: none yet).
  struct DistanceTable {
    int version = -1;
    LatticeFrame frame;
    std::vector<int> slots;
  };
  // The tables every copy of an environment shares, a pure function of its configuration (the
  // VecEnv's environments are copies of its first): UAV n's Destinations table of
  // min_moves_around, made when first asked (once, whichever thread asks).
  struct SharedTables {
    std::vector<DistanceTable> destinations;
    std::unique_ptr<std::once_flag[]> made;  // destinations[n] made
  };
  std::shared_ptr<SharedTables> tables_;
  /// min_moves_around's table of UAV n around `what`, made afresh.
  DistanceTable clear_table(int n, ClearOf what) const;
  double w_rate_, w_arr_, w_bud_, w_col_, w_fea_;
  std::shared_ptr<const Dynamics> dynamics_;
  Mission mission_;  // the area, starts, destinations and T_max the dynamics flies
  std::shared_ptr<const Reachability> reach_;  // the dynamics' reachability of mission_ (copies share it)
  PropulsionModel propulsion_;
  Objective objective_kind_ = Objective::SumRate;
  double bandwidth_hz_ = 1e6, w_energy_ = 0, budget_j_ = 0;
  bool objective_reward_ = false;  // env.reward = "objective"
  SpecParams spec_params_;  // what spec_ is made from (N, K, area, horizon, env.state, marl.encoder)
  std::shared_ptr<const EnvSpec> spec_;
  World world_;
  Positions seen_;             // world_.positions with the decided landings (show_decided) in place
  bool any_decided_ = false;   // seen_ differs from world_.positions
  std::shared_ptr<RateOracle> oracle_;
  int parked_ = 0;  // arrived UAVs so far this episode: the version of the Parked tables
  // min_moves_around's Parked tables, per UAV: a cache of a pure function of the state.
  mutable std::vector<DistanceTable> parked_tables_;
  // The set observation's user kernels, one axis at a time (write_set_observation): for each UAV
  // coordinate seen since the users were set, every user's G factors along that axis (zeros where
  // the user is out of the kernel's reach) and the users within reach. A cache of a pure function
  // of (users, coordinate): cleared in set_oracle, and a copied environment starts with an empty one.
  struct KernelAxes {
    struct Axis {
      std::size_t factors = 0, reach = 0, count = 0;  // offsets into f and reach; the users within reach
    };
    std::unordered_map<std::uint64_t, Axis> x, y;  // a coordinate's bits -> its tables
    std::vector<double> f;  // per coordinate: K rows of G factors
    std::vector<int> reach;  // per coordinate: the users within reach along that axis, ascending
    KernelAxes() = default;
    KernelAxes(const KernelAxes&) {}
    KernelAxes& operator=(const KernelAxes&) {
      clear();
      return *this;
    }
    void clear() {
      x.clear();
      y.clear();
      f.clear();
      reach.clear();
    }
  };
  mutable KernelAxes kernel_axes_;

  // ---- the field writers (src/env/observations.cpp): observation_fields() and state_fields()
  // hold a row per field whose writer reads the state below --------------------------------------
  friend const std::vector<ObservationField>& observation_fields();
  friend const std::vector<StateField>& state_fields();
  /// Every field of `a` by its writer at its offset (agent n's, or the environment's).
  void write_array(const ArraySpec& a, int n, float* out) const;
  /// The observations' previous-action field (Dynamics::write_previous_action: one-hot, or a
  /// commanding model's last velocity / v_max).
  void write_previous_action(int n, float* out) const;
  /// For each action a of UAV n (continuous model: each primitive), tanh(kGainScale (R_a - R) / R):
  /// R_a the sum rate with UAV n landed where a takes it (landing(n, a)) and every other UAV where
  /// it is, R the sum rate now; the one-slot look-ahead Greedy ranks moves by (its sign and order),
  /// so a learner sees a rate landscape its user-density features cannot show (3GPP LoS states,
  /// WMMSE's steep rates). Zeros for an arrived UAV and where R = 0. The oracle is asked for the
  /// A + 1 position sets in one batched call (memoised).
  void write_move_gains(int n, float* out) const;
  /// The radio map around UAV n: at each cell c of rate_map_offsets(marl.rate_map), the point
  /// x + D_fly c (x the UAV's position, on or off the lattice), tanh(kGainScale (R_c - R) / R) with
  /// R_c the sum rate with UAV n there and every other UAV where it is; -1 at a point outside the
  /// area. Beyond the moves' gains it shows where the rate is two or more slots away (a 3GPP LoS
  /// patch, WMMSE's peaks), which the optimum plans towards and a one-slot look-ahead cannot see.
  /// Zeros for an arrived UAV and where R = 0; the cells in one batched, memoised oracle call.
  void write_rate_map(int n, float* out) const;
  /// UAV n's altitude within the dynamics' band, in [0, 1] (the observations' altitude field).
  float altitude_share(int n) const;
  /// The users' kernels around UAV n (kernel_axes_: its cache).
  void write_users_density(int n, float* out) const;
  /// The other UAVs' kernels (where seen_positions() has them) on a G x G grid around UAV n.
  void write_uav_kernels(int n, float* out, int G, double step, double width) const;
  std::vector<int> prev_tmin_;
  bool done_ = false;
  int tot_arr_ = 0, tot_bud_ = 0, tot_col_ = 0;
  double tot_reward_ = 0;
};

}  // namespace skyloop
