#include "skyloop/planning/safety.hpp"

#include <algorithm>
#include <cmath>
#include <functional>
#include <optional>
#include <stdexcept>
#include <string>

#include "skyloop/core/config.hpp"
#include "skyloop/planning/ways_home.hpp"

namespace skyloop {

namespace {

bool too_close(double ax, double ay, double az, double bx, double by, double bz, double d_min) {
  return UavEnv::separation(ax - bx, ay - by, az - bz) < d_min - 1e-9;
}

/// The counts of the moves still needed under a clearance, strictest first.
std::vector<UavEnv::ClearOf> counts_of(Clearance c) {
  switch (c) {
    case Clearance::Destinations: return {UavEnv::ClearOf::Destinations, UavEnv::ClearOf::Parked};
    case Clearance::Parked: return {UavEnv::ClearOf::Parked};
    default: return {};
  }
}

/// Moves UAV n still needs from a landing: the strictest count of the clearance that gets it home
/// in the slots left, else as if nothing were to be kept clear of (UavEnv::min_moves_around).
int moves_needed(const UavEnv& env, int n, const UavEnv::Landing& l, Clearance clearance) {
  for (const auto what : counts_of(clearance)) {
    const int d = env.min_moves_around(n, l, what);
    if (d <= env.t_max() - env.t()) return d;
  }
  return env.min_moves(n, l);
}
int moves_needed_now(const UavEnv& env, int n, Clearance clearance) { return moves_needed(env, n, env.current(n), clearance); }

/// UAV n's slack after action a: slots left after the move less the moves it still needs.
int slack_after(const UavEnv& env, int n, int a, Clearance clearance) {
  return env.t_max() - (env.t() + 1) - moves_needed(env, n, env.landing(n, a), clearance);
}

/// Placed UAVs' end positions for the shield.
struct Placed {
  std::vector<double> x, y, z;
  bool clear(double px, double py, double pz, double d_min) const {
    for (std::size_t i = 0; i < x.size(); ++i)
      if (too_close(px, py, pz, x[i], y[i], z[i], d_min)) return false;
    return true;
  }
  bool clear(const UavEnv::Landing& l, double d_min) const { return clear(l.x, l.y, l.z, d_min); }
  void add(double px, double py, double pz) { x.push_back(px), y.push_back(py), z.push_back(pz); }
  void add(const UavEnv::Landing& l) { add(l.x, l.y, l.z); }
  void pop() { x.pop_back(), y.pop_back(), z.pop_back(); }
  std::size_t size() const { return x.size(); }
  void resize(std::size_t k) { x.resize(k), y.resize(k), z.resize(k); }
};

/// Arrived UAVs stay where they are: placed before anyone chooses.
Placed arrived_uavs(const UavEnv& env) {
  Placed p;
  for (int n = 0; n < env.uavs(); ++n)
    if (env.arrived(n)) p.add(env.current(n));
  return p;
}

/// The moves of `allowed` landing at least D_min from every placed UAV.
ActionSet clear_moves(const UavEnv& env, int n, ActionSet allowed, const Placed& placed) {
  ActionSet safe = 0;
  for (int a = 0; a < env.actions(); ++a) {
    if (!(allowed >> a & 1u)) continue;
    if (placed.clear(env.landing(n, a), env.d_min())) safe |= action_bit(a);
  }
  return safe;
}

/// allowed minus the moves landing within D_min of a placed UAV; if that leaves nothing and the
/// mask keeps a margin, the clear moves of the margin-0 mask; else allowed.
ActionSet shielded(const UavEnv& env, int n, ActionSet allowed, const Placed& placed, const SafetyOptions& safety) {
  if (const ActionSet safe = clear_moves(env, n, allowed, placed)) return safe;
  if (safety.mask && safety.margin > 0)
    if (const ActionSet wider = clear_moves(env, n, reachable_moves(env, n, 0, safety.clearance), placed)) return wider;
  // Last, the clearance: its moves home through the others' destinations and parked UAVs.
  if (safety.mask && safety.clearance != Clearance::None)
    if (const ActionSet plain = clear_moves(env, n, reachable_moves(env, n, 0, Clearance::None), placed)) return plain;
  return allowed;
}

}  // namespace

ActionSet all_actions(const UavEnv& env) { return env.actions() >= 64 ? ~ActionSet{0} : action_bit(env.actions()) - 1; }

namespace {

/// reachable_moves under one count; `inside` receives the moves that stay in the area.
/// (`count` null: through everything.)
ActionSet reachable_counted(const UavEnv& env, int n, int margin, const UavEnv::ClearOf* count, ActionSet& inside) {
  ActionSet m = 0;
  inside = 0;
  const int left_after = env.t_max() - (env.t() + 1);
  auto needed = [&](const UavEnv::Landing& l) { return count ? env.min_moves_around(n, l, *count) : env.min_moves(n, l); };
  // The slack a move must leave: the margin, or all the UAV still has if the shield spent some
  // (a move towards the destination keeps the slack; STAY and moves away spend one or two).
  const int slack_now = left_after + 1 - needed(env.current(n));
  const int keep = std::max(0, std::min(margin, slack_now));
  for (int a = 0; a < env.actions(); ++a) {
    const UavEnv::Landing l = env.landing(n, a);
    if (!l.inside) continue;
    inside |= action_bit(a);
    const int d = needed(l);
    if (d <= left_after && left_after - d >= keep) m |= action_bit(a);
  }
  if (!m && margin > 0) return reachable_counted(env, n, 0, count, inside);
  return m;
}

}  // namespace

SafetyOptions safety_options(const Config& cfg) {
  const auto& m = cfg.marl;
  return SafetyOptions{m.action_mask, m.shield, m.slack_margin, m.mask_clearance, m.reserve_slack};
}

SafetyOptions training_safety_options(const Config& cfg) {
  SafetyOptions s = safety_options(cfg);
  s.reserve = -1;
  return s;
}

ActionSet reachable_moves(const UavEnv& env, int n, int margin, Clearance clearance) {
  if (env.arrived(n)) return action_bit(env.hover());
  ActionSet inside = 0;
  for (const auto& what : counts_of(clearance))
    if (const ActionSet m = reachable_counted(env, n, margin, &what, inside)) return m;
  if (const ActionSet m = reachable_counted(env, n, margin, nullptr, inside)) return m;
  return inside;
}

ActionSet allowed_moves(const UavEnv& env, int n, const SafetyOptions& safety) {
  if (env.arrived(n)) return action_bit(env.hover());
  return safety.mask ? reachable_moves(env, n, safety.margin, safety.clearance) : all_actions(env);
}

namespace {

/// (slack, UAV) of the UAVs not arrived, least slack first, ties by index: the shield order.
std::vector<std::pair<int, int>> by_slack(const UavEnv& env, Clearance clearance) {
  std::vector<std::pair<int, int>> key;
  const int left = env.t_max() - env.t();
  for (int n = 0; n < env.uavs(); ++n)
    if (!env.arrived(n)) key.emplace_back(left - moves_needed_now(env, n, clearance), n);
  std::sort(key.begin(), key.end());
  return key;
}

/// The move of `set` after which UAV n needs the fewest moves home (lowest index on ties).
int towards_home(const UavEnv& env, int n, ActionSet set) {
  int pick = -1, fewest = 0;
  for (int a = 0; a < env.actions(); ++a)
    if (set >> a & 1u) {
      const int d = env.min_moves(n, env.landing(n, a));
      if (pick < 0 || d < fewest) pick = a, fewest = d;
    }
  return pick;
}

/// Whether the UAVs at or below safety.reserve slack reserve their ways home (lattice models).
bool reserving(const UavEnv& env, const SafetyOptions& safety) {
  return safety.reserve >= 0 && env.dynamics().lattice();
}

/// The order in which the UAVs choose when the UAVs with at most safety.reserve slack reserve
/// their ways home, and a way for each. First the UAVs that carry a way from the slot before
/// (`memory`), least slack first (ties by index): they keep it. Then the other UAVs with at most
/// safety.reserve slack, each planned around the ways reserved before it with its move towards
/// home (the fewest moves still needed) standing in for its choice; while some of them find no
/// way, those are moved to the front of them and all planned again (at most kReorders times; the
/// order in which fewest find none). Then the others in shield order. `urgent` receives how many
/// lead the order, `ways` their ways.
std::vector<int> reserve_order(const UavEnv& env, const SafetyOptions& safety, const std::vector<std::pair<int, int>>& slacks,
                               const WaysMemory* memory, std::size_t& urgent_out, std::optional<WaysHome>& ways_out) {
  constexpr int kReorders = 8;
  const WaysHome carried = memory ? WaysHome(env, *memory) : WaysHome(env);
  std::vector<int> holding, urgent, rest, best;
  for (const auto& [slack, n] : slacks) (carried.holds(n) ? holding : slack <= safety.reserve ? urgent : rest).push_back(n);
  std::size_t best_failed = urgent.size() + 1;
  ways_out.emplace(carried);
  for (int round = 0; round <= kReorders && !urgent.empty(); ++round) {
    WaysHome ways(carried);
    std::vector<int> failed, found;
    for (const int n : urgent) {
      const ActionSet way = ways.moves(n);
      if (!way) {
        failed.push_back(n);
        continue;
      }
      found.push_back(n);
      ways.reserve(n, towards_home(env, n, way));
    }
    if (failed.size() < best_failed) {
      best_failed = failed.size();
      best = found;
      best.insert(best.end(), failed.begin(), failed.end());
      ways_out.reset();
      ways_out.emplace(ways);
    }
    if (failed.empty() || failed.size() == urgent.size()) break;
    urgent = failed;
    urgent.insert(urgent.end(), found.begin(), found.end());
  }
  best.insert(best.begin(), holding.begin(), holding.end());
  urgent_out = best.size();
  best.insert(best.end(), rest.begin(), rest.end());
  return best;
}

/// The moves of `set` that do not park UAV n while a reserved way still passes its destination
/// (all of `set` if that leaves none).
ActionSet unless_blocking(const UavEnv& env, int n, ActionSet set, const WaysHome& ways) {
  if (ways.may_park(n)) return set;
  ActionSet out = 0;
  for (int a = 0; a < env.actions(); ++a) {
    if (!(set >> a & 1u)) continue;
    const UavEnv::Landing l = env.landing(n, a);
    if (std::hypot(l.x - env.destinations()(n, 0), l.y - env.destinations()(n, 1)) > 1e-9) out |= action_bit(a);
  }
  return out ? out : set;
}

}  // namespace

std::vector<int> shield_order(const UavEnv& env, Clearance clearance) {
  std::vector<int> order;
  for (const auto& k : by_slack(env, clearance)) order.push_back(k.second);
  return order;
}

namespace {

/// The order in which the UAVs choose this slot (the turns and the joint search alike): where the
/// UAVs with little slack reserve their ways home, reserve_order's (`urgent` and `ways` as there);
/// else the shield order.
std::vector<int> turn_order(const UavEnv& env, const SafetyOptions& safety, const WaysMemory* memory, std::size_t& urgent,
                            std::optional<WaysHome>& ways) {
  if (reserving(env, safety)) return reserve_order(env, safety, by_slack(env, safety.clearance), memory, urgent, ways);
  return shield_order(env, safety.clearance);
}

}  // namespace

struct SafeTurns::State {
  const UavEnv& env;
  SafetyOptions safety;
  WaysMemory* memory;
  std::vector<int> actions;
  std::vector<ActionSet> allowed_sets;
  Placed placed;
  bool reserve;
  std::optional<WaysHome> ways;
  std::size_t urgent = 0;
  std::vector<int> order;
  std::size_t i = 0;          // the turn
  ActionSet allowed = 0, way = 0;  // the turn's allowed moves, and its way home's (urgent UAVs)
  State(const UavEnv& e, const SafetyOptions& s, WaysMemory* m) : env(e), safety(s), memory(m) {}
};

SafeTurns::SafeTurns(const UavEnv& env, const SafetyOptions& safety, WaysMemory* memory)
    : s_(std::make_unique<State>(env, safety, memory)) {
  State& s = *s_;
  const int N = env.uavs();
  s.actions.assign(static_cast<std::size_t>(N), env.hover());
  s.allowed_sets.assign(static_cast<std::size_t>(N), action_bit(env.hover()));
  s.placed = arrived_uavs(env);
  s.reserve = reserving(env, safety);
  s.order = turn_order(env, safety, memory, s.urgent, s.ways);
  begin_turn();
}

SafeTurns::~SafeTurns() = default;
SafeTurns::SafeTurns(SafeTurns&&) noexcept = default;
SafeTurns& SafeTurns::operator=(SafeTurns&&) noexcept = default;

bool SafeTurns::done() const { return s_->i == s_->order.size(); }
int SafeTurns::uav() const {
  if (done()) throw std::logic_error("SafeTurns::uav: every turn is taken");
  return s_->order[s_->i];
}
ActionSet SafeTurns::allowed() const { return done() ? 0 : s_->allowed; }
const std::vector<int>& SafeTurns::actions() const { return s_->actions; }
const std::vector<ActionSet>& SafeTurns::allowed_sets() const { return s_->allowed_sets; }

void SafeTurns::begin_turn() {
  State& s = *s_;
  if (done()) {
    if (s.memory) *s.memory = s.reserve ? s.ways->memory() : WaysMemory{};
    return;
  }
  const UavEnv& env = s.env;
  const int n = s.order[s.i];
  ActionSet allowed = allowed_moves(env, n, s.safety);
  // A UAV with little slack left: its moves that keep a way home clear of the ways reserved
  // before it (those the mask allows, if any), clear of the UAVs placed without one.
  ActionSet way = s.i < s.urgent ? s.ways->moves(n) : 0;
  if (way) way = clear_moves(env, n, (allowed & way) ? (allowed & way) : way, s.placed);
  if (way) {
    allowed = way;
  } else {
    if (s.reserve) allowed = unless_blocking(env, n, allowed, *s.ways);
    if (s.safety.shield) allowed = shielded(env, n, allowed, s.placed, s.safety);
  }
  s.allowed = allowed;
  s.way = way;
}

void SafeTurns::choose(int a) {
  State& s = *s_;
  const int n = uav();
  if (a < 0 || a >= s.env.actions())
    throw std::out_of_range("SafeTurns::choose: no move " + std::to_string(a) + " (UAV " + std::to_string(n) + ")");
  if (s.way) s.ways->reserve(n, a);
  s.actions[static_cast<std::size_t>(n)] = a;
  s.allowed_sets[static_cast<std::size_t>(n)] = s.allowed;
  s.placed.add(s.env.landing(n, a));
  ++s.i;
  begin_turn();
}

std::vector<int> sequential_safe_actions(const UavEnv& env, const SafetyOptions& safety,
                                         const std::function<int(int, ActionSet)>& choose,
                                         std::vector<ActionSet>* allowed_out, WaysMemory* memory) {
  SafeTurns turns(env, safety, memory);
  while (!turns.done()) turns.choose(choose(turns.uav(), turns.allowed()));
  if (allowed_out) *allowed_out = turns.allowed_sets();
  return turns.actions();
}

namespace {
/// The turns (degrees, each side) safe_velocities tries on a command that would leave the area.
constexpr double kSlideDegrees[] = {15, 30, 45, 60, 90, 120, 180};
/// Nodes the shields' depth-first searches over joint moves may visit before they give up.
constexpr long kShieldNodes = 200000;
}  // namespace

Positions safe_velocities(const UavEnv& env, const SafetyOptions& safety, const Positions& wanted) {
  // Each UAV's candidates in order of preference: its command if the mask lets it fly it; a command
  // that would leave the area turned by growing angles (a slide along the boundary); then the
  // allowed primitives by how near their flown velocity is to the one asked for.
  struct Candidate {
    double vx, vy, x, y, z;
  };
  const auto order = shield_order(env, safety.clearance);
  std::vector<std::vector<Candidate>> candidates;
  const int left_after = env.t_max() - (env.t() + 1);
  for (const int n : order) {
    const UavEnv::Landing want = env.landing_velocity(n, wanted(n, 0), wanted(n, 1));
    const int slack_now = left_after + 1 - env.min_moves(n, env.current(n));
    const int keep = std::max(0, std::min(safety.margin, slack_now));
    const bool reach = !safety.mask || (want.inside && env.min_moves(n, want) <= left_after - keep);
    std::vector<Candidate> c;
    if (reach) c.push_back({wanted(n, 0), wanted(n, 1), want.x, want.y, want.z});
    if (safety.mask && !want.inside && (wanted(n, 0) != 0 || wanted(n, 1) != 0)) {
      // The command turned by growing angles, each side, at its speed where a_max allows: a UAV
      // that meets the boundary slides along it instead of stopping at hover power (of the
      // primitives, HOVER is often the nearest to a command at cruise speed; BENCHMARKS.md, mobility).
      for (const double deg : kSlideDegrees)
        for (const double sign : {1.0, -1.0}) {
          if (deg == 180.0 && sign < 0) continue;  // one reversal
          const double r = sign * deg * std::acos(-1.0) / 180.0, cs = std::cos(r), sn = std::sin(r);
          const double vx = cs * wanted(n, 0) - sn * wanted(n, 1), vy = sn * wanted(n, 0) + cs * wanted(n, 1);
          const UavEnv::Landing l = env.landing_velocity(n, vx, vy);
          if (l.inside && env.min_moves(n, l) <= left_after - keep) c.push_back({vx, vy, l.x, l.y, l.z});
        }
    }
    if (!reach || safety.shield) {
      ActionSet options = allowed_moves(env, n, safety);
      if (safety.mask && safety.margin > 0) options |= reachable_moves(env, n, 0, safety.clearance);  // the shield may spend the margin
      std::vector<std::pair<double, int>> near;
      for (int a = 0; a < env.actions(); ++a)
        if (options >> a & 1u) {
          const UavEnv::Landing l = env.landing(n, a);
          near.emplace_back(std::hypot(l.vx - want.vx, l.vy - want.vy) + (safety.mask && env.min_moves(n, l) > left_after - keep ? 1e6 : 0.0), a);
        }
      std::stable_sort(near.begin(), near.end());
      for (const auto& [d, a] : near) {
        Candidate k{};
        env.primitive_velocity(n, a, k.vx, k.vy);
        const UavEnv::Landing l = env.landing(n, a);
        k.x = l.x, k.y = l.y, k.z = l.z;
        c.push_back(k);
      }
    }
    if (c.empty()) c.push_back({wanted(n, 0), wanted(n, 1), want.x, want.y, want.z});  // nothing allowed: as asked
    candidates.push_back(std::move(c));
  }
  Positions out = Positions::Zero(env.uavs(), 2);
  std::vector<std::size_t> pick(order.size(), 0);
  if (safety.shield) {
    // Depth first over the UAVs in shield order, each its candidates best first: the first joint
    // choice in which no two UAVs end within D_min (bounded; else each UAV its first candidate).
    Placed placed = arrived_uavs(env);
    const std::size_t base = placed.size();
    long nodes = 0;
    std::function<bool(std::size_t)> dfs = [&](std::size_t i) {
      if (i == order.size()) return true;
      for (std::size_t k = 0; k < candidates[i].size(); ++k) {
        if (++nodes > kShieldNodes) return false;
        const Candidate& c = candidates[i][k];
        if (!placed.clear(c.x, c.y, c.z, env.d_min())) continue;
        placed.add(c.x, c.y, c.z);
        pick[i] = k;
        if (dfs(i + 1)) return true;
        placed.pop();
      }
      return false;
    };
    if (!dfs(0)) {
      std::fill(pick.begin(), pick.end(), 0);
      placed.resize(base);
      // Sequentially: each UAV its first candidate clear of those placed, else its first.
      for (std::size_t i = 0; i < order.size(); ++i) {
        for (std::size_t k = 0; k < candidates[i].size(); ++k)
          if (placed.clear(candidates[i][k].x, candidates[i][k].y, candidates[i][k].z, env.d_min())) {
            pick[i] = k;
            break;
          }
        const Candidate& c = candidates[i][pick[i]];
        placed.add(c.x, c.y, c.z);
      }
    }
  }
  for (std::size_t i = 0; i < order.size(); ++i) {
    const Candidate& c = candidates[i][pick[i]];
    out(order[i], 0) = c.vx, out(order[i], 1) = c.vy;
  }
  return out;
}

namespace {

int best_of(const std::vector<float>& s, ActionSet allowed, int hover) {
  int best = -1;
  for (int a = 0; a < static_cast<int>(s.size()); ++a)
    if ((allowed >> a & 1u) && (best < 0 || s[static_cast<std::size_t>(a)] > s[static_cast<std::size_t>(best)])) best = a;
  return best < 0 ? hover : best;
}

struct Search {
  const UavEnv& env;
  const std::vector<int>& order;
  std::vector<std::vector<int>> candidates;  // per position in `order`: allowed moves, best first
  std::vector<int>& actions;
  Placed placed;
  long nodes = 0;

