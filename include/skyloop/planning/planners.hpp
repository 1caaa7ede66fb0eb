#pragma once
// Trajectory planners over UavEnv: the paper's Random and Greedy baselines (Section VI-C) and,
// beyond the paper, the exact optimum of P2.2 by dynamic programming.
#include <cstdint>
#include <iosfwd>
#include <memory>
#include <string>
#include <vector>

#include "skyloop/core/rng.hpp"
#include "skyloop/env/uav_env.hpp"
#include "skyloop/planning/safety.hpp"

namespace skyloop {

class Planner {
 public:
  virtual ~Planner() = default;
  virtual std::string name() const = 0;
  /// Called after env.reset(), before the first act().
  virtual void reset(UavEnv& env) {}
  /// Joint action for the current slot.
  virtual std::vector<int> act(UavEnv& env) = 0;
  /// True for planners that command velocities (trajectory.mobility = continuous): run_episode
  /// then steps with act_velocities().
  virtual bool commands_velocities() const { return false; }
  /// Velocity commands for the current slot (m/s; row n = UAV n).
  virtual Positions act_velocities(UavEnv& env);
  /// True for planners that draw from their seed (PlannerArgs::seed): the others fly the same
  /// episode under any seed, so an evaluation over seeds flies them once (skyloop bench).
  virtual bool seeded() const { return false; }
};

/// Uniform over each UAV's feasible actions (in the area, destination still reachable in the
/// slots left); arrived UAVs STAY. Collisions are not avoided.
class RandomPlanner final : public Planner {
 public:
  explicit RandomPlanner(std::uint64_t seed) : seed_(seed), rng_(seed) {}
  std::string name() const override { return "random"; }
  bool seeded() const override { return true; }
  void reset(UavEnv&) override { rng_ = Rng(seed_); }
  std::vector<int> act(UavEnv& env) override;

 private:
  std::uint64_t seed_;
  Rng rng_;
};

/// Exhaustive search over the A^N joint actions (A = the mobility model's actions) for the highest
/// next-slot sum rate (under another env.objective: the objective one slot ahead, the move's energy included), among joint actions that keep every destination reachable, stay in the area
/// and avoid collisions (if none avoids collisions, the fewest colliding UAVs first). Ties go to the
/// lowest joint index. Exponential in N: refused (InputError) above kMaxJointActions, where
/// SequentialGreedyPlanner serves.
class GreedyPlanner final : public Planner {
 public:
  static constexpr long kMaxJointActions = 390625;  // 5^8: the grid model up to 8 UAVs, headings (17) up to 4
  std::string name() const override { return "greedy"; }
  void reset(UavEnv& env) override;
  std::vector<int> act(UavEnv& env) override;
};

/// Greedy one UAV at a time, linear in N (5 N candidate positions per slot): the UAVs choose in
/// order of least slack (moves left minus moves needed to reach the destination; ties by index),
/// each the feasible action (in the area, destination still reachable) with the highest
/// next-slot sum rate (or env.objective one slot ahead) given the moves already chosen, the UAVs still to choose held in place.
/// An action that brings the UAV within D_min of a UAV already placed (or of one still in place)
/// is masked whenever another feasible action avoids it. Ties go to the lowest action index.
/// The 5 candidates of each UAV go to the oracle in one batched call. If the pass still leaves a
/// collision, a depth-first search over each UAV's moves in the pass's order of preference finds
/// a collision-free joint move whenever one exists (within kSearchBudget steps; beyond it, the
/// pass's move).
class SequentialGreedyPlanner final : public Planner {
 public:
  static constexpr long kSearchBudget = 2000000;
  /// Its moves: the reachability mask with `safety`'s slack margin and clearance (safety.hpp; the
  /// mask always, whatever safety.mask); the collision search may spend the margin. The defaults
  /// are UavEnv::feasible's moves.
  explicit SequentialGreedyPlanner(const SafetyOptions& safety = {}) : safety_(safety) { safety_.mask = true, safety_.shield = false; }
  std::string name() const override { return "seqgreedy"; }
  std::vector<int> act(UavEnv& env) override;

