#include "skyloop/env/mobility.hpp"

#include <cmath>
#include <deque>

#include "skyloop/core/config.hpp"
#include "skyloop/core/error.hpp"
#include "skyloop/core/io.hpp"

namespace skyloop {

const MobilityInfo kMobilityModels[2] = {
    {"grid", "the paper's five moves: UP, DOWN, LEFT, RIGHT by D_fly, STAY; V = D_fly / slot_s"},
    {"headings", "8 headings x the positive speeds_mps, then HOVER; king moves of k = v slot_s / D_fly lattice steps"},
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

LatticeFrame::LatticeFrame(double x, double y, double area_x, double area_y, double d)
    : ox(std::fmod(x, d)), oy(std::fmod(y, d)), pitch(d) {
  nx = static_cast<int>(std::floor((area_x - ox) / d + 1e-9)) + 1;
  ny = static_cast<int>(std::floor((area_y - oy) / d + 1e-9)) + 1;
}

int LatticeFrame::cell(double x, double y) const {
  return static_cast<int>(std::lround((y - oy) / pitch)) * nx + static_cast<int>(std::lround((x - ox) / pitch));
}

std::vector<int> MobilityModel::slots_to(int nx, int ny, int to) const {
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
      if (d < 0) d = dist[static_cast<std::size_t>(c)] + 1, queue.push_back(jy * nx + jx);
    }
  }
  return dist;
}

}  // namespace skyloop