  bool dfs(std::size_t i) {
    if (i == order.size()) return true;
    const int n = order[i];
    for (const int a : candidates[i]) {
      if (++nodes > kShieldNodes) return false;
      const UavEnv::Landing l = env.landing(n, a);
      if (!placed.clear(l, env.d_min())) continue;
      placed.add(l);
      actions[static_cast<std::size_t>(n)] = a;
      if (dfs(i + 1)) return true;
      placed.pop();
    }
    return false;
  }
};

}  // namespace

std::vector<int> shielded_argmax(const UavEnv& env, const SafetyOptions& safety,
                                 const std::vector<std::vector<float>>& scores, WaysMemory* memory) {
  auto sequential = [&] {
    return sequential_safe_actions(
        env, safety, [&](int n, ActionSet allowed) { return best_of(scores[static_cast<std::size_t>(n)], allowed, env.hover()); },
        nullptr, memory);
  };
  if (!safety.shield) return sequential();
  const bool reserve = reserving(env, safety);
  std::size_t urgent = 0;
  std::optional<WaysHome> ways;
  const std::vector<int> order = turn_order(env, safety, memory, urgent, ways);
  std::vector<int> actions(static_cast<std::size_t>(env.uavs()), env.hover());
  // Each UAV's moves best first, those that keep the slack margin before those that spend it: the
  // first collision-free joint move spends margin only where a collision demands it.
  Search s{env, order, {}, actions, arrived_uavs(env)};
  SafetyOptions plain = safety;
  plain.margin = 0;
  for (std::size_t i = 0; i < order.size(); ++i) {
    const int n = order[i];
    const auto& sc = scores[static_cast<std::size_t>(n)];
    auto best_first = [&](ActionSet set) {
      std::vector<int> c;
      for (int a = 0; a < env.actions(); ++a)
        if (set >> a & 1u) c.push_back(a);
      std::stable_sort(c.begin(), c.end(), [&](int a, int b) { return sc[static_cast<std::size_t>(a)] > sc[static_cast<std::size_t>(b)]; });
      return c;
    };
    const ActionSet keep = allowed_moves(env, n, safety);
    auto c = best_first(keep);
    // Moves that spend slack: the least spent first (STAY spends one slot, a move away two).
    auto spend = best_first(allowed_moves(env, n, plain) & ~keep);
    std::stable_sort(spend.begin(), spend.end(), [&](int a, int b) {
      return slack_after(env, n, a, safety.clearance) > slack_after(env, n, b, safety.clearance);
    });
    c.insert(c.end(), spend.begin(), spend.end());
    // Last, moves that give up the clearance (counted home through the others' destinations and
    // parked UAVs): a detour kept clear of them is worth less than a collision now.
    if (safety.mask && safety.clearance != Clearance::None) {
      auto through = best_first(reachable_moves(env, n, 0, Clearance::None) & ~(keep | allowed_moves(env, n, plain)));
      std::stable_sort(through.begin(), through.end(), [&](int a, int b) {
        return slack_after(env, n, a, Clearance::None) > slack_after(env, n, b, Clearance::None);
      });
      c.insert(c.end(), through.begin(), through.end());
    }
    if (reserve) {
      // Little slack left: its best move that keeps a way home clear of the ways reserved before
      // it, reserved, and no other (if it has none, every move as above). Else: not parking while
      // a reserved way passes its destination.
      const ActionSet way = i < urgent ? ways->moves(n) : 0;
      const ActionSet keep_out = way ? 0 : ~unless_blocking(env, n, all_actions(env), *ways);
      std::vector<int> kept;
      for (const int a : c)
        if (way ? (way >> a & 1u) : !(keep_out >> a & 1u)) kept.push_back(a);
      if (way && kept.empty())  // a way home the mask would refuse (the margin or clearance)
        for (int a = 0; a < env.actions(); ++a)
          if (way >> a & 1u) kept.push_back(a);
      if (way) {
        kept.resize(1);
        ways->reserve(n, kept[0]);
      }
      if (!kept.empty()) c = std::move(kept);
    }
    s.candidates.push_back(std::move(c));
  }
  if (s.dfs(0)) {
    if (memory) *memory = reserve ? ways->memory() : WaysMemory{};
    return actions;
  }
  return sequential();
}

struct TurnPasses::State {
  UavEnv& env;
  SafetyOptions safety;
  int passes, p = 0;
  WaysMemory* memory;
  WaysMemory start, ways;  // each pass plans from a copy of the memory it began with
  std::optional<SafeTurns> turns;
  State(UavEnv& e, const SafetyOptions& s, int n, WaysMemory* m) : env(e), safety(s), passes(n), memory(m) {
    if (m) start = *m;
  }
  void begin_pass() {
    ways = start;
    turns.emplace(env, safety, memory ? &ways : nullptr);
  }
};

TurnPasses::TurnPasses(UavEnv& env, const SafetyOptions& safety, int passes, WaysMemory* memory) {
  if (passes < 1) throw std::invalid_argument("take_turns: passes = " + std::to_string(passes) + ", allowed >= 1");
  s_ = std::make_unique<State>(env, safety, passes, memory);
  s_->begin_pass();
  settle();
}

TurnPasses::~TurnPasses() = default;
TurnPasses::TurnPasses(TurnPasses&&) noexcept = default;
TurnPasses& TurnPasses::operator=(TurnPasses&&) noexcept = default;

bool TurnPasses::done() const { return s_->turns->done(); }
int TurnPasses::uav() const { return s_->turns->uav(); }
int TurnPasses::pass() const { return s_->p; }
bool TurnPasses::last() const { return s_->p + 1 == s_->passes; }
ActionSet TurnPasses::allowed() const { return s_->turns->allowed(); }
const std::vector<int>& TurnPasses::actions() const { return s_->turns->actions(); }

void TurnPasses::choose(int a) {
  State& s = *s_;
  const int n = uav();
  s.turns->choose(a);  // std::out_of_range for no such move, before anything changes
  const UavEnv::Landing l = s.env.landing(n, a);
  s.env.show_decided(n, l.x, l.y, l.z);
  settle();
}

void TurnPasses::settle() {
  State& s = *s_;
  // Every flying UAV chose in the pass before, so its landing there is still shown: its intention
  // until it chooses again in this pass.
  while (s.turns->done() && s.p + 1 < s.passes) {
    ++s.p;
    s.begin_pass();
  }
  if (s.turns->done()) {
    if (s.memory) *s.memory = s.ways;  // the last pass's ways
    return;
  }
  const int n = s.turns->uav();
  if (s.p > 0) s.env.show_decided(n, s.env.positions()(n, 0), s.env.positions()(n, 1), s.env.altitude(n));  // itself where it is
}

std::vector<int> take_turns(UavEnv& env, const SafetyOptions& safety, int passes,
                            const std::function<int(int n, ActionSet allowed, bool last)>& choose, WaysMemory* memory) {
  TurnPasses turns(env, safety, passes, memory);
  while (!turns.done()) turns.choose(choose(turns.uav(), turns.allowed(), turns.last()));
  return turns.actions();
}

}  // namespace skyloop
