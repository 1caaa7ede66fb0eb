// The exact optimum (solve_optimal): dynamic programming over the joint lattice states of every
// UAV, with Dinkelbach's iteration for the ratio objectives (skyloop/planning/planners.hpp).
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <limits>
#include <ostream>
#include <stdexcept>

#include "joint.hpp"
#include "skyloop/core/error.hpp"
#include "skyloop/core/io.hpp"
#include "skyloop/planning/planners.hpp"

namespace skyloop {

namespace {
constexpr double kNegInf = -std::numeric_limits<double>::infinity();

/// One solve: the joint lattice (states s = sum_n stride[n] cell_n), the sum rate of every state
/// that can occur, the slots in which each state is alive, and the value tables V[t].
class JointDp {
 public:
  JointDp(UavEnv& env, std::ostream* progress);
  OptimalPlan solve();

 private:
  /// The settings the DP's state cannot hold (a kinetic energy term, an energy budget).
  void check_settings() const;
  /// Each start's and destination's cell, and the joint grid's size within the limits.
  void place_uavs();
  /// neighbour[c * A + a], and each UAV's fewest slots from its start and to its destination.
  void make_moves();
  /// Dinkelbach's weights of env.objective (alpha R - beta lambda - gamma E), the moves' energy.
  void make_weights();
  /// R of every state whose cells lie on a way home in time and that no collision rules out.
  void evaluate_rates();
  /// first[s] <= t <= last[s]: the slots in which state s can occur.
  void alive_windows();
  /// V[t] for t = T_max..1 under energy costs `cost` and ratio `lambda`.
  void backward(const std::vector<double>& cost, double lambda);
  /// The maximiser's path from the start under `cost` (g: the energy weight in use), into plan.
  void recover(const std::vector<double>& cost, double g, OptimalPlan& plan);

  int cell(std::size_t s, int n) const { return static_cast<int>((s / stride_[static_cast<std::size_t>(n)]) % static_cast<std::size_t>(G_)); }
  /// Row n of p: state s's cell of UAV n (its altitude too).
  void place(Positions& p, std::size_t s) const {
    for (int n = 0; n < N_; ++n) {
      const int c = cell(s, n);
      p(n, 0) = frame_.x(c), p(n, 1) = frame_.y(c), p(n, 2) = frame_.z(c);
    }
  }
  std::size_t state_of(const std::vector<int>& cells) const {
    std::size_t s = 0;
    for (int n = 0; n < N_; ++n) s += stride_[static_cast<std::size_t>(n)] * static_cast<std::size_t>(cells[static_cast<std::size_t>(n)]);
    return s;
  }

