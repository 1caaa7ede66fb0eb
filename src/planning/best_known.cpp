// The best-known planner: the exact optimum where the joint dynamic programme fits, and beyond it
// iterated best responses, each UAV's exact single-UAV optimum (Dinkelbach over its own grid and
// the slots) with the other UAVs' trajectories fixed, until no UAV improves the joint objective.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <ostream>

#include "skyloop/core/error.hpp"
#include "skyloop/core/io.hpp"
#include "skyloop/planning/planners.hpp"

namespace skyloop {

namespace {

constexpr double kNegInf = -std::numeric_limits<double>::infinity();

/// One UAV's D_fly lattice through its start, clipped to the area (over the dynamics' levels).
struct Lattice : LatticeFrame {
  const LatticeDynamics* mob;
  std::vector<int> from_start, to_dest;  // fewest slots from the start / to the destination
  Lattice(const UavEnv& env, int n) : LatticeFrame(env.dynamics().lattice()->frame(env.mission(), n)), mob(env.dynamics().lattice()) {
    auto fix = [&](std::vector<int> v) {
      for (int& x : v) x = x < 0 ? env.t_max() + 1 : x;
      return v;
    };
    from_start = fix(mob->slots_to(*this, at(env.starts(), n)));
    to_dest = fix(mob->slots_to(*this, at(env.destinations(), n)));
  }
  /// The cell of row n of p.
  int at(const Positions& p, int n) const { return cell(p(n, 0), p(n, 1), p(n, 2)); }
  /// The cell after action a, or -1 outside the grid.
  int step(int c, int a) const { return move(c, mob->step(a)); }
  int action(int from, int to) const {
    for (int a = 0; a < mob->count(); ++a)
      if (step(from, a) == to) return a;
    throw std::logic_error("best-known planner: non-adjacent cells on a trajectory");
  }
};

/// Joint trajectories as positions per UAV and slot (slot 1 = the starts); after its arrival a
/// UAV stays at its destination.
struct Trajectories {
  std::vector<std::vector<int>> cell;  // [N][T_n] cells of each UAV's own lattice, slot 1..T_n
  int T() const {
    std::size_t t = 0;
    for (const auto& c : cell) t = std::max(t, c.size());
    return static_cast<int>(t);
  }
  int at(int n, int t) const {  // cell at slot t (1-based), the destination after arrival
    const auto& c = cell[static_cast<std::size_t>(n)];
    return c[std::min(c.size(), static_cast<std::size_t>(t)) - 1];
  }
};

/// Iterated best responses from the sequential greedy's episode (the plan beyond the DP's size).
class BestResponses {
 public:
  BestResponses(UavEnv& env, std::ostream* progress);
  /// Rounds of best responses until none improves (at most max_rounds), into plan.
  void run(int max_rounds, BestKnownPlan& plan);

 private:
  /// The sequential greedy's episode as cells of each UAV's lattice.
  void greedy_start();
  Positions positions_at(const Trajectories& tr, int t) const;
  /// (1/T) sum R[t] of tr, and its collisions.
  double evaluate(const Trajectories& tr, int& collisions) const;
  /// Best response of UAV i with the others fixed; true if it improved tr.
  bool best_response(int i, Trajectories& tr, double& objective, int& collisions) const;
  /// One UAV's view of a best response: its lattice and cells, the others' horizon, its rates.
  struct Response {
    const Lattice& L;
    int G, si, di, T_others;
    std::vector<std::vector<double>> R;  // R[t][c]: sum rate at slot t with UAV i at c (NaN: not there)
    /// After arriving at slot tau, UAV i waits at its destination until the others are home.
    double tail(int tau, double lambda) const;
    /// r - lambda + the value after it of moving from c to c2 at slot t + 1 (kNegInf: no move).
    double value(const std::vector<std::vector<double>>& V, int t, int c2, double lambda) const;
  };
  /// R[t][c] for UAV i with the others on tr: slots up to max(T_max, T_others), the cells on a
  /// way home in time and clear of the others.
  void rate_table(int i, const Trajectories& tr, Response& r) const;
  /// The best path of UAV i (its cells from slot 1) under ratio lambda, or empty when none.
  std::vector<int> best_path(const Response& r, double lambda) const;