 private:
  SafetyOptions safety_;
};

/// Multiagent rollout over a base planner (Bertsekas, "Multiagent Rollout Algorithms and
/// Reinforcement Learning", arXiv:1910.00120, 2019; rollout: Bertsekas, Tsitsiklis and Wu, J.
/// Heuristics 1997). Each slot it starts from the base planner's joint action; then UAV by UAV
/// (index order), with the moves already chosen fixed and the base's moves for the UAVs still to
/// choose, it tries every feasible move of the UAV (UavEnv::feasible; an arrived UAV hovers),
/// scores each by flying the rest of the mission on a copy of the environment with the base
/// planner (the oracle and its memo shared), and keeps the move with the best score: fewest
/// failures (UAVs not home at the end, colliding UAVs, boundary events, UAVs past energy.budget_j,
/// summed over the mission), then the highest J of env.objective; a move replaces the one held
/// only if its score is strictly better. The pass over the UAVs repeats while it changes a move,
/// at most kMaxPasses times (a second pass lets a UAV answer the moves chosen after it).
///
/// Every mobility model: a base that commands velocities (a continuous-action policy) keeps its
/// command unless one of the UAV's feasible primitives (UavEnv::primitive_velocity: the 8
/// headings at two speeds, HOME, HOVER) scores strictly better; a base that chooses primitives
/// is rolled out over them as over the lattice moves.
///
/// Cost improvement: when the base planner's joint action is a function of the environment's
/// state alone (deterministic, no memory from slot to slot), the rollout's mission is never worse
/// than the base planner's in that order (tests/unit/planners_test.cpp). Its cost per slot is
/// about (sum over the UAVs of their feasible moves) remainders of the mission per pass, each a
/// base decision per slot: linear in N.
class RolloutPlanner final : public Planner {
 public:
  /// `label`: the planner's name (default: the base's name + "+rollout").
  explicit RolloutPlanner(std::unique_ptr<Planner> base, std::string label = {});
  std::string name() const override { return name_; }
  void reset(UavEnv& env) override;
  std::vector<int> act(UavEnv& env) override;
  bool commands_velocities() const override { return base_->commands_velocities(); }
  Positions act_velocities(UavEnv& env) override;
  /// Environment steps simulated since reset.
  long simulated_steps() const { return simulated_; }
  static constexpr int kMaxPasses = 3;

 private:
  struct Score {
    int failures = 0;
    double objective = 0;
    bool better_than(const Score& o) const { return failures != o.failures ? failures < o.failures : objective > o.objective; }
  };
  /// The mission's score when the UAVs take `joint` now and the base planner flies the rest.
  Score simulate(const UavEnv& env, const std::vector<int>& joint);
  /// The same for velocity commands [N x 2] (m/s).
  Score simulate(const UavEnv& env, const Positions& commands);
  Score score(const UavEnv& finished) const;
  std::unique_ptr<Planner> base_;
  std::string name_;
  long simulated_ = 0;
};

struct OptimalPlan {
  double objective = 0;                     // J of env.objective (sum-rate: (1/T) sum_{t=1}^T R[t])
  double sum_rate_objective = 0;            // (1/T) sum_{t=1}^T R[t]
  double energy_j = 0;                      // the plan's propulsion energy (J)
  int T = 0;                                // slot of the last arrival
  std::vector<std::vector<int>> actions;    // joint action of slots 1..T-1
  int iterations = 0;                       // Dinkelbach iterations
  std::size_t states = 0;                   // joint grid states (G^N)
  std::size_t evaluated_states = 0;         // states whose R was needed
  std::size_t memory_bytes = 0;             // value tables
  double seconds = 0;
};

/// Exact optimum of P2.2 for the environment's users and oracle: maximise (1/T) sum_t R[t] over
/// joint trajectories on the D_fly grid with every UAV at its destination by T <= T_max, arrival
/// absorbing, no collision and no boundary exit. The ratio objective is solved by Dinkelbach's
/// method: each iteration maximises sum_t (R[t] - lambda) by backward dynamic programming over
/// the joint grid state (value tables per slot, the max over the A^N joint actions taken one UAV
/// at a time), then lambda <- the objective of the maximiser, until lambda stops increasing.
/// Any mobility model's moves (the lattice steps of its actions) and any env.objective: the
/// energy of each move is the transition cost (UavEnv's J: weighted = sum_t (R[t] - lambda) - w
/// sum E / delta_t; energy-efficiency = B delta_t sum R / 1000 - lambda E; energy = -E / 1000, one
/// pass). Refused: energy.acceleration = kinetic (the state holds no speed), energy.budget_j > 0.
/// Throws InputError if starts and destinations are not on one D_fly lattice, the joint grid is
/// too large (G^N > 5e6), or no feasible joint trajectory exists.
OptimalPlan solve_optimal(UavEnv& env, std::ostream* progress = nullptr);

/// The joint action of the environment's current slot in a plan of slots 1..T-1 (every UAV STAYs
/// past its end): how OptimalPlanner and BestKnownPlanner fly their plans.
std::vector<int> replay(const std::vector<std::vector<int>>& actions, const UavEnv& env);

/// Replays solve_optimal's plan.
class OptimalPlanner final : public Planner {
 public:
  /// `memo_key`: when not empty, the plan is kept for the process under this key (it must name
  /// everything the plan depends on: the resolved config and the users) and a later planner with
  /// the same key reuses it; the DP over joint states is the expensive part under the shared
  /// spectrum, where every joint state is one network for the oracle.
  explicit OptimalPlanner(std::ostream* progress = nullptr, std::string memo_key = {})
      : progress_(progress), memo_key_(std::move(memo_key)) {}
  std::string name() const override { return "optimal"; }
  void reset(UavEnv& env) override;
  std::vector<int> act(UavEnv& env) override;
  const OptimalPlan& plan() const { return plan_; }

