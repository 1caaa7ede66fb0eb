// The continuous dynamics: velocity commands within v_max and a_max (skyloop/env/continuous.hpp).
#include "skyloop/env/continuous.hpp"

#include <algorithm>
#include <cmath>

#include "skyloop/core/error.hpp"
#include "skyloop/core/io.hpp"

namespace skyloop {

namespace {
// E, NE, N, NW, W, SW, S, SE
constexpr int kHx[8] = {1, 1, 0, -1, -1, -1, 0, 1};
constexpr int kHy[8] = {0, 1, 1, 1, 0, -1, -1, -1};
constexpr const char* kHeadingNames[8] = {"E", "NE", "N", "NW", "W", "SW", "S", "SE"};
}  // namespace

ContinuousDynamics::ContinuousDynamics(const Config& cfg) : Dynamics(cfg) {
  const auto& t = cfg.trajectory;
  if (cfg.energy.model != Propulsion::None && t.v_max_mps >= cfg.energy.u_tip_mps)
    throw InputError("trajectory.v_max_mps = " + format_double(t.v_max_mps) + " is at or above energy.u_tip_mps = " +
                     format_double(cfg.energy.u_tip_mps) + ": allowed a ground speed below the tip speed (the power model's range)");
  v_max_ = t.v_max_mps, dv_max_ = t.a_max_mps2 * slot_s_, arrival_m_ = t.arrival_m, a_max_ = dv_max_ / slot_s_;
  a_max_mps2_ = t.a_max_mps2;
  command_ = t.command, polar_ = command_ == Command::Polar;
  actions_.dims = 2;
  for (const double v : {v_max_ / 2, v_max_})
    for (int h = 0; h < 8; ++h) {
      actions_.names.push_back(std::string(kHeadingNames[h]) + "@" + format_double(v));
      const double norm = std::hypot(kHx[h], kHy[h]);
      prim_vx_.push_back(v * kHx[h] / norm), prim_vy_.push_back(v * kHy[h] / norm);
    }
  home_ = actions_.count();
  actions_.names.push_back("HOME");
  prim_vx_.push_back(0), prim_vy_.push_back(0);
  actions_.names.push_back("HOVER");
  prim_vx_.push_back(0), prim_vy_.push_back(0);
  actions_.hover = actions_.count() - 1;
  reach_ = v_max_ * slot_s_;
}

void ContinuousDynamics::velocity(double u0, double u1, double& vx, double& vy) const {
  u0 = std::max(-1.0, std::min(1.0, u0)), u1 = std::max(-1.0, std::min(1.0, u1));
  const double l2 = std::hypot(u0, u1), linf = std::max(std::abs(u0), std::abs(u1));
  const double scale = l2 > 0 ? v_max_ * linf / l2 : 0.0;
  vx = u0 * scale, vy = u1 * scale;
}

void ContinuousDynamics::commanded_velocity(double u0, double u1, double px, double py, double tx, double ty, double& vx,
                                            double& vy) const {
  if (!polar_) {
    velocity(u0, u1, vx, vy);
    return;
  }
  const double p = std::hypot(px, py), t = std::hypot(tx, ty);
  const double heading = p > 1e-9 ? std::atan2(py, px) : t > 1e-9 ? std::atan2(ty, tx) : 0.0;
  const double fx = std::cos(heading), fy = std::sin(heading);
  // polar: a speed and a turn, the turn a share of the widest that keeps |V[t] - V[t-1]| <= dv_max
  // at that speed: s^2 + p^2 - 2 s p cos(turn) <= dv_max^2.
  u0 = std::max(-1.0, std::min(1.0, u0)), u1 = std::max(-1.0, std::min(1.0, u1));
  constexpr double kPi = 3.14159265358979323846;
  const double speed = v_max_ * (u0 + 1) / 2;
  double widest = kPi;
  if (p > 1e-9 && speed > 1e-9) {
    const double c = (speed * speed + p * p - dv_max_ * dv_max_) / (2 * speed * p);
    widest = c <= -1 ? kPi : c >= 1 ? 0.0 : std::acos(c);
  }
  const double turn = widest * u1;
  vx = speed * (fx * std::cos(turn) - fy * std::sin(turn)), vy = speed * (fy * std::cos(turn) + fx * std::sin(turn));
}

void ContinuousDynamics::command(double vx, double vy, double& u0, double& u1) const {
  const double v = std::hypot(vx, vy);
  if (v > v_max_) vx *= v_max_ / v, vy *= v_max_ / v;
  const double wx = vx / v_max_, wy = vy / v_max_;
  const double l2 = std::hypot(wx, wy), linf = std::max(std::abs(wx), std::abs(wy));
  const double scale = linf > 0 ? l2 / linf : 0.0;
  u0 = std::max(-1.0, std::min(1.0, wx * scale)), u1 = std::max(-1.0, std::min(1.0, wy * scale));
}

void ContinuousDynamics::project(double vx, double vy, double px, double py, double& ox, double& oy) const {
  const double R = v_max_, r = dv_max_, eps = 1e-9;
  auto in_a = [&](double x, double y) { return std::hypot(x, y) <= R + eps; };
  auto in_b = [&](double x, double y) { return std::hypot(x - px, y - py) <= r + eps; };
  if (in_a(vx, vy) && in_b(vx, vy)) {
    ox = vx, oy = vy;
    return;
  }
  // The nearest point of either disc, if it lies in the other.
  const double na = std::hypot(vx, vy), ax = na > R ? vx * R / na : vx, ay = na > R ? vy * R / na : vy;
  if (in_b(ax, ay)) {
    ox = ax, oy = ay;
    return;
  }
  const double nb = std::hypot(vx - px, vy - py);
  const double bx = nb > r ? px + (vx - px) * r / nb : vx, by = nb > r ? py + (vy - py) * r / nb : vy;
  if (in_a(bx, by)) {
    ox = bx, oy = by;
    return;
  }
  // Otherwise a corner of the lens: the nearer point where the two circles cross.
  const double d = std::hypot(px, py);
  if (d < 1e-12) {  // concentric (then one disc holds the other and a projection above fitted)
    ox = bx, oy = by;
    return;
  }
  const double a = (R * R - r * r + d * d) / (2 * d), h = std::sqrt(std::max(0.0, R * R - a * a));
  const double ex = px / d, ey = py / d, cx = a * ex, cy = a * ey;
  const double x1 = cx - h * ey, y1 = cy + h * ex, x2 = cx + h * ey, y2 = cy - h * ex;
  if (std::hypot(vx - x1, vy - y1) <= std::hypot(vx - x2, vy - y2)) ox = x1, oy = y1;
  else ox = x2, oy = y2;
}

void ContinuousDynamics::home_command(double dx, double dy, double& vx, double& vy) const {
  const double d = std::hypot(dx, dy);
  if (d <= 0) {
    vx = vy = 0;
    return;
  }
  const double s = std::min({v_max_, d / slot_s_, std::sqrt(2 * a_max_ * d)});
  vx = dx / d * s, vy = dy / d * s;
}

Flight ContinuousDynamics::step(const Flight& now, double cx, double cy, double dx, double dy, const Mission& m) const {
  Flight l;
  l.z = now.z;  // the altitude is kept
  project(cx, cy, now.vx, now.vy, l.vx, l.vy);
  l.x = now.x + l.vx * slot_s_, l.y = now.y + l.vy * slot_s_;
  if (!m.contains(l.x, l.y)) {
    l.x = now.x, l.y = now.y, l.vx = l.vy = 0, l.inside = false;
    return l;
  }
  l.speed = std::hypot(l.vx, l.vy);
  if (std::hypot(l.x - dx, l.y - dy) <= arrival_m_) l.x = dx, l.y = dy;
  return l;
}

int ContinuousDynamics::home_slots(const Flight& from, double dx, double dy, const Mission& m, int limit, bool* blocked) const {
  if (blocked) *blocked = false;
  Flight at = from;
  for (int k = 0; k <= limit; ++k) {
    if (std::hypot(at.x - dx, at.y - dy) <= 1e-9) return k;
    double cx, cy;
    home_command(dx - at.x, dy - at.y, cx, cy);
    const Flight l = step(at, cx, cy, dx, dy, m);
    if (!l.inside) {  // HOME would hit the boundary: no way home that keeps a_max
      if (blocked) *blocked = true;
      break;
    }
    at.x = l.x, at.y = l.y, at.vx = l.vx, at.vy = l.vy;
  }
  return limit + 1;
}

Flight ContinuousDynamics::fly(int n, const Flight& now, int a, const Mission& m) const {
  double vx, vy;
  primitive_velocity(n, now, a, m, vx, vy);
  return fly_command(n, now, vx, vy, m);
}

Flight ContinuousDynamics::fly_command(int n, const Flight& now, double vx, double vy, const Mission& m) const {
  return step(now, vx, vy, m.dest_x(n), m.dest_y(n), m);
}

void ContinuousDynamics::command_velocity(int n, const Flight& now, double u0, double u1, const Mission& m, double& vx,
                                          double& vy) const {
  commanded_velocity(u0, u1, now.vx, now.vy, m.dest_x(n) - now.x, m.dest_y(n) - now.y, vx, vy);
}

void ContinuousDynamics::primitive_velocity(int n, const Flight& now, int a, const Mission& m, double& vx, double& vy) const {
  if (a == home_) home_command(m.dest_x(n) - now.x, m.dest_y(n) - now.y, vx, vy);
  else vx = prim_vx_[static_cast<std::size_t>(a)], vy = prim_vy_[static_cast<std::size_t>(a)];
}

bool ContinuousDynamics::arrived(double x, double y, double dx, double dy) const { return std::hypot(x - dx, y - dy) <= arrival_m_; }

namespace {
class HomeFlight : public Reachability {
 public:
  HomeFlight(const ContinuousDynamics& d, const Mission& m) : d_(d), m_(m) {}
  int slots(int n, const Flight& from, int limit) const override { return d_.home_slots(from, m_.dest_x(n), m_.dest_y(n), m_, limit); }

