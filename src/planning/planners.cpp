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

namespace skyloop {

namespace {
constexpr double kNegInf = -std::numeric_limits<double>::infinity();

/// All joint actions of n UAVs with A actions each, index j -> digit n = (j / A^n) % A.
std::vector<int> joint_action(long j, int n, int A) {
  std::vector<int> a(static_cast<std::size_t>(n));
  for (int i = 0; i < n; ++i, j /= A) a[static_cast<std::size_t>(i)] = static_cast<int>(j % A);
  return a;
}
/// A^n, or -1 above 2^40.
long joint_count(int A, int n) {
  long p = 1;
  for (int i = 0; i < n; ++i) {
    if (p > (1L << 40) / A) return -1;
    p *= A;
  }
  return p;
}
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
                     " (trajectory.mobility = " + env.mobility().name() +
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
    slack[static_cast<std::size_t>(i)] = left - env.min_moves(i, env.positions()(i, 0), env.positions()(i, 1));
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
      const UavEnv::Landing l = env.landing(i, k);
      const double nx = l.x, ny = l.y;
      p(i, 0) = nx, p(i, 1) = ny;
      bool ok = true;
      for (int m = 0; m < n && ok; ++m)
        if (m != i && std::hypot(nx - p(m, 0), ny - p(m, 1)) < dmin) ok = false;
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
  std::vector<double> x(static_cast<std::size_t>(n)), y(static_cast<std::size_t>(n));
  for (int i = 0; i < n; ++i)  // after its ranked moves, the ones that spend margin
    for (int k = 0; k < env.actions(); ++k)
      if (spend[static_cast<std::size_t>(i)] >> k & 1u) ranked[static_cast<std::size_t>(i)].push_back(k);
  std::vector<std::vector<std::pair<double, double>>> target(static_cast<std::size_t>(n));
  for (int i = 0; i < n; ++i)
    for (int k : ranked[static_cast<std::size_t>(i)]) {
      const UavEnv::Landing l = env.landing(i, k);
      target[static_cast<std::size_t>(i)].emplace_back(l.x, l.y);
    }
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
    const auto [nx, ny] = target[static_cast<std::size_t>(i)][k];
    bool ok = true;
    for (int d = 0; d < depth && ok; ++d) {
      const int m = order[static_cast<std::size_t>(d)];
      ok = std::hypot(nx - x[static_cast<std::size_t>(m)], ny - y[static_cast<std::size_t>(m)]) >= dmin;
    }
    if (!ok) {
      ++k;
      continue;
    }
    x[static_cast<std::size_t>(i)] = nx, y[static_cast<std::size_t>(i)] = ny;
    ++depth;
    if (depth < n) pick[static_cast<std::size_t>(depth)] = 0;
  }
  for (int i = 0; i < n; ++i) a[static_cast<std::size_t>(i)] = ranked[static_cast<std::size_t>(i)].front();
  return a;
}

// ---- exact optimum --------------------------------------------------------------------------

void require_lattice(const UavEnv& env, const std::string& who) {
  if (env.mobility().continuous())
    throw InputError(who + " searches the D_fly lattice, which trajectory.mobility = \"continuous\" leaves: allowed "
                     "trajectory.mobility = grid or headings (continuous missions: random, greedy, seqgreedy, the learners)");
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
  if (env.mobility().continuous()) return false;
  const double d = env.d_fly();
  const LatticeFrame f(env.starts()(0, 0), env.starts()(0, 1), env.area_x(), env.area_y(), d);
  const double G = static_cast<double>(f.nx) * static_cast<double>(f.ny);
  const double states = std::pow(G, env.uavs());
  return states <= 5e6 && states * env.t_max() <= 134217728.0;
}