  std::chrono::steady_clock::time_point t0_ = std::chrono::steady_clock::now();  // plan.seconds from here
  UavEnv& env_;
  std::ostream* progress_;
  const LatticeDynamics& mob_;
  int N_, Tmax_, A_, hover_;
  double d_;
  LatticeFrame frame_;  // every UAV's lattice (the one through start 0, with the dynamics' levels)
  int G_ = 0;
  std::size_t S_ = 0, s0_ = 0, s_home_ = 0;
  std::vector<int> s_cell_, d_cell_;
  std::vector<std::size_t> stride_;
  std::vector<int> neighbour_;
  std::vector<std::vector<int>> from_start_, to_dest_;
  Objective kind_ = Objective::SumRate;
  double alpha_ = 1, beta_ = 1, gamma_ = 0;
  std::vector<double> move_energy_;
  std::vector<double> R_;
  std::vector<std::int32_t> first_, last_;
  std::vector<std::vector<double>> V_;
  std::vector<double> M_, tmp_;
  std::vector<std::size_t> path_;
};

JointDp::JointDp(UavEnv& env, std::ostream* progress)
    : env_(env),
      progress_(progress),
      mob_(require_lattice(env, "the optimal planner")),
      N_(env.uavs()),
      Tmax_(env.t_max()),
      A_(env.actions()),
      hover_(env.hover()),
      d_(env.d_fly()) {
  env_.reset();
  check_settings();
  place_uavs();
  make_moves();
  make_weights();
}

void JointDp::check_settings() const {
  if (env_.propulsion().kinetic())
    throw InputError("energy.acceleration = \"kinetic\" makes a move's energy depend on the previous speed, which the optimal "
                     "planner's state does not hold: allowed energy.acceleration = \"none\" for the optimal planner");
  if (env_.budget_j() > 0)
    throw InputError("energy.budget_j = " + format_double(env_.budget_j()) + " is not a constraint of the optimal planner's DP: "
                     "allowed energy.budget_j = 0 for the optimal planner (the plans report each UAV's energy)");
}

void JointDp::place_uavs() {
  const Positions start = env_.positions(), dest = env_.destinations();
  // The D_fly lattice through start 0, clipped to the area (over the dynamics' altitude levels).
  frame_ = mob_.frame(env_.mission(), 0);
  G_ = frame_.cells();
  const int nx_ = frame_.nx, ny_ = frame_.ny;
  auto cell_of = [&](const Positions& p, int n, const std::string& what) {
    const double fx = (p(n, 0) - frame_.ox) / d_, fy = (p(n, 1) - frame_.oy) / d_;
    const long ix = std::lround(fx), iy = std::lround(fy);
    if (std::abs(fx - static_cast<double>(ix)) > 1e-6 || std::abs(fy - static_cast<double>(iy)) > 1e-6 || ix < 0 || iy < 0 ||
        ix >= nx_ || iy >= ny_)
      throw InputError(what + " = [" + format_double(p(n, 0)) + ", " + format_double(p(n, 1)) +
                       "] is not on the D_fly grid of trajectory.starts[0]: the optimal planner needs every start and "
                       "destination on one grid of spacing trajectory.d_fly_m");
    return frame_.cell(p(n, 0), p(n, 1), p(n, 2));
  };
  s_cell_.resize(static_cast<std::size_t>(N_)), d_cell_.resize(static_cast<std::size_t>(N_));
  for (int n = 0; n < N_; ++n) {
    s_cell_[static_cast<std::size_t>(n)] = cell_of(start, n, "trajectory.starts[" + std::to_string(n) + "]");
    d_cell_[static_cast<std::size_t>(n)] = cell_of(dest, n, "trajectory.destinations[" + std::to_string(n) + "]");
  }
  double Sd = 1;
  for (int n = 0; n < N_; ++n) Sd *= G_;
  if (Sd > 5e6) {
    // The largest instances within the limit: UAVs on this grid, and the grid for this many UAVs.
    int max_uavs = 0;
    for (double s = G_; s <= 5e6; s *= G_) ++max_uavs;
    const int max_cells = static_cast<int>(std::floor(std::pow(5e6, 1.0 / N_) + 1e-9));
    throw InputError("the optimal planner's joint grid has " + format_double(Sd) + " states (" + std::to_string(G_) +
                     " cells ^ " + std::to_string(N_) + " UAVs): allowed at most 5e6, i.e. at most " + std::to_string(max_uavs) +
                     " UAVs on this " + std::to_string(nx_) + " x " + std::to_string(ny_) +
                     (frame_.nz > 1 ? " x " + std::to_string(frame_.nz) + " levels" : std::string()) + " grid, or at most " +
                     std::to_string(max_cells) + " cells for " + std::to_string(N_) + " UAVs; use seqgreedy or a learned planner beyond");
  }
  // The value table holds T_max x states doubles: at most 2^27 of them (1 GiB).
  constexpr double kMaxTableEntries = 134217728.0;
  if (Sd * Tmax_ > kMaxTableEntries)
    throw InputError("the optimal planner's value table has " + format_double(Sd * Tmax_) + " entries (" +
                     format_double(Sd) + " joint states x trajectory.t_max = " + std::to_string(Tmax_) +
                     "): allowed at most 2^27 (1 GiB), i.e. trajectory.t_max <= " +
                     std::to_string(static_cast<long long>(kMaxTableEntries / Sd)) + " on this grid; use seqgreedy beyond");
  S_ = static_cast<std::size_t>(Sd);
  stride_.resize(static_cast<std::size_t>(N_));
  for (int n = 0; n < N_; ++n)
    stride_[static_cast<std::size_t>(n)] = n == 0 ? 1 : stride_[static_cast<std::size_t>(n - 1)] * static_cast<std::size_t>(G_);
  s0_ = state_of(s_cell_);
  s_home_ = state_of(d_cell_);
}

void JointDp::make_moves() {
  // neighbour[c * A + a] = cell after action a, or -1 outside the grid.
  neighbour_.assign(static_cast<std::size_t>(G_ * A_), -1);
  for (int c = 0; c < G_; ++c)
    for (int a = 0; a < A_; ++a) neighbour_[static_cast<std::size_t>(c * A_ + a)] = frame_.move(c, mob_.step(a));
  // Fewest slots between each cell and each UAV's start and destination (the model's moves inside
  // the area; unreachable = a number past the horizon).
  auto fix = [&](std::vector<int> v) {
    for (int& x : v) x = x < 0 ? Tmax_ + 1 : x;
    return v;
  };
  for (int n = 0; n < N_; ++n) {
    from_start_.push_back(fix(mob_.slots_to(frame_, s_cell_[static_cast<std::size_t>(n)])));
    to_dest_.push_back(fix(mob_.slots_to(frame_, d_cell_[static_cast<std::size_t>(n)])));
  }
}

void JointDp::make_weights() {
  // The objective as Dinkelbach's parametric problem: maximise sum_t (alpha R[t] - beta lambda)
  // - sum_moves gamma E(move), then lambda <- J of the maximiser (env.objective; UavEnv's J).
  kind_ = env_.objective_kind();
  const double dt = mob_.slot_s();
  switch (kind_) {
    case Objective::SumRate: break;
    case Objective::Weighted: gamma_ = env_.energy_weight() / dt; break;
    case Objective::EnergyEfficiency: alpha_ = env_.bandwidth_hz() * dt / 1e3, beta_ = 0; break;
    case Objective::Energy: alpha_ = 0, beta_ = 0, gamma_ = 1e-3; break;
  }
  move_energy_.resize(static_cast<std::size_t>(A_));
  for (int a = 0; a < A_; ++a) move_energy_[static_cast<std::size_t>(a)] = mob_.move_energy(a, env_.propulsion());
}

void JointDp::evaluate_rates() {
  // A state is possible at some slot t when every UAV can have reached its cell from its start by
  // t and can still reach its destination from it by T_max (alive_windows' window, which must not
  // be empty: the slowest UAV from its start plus the slowest to its destination fit in
  // T_max - 1 slots), and no two UAVs are closer than D_min. R is computed there only: on the
  // paper's grid a third of the states whose UAVs could each be there alone are never alive.
  std::vector<std::vector<char>> useful(static_cast<std::size_t>(N_), std::vector<char>(static_cast<std::size_t>(G_), 0));
  for (int n = 0; n < N_; ++n)
    for (int c = 0; c < G_; ++c)
      useful[static_cast<std::size_t>(n)][static_cast<std::size_t>(c)] =
          from_start_[static_cast<std::size_t>(n)][static_cast<std::size_t>(c)] + to_dest_[static_cast<std::size_t>(n)][static_cast<std::size_t>(c)] <= Tmax_ - 1;
  R_.assign(S_, std::numeric_limits<double>::quiet_NaN());
  std::vector<std::size_t> need;
  Positions p(N_, 3);
  for (std::size_t s = 0; s < S_; ++s) {
    bool ok = true;
    int from = 0, to = 0;
    for (int n = 0; n < N_ && ok; ++n) {
      const auto c = static_cast<std::size_t>(cell(s, n));
      ok = useful[static_cast<std::size_t>(n)][c];
      from = std::max(from, from_start_[static_cast<std::size_t>(n)][c]);
      to = std::max(to, to_dest_[static_cast<std::size_t>(n)][c]);
    }
    if (!ok || from + to > Tmax_ - 1) continue;
    place(p, s);
    if (env_.collisions(p) > 0) continue;
    need.push_back(s);
  }
  if (progress_) *progress_ << "optimal: " << need.size() << " feasible joint states of " << S_ << "; evaluating R\n" << std::flush;
  const std::size_t chunk = 20000;
  for (std::size_t first = 0; first < need.size(); first += chunk) {
    std::vector<Positions> batch;
    const std::size_t last = std::min(need.size(), first + chunk);
    for (std::size_t i = first; i < last; ++i) {
      place(p, need[i]);
      batch.push_back(p);
    }
    const auto r = env_.oracle().sum_rates(batch);
    for (std::size_t i = first; i < last; ++i) R_[need[i]] = r[i - first];
  }
}

void JointDp::alive_windows() {
  // A state is alive at slot t when every UAV can have reached its cell from its start by slot t
  // and can reach its destination by T_max: first[s] <= t <= last[s] (first > last: never,
  // including the states with no rate, i.e. impossible or colliding ones).
  first_.resize(S_), last_.resize(S_);
  for (std::size_t s = 0; s < S_; ++s) {
    int from = 0, to = 0;
    for (int n = 0; n < N_; ++n) {
      const auto c = static_cast<std::size_t>(cell(s, n));
      from = std::max(from, from_start_[static_cast<std::size_t>(n)][c]);
      to = std::max(to, to_dest_[static_cast<std::size_t>(n)][c]);
    }
    const bool never = std::isnan(R_[s]);
    first_[s] = static_cast<std::int32_t>(never ? Tmax_ + 1 : from + 1);
    last_[s] = static_cast<std::int32_t>(never ? 0 : Tmax_ - to);
  }
}

void JointDp::backward(const std::vector<double>& cost, double lambda) {
  // The moves of UAV n out of cell c: the offset of the successor state and the move's index.
  struct Move {
    std::ptrdiff_t offset;
    int action;
  };
  std::vector<std::vector<Move>> moves(static_cast<std::size_t>(G_));
  const double hover_cost = cost[static_cast<std::size_t>(hover_)];
  for (int t = Tmax_; t >= 1; --t) {
    auto& Vt = V_[static_cast<std::size_t>(t - 1)];
    if (t < Tmax_) {
      // M(s) = max over joint actions of V[t+1](s') less their energy cost, one UAV at a time
      // (arrived UAVs only hover).
      M_ = V_[static_cast<std::size_t>(t)];
      for (int n = 0; n < N_; ++n) {
        // States in blocks of equal cell c of UAV n: s = (upper * G + c) * st + lower.
        const std::size_t st = stride_[static_cast<std::size_t>(n)], block = st * static_cast<std::size_t>(G_);
        for (int c = 0; c < G_; ++c) {
          auto& mv = moves[static_cast<std::size_t>(c)];
          mv.clear();
          if (c != d_cell_[static_cast<std::size_t>(n)])
            for (int a = 0; a < A_; ++a) {
              const int c2 = neighbour_[static_cast<std::size_t>(c * A_ + a)];
              if (a != hover_ && c2 >= 0) mv.push_back({static_cast<std::ptrdiff_t>(st) * (c2 - c), a});
            }
        }
        for (std::size_t upper = 0; upper < S_; upper += block)
          for (int c = 0; c < G_; ++c) {
            const auto& mv = moves[static_cast<std::size_t>(c)];
            const std::size_t from = upper + static_cast<std::size_t>(c) * st;
            const double* m = M_.data() + from;
            double* out = tmp_.data() + from;
            // Without an energy term every cost is 0, and v - 0 is v exactly.
            for (std::size_t i = 0; i < st; ++i) out[i] = m[i] - hover_cost;
            for (const Move& x : mv) {
              const double* m2 = m + x.offset;
              const double move_cost = cost[static_cast<std::size_t>(x.action)];
              for (std::size_t i = 0; i < st; ++i) out[i] = std::max(out[i], m2[i] - move_cost);
            }
          }
        M_.swap(tmp_);
      }
    }
    for (std::size_t s = 0; s < S_; ++s) {
      if (t < first_[s] || t > last_[s]) {
        Vt[s] = kNegInf;
        continue;
      }
      const double gain = kind_ == Objective::SumRate ? R_[s] - lambda : alpha_ * R_[s] - beta_ * lambda;
      if (s == s_home_) Vt[s] = gain;                        // the episode ends: T = t
      else Vt[s] = t < Tmax_ ? gain + M_[s] : kNegInf;       // not home at T_max: infeasible
    }
  }
}

void JointDp::recover(const std::vector<double>& cost, double g, OptimalPlan& plan) {
  const long joint = joint_count(A_, N_);
  path_.assign(1, s0_);
  std::vector<std::vector<int>> actions;
  int t = 1;
  while (path_.back() != s_home_) {
    const std::size_t s = path_.back();
    double best = kNegInf;
    std::size_t best_s = s;
    std::vector<int> best_a;
    for (long j = 0; j < joint; ++j) {
      const auto a = joint_action(j, N_, A_);
      std::size_t s2 = s;
      bool ok = true;
      double c_move = 0;
      for (int n = 0; n < N_ && ok; ++n) {
        const int c = cell(s, n);
        const int act = c == d_cell_[static_cast<std::size_t>(n)] ? hover_ : a[static_cast<std::size_t>(n)];
        if (act != a[static_cast<std::size_t>(n)]) {  // arrived UAVs: hover only
          ok = false;
          break;
        }
        c_move += cost[static_cast<std::size_t>(act)];
        const int c2 = neighbour_[static_cast<std::size_t>(c * A_ + act)];
        if (act != hover_ && c2 < 0) ok = false;
        else if (act != hover_)
          s2 = s2 + stride_[static_cast<std::size_t>(n)] * static_cast<std::size_t>(c2) - stride_[static_cast<std::size_t>(n)] * static_cast<std::size_t>(c);
      }
      if (!ok) continue;
      const double v = g != 0 ? V_[static_cast<std::size_t>(t)][s2] - c_move : V_[static_cast<std::size_t>(t)][s2];
      if (v > best) best = v, best_s = s2, best_a = a;
    }
    if (best_a.empty()) throw std::logic_error("optimal planner: no successor on the optimal path");
    actions.push_back(best_a);
    path_.push_back(best_s);
    ++t;
  }
  double total = 0, energy = 0;
  for (std::size_t s : path_) total += R_[s];
  for (const auto& a : actions)
    for (const int x : a) energy += move_energy_[static_cast<std::size_t>(x)];
  plan.objective = env_.objective_of(total, static_cast<int>(path_.size()), energy);
  plan.sum_rate_objective = total / static_cast<double>(path_.size());
  plan.energy_j = energy;
  plan.T = static_cast<int>(path_.size());
  plan.actions = actions;
}

OptimalPlan JointDp::solve() {
  evaluate_rates();
  OptimalPlan plan;
  plan.states = S_;
  for (double r : R_) plan.evaluated_states += !std::isnan(r);
  // Value tables V[t] for slots t = 1..Tmax (index t - 1).
  V_.assign(static_cast<std::size_t>(Tmax_), std::vector<double>(S_, kNegInf));
  plan.memory_bytes = static_cast<std::size_t>(Tmax_) * S_ * sizeof(double) + S_ * sizeof(double) * 3 + S_ * sizeof(std::int32_t) * 2;
  M_.resize(S_), tmp_.resize(S_);
  if (std::isnan(R_[s0_])) throw InputError("the start positions collide or cannot reach the destinations by trajectory.t_max");
  alive_windows();
  double lambda = 0.0;
  for (int iter = 1; iter <= 50; ++iter) {
    // Energy cost of each action this iteration (gamma, or lambda under energy-efficiency).
    const double g = kind_ == Objective::EnergyEfficiency ? lambda : gamma_;
    std::vector<double> cost(static_cast<std::size_t>(A_), 0.0);
    if (g != 0)
      for (int a = 0; a < A_; ++a) cost[static_cast<std::size_t>(a)] = g * move_energy_[static_cast<std::size_t>(a)];
    plan.iterations = iter;
    backward(cost, lambda);
    if (!std::isfinite(V_[0][s0_])) throw InputError("no joint trajectory brings every UAV home by trajectory.t_max without a collision");
    // Recover the maximiser and its true objective.
    recover(cost, g, plan);
    const double next = plan.objective;
    if (progress_)
      *progress_ << "optimal: iteration " << iter << "  lambda " << format_double(lambda) << " -> " << format_double(next)
                 << "  T = " << plan.T << "\n" << std::flush;
    if (kind_ == Objective::Energy) break;  // no ratio: one pass is the optimum
    // Dinkelbach's lambda rises from the ratio of a feasible plan: lambda = 0 before the first
    // iteration is none when the optimum is negative (weighted with a large w), so always go on once.
    if (iter > 1 && next <= (lambda >= 0 ? lambda * (1 + 1e-12) : lambda + 1e-12 * -lambda)) break;
    lambda = next;
  }
  // Arrived UAVs in the plan STAY (their recorded action is whatever index matched: normalise).
  for (std::size_t k = 0; k < plan.actions.size(); ++k)
    for (int n = 0; n < N_; ++n)
      if (cell(path_[k], n) == d_cell_[static_cast<std::size_t>(n)]) plan.actions[k][static_cast<std::size_t>(n)] = hover_;
  plan.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0_).count();
  env_.reset();
  return plan;
}

}  // namespace

OptimalPlan solve_optimal(UavEnv& env, std::ostream* progress) { return JointDp(env, progress).solve(); }

}  // namespace skyloop
