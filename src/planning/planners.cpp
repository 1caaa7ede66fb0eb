#include "skyloop/planning/planners.hpp"

#include <algorithm>
#include <chrono>
#include <future>
#include <map>
#include <mutex>
#include <cmath>
#include <cstdint>
#include <limits>
#include <ostream>
#include <stdexcept>

#include "skyloop/core/error.hpp"
#include "skyloop/core/io.hpp"
#include "joint.hpp"

namespace skyloop {

namespace {
constexpr double kNegInf = -std::numeric_limits<double>::infinity();

}  // namespace

std::vector<int> RandomPlanner::act(UavEnv& env) {
  std::vector<int> a(static_cast<std::size_t>(env.uavs()), env.hover());
  for (int n = 0; n < env.uavs(); ++n) {
    std::vector<int> ok;
    for (int k = 0; k < env.actions(); ++k)
      if (env.feasible(n, k)) ok.push_back(k);
    if (!ok.empty()) a[static_cast<std::size_t>(n)] = ok[rng_.below(ok.size())];
  }
  return a;
}

void GreedyPlanner::reset(UavEnv& env) {
  const long total = joint_count(env.actions(), env.uavs());
  if (total < 0 || total > kMaxJointActions)
    throw InputError("planner greedy enumerates A^N joint actions and takes at most " + std::to_string(kMaxJointActions) +
                     ", while the scenario has " + std::to_string(env.actions()) + "^" + std::to_string(env.uavs()) +
                     " (trajectory.mobility = " + env.dynamics().name() +
                     "): allowed seqgreedy (the sequential greedy, linear in N) for larger fleets or action spaces");
}

std::vector<int> GreedyPlanner::act(UavEnv& env) {
  const int n = env.uavs(), A = env.actions();
  const long total = joint_count(A, n);
  std::vector<std::vector<int>> candidates;
  std::vector<Positions> next;
  std::vector<int> colliding;
  for (long j = 0; j < total; ++j) {
    auto a = joint_action(j, n, A);
    bool ok = true;
    for (int i = 0; i < n && ok; ++i) ok = env.feasible(i, a[static_cast<std::size_t>(i)]);
    if (!ok) continue;
    next.push_back(env.next_positions(a));
    colliding.push_back(env.collisions(next.back()));
    candidates.push_back(std::move(a));
  }
  if (candidates.empty()) return std::vector<int>(static_cast<std::size_t>(n), env.hover());
  auto rates = env.oracle().sum_rates(next);
  // Under an energy-aware objective the look-ahead is the objective itself, the move's energy included.
  if (env.objective_kind() != Objective::SumRate)
    for (std::size_t c = 0; c < candidates.size(); ++c) rates[c] = env.objective_after(rates[c], env.step_energy(candidates[c]));
  std::size_t best = 0;
  for (std::size_t c = 1; c < candidates.size(); ++c)
    if (colliding[c] < colliding[best] || (colliding[c] == colliding[best] && rates[c] > rates[best])) best = c;
  return candidates[best];
}

std::vector<int> SequentialGreedyPlanner::act(UavEnv& env) {
  const int n = env.uavs();
  const int left = env.t_max() - env.t();
  std::vector<int> order(static_cast<std::size_t>(n)), slack(static_cast<std::size_t>(n));
  for (int i = 0; i < n; ++i) {
    order[static_cast<std::size_t>(i)] = i;
    slack[static_cast<std::size_t>(i)] = left - env.min_moves(i, env.positions()(i, 0), env.positions()(i, 1), env.altitude(i));
  }
  std::stable_sort(order.begin(), order.end(),
                   [&](int a, int b) { return slack[static_cast<std::size_t>(a)] < slack[static_cast<std::size_t>(b)]; });
  // The moves the mask allows (with the default safety: UavEnv::feasible's), and those the
  // collision search may add by spending the slack margin.
  const bool plain = safety_.margin == 0 && safety_.clearance == Clearance::None;
  std::vector<ActionSet> allowed(static_cast<std::size_t>(n), 0), spend(static_cast<std::size_t>(n), 0);
  for (int i = 0; i < n && !plain; ++i) {
    if (env.arrived(i)) continue;
    allowed[static_cast<std::size_t>(i)] = allowed_moves(env, i, safety_);
    if (safety_.margin > 0)
      spend[static_cast<std::size_t>(i)] = reachable_moves(env, i, 0, safety_.clearance) & ~allowed[static_cast<std::size_t>(i)];
  }
  auto may = [&](int i, int k) { return plain ? env.feasible(i, k) : (allowed[static_cast<std::size_t>(i)] >> k & 1u) != 0; };
  std::vector<int> a(static_cast<std::size_t>(n), env.hover());
  // Each UAV's feasible moves in the order the greedy pass prefers them (its choice first).
  std::vector<std::vector<int>> ranked(static_cast<std::size_t>(n), std::vector<int>{env.hover()});
  Positions placed = env.positions();  // chosen moves so far; the others still in place
  const double dmin = env.d_min() - 1e-9;
  for (int i : order) {
    if (env.arrived(i)) continue;
    std::vector<int> options;
    std::vector<Positions> next;
    std::vector<char> clear;
    for (int k = 0; k < env.actions(); ++k) {
      if (!may(i, k)) continue;
      Positions p = placed;
      place(p, i, env.landing(i, k));
      bool ok = true;
      for (int m = 0; m < n && ok; ++m)
        if (m != i && UavEnv::separation(p, i, m) < dmin) ok = false;
      options.push_back(k);
      next.push_back(std::move(p));
      clear.push_back(ok ? 1 : 0);
    }
    if (options.empty()) continue;  // cannot happen on a feasible mission: STAY keeps it as it was
    const bool any_clear = std::find(clear.begin(), clear.end(), 1) != clear.end();
    auto rates = env.oracle().sum_rates(next);
    if (env.objective_kind() != Objective::SumRate)  // the objective one slot ahead, the UAVs still to choose hovering
      for (std::size_t c = 0; c < options.size(); ++c) {
        std::vector<int> partial = a;
        partial[static_cast<std::size_t>(i)] = options[c];
        rates[c] = env.objective_after(rates[c], env.step_energy(partial));
      }
    std::vector<std::size_t> pref(options.size());
    for (std::size_t c = 0; c < pref.size(); ++c) pref[c] = c;
    std::stable_sort(pref.begin(), pref.end(), [&](std::size_t x, std::size_t y) {
      if (any_clear && clear[x] != clear[y]) return clear[x] > clear[y];
      return rates[x] > rates[y];
    });
    auto& r = ranked[static_cast<std::size_t>(i)];
    r.clear();
    for (std::size_t c : pref) r.push_back(options[c]);
    a[static_cast<std::size_t>(i)] = options[pref.front()];
    placed = next[pref.front()];
  }
  if (env.collisions(env.next_positions(a)) == 0) return a;
  // The pass left a collision (a UAV met a move chosen before it with no clear move of its own).
  // Search the UAVs' ranked moves depth-first, in the same order, for a collision-free joint move:
  // the first found deviates least from the greedy choices. Bounded; the greedy move otherwise.
  std::vector<double> x(static_cast<std::size_t>(n)), y(static_cast<std::size_t>(n)), z(static_cast<std::size_t>(n));
  for (int i = 0; i < n; ++i)  // after its ranked moves, the ones that spend margin
    for (int k = 0; k < env.actions(); ++k)
      if (spend[static_cast<std::size_t>(i)] >> k & 1u) ranked[static_cast<std::size_t>(i)].push_back(k);
  std::vector<std::vector<UavEnv::Landing>> target(static_cast<std::size_t>(n));
  for (int i = 0; i < n; ++i)
    for (int k : ranked[static_cast<std::size_t>(i)]) target[static_cast<std::size_t>(i)].push_back(env.landing(i, k));
  std::vector<std::size_t> pick(static_cast<std::size_t>(n), 0);
  long budget = kSearchBudget;
  int depth = 0;
  while (depth >= 0 && budget-- > 0) {
    if (depth == n) {
      for (int d = 0; d < n; ++d) {
        const int i = order[static_cast<std::size_t>(d)];
        a[static_cast<std::size_t>(i)] = ranked[static_cast<std::size_t>(i)][pick[static_cast<std::size_t>(d)]];
      }
      return a;
    }
    const int i = order[static_cast<std::size_t>(depth)];
    auto& k = pick[static_cast<std::size_t>(depth)];
    if (k >= ranked[static_cast<std::size_t>(i)].size()) {  // exhausted: back up
      k = 0;
      if (--depth >= 0) ++pick[static_cast<std::size_t>(depth)];
      continue;
    }
    const UavEnv::Landing& to = target[static_cast<std::size_t>(i)][k];
    bool ok = true;
    for (int d = 0; d < depth && ok; ++d) {
      const auto m = static_cast<std::size_t>(order[static_cast<std::size_t>(d)]);
      ok = UavEnv::separation(to.x - x[m], to.y - y[m], to.z - z[m]) >= dmin;
    }
    if (!ok) {
      ++k;
      continue;
    }
    x[static_cast<std::size_t>(i)] = to.x, y[static_cast<std::size_t>(i)] = to.y, z[static_cast<std::size_t>(i)] = to.z;
    ++depth;
    if (depth < n) pick[static_cast<std::size_t>(depth)] = 0;
  }
  for (int i = 0; i < n; ++i) a[static_cast<std::size_t>(i)] = ranked[static_cast<std::size_t>(i)].front();
  return a;
}

// ---- exact optimum --------------------------------------------------------------------------

const LatticeDynamics& require_lattice(const UavEnv& env, const std::string& who) {
  const LatticeDynamics* lattice = env.dynamics().lattice();
  if (!lattice)
    throw InputError(who + " searches the D_fly lattice, which trajectory.mobility = \"" + env.dynamics().name() +
                     "\" leaves: allowed trajectory.mobility = " + lattice_dynamics_names() +
                     " (missions off the lattice: random, greedy, seqgreedy, the learners)");
  return *lattice;
}

std::string optimum_key(const Config& cfg) {
  Config key = cfg;
  const EnvConfig plain;
  key.env.w_rate = plain.w_rate, key.env.w_arr = plain.w_arr, key.env.w_bud = plain.w_bud, key.env.w_col = plain.w_col,
  key.env.w_fea = plain.w_fea;
  key.env.reward = plain.reward;
  key.env.state = plain.state;
  key.env.resample_users = false;
  key.env.users_min = key.env.users_max = 0;
  // One "key = value" line per field the optimum can depend on: the learners' and the run's
  // sections and the fields' help texts stay out, so that a new learner setting or a reworded help
  // leaves every cached optimum valid.
  std::string text;
  for (const auto& f : config_fields()) {
    if (f.key.rfind("marl.", 0) == 0 || f.key.rfind("run.", 0) == 0) continue;
    text += f.key + " = " + format_value(f.get(key)) + "\n";
  }
  return text;
}

bool fits_optimal(const UavEnv& env) {
  if (!env.dynamics().lattice()) return false;
  const LatticeFrame f = env.dynamics().lattice()->frame(env.mission(), 0);
  const double G = static_cast<double>(f.nx) * static_cast<double>(f.ny) * static_cast<double>(f.nz);
  const double states = std::pow(G, env.uavs());
  return states <= 5e6 && states * env.t_max() <= 134217728.0;
}

void OptimalPlanner::reset(UavEnv& env) {
  if (memo_key_.empty()) {
    plan_ = solve_optimal(env, progress_);
    return;
  }
  // One solve per key and process: a second thread asking for a key being solved waits for it
  // (reproduce evaluates pieces on several threads, and pieces share optima).
  static std::mutex mutex;
  static std::map<std::string, std::shared_future<OptimalPlan>> memo;
  std::promise<OptimalPlan> mine;
  std::shared_future<OptimalPlan> plan;
  bool solve = false;
  {
    std::lock_guard<std::mutex> lock(mutex);
    auto it = memo.find(memo_key_);
    if (it == memo.end()) {
      it = memo.emplace(memo_key_, mine.get_future().share()).first;
      solve = true;
    }
    plan = it->second;
  }
  if (solve) {
    try {
      mine.set_value(solve_optimal(env, progress_));
    } catch (...) {
      {
        std::lock_guard<std::mutex> lock(mutex);
        memo.erase(memo_key_);  // a failed solve is not remembered: the next caller gets its own error
      }
      mine.set_exception(std::current_exception());
    }
  }
  plan_ = plan.get();
}

std::vector<int> replay(const std::vector<std::vector<int>>& actions, const UavEnv& env) {
  const auto k = static_cast<std::size_t>(env.t() - 1);
  if (k >= actions.size()) return std::vector<int>(static_cast<std::size_t>(env.uavs()), env.hover());
  return actions[k];
}

std::vector<int> OptimalPlanner::act(UavEnv& env) { return replay(plan_.actions, env); }

double brute_force_optimum(UavEnv& env) {
  const LatticeDynamics& lattice = require_lattice(env, "the brute-force optimum");
  env.reset();
  const int N = env.uavs();
  double best = kNegInf;
  bool found = false;
  // Depth-first over joint actions; the environment cannot be copied cheaply, so positions are
  // tracked here and R comes from the oracle.
  struct Frame {
    Positions pos;
    std::vector<bool> home;
    double sum;
    int t;
    double energy;
  };
  const int A = env.actions(), hover = env.hover();
  const long joint = joint_count(A, N);
  std::vector<double> move_energy(static_cast<std::size_t>(A));
  for (int a = 0; a < A; ++a)
    move_energy[static_cast<std::size_t>(a)] = lattice.move_energy(a, env.propulsion());
  const Positions dest = env.destinations();
  auto is_home = [&](const Positions& p, int n) {
    return std::abs(p(n, 0) - dest(n, 0)) < 1e-6 && std::abs(p(n, 1) - dest(n, 1)) < 1e-6 && std::abs(p(n, 2) - dest(n, 2)) < 1e-6;
  };
  std::vector<Frame> stack;
  Frame f0{env.positions(), std::vector<bool>(static_cast<std::size_t>(N)), env.rates().front(), 1, 0.0};
  for (int n = 0; n < N; ++n) f0.home[static_cast<std::size_t>(n)] = is_home(f0.pos, n);
  stack.push_back(f0);
  while (!stack.empty()) {
    Frame f = std::move(stack.back());
    stack.pop_back();
    if (std::all_of(f.home.begin(), f.home.end(), [](bool b) { return b; })) {
      const double j = env.objective_of(f.sum, f.t, f.energy);
      found = true;
      best = std::max(best, j);
      continue;
    }
    if (f.t >= env.t_max()) continue;
    for (long j = 0; j < joint; ++j) {
      const auto a = joint_action(j, N, A);
      Positions next = f.pos;
      bool ok = true;
      double e = 0;
      for (int n = 0; n < N && ok; ++n) {
        e += move_energy[static_cast<std::size_t>(a[static_cast<std::size_t>(n)])];
        if (f.home[static_cast<std::size_t>(n)]) {
          ok = a[static_cast<std::size_t>(n)] == hover;
          continue;
        }
        Flight from;
        from.x = f.pos(n, 0), from.y = f.pos(n, 1), from.z = f.pos(n, 2);
        const Flight to = lattice.fly(n, from, a[static_cast<std::size_t>(n)], env.mission());
        ok = to.inside;
        place(next, n, to);
      }
      if (!ok || env.collisions(next) > 0) continue;
      Frame g{next, f.home, f.sum + env.oracle().sum_rate(next), f.t + 1, f.energy + e};
      for (int n = 0; n < N; ++n) g.home[static_cast<std::size_t>(n)] = g.home[static_cast<std::size_t>(n)] || is_home(next, n);
      stack.push_back(std::move(g));
    }
  }
  return found ? best : std::numeric_limits<double>::quiet_NaN();
}

Positions Planner::act_velocities(UavEnv& env) { return env.primitive_velocities(act(env)); }

EpisodeRecord run_episode(UavEnv& env, Planner& planner) {
  env.reset();
  planner.reset(env);
  EpisodeRecord r;
  r.planner = planner.name();
  r.action_names = env.dynamics().actions();
  r.positions.push_back(env.positions());
  while (!env.done()) {
    std::vector<int> a;
    StepInfo info;
    if (planner.commands_velocities()) {
      const Positions v = planner.act_velocities(env);
      for (int n = 0; n < env.uavs(); ++n) a.push_back(env.arrived(n) ? env.hover() : -1);
      info = env.step_velocities(v);
    } else {
      a = planner.act(env);
      for (int n = 0; n < env.uavs(); ++n)
        if (env.arrived(n)) a[static_cast<std::size_t>(n)] = env.hover();
      info = env.step(a);
    }
    r.actions.push_back(a);
    r.steps.push_back(info);
    r.positions.push_back(env.positions());
    std::vector<double> v, p;
    for (int n = 0; n < env.uavs(); ++n) v.push_back(env.last_speed(n)), p.push_back(env.last_power(n));
    r.speeds.push_back(std::move(v));
    r.powers.push_back(std::move(p));
    r.reward += info.reward;
    r.success = info.success;
  }
  r.T = env.t();
  r.rates = env.rates();
  r.objective = env.objective();
  r.sum_rate_objective = env.sum_rate_objective();
  r.energy_j = env.energy_j();
  r.bits_per_joule = env.bits_per_joule();
  for (int n = 0; n < env.uavs(); ++n) r.uav_energy_j.push_back(env.energy_j(n));
  r.over_budget = env.over_budget();
  r.arrivals = env.total_arrivals();
  r.boundary = env.total_boundary();
  r.collisions = env.total_collisions();
  return r;
}

}  // namespace skyloop