OptimalPlan solve_optimal(UavEnv& env, std::ostream* progress) {
  using Clock = std::chrono::steady_clock;
  const auto t0 = Clock::now();
  env.reset();
  const int N = env.uavs(), Tmax = env.t_max(), A = env.actions(), hover = env.hover();
  const MobilityModel& mob = env.mobility();
  const PropulsionModel& prop = env.propulsion();
  require_lattice(env, "the optimal planner");
  if (prop.kinetic())
    throw InputError("energy.acceleration = \"kinetic\" makes a move's energy depend on the previous speed, which the optimal "
                     "planner's state does not hold: allowed energy.acceleration = \"none\" for the optimal planner");
  if (env.budget_j() > 0)
    throw InputError("energy.budget_j = " + format_double(env.budget_j()) + " is not a constraint of the optimal planner's DP: "
                     "allowed energy.budget_j = 0 for the optimal planner (the plans report each UAV's energy)");
  const double d = env.d_fly();
  const Positions start = env.positions(), dest = env.destinations();
  // The D_fly lattice through start 0, clipped to the area.
  const LatticeFrame frame(start(0, 0), start(0, 1), env.area_x(), env.area_y(), d);
  const double ox = frame.ox, oy = frame.oy;
  const int nx = frame.nx, ny = frame.ny;
  const int G = nx * ny;
  auto cell_of = [&](double x, double y, const std::string& what) {
    const double fx = (x - ox) / d, fy = (y - oy) / d;
    const long ix = std::lround(fx), iy = std::lround(fy);
    if (std::abs(fx - static_cast<double>(ix)) > 1e-6 || std::abs(fy - static_cast<double>(iy)) > 1e-6 || ix < 0 || iy < 0 ||
        ix >= nx || iy >= ny)
      throw InputError(what + " = [" + format_double(x) + ", " + format_double(y) +
                       "] is not on the D_fly grid of trajectory.starts[0]: the optimal planner needs every start and "
                       "destination on one grid of spacing trajectory.d_fly_m");
    return static_cast<int>(iy * nx + ix);
  };
  std::vector<int> s_cell(static_cast<std::size_t>(N)), d_cell(static_cast<std::size_t>(N));
  for (int n = 0; n < N; ++n) {
    s_cell[static_cast<std::size_t>(n)] = cell_of(start(n, 0), start(n, 1), "trajectory.starts[" + std::to_string(n) + "]");
    d_cell[static_cast<std::size_t>(n)] = cell_of(dest(n, 0), dest(n, 1), "trajectory.destinations[" + std::to_string(n) + "]");
  }
  double Sd = 1;
  for (int n = 0; n < N; ++n) Sd *= G;
  if (Sd > 5e6) {
    // The largest instances within the limit: UAVs on this grid, and the grid for this many UAVs.
    int max_uavs = 0;
    for (double s = G; s <= 5e6; s *= G) ++max_uavs;
    const int max_cells = static_cast<int>(std::floor(std::pow(5e6, 1.0 / N) + 1e-9));
    throw InputError("the optimal planner's joint grid has " + format_double(Sd) + " states (" + std::to_string(G) +
                     " cells ^ " + std::to_string(N) + " UAVs): allowed at most 5e6, i.e. at most " + std::to_string(max_uavs) +
                     " UAVs on this " + std::to_string(nx) + " x " + std::to_string(ny) + " grid, or at most " +
                     std::to_string(max_cells) + " cells for " + std::to_string(N) + " UAVs; use seqgreedy or a learned planner beyond");
  }
  // The value table holds T_max x states doubles: at most 2^27 of them (1 GiB).
  constexpr double kMaxTableEntries = 134217728.0;
  if (Sd * Tmax > kMaxTableEntries)
    throw InputError("the optimal planner's value table has " + format_double(Sd * Tmax) + " entries (" +
                     format_double(Sd) + " joint states x trajectory.t_max = " + std::to_string(Tmax) +
                     "): allowed at most 2^27 (1 GiB), i.e. trajectory.t_max <= " +
                     std::to_string(static_cast<long long>(kMaxTableEntries / Sd)) + " on this grid; use seqgreedy beyond");
  const std::size_t S = static_cast<std::size_t>(Sd);
  std::vector<std::size_t> stride(static_cast<std::size_t>(N));
  for (int n = 0; n < N; ++n) stride[static_cast<std::size_t>(n)] = n == 0 ? 1 : stride[static_cast<std::size_t>(n - 1)] * static_cast<std::size_t>(G);
  auto cx = [&](int c) { return ox + d * (c % nx); };
  auto cy = [&](int c) { return oy + d * (c / nx); };
  // neighbour[c * A + a] = cell after action a, or -1 outside the grid.
  std::vector<int> neighbour(static_cast<std::size_t>(G * A), -1);
  for (int c = 0; c < G; ++c)
    for (int a = 0; a < A; ++a) {
      const int jx = c % nx + mob.step(a).dx, jy = c / nx + mob.step(a).dy;
      if (jx >= 0 && jx < nx && jy >= 0 && jy < ny) neighbour[static_cast<std::size_t>(c * A + a)] = jy * nx + jx;
    }
  // Fewest slots between each cell and each UAV's start and destination (the model's moves inside
  // the area; unreachable = a number past the horizon).
  std::vector<std::vector<int>> from_start, to_dest;
  for (int n = 0; n < N; ++n) {
    auto fix = [&](std::vector<int> v) {
      for (int& x : v) x = x < 0 ? Tmax + 1 : x;
      return v;
    };
    from_start.push_back(fix(mob.slots_to(nx, ny, s_cell[static_cast<std::size_t>(n)])));
    to_dest.push_back(fix(mob.slots_to(nx, ny, d_cell[static_cast<std::size_t>(n)])));
  }
  // The objective as Dinkelbach's parametric problem: maximise sum_t (alpha R[t] - beta lambda)
  // - sum_moves gamma E(move), then lambda <- J of the maximiser (env.objective; UavEnv's J).
  const Objective kind = env.objective_kind();
  const double dt = mob.slot_s();
  double alpha = 1, beta = 1, gamma = 0;
  switch (kind) {
    case Objective::SumRate: break;
    case Objective::Weighted: gamma = env.energy_weight() / dt; break;
    case Objective::EnergyEfficiency: alpha = env.bandwidth_hz() * dt / 1e3, beta = 0; break;
    case Objective::Energy: alpha = 0, beta = 0, gamma = 1e-3; break;
  }
  std::vector<double> move_energy(static_cast<std::size_t>(A));
  for (int a = 0; a < A; ++a) move_energy[static_cast<std::size_t>(a)] = prop.slot_energy(mob.speed(a), 0.0, dt);
  auto cell = [&](std::size_t s, int n) { return static_cast<int>((s / stride[static_cast<std::size_t>(n)]) % static_cast<std::size_t>(G)); };
  // A state is possible at some slot if each UAV's cell lies on a path start -> dest of length <= T_max - 1,
  // and no two UAVs are closer than D_min.
  std::vector<std::vector<char>> useful(static_cast<std::size_t>(N), std::vector<char>(static_cast<std::size_t>(G), 0));
  for (int n = 0; n < N; ++n)
    for (int c = 0; c < G; ++c)
      useful[static_cast<std::size_t>(n)][static_cast<std::size_t>(c)] =
          from_start[static_cast<std::size_t>(n)][static_cast<std::size_t>(c)] + to_dest[static_cast<std::size_t>(n)][static_cast<std::size_t>(c)] <= Tmax - 1;
  std::vector<double> R(S, std::numeric_limits<double>::quiet_NaN());
  {
    std::vector<std::size_t> need;
    Positions p(N, 2);
    for (std::size_t s = 0; s < S; ++s) {
      bool ok = true;
      for (int n = 0; n < N && ok; ++n) ok = useful[static_cast<std::size_t>(n)][static_cast<std::size_t>(cell(s, n))];
      if (!ok) continue;
      for (int n = 0; n < N; ++n) p(n, 0) = cx(cell(s, n)), p(n, 1) = cy(cell(s, n));
      if (env.collisions(p) > 0) continue;
      need.push_back(s);
    }
    if (progress) *progress << "optimal: " << need.size() << " feasible joint states of " << S << "; evaluating R\n" << std::flush;
    const std::size_t chunk = 20000;
    for (std::size_t first = 0; first < need.size(); first += chunk) {
      std::vector<Positions> batch;
      const std::size_t last = std::min(need.size(), first + chunk);
      for (std::size_t i = first; i < last; ++i) {
        for (int n = 0; n < N; ++n) p(n, 0) = cx(cell(need[i], n)), p(n, 1) = cy(cell(need[i], n));
        batch.push_back(p);
      }
      const auto r = env.oracle().sum_rates(batch);
      for (std::size_t i = first; i < last; ++i) R[need[i]] = r[i - first];
    }
  }
  OptimalPlan plan;
  plan.states = S;
  for (double r : R) plan.evaluated_states += !std::isnan(r);
  // Value tables V[t] for slots t = 1..Tmax (index t - 1).
  std::vector<std::vector<double>> V(static_cast<std::size_t>(Tmax), std::vector<double>(S, kNegInf));
  plan.memory_bytes = static_cast<std::size_t>(Tmax) * S * sizeof(double) + S * sizeof(double) * 3 + S * sizeof(std::int32_t) * 2;
  std::vector<double> M(S), tmp(S);
  const std::size_t s0 = [&] {
    std::size_t s = 0;
    for (int n = 0; n < N; ++n) s += stride[static_cast<std::size_t>(n)] * static_cast<std::size_t>(s_cell[static_cast<std::size_t>(n)]);
    return s;
  }();
  const std::size_t s_home = [&] {
    std::size_t s = 0;
    for (int n = 0; n < N; ++n) s += stride[static_cast<std::size_t>(n)] * static_cast<std::size_t>(d_cell[static_cast<std::size_t>(n)]);
    return s;
  }();
  auto all_home = [&](std::size_t s) { return s == s_home; };
  if (std::isnan(R[s0])) throw InputError("the start positions collide or cannot reach the destinations by trajectory.t_max");
  // A state is alive at slot t when every UAV can have reached its cell from its start by slot t
  // and can reach its destination by T_max: first[s] <= t <= last[s] (first > last: never,
  // including the states with no rate, i.e. impossible or colliding ones).
  std::vector<std::int32_t> first(S), last(S);
  for (std::size_t s = 0; s < S; ++s) {
    int from = 0, to = 0;
    for (int n = 0; n < N; ++n) {
      const auto c = static_cast<std::size_t>(cell(s, n));
      from = std::max(from, from_start[static_cast<std::size_t>(n)][c]);
      to = std::max(to, to_dest[static_cast<std::size_t>(n)][c]);
    }
    const bool never = std::isnan(R[s]);
    first[s] = static_cast<std::int32_t>(never ? Tmax + 1 : from + 1);
    last[s] = static_cast<std::int32_t>(never ? 0 : Tmax - to);
  }
  // The moves of UAV n out of cell c: the offset of the successor state and the move's index.
  struct Move {
    std::ptrdiff_t offset;
    int action;
  };
  std::vector<std::vector<Move>> moves(static_cast<std::size_t>(G));
  double lambda = 0.0;
  std::vector<std::size_t> path;
  const long joint = joint_count(A, N);
  for (int iter = 1; iter <= 50; ++iter) {
    // Energy cost of each action this iteration (gamma, or lambda under energy-efficiency).
    const double g = kind == Objective::EnergyEfficiency ? lambda : gamma;
    std::vector<double> cost(static_cast<std::size_t>(A), 0.0);
    if (g != 0)
      for (int a = 0; a < A; ++a) cost[static_cast<std::size_t>(a)] = g * move_energy[static_cast<std::size_t>(a)];
    const double hover_cost = cost[static_cast<std::size_t>(hover)];
    plan.iterations = iter;
    for (int t = Tmax; t >= 1; --t) {
      auto& Vt = V[static_cast<std::size_t>(t - 1)];
      if (t < Tmax) {
        // M(s) = max over joint actions of V[t+1](s') less their energy cost, one UAV at a time
        // (arrived UAVs only hover).
        M = V[static_cast<std::size_t>(t)];
        for (int n = 0; n < N; ++n) {
          // States in blocks of equal cell c of UAV n: s = (upper * G + c) * st + lower.
          const std::size_t st = stride[static_cast<std::size_t>(n)], block = st * static_cast<std::size_t>(G);
          for (int c = 0; c < G; ++c) {
            auto& mv = moves[static_cast<std::size_t>(c)];
            mv.clear();
            if (c != d_cell[static_cast<std::size_t>(n)])
              for (int a = 0; a < A; ++a) {
                const int c2 = neighbour[static_cast<std::size_t>(c * A + a)];
                if (a != hover && c2 >= 0)
                  mv.push_back({static_cast<std::ptrdiff_t>(st) * (c2 - c), a});
              }
          }
          for (std::size_t upper = 0; upper < S; upper += block)
            for (int c = 0; c < G; ++c) {
              const auto& mv = moves[static_cast<std::size_t>(c)];
              const std::size_t from = upper + static_cast<std::size_t>(c) * st;
              const double* m = M.data() + from;
              double* out = tmp.data() + from;
              // Without an energy term every cost is 0, and v - 0 is v exactly.
              for (std::size_t i = 0; i < st; ++i) out[i] = m[i] - hover_cost;
              for (const Move& x : mv) {
                const double* m2 = m + x.offset;
                const double move_cost = cost[static_cast<std::size_t>(x.action)];
                for (std::size_t i = 0; i < st; ++i) out[i] = std::max(out[i], m2[i] - move_cost);
              }
            }
          M.swap(tmp);
        }
      }
      for (std::size_t s = 0; s < S; ++s) {
        if (t < first[s] || t > last[s]) {
          Vt[s] = kNegInf;
          continue;
        }
        const double gain = kind == Objective::SumRate ? R[s] - lambda : alpha * R[s] - beta * lambda;
        if (all_home(s)) Vt[s] = gain;                                 // the episode ends: T = t
        else Vt[s] = t < Tmax ? gain + M[s] : kNegInf;                 // not home at T_max: infeasible
      }
    }
    if (!std::isfinite(V[0][s0])) throw InputError("no joint trajectory brings every UAV home by trajectory.t_max without a collision");
    // Recover the maximiser and its true objective.
    path.assign(1, s0);
    std::vector<std::vector<int>> actions;
    int t = 1;
    while (!all_home(path.back())) {
      const std::size_t s = path.back();
      double best = kNegInf;
      std::size_t best_s = s;
      std::vector<int> best_a;
      for (long j = 0; j < joint; ++j) {
        const auto a = joint_action(j, N, A);
        std::size_t s2 = s;
        bool ok = true;
        double c_move = 0;
        for (int n = 0; n < N && ok; ++n) {
          const int c = cell(s, n);
          const int act = c == d_cell[static_cast<std::size_t>(n)] ? hover : a[static_cast<std::size_t>(n)];
          if (act != a[static_cast<std::size_t>(n)]) { ok = false; break; }  // arrived UAVs: hover only
          c_move += cost[static_cast<std::size_t>(act)];
          const int c2 = neighbour[static_cast<std::size_t>(c * A + act)];
          if (act != hover && c2 < 0) ok = false;
          else if (act != hover) s2 = s2 + stride[static_cast<std::size_t>(n)] * static_cast<std::size_t>(c2) - stride[static_cast<std::size_t>(n)] * static_cast<std::size_t>(c);
        }
        if (!ok) continue;
        const double v = g != 0 ? V[static_cast<std::size_t>(t)][s2] - c_move : V[static_cast<std::size_t>(t)][s2];
        if (v > best) best = v, best_s = s2, best_a = a;
      }
      if (best_a.empty()) throw std::logic_error("optimal planner: no successor on the optimal path");
      actions.push_back(best_a);
      path.push_back(best_s);
      ++t;
    }
    double total = 0, energy = 0;
    for (std::size_t s : path) total += R[s];
    for (const auto& a : actions)
      for (const int x : a) energy += move_energy[static_cast<std::size_t>(x)];
    const double next = env.objective_of(total, static_cast<int>(path.size()), energy);
    plan.objective = next;
    plan.sum_rate_objective = total / static_cast<double>(path.size());
    plan.energy_j = energy;
    plan.T = static_cast<int>(path.size());
    plan.actions = actions;
    if (progress)
      *progress << "optimal: iteration " << iter << "  lambda " << format_double(lambda) << " -> " << format_double(next)
                << "  T = " << plan.T << "\n" << std::flush;
    if (kind == Objective::Energy) break;  // no ratio: one pass is the optimum
    // Dinkelbach's lambda rises from the ratio of a feasible plan: lambda = 0 before the first
    // iteration is none when the optimum is negative (weighted with a large w), so always go on once.
    if (iter > 1 && next <= (lambda >= 0 ? lambda * (1 + 1e-12) : lambda + 1e-12 * -lambda)) break;
    lambda = next;
  }
  // Arrived UAVs in the plan STAY (their recorded action is whatever index matched: normalise).
  for (std::size_t k = 0; k < plan.actions.size(); ++k)
    for (int n = 0; n < N; ++n)
      if (cell(path[k], n) == d_cell[static_cast<std::size_t>(n)]) plan.actions[k][static_cast<std::size_t>(n)] = hover;
  plan.seconds = std::chrono::duration<double>(Clock::now() - t0).count();
  env.reset();
  return plan;
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
  require_lattice(env, "the brute-force optimum");
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
    move_energy[static_cast<std::size_t>(a)] = env.propulsion().slot_energy(env.mobility().speed(a), 0.0, env.mobility().slot_s());
  const Positions dest = env.destinations();
  auto is_home = [&](const Positions& p, int n) {
    return std::abs(p(n, 0) - dest(n, 0)) < 1e-6 && std::abs(p(n, 1) - dest(n, 1)) < 1e-6;
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
        double nx, ny;
        ok = env.move(f.pos(n, 0), f.pos(n, 1), a[static_cast<std::size_t>(n)], nx, ny);
        next(n, 0) = nx, next(n, 1) = ny;
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
  r.action_names = env.mobility().actions();
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
