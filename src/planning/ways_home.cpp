#include "skyloop/planning/ways_home.hpp"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <stdexcept>

#include "skyloop/core/memory.hpp"

namespace skyloop {

namespace {

/// The search's tables over (layer, cell), one set per thread and reused: an entry is set when it
/// holds the current stamp, so a new search clears nothing.
struct Scratch {
  std::vector<std::uint32_t> blocked, seen, valid;
  std::vector<std::vector<int>> layer;
  std::uint32_t stamp = 0;
  void begin(std::size_t size, int layers) {
    if (blocked.size() < size) blocked.resize(size, 0), seen.resize(size, 0), valid.resize(size, 0);
    if (layer.size() < static_cast<std::size_t>(layers) + 1) layer.resize(static_cast<std::size_t>(layers) + 1);
    if (++stamp == 0) {  // wrapped: clear once
      std::fill(blocked.begin(), blocked.end(), 0), std::fill(seen.begin(), seen.end(), 0), std::fill(valid.begin(), valid.end(), 0);
      stamp = 1;
    }
  }
};
Scratch& scratch() {
  thread_local Scratch s;
  return s;
}

}  // namespace

WaysHome::WaysHome(const UavEnv& env) : env_(env) {
  if (!env.dynamics().lattice()) throw std::logic_error("WaysHome: ways home are planned on the lattice (" + lattice_dynamics_names() + ")");
  // The search's scratch: three stamps per lattice point and slot left (at most T_max + 1 layers).
  const LatticeFrame f = env.dynamics().lattice()->frame(env.mission(), 0);
  const double bytes = 12.0 * (env.t_max() + 1.0) * f.cells();
  if (bytes > memory_limit_bytes())  // checked before the message is built: one of these per slot
    require_memory(bytes,
                   "marl.reserve_slack's ways home over trajectory.t_max = " + std::to_string(env.t_max()) + " slots x " +
                       std::to_string(f.cells()) + " lattice points",
                   "allowed a smaller trajectory.t_max or a coarser lattice (trajectory.d_fly_m), or marl.reserve_slack = -1");
}

WaysHome::WaysHome(const UavEnv& env, const WaysMemory& memory) : WaysHome(env) {
  if (memory.t != env.t() - 1) return;
  std::vector<char> kept(static_cast<std::size_t>(env.uavs()), 0);
  for (const ReservedPoint& p : memory.points)
    if (p.tau == env.t() && p.uav >= 0 && p.uav < env.uavs() && !env.arrived(p.uav) &&
        std::hypot(env.positions()(p.uav, 0) - p.x, env.positions()(p.uav, 1) - p.y) < 1e-6 && std::abs(env.altitude(p.uav) - p.z) < 1e-6)
      kept[static_cast<std::size_t>(p.uav)] = 1;
  for (const ReservedPoint& p : memory.points)
    if (p.uav >= 0 && p.uav < env.uavs() && kept[static_cast<std::size_t>(p.uav)] && p.tau > env.t()) ways_.push_back(p);
}

bool WaysHome::holds(int n) const {
  return std::any_of(ways_.begin(), ways_.end(), [n](const ReservedPoint& p) { return p.uav == n; });
}

ActionSet WaysHome::moves(int n) {
  Scratch& s = scratch();
  planned_ = n;
  const int t0 = env_.t();
  layers_ = env_.t_max() - t0;  // layer k: the position at the end of slot t0 + k
  if (env_.arrived(n) || layers_ < 1) return 0;
  frame_ = env_.dynamics().lattice()->frame(env_.mission(), n);
  const int cells = frame_.cells();
  const auto at = [cells](int k, int c) { return static_cast<std::size_t>(k) * static_cast<std::size_t>(cells) + static_cast<std::size_t>(c); };
  s.begin(static_cast<std::size_t>(layers_ + 1) * static_cast<std::size_t>(cells), layers_);
  const std::uint32_t stamp = s.stamp;

  // Blocked: the lattice points strictly within D_min of a parked UAV (every layer) or of a
  // reserved way's position in that layer (the environment's collision rule).
  const double d_min = env_.d_min(), pitch = frame_.pitch;
  const int r = static_cast<int>(std::ceil(d_min / pitch)) + 1;
  auto mark = [&](int k0, int k1, double px, double py, double pz) {
    const long cx = std::lround((px - frame_.ox) / pitch), cy = std::lround((py - frame_.oy) / pitch);
    for (int iz = 0; iz < frame_.nz; ++iz) {
      const double dz = frame_.nz > 1 ? frame_.oz + frame_.pz * iz - pz : 0.0;
      for (long iy = std::max(0L, cy - r); iy <= std::min<long>(frame_.ny - 1, cy + r); ++iy)
        for (long ix = std::max(0L, cx - r); ix <= std::min<long>(frame_.nx - 1, cx + r); ++ix)
          if (UavEnv::separation(frame_.ox + pitch * static_cast<double>(ix) - px, frame_.oy + pitch * static_cast<double>(iy) - py, dz) <
              d_min - 1e-9)
            for (int k = k0; k <= k1; ++k) s.blocked[at(k, static_cast<int>((iz * frame_.ny + iy) * frame_.nx + ix))] = stamp;
    }
  };
  for (int m = 0; m < env_.uavs(); ++m)
    if (m != n && env_.arrived(m)) mark(1, layers_, env_.positions()(m, 0), env_.positions()(m, 1), env_.altitude(m));
  for (const ReservedPoint& p : ways_)
    if (p.uav != n && p.tau > t0 && p.tau <= t0 + layers_) mark(p.tau - t0, p.tau - t0, p.x, p.y, p.z);
  auto blocked = [&](int k, int c) { return s.blocked[at(k, c)] == stamp; };

  dest_ = frame_.cell(env_.destinations()(n, 0), env_.destinations()(n, 1), env_.destinations()(n, 2));
  // Parked from layer k on, the destination must stay clear until the mission ends.
  int free_from = layers_ + 1;
  while (free_from > 1 && !blocked(free_from - 1, dest_)) --free_from;
  const int needed_max = layers_;
  auto needed = [&](int c) { return env_.min_moves(n, frame_.x(c), frame_.y(c), frame_.z(c)); };
  const LatticeDynamics& mob = *env_.dynamics().lattice();
  const int actions = mob.count();
  auto next = [&](int c, int a) { return frame_.move(c, mob.step(a)); };

  // Forward: the states the UAV can be in, clear of what is blocked, with its destination
  // still in reach (an arrived UAV stays where it is: no successors at the destination).
  s.layer[0].assign(1, frame_.cell(env_.positions()(n, 0), env_.positions()(n, 1), env_.altitude(n)));
  for (int k = 1; k <= layers_; ++k) {
    auto& layer = s.layer[static_cast<std::size_t>(k)];
    layer.clear();
    for (const int c : s.layer[static_cast<std::size_t>(k - 1)]) {
      if (c == dest_) continue;
      for (int a = 0; a < actions; ++a) {
        const int j = next(c, a);
        if (j < 0 || blocked(k, j) || s.seen[at(k, j)] == stamp || needed(j) > needed_max - k) continue;
        s.seen[at(k, j)] = stamp;
        layer.push_back(j);
      }
    }
  }
  // Backward: the states from which a way home exists (parked at the destination from a layer on
  // which it stays clear; else a move to such a state in the next layer).
  for (int k = layers_; k >= 1; --k)
    for (const int c : s.layer[static_cast<std::size_t>(k)]) {
      bool ok = false;
      if (c == dest_) {
        ok = k >= free_from;
      } else if (k < layers_) {
        for (int a = 0; a < actions && !ok; ++a) {
          const int j = next(c, a);
          ok = j >= 0 && s.valid[at(k + 1, j)] == stamp;
        }
      }
      if (ok) s.valid[at(k, c)] = stamp;
    }

  ActionSet out = 0;
  for (int a = 0; a < actions; ++a) {
    const UavEnv::Landing l = env_.landing(n, a);
    if (l.inside && s.valid[at(1, frame_.cell(l.x, l.y, l.z))] == stamp) out |= action_bit(a);
  }
  return out;
}

void WaysHome::reserve(int n, int a) {
  if (n != planned_ || layers_ < 1 || env_.arrived(n)) return;
  const Scratch& s = scratch();
  const int cells = frame_.cells();
  const auto valid = [&](int k, int c) {
    return s.valid[static_cast<std::size_t>(k) * static_cast<std::size_t>(cells) + static_cast<std::size_t>(c)] == s.stamp;
  };
  const UavEnv::Landing l = env_.landing(n, a);
  int c = frame_.cell(l.x, l.y, l.z);
  if (!l.inside || !valid(1, c)) return;
  const int t0 = env_.t();
  const LatticeDynamics& mob = *env_.dynamics().lattice();
  ways_.erase(std::remove_if(ways_.begin(), ways_.end(), [n](const ReservedPoint& p) { return p.uav == n; }), ways_.end());
  for (int k = 1; k <= layers_; ++k) {
    ways_.push_back({n, t0 + k, frame_.x(c), frame_.y(c), frame_.z(c)});
    if (c == dest_) {  // parked until the mission ends
      for (int j = k + 1; j <= layers_; ++j) ways_.push_back({n, t0 + j, frame_.x(c), frame_.y(c), frame_.z(c)});
      break;
    }
    if (k == layers_) break;
    // The move that keeps a way home and needs the fewest moves after it (lowest index on ties).
    int best = -1, best_needed = 0;
    for (int b = 0; b < mob.count(); ++b) {
      const int j = frame_.move(c, mob.step(b));
      if (j < 0 || !valid(k + 1, j)) continue;
      const int d = env_.min_moves(n, frame_.x(j), frame_.y(j), frame_.z(j));
      if (best < 0 || d < best_needed) best = j, best_needed = d;
    }
    if (best < 0) break;  // cannot happen: a valid state has a valid successor
    c = best;
  }
  planned_ = -1;
}

bool WaysHome::may_park(int m) const {
  const double dx = env_.destinations()(m, 0), dy = env_.destinations()(m, 1);
  for (const ReservedPoint& p : ways_)
    if (p.uav != m && p.tau > env_.t() && std::hypot(p.x - dx, p.y - dy) < env_.d_min() - 1e-9) return false;
  return true;
}

std::vector<std::pair<double, double>> WaysHome::reserved_at(int tau) const {
  std::vector<std::pair<double, double>> out;
  for (const ReservedPoint& p : ways_)
    if (p.tau == tau) out.emplace_back(p.x, p.y);
  return out;
}

}  // namespace skyloop
