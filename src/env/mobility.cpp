#include "skyloop/env/mobility.hpp"

#include <algorithm>
#include <cmath>
#include <deque>

#include "skyloop/core/config.hpp"
#include "skyloop/core/error.hpp"
#include "skyloop/core/io.hpp"

namespace skyloop {

const MobilityInfo kMobilityModels[3] = {
    {"grid", "the paper's five moves: UP, DOWN, LEFT, RIGHT by D_fly, STAY; V = D_fly / slot_s"},
    {"headings", "8 headings x the positive speeds_mps, then HOVER; king moves of k = v slot_s / D_fly lattice steps"},
    {"continuous", "a velocity command in [-1, 1]^2 onto the disc of v_max_mps, its change at most a_max_mps2 x slot_s"},
};

namespace {
// E, NE, N, NW, W, SW, S, SE
constexpr int kHx[8] = {1, 1, 0, -1, -1, -1, 0, 1};
constexpr int kHy[8] = {0, 1, 1, 1, 0, -1, -1, -1};
constexpr const char* kHeadingNames[8] = {"E", "NE", "N", "NW", "W", "SW", "S", "SE"};

}  // namespace

MobilityModel::MobilityModel(const Config& cfg)
    : name_(cfg.trajectory.mobility), pitch_(cfg.trajectory.d_fly_m), slot_s_(cfg.trajectory.slot_s) {
  validate_mobility(cfg);
  grid_ = name_ == "grid";
  continuous_ = name_ == "continuous";
  if (continuous_) {
    const auto& t = cfg.trajectory;
    v_max_ = t.v_max_mps, dv_max_ = t.a_max_mps2 * slot_s_, arrival_m_ = t.arrival_m;
    command_ = t.command, polar_ = command_ == "polar";
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
    hover_ = actions_.hover = actions_.count() - 1;
    reach_ = v_max_ * slot_s_;
    return;
  }
  if (grid_) {
    actions_ = grid_actions();
    steps_ = {{0, 1}, {0, -1}, {-1, 0}, {1, 0}, {0, 0}};  // UP, DOWN, LEFT, RIGHT, STAY (spec.hpp's Action)
    hover_ = kStay;
    reach_ = pitch_;
    for (const auto& s : steps_) speeds_.push_back(s.dx || s.dy ? pitch_ / slot_s_ : 0.0);
    return;
  }
  long kmax = 0;
  for (const double v : cfg.trajectory.speeds_mps) {
    if (v == 0) continue;
    const long k = lattice_steps(v, slot_s_, pitch_);
    kmax = std::max(kmax, k);
    for (int h = 0; h < 8; ++h) {
      actions_.names.push_back(std::string(kHeadingNames[h]) + "@" + format_double(v));
      steps_.push_back({kHx[h] * static_cast<int>(k), kHy[h] * static_cast<int>(k)});
      speeds_.push_back(std::hypot(kHx[h], kHy[h]) * static_cast<double>(k) * pitch_ / slot_s_);
    }
  }
  actions_.names.push_back("HOVER");
  steps_.push_back({0, 0});
  speeds_.push_back(0.0);
  hover_ = actions_.hover = actions_.count() - 1;
  reach_ = static_cast<double>(kmax) * pitch_;
}

void MobilityModel::velocity(double u0, double u1, double& vx, double& vy) const {
  u0 = std::max(-1.0, std::min(1.0, u0)), u1 = std::max(-1.0, std::min(1.0, u1));
  const double l2 = std::hypot(u0, u1), linf = std::max(std::abs(u0), std::abs(u1));
  const double scale = l2 > 0 ? v_max_ * linf / l2 : 0.0;
  vx = u0 * scale, vy = u1 * scale;
}

void MobilityModel::commanded_velocity(double u0, double u1, double px, double py, double tx, double ty, double& vx,
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

void MobilityModel::command(double vx, double vy, double& u0, double& u1) const {
  const double v = std::hypot(vx, vy);
  if (v > v_max_) vx *= v_max_ / v, vy *= v_max_ / v;
  const double wx = vx / v_max_, wy = vy / v_max_;
  const double l2 = std::hypot(wx, wy), linf = std::max(std::abs(wx), std::abs(wy));
  const double scale = linf > 0 ? l2 / linf : 0.0;
  u0 = std::max(-1.0, std::min(1.0, wx * scale)), u1 = std::max(-1.0, std::min(1.0, wy * scale));
}

void MobilityModel::project(double vx, double vy, double px, double py, double& ox, double& oy) const {
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

void MobilityModel::home_command(double dx, double dy, double& vx, double& vy) const {
  const double d = std::hypot(dx, dy);
  if (d <= 0) {
    vx = vy = 0;
    return;
  }
  const double a_max = dv_max_ / slot_s_;
  const double s = std::min({v_max_, d / slot_s_, std::sqrt(2 * a_max * d)});
  vx = dx / d * s, vy = dy / d * s;
}

LatticeFrame::LatticeFrame(double x, double y, double area_x, double area_y, double d)
    : ox(std::fmod(x, d)), oy(std::fmod(y, d)), pitch(d) {
  const double fx = std::floor((area_x - ox) / d + 1e-9) + 1, fy = std::floor((area_y - oy) / d + 1e-9) + 1;
  if (fx * fy > kMaxLatticeCells) {
    // The finest pitch within the limit: (area_x / d + 1) (area_y / d + 1) <= kMaxLatticeCells.
    const double a = kMaxLatticeCells - 1, b = -(area_x + area_y), c = -area_x * area_y;
    const double finest = (-b + std::sqrt(b * b - 4 * a * c)) / (2 * a);
    throw InputError("the D_fly lattice of the " + format_double(area_x) + " x " + format_double(area_y) +
                     " m area (scenario.area_x_m x scenario.area_y_m) at trajectory.d_fly_m = " + format_double(d) + " has " +
                     format_double(fx * fy) + " points: allowed at most 2^24 (16,777,216), i.e. trajectory.d_fly_m >= " +
                     format_double(std::ceil(finest * 1000) / 1000) + " m on this area (the planners, the headings model and "
                     "the mask's clearances plan on it)");
  }
  nx = static_cast<int>(fx);
  ny = static_cast<int>(fy);
}

int LatticeFrame::cell(double x, double y) const {
  return static_cast<int>(std::lround((y - oy) / pitch)) * nx + static_cast<int>(std::lround((x - ox) / pitch));
}

std::vector<int> MobilityModel::slots_to(int nx, int ny, int to, const std::vector<char>* closed) const {
  std::vector<int> dist(static_cast<std::size_t>(nx) * static_cast<std::size_t>(ny), -1);
  std::deque<int> queue{to};
  dist[static_cast<std::size_t>(to)] = 0;
  // The move set is symmetric (every step has its opposite), so distances to `to` are distances from it.
  while (!queue.empty()) {
    const int c = queue.front();
    queue.pop_front();
    const int ix = c % nx, iy = c / nx;
    for (const auto& s : steps_) {
      const int jx = ix + s.dx, jy = iy + s.dy;
      if ((s.dx == 0 && s.dy == 0) || jx < 0 || jy < 0 || jx >= nx || jy >= ny) continue;
      auto& d = dist[static_cast<std::size_t>(jy * nx + jx)];
      if (closed && (*closed)[static_cast<std::size_t>(jy * nx + jx)]) continue;
      if (d < 0) d = dist[static_cast<std::size_t>(c)] + 1, queue.push_back(jy * nx + jx);
    }
  }
  return dist;
}

}  // namespace skyloop