  UavEnv& env_;
  std::ostream* progress_;
  int N_, Tmax_, A_, hover_;
  double dmin_;
  std::vector<Lattice> lat_;
  std::vector<int> s_cell_, d_cell_;
  Trajectories cur_;
};

BestResponses::BestResponses(UavEnv& env, std::ostream* progress)
    : env_(env), progress_(progress), N_(env.uavs()), Tmax_(env.t_max()), A_(env.actions()), hover_(env.hover()), dmin_(env.d_min() - 1e-9) {
  env_.reset();
  if (env_.objective_kind() != Objective::SumRate)
    throw InputError("the best-known planner's best responses score the sum rate only: allowed env.objective = \"sum-rate\" "
                     "beyond the optimal planner's size (the optimal planner takes every objective)");
  for (int n = 0; n < N_; ++n) lat_.emplace_back(env_, n);
  // A best response's rate table holds (T_max + 1) x the UAV's lattice points: at most 2^27
  // doubles (1 GiB), the optimal planner's limit on its value table.
  constexpr double kMaxTableEntries = 134217728.0;
  double cells = 0;
  for (const auto& l : lat_) cells = std::max(cells, static_cast<double>(l.cells()));
  if ((Tmax_ + 1.0) * cells > kMaxTableEntries)
    throw InputError("the best-known planner's rate table has " + format_double((Tmax_ + 1.0) * cells) +
                     " entries ((trajectory.t_max + 1) x " + format_double(cells) +
                     " lattice points of a UAV): allowed at most 2^27 (1 GiB), i.e. trajectory.t_max <= " +
                     std::to_string(static_cast<long long>(kMaxTableEntries / cells) - 1) + " on this lattice; use seqgreedy beyond");
  s_cell_.resize(static_cast<std::size_t>(N_)), d_cell_.resize(static_cast<std::size_t>(N_));
  for (int n = 0; n < N_; ++n) {
    s_cell_[static_cast<std::size_t>(n)] = lat_[static_cast<std::size_t>(n)].at(env_.starts(), n);
    d_cell_[static_cast<std::size_t>(n)] = lat_[static_cast<std::size_t>(n)].at(env_.destinations(), n);
  }
  greedy_start();
}

void BestResponses::greedy_start() {
  cur_.cell.resize(static_cast<std::size_t>(N_));
  SequentialGreedyPlanner seq;
  const auto rec = run_episode(env_, seq);
  for (int n = 0; n < N_; ++n) {
    auto& c = cur_.cell[static_cast<std::size_t>(n)];
    for (const auto& p : rec.positions) {
      c.push_back(lat_[static_cast<std::size_t>(n)].at(p, n));
      if (c.back() == d_cell_[static_cast<std::size_t>(n)]) break;
    }
    if (c.back() != d_cell_[static_cast<std::size_t>(n)])
      throw InputError("the best-known planner's start (the sequential greedy) does not bring UAV " + std::to_string(n) +
                       " home by trajectory.t_max");
  }
}

Positions BestResponses::positions_at(const Trajectories& tr, int t) const {
  Positions p(N_, 3);
  for (int n = 0; n < N_; ++n) {
    const int c = tr.at(n, t);
    const Lattice& L = lat_[static_cast<std::size_t>(n)];
    p(n, 0) = L.x(c), p(n, 1) = L.y(c), p(n, 2) = L.z(c);
  }
  return p;
}

double BestResponses::evaluate(const Trajectories& tr, int& collisions) const {
  std::vector<Positions> slots;
  collisions = 0;
  for (int t = 1; t <= tr.T(); ++t) {
    slots.push_back(positions_at(tr, t));
    collisions += env_.collisions(slots.back());
  }
  const auto r = env_.oracle().sum_rates(slots);
  double total = 0;
  for (double x : r) total += x;
  return total / static_cast<double>(tr.T());
}

double BestResponses::Response::tail(int tau, double lambda) const {
  double v = 0;
  for (int t = tau + 1; t <= T_others; ++t) {
    const double r = R[static_cast<std::size_t>(t)][static_cast<std::size_t>(di)];
    if (std::isnan(r)) return kNegInf;
    v += r - lambda;
  }
  return v;
}

double BestResponses::Response::value(const std::vector<std::vector<double>>& V, int t, int c2, double lambda) const {
  const double r = R[static_cast<std::size_t>(t + 1)][static_cast<std::size_t>(c2)];
  if (std::isnan(r)) return std::numeric_limits<double>::quiet_NaN();
  return r - lambda + (c2 == di ? tail(t + 1, lambda) : V[static_cast<std::size_t>(t + 1)][static_cast<std::size_t>(c2)]);
}

void BestResponses::rate_table(int i, const Trajectories& tr, Response& r) const {
  const Lattice& L = r.L;
  const int Tend = std::max(Tmax_, r.T_others);
  r.R.assign(static_cast<std::size_t>(Tend + 1), std::vector<double>(static_cast<std::size_t>(r.G), NAN));
  std::vector<Positions> batch;
  std::vector<std::pair<int, int>> where;
  for (int t = 1; t <= Tend; ++t) {
    Positions p = positions_at(tr, t);
    for (int c = 0; c < r.G; ++c) {
      const bool on_path =
          t <= Tmax_ ? L.from_start[static_cast<std::size_t>(c)] <= t - 1 && L.to_dest[static_cast<std::size_t>(c)] <= Tmax_ - t : c == r.di;
      if (!on_path) continue;
      const double x = L.x(c), y = L.y(c), z = L.z(c);
      bool clear = true;
      for (int m = 0; m < N_ && clear; ++m)
        if (m != i) clear = UavEnv::separation(x - p(m, 0), y - p(m, 1), z - p(m, 2)) >= dmin_;
      if (!clear) continue;
      p(i, 0) = x, p(i, 1) = y, p(i, 2) = z;
      batch.push_back(p);
      where.emplace_back(t, c);
    }
  }
  const auto rates = env_.oracle().sum_rates(batch);
  for (std::size_t k = 0; k < rates.size(); ++k)
    r.R[static_cast<std::size_t>(where[k].first)][static_cast<std::size_t>(where[k].second)] = rates[k];
}

std::vector<int> BestResponses::best_path(const Response& r, double lambda) const {
  const Lattice& L = r.L;
  std::vector<std::vector<double>> V(static_cast<std::size_t>(Tmax_ + 1), std::vector<double>(static_cast<std::size_t>(r.G), kNegInf));
  // V[t][c]: the best sum of (R - lambda) over slots t + 1.. from cell c at slot t (not arrived).
  for (int t = Tmax_; t >= 1; --t)
    for (int c = 0; c < r.G; ++c) {
      double best = kNegInf;
      if (t < Tmax_ && c != r.di && !std::isnan(r.R[static_cast<std::size_t>(t)][static_cast<std::size_t>(c)]))
        for (int a = 0; a < A_; ++a) {
          const int c2 = a == hover_ ? c : L.step(c, a);
          if (c2 < 0) continue;
          const double v = r.value(V, t, c2, lambda);
          if (!std::isnan(v)) best = std::max(best, v);
        }
      V[static_cast<std::size_t>(t)][static_cast<std::size_t>(c)] = best;
    }
  if (!std::isfinite(V[1][static_cast<std::size_t>(r.si)])) return {};
  // The maximiser's path.
  std::vector<int> path{r.si};
  while (path.back() != r.di) {
    const int t = static_cast<int>(path.size()), c = path.back();
    int next = -1;
    double best = kNegInf;
    for (int a = 0; a < A_; ++a) {
      const int c2 = a == hover_ ? c : L.step(c, a);
      if (c2 < 0) continue;
      const double v = r.value(V, t, c2, lambda);
      if (std::isnan(v)) continue;
      if (v > best) best = v, next = c2;
    }
    path.push_back(next);
  }
  return path;
}

bool BestResponses::best_response(int i, Trajectories& tr, double& objective, int& collisions) const {
  const Lattice& L = lat_[static_cast<std::size_t>(i)];
  int T_others = 0;
  for (int m = 0; m < N_; ++m)
    if (m != i) T_others = std::max(T_others, static_cast<int>(tr.cell[static_cast<std::size_t>(m)].size()));
  Response r{L, L.cells(), s_cell_[static_cast<std::size_t>(i)], d_cell_[static_cast<std::size_t>(i)], T_others, {}};
  rate_table(i, tr, r);
  if (std::isnan(r.R[1][static_cast<std::size_t>(r.si)])) return false;
  double lambda = objective;
  bool improved = false;
  for (int iter = 0; iter < 50; ++iter) {
    const std::vector<int> path = best_path(r, lambda);
    if (path.empty()) return improved;
    Trajectories trial = tr;
    trial.cell[static_cast<std::size_t>(i)] = path;
    int trial_collisions = 0;
    const double j = evaluate(trial, trial_collisions);
    const bool better = trial_collisions < collisions || (trial_collisions == collisions && j > objective * (1 + 1e-12));
    if (!better) break;
    tr = trial, objective = j, collisions = trial_collisions, improved = true;
    if (j <= lambda * (1 + 1e-12)) break;
    lambda = j;
  }
  return improved;
}

void BestResponses::run(int max_rounds, BestKnownPlan& plan) {
  int cur_collisions = 0;
  double cur_objective = evaluate(cur_, cur_collisions);
  plan.start_objective = cur_objective;
  for (int round = 1; round <= max_rounds; ++round) {
    plan.rounds = round;
    bool any = false;
    for (int i = 0; i < N_; ++i)
      if (best_response(i, cur_, cur_objective, cur_collisions)) any = true, ++plan.improvements;
    if (progress_)
      *progress_ << "bestknown: round " << round << "  objective " << format_double(cur_objective) << "  collisions "
                 << cur_collisions << "\n" << std::flush;
    if (!any) break;
  }
  plan.objective = cur_objective;
  plan.T = cur_.T();
  plan.collisions = cur_collisions;
  for (int t = 1; t < plan.T; ++t) {
    std::vector<int> a(static_cast<std::size_t>(N_), hover_);
    for (int n = 0; n < N_; ++n)
      if (cur_.at(n, t) != d_cell_[static_cast<std::size_t>(n)])
        a[static_cast<std::size_t>(n)] = lat_[static_cast<std::size_t>(n)].action(cur_.at(n, t), cur_.at(n, t + 1));
    plan.actions.push_back(std::move(a));
  }
}

}  // namespace

BestKnownPlan solve_best_known(UavEnv& env, std::ostream* progress, int max_rounds, bool iterated) {
  using Clock = std::chrono::steady_clock;
  const auto t0 = Clock::now();
  BestKnownPlan plan;
  require_lattice(env, "the best-known planner");
  if (!iterated && fits_optimal(env)) {
    const auto o = solve_optimal(env, progress);
    plan.objective = o.objective, plan.T = o.T, plan.actions = o.actions, plan.exact = true;
    plan.seconds = std::chrono::duration<double>(Clock::now() - t0).count();
    return plan;
  }
  BestResponses(env, progress).run(max_rounds, plan);
  plan.seconds = std::chrono::duration<double>(Clock::now() - t0).count();
  env.reset();
  return plan;
}

void BestKnownPlanner::reset(UavEnv& env) { plan_ = solve_best_known(env, progress_, max_rounds_, force_iterated_); }

std::vector<int> BestKnownPlanner::act(UavEnv& env) { return replay(plan_.actions, env); }

}  // namespace skyloop