 private:
  std::ostream* progress_;
  std::string memo_key_;
  OptimalPlan plan_;
};

/// The settings the exact optimum of a scenario depends on, one "key = value" line per field (no
/// help texts): the resolved config less the learners' [marl] and the [run] settings, and less the
/// [env] settings that shape only the
/// learners' reward and inputs or the drawing of layouts (the w_* weights, env.reward, env.state,
/// env.resample_users, env.users_min / users_max). With the users, it keys every store of optima:
/// OptimalPlanner's memo (run_planners) and the layout evaluation's --cache.
std::string optimum_key(const Config& cfg);

/// Whether solve_optimal can run on this scenario: the joint grid (cells^N) within 5e6 states and
/// the value table (states x T_max) within 2^27 entries.
bool fits_optimal(const UavEnv& env);
/// Refuses (InputError, naming `who`) the continuous mobility model, which the lattice searches
/// (the optimal, brute-force and best-known planners) cannot represent.
const LatticeDynamics& require_lattice(const UavEnv& env, const std::string& who);

struct BestKnownPlan {
  double objective = 0;                     // (1/T) sum_{t=1}^T R[t]
  int T = 0;
  std::vector<std::vector<int>> actions;    // joint action of slots 1..T-1
  bool exact = false;                       // the exact optimum (solve_optimal) rather than best responses
  double start_objective = 0;               // the sequential greedy's, where the best responses began
  int rounds = 0, improvements = 0, collisions = 0;
  double seconds = 0;
};

/// The best joint trajectories known without the joint DP: the exact optimum (solve_optimal)
/// where it fits (fits_optimal) unless `iterated` is set; otherwise, from the sequential greedy's
/// episode, rounds of best responses: for each UAV in turn, its exact optimum of the joint
/// objective over its own trajectory (Dinkelbach's method and a DP over its grid cells and the
/// slots, the sum rate evaluated with the other UAVs at their fixed positions of each slot,
/// cells within D_min of them excluded, waiting at its destination until the others are home),
/// kept if it lowers the collisions or raises the objective; until a round improves no UAV or
/// `max_rounds`. Each round evaluates about (grid cells x T_max) joint positions per UAV.
BestKnownPlan solve_best_known(UavEnv& env, std::ostream* progress = nullptr, int max_rounds = 20, bool iterated = false);

/// Replays solve_best_known's plan.
class BestKnownPlanner final : public Planner {
 public:
  explicit BestKnownPlanner(std::ostream* progress = nullptr, int max_rounds = 20, bool iterated = false)
      : progress_(progress), max_rounds_(max_rounds), force_iterated_(iterated) {}
  std::string name() const override { return "bestknown"; }
  void reset(UavEnv& env) override;
  std::vector<int> act(UavEnv& env) override;
  const BestKnownPlan& plan() const { return plan_; }

 private:
  std::ostream* progress_;
  int max_rounds_;
  bool force_iterated_;
  BestKnownPlan plan_;
};

/// Best objective J (env.objective) by enumerating every feasible joint action sequence (tiny
/// instances only; the check of solve_optimal). NaN if no sequence brings every UAV home by T_max.
double brute_force_optimum(UavEnv& env);

struct EpisodeRecord {
  std::string planner;
  ActionSpec action_names;                  // the mobility model's actions (names of `actions`)
  std::vector<Positions> positions;         // slots 1..T
  std::vector<std::vector<int>> actions;    // slots 1..T-1 (as executed: arrived UAVs hover; -1: a velocity command)
  std::vector<std::vector<double>> speeds;  // [slot 1..T-1][UAV] ground speed flown (m/s)
  std::vector<std::vector<double>> powers;  // [slot 1..T-1][UAV] propulsion power (W; energy / delta_t)
  std::vector<StepInfo> steps;              // after each action
  std::vector<double> rates;                // R[1..T]
  double objective = 0;                     // J of env.objective (sum-rate: (1/T) sum_{t=1}^T R[t])
  double sum_rate_objective = 0;            // (1/T) sum_{t=1}^T R[t]
  double energy_j = 0, bits_per_joule = 0;  // the fleet's propulsion energy, B delta_t sum R / energy
  std::vector<double> uav_energy_j;         // per UAV
  int over_budget = 0;                      // UAVs past energy.budget_j
  int T = 0;
  bool success = false;                     // every UAV arrived by T_max
  int arrivals = 0, boundary = 0, collisions = 0;
  double reward = 0;                        // sum of r[t]
};

/// Resets the environment and runs one episode with the planner.
EpisodeRecord run_episode(UavEnv& env, Planner& planner);

}  // namespace skyloop