 private:
  ContinuousDynamics d_;  // a copy: the reachability outlives no one's dynamics
  Mission m_;
};
}  // namespace

std::shared_ptr<const Reachability> ContinuousDynamics::reachability(const Mission& m) const {
  return std::make_shared<HomeFlight>(*this, m);
}

std::string ContinuousDynamics::unreachable(int n, const Mission& m, const Reachability&) const {
  const std::string who = "trajectory: UAV " + std::to_string(n);
  const std::string allows = "trajectory.t_max = " + std::to_string(m.t_max) + " allows " + std::to_string(m.t_max - 1);
  // The HOME flight from a standstill without t_max's cap (bounded: a flight that takes more
  // than kLongest slots is reported as such).
  constexpr int kLongest = 10000000;
  const std::string cause = "(trajectory.v_max_mps = " + format_double(v_max_) + ", a_max_mps2 = " + format_double(a_max_mps2_) +
                            ", slot_s = " + format_double(slot_s_) + ")";
  bool blocked = false;
  Flight start;
  start.x = m.starts(n, 0), start.y = m.starts(n, 1);
  const int k = home_slots(start, m.dest_x(n), m.dest_y(n), m, kLongest, &blocked);
  if (blocked)
    return who + " cannot fly home from its start within the area at its speed and acceleration " + cause +
           ": allowed a start and destination it can fly between without meeting the boundary";
  if (k > kLongest)
    return who + " needs more than " + std::to_string(kLongest) + " slots to fly home from its start " + cause + " but " + allows +
           ": allowed a faster UAV (trajectory.v_max_mps, a_max_mps2) or longer slots (trajectory.slot_s)";
  return who + " needs " + std::to_string(k) + " slots to fly home from its start at its speed and acceleration " + cause + " but " +
         allows + ": allowed trajectory.t_max >= " + std::to_string(k + 1) + ", or a faster UAV";
}

void ContinuousDynamics::write_previous_action(int, const Flight& now, float* o) const {
  o[0] = static_cast<float>(now.vx / v_max_);
  o[1] = static_cast<float>(now.vy / v_max_);
}

std::optional<Config> ContinuousDynamics::reference_twin(const Config& cfg) const {
  Config twin = cfg;
  const auto& t = cfg.trajectory;
  twin.trajectory.mobility = "headings";
  twin.trajectory.speeds_mps = {0.0, t.v_max_mps / 2, t.v_max_mps};
  // The continuous settings do not act on headings: defaults, so that twins share cached optima.
  const TrajectoryConfig defaults;
  twin.trajectory.v_max_mps = defaults.v_max_mps, twin.trajectory.a_max_mps2 = defaults.a_max_mps2;
  twin.trajectory.arrival_m = defaults.arrival_m, twin.trajectory.command = defaults.command;
  if (lattice_steps(t.v_max_mps / 2, t.slot_s, t.d_fly_m) < 1 || lattice_steps(t.v_max_mps, t.slot_s, t.d_fly_m) < 1)
    throw InputError("trajectory.v_max_mps = " + format_double(t.v_max_mps) + ": the continuous model's reference is the optimum "
                     "of its lattice twin (headings at v_max / 2 and v_max), which needs v_max / 2 x trajectory.slot_s to be a "
                     "whole multiple of trajectory.d_fly_m = " + format_double(t.d_fly_m) + " m: allowed v_max_mps = " +
                     format_double(2 * t.d_fly_m / t.slot_s) + " x k");
  validate(twin);
  return twin;
}

std::shared_ptr<const Dynamics> make_continuous_dynamics(const Config& cfg) { return std::make_shared<ContinuousDynamics>(cfg); }

}  // namespace skyloop
