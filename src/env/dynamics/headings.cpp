// Headings: 8 headings (king moves) at each positive speed of trajectory.speeds_mps, then HOVER.
#include <algorithm>
#include <cmath>

#include "skyloop/core/config_io.hpp"
#include "skyloop/core/error.hpp"
#include "skyloop/core/io.hpp"
#include "skyloop/env/dynamics.hpp"

namespace skyloop {

namespace {
// E, NE, N, NW, W, SW, S, SE
constexpr int kHx[8] = {1, 1, 0, -1, -1, -1, 0, 1};
constexpr int kHy[8] = {0, 1, 1, 1, 0, -1, -1, -1};
constexpr const char* kHeadingNames[8] = {"E", "NE", "N", "NW", "W", "SW", "S", "SE"};

/// trajectory.speeds_mps: each positive speed a whole number of lattice steps per slot, distinct,
/// below the rotor's tip speed on the diagonal; at least one; at most kMaxActions actions.
void validate_speeds(const Config& c) {
  const auto& t = c.trajectory;
  int moving = 0;
  for (std::size_t i = 0; i < t.speeds_mps.size(); ++i) {
    const double v = t.speeds_mps[i];
    if (v == 0) continue;
    const long k = lattice_steps(v, t.slot_s, t.d_fly_m);
    if (k < 1)
      throw InputError("trajectory.speeds_mps[" + std::to_string(i) + "] = " + format_double(v) + " m/s flies " +
                       format_double(v * t.slot_s) + " m per slot of trajectory.slot_s = " + format_double(t.slot_s) +
                       " s: allowed speeds whose step is a whole multiple of trajectory.d_fly_m = " + format_double(t.d_fly_m) +
                       " m (the lattice pitch), or 0 (hover)");
    for (std::size_t j = 0; j < i; ++j)
      if (t.speeds_mps[j] == v)
        throw InputError("trajectory.speeds_mps[" + std::to_string(i) + "] = " + format_double(v) + " repeats entry " +
                         std::to_string(j) + ": allowed distinct speeds");
    if (std::sqrt(2.0) * v >= c.energy.u_tip_mps && c.energy.model != Propulsion::None)
      throw InputError("trajectory.speeds_mps[" + std::to_string(i) + "] = " + format_double(v) + " m/s flies " +
                       format_double(std::sqrt(2.0) * v) + " m/s on a diagonal, at or above energy.u_tip_mps = " +
                       format_double(c.energy.u_tip_mps) + ": allowed ground speeds below the tip speed (the power model's range)");
    ++moving;
  }
  if (moving == 0)
    throw InputError("trajectory.speeds_mps = " + format_value(FieldValue(t.speeds_mps)) +
                     " has no positive speed: allowed at least one speed above 0 (0 = hover)");
  if (8 * moving + 1 > kMaxActions)
    throw InputError("trajectory.speeds_mps has " + std::to_string(moving) + " positive speeds, " + std::to_string(8 * moving + 1) +
                     " actions: allowed at most " + std::to_string((kMaxActions - 1) / 8) + " positive speeds (" +
                     std::to_string(kMaxActions) + " actions)");
}

class HeadingsDynamics : public LatticeDynamics {
 public:
  explicit HeadingsDynamics(const Config& cfg) : LatticeDynamics(cfg), speeds_text_(format_value(FieldValue(cfg.trajectory.speeds_mps))) {
    validate_speeds(cfg);
    long kmax = 0;
    for (const double v : cfg.trajectory.speeds_mps) {
      if (v == 0) continue;
      const long k = lattice_steps(v, slot_s_, pitch_);
      kmax = std::max(kmax, k);
      for (int h = 0; h < 8; ++h)
        add(std::string(kHeadingNames[h]) + "@" + format_double(v), {kHx[h] * static_cast<int>(k), kHy[h] * static_cast<int>(k)},
            std::hypot(kHx[h], kHy[h]) * static_cast<double>(k) * pitch_ / slot_s_);
    }
    add("HOVER", {0, 0}, 0.0);
    actions_.hover = count() - 1;
    reach_ = static_cast<double>(kmax) * pitch_;
  }

  /// The lattice's tables, and a destination that no speed set reaches refused (a speed set
  /// without single steps leaves some lattice points out of reach).
  std::shared_ptr<const Reachability> reachability(const Mission& m) const override {
    auto r = LatticeDynamics::reachability(m);
    constexpr int kNever = 1 << 30;  // beyond any lattice's distances (kMaxLatticeCells)
    for (int n = 0; n < static_cast<int>(m.starts.rows()); ++n) {
      Flight start;
      start.x = m.starts(n, 0), start.y = m.starts(n, 1);
      if (r->slots(n, start, kNever) > kNever)
        throw InputError("trajectory.destinations[" + std::to_string(n) + "] cannot be reached from trajectory.starts[" +
                         std::to_string(n) + "] with trajectory.speeds_mps = " + speeds_text_ +
                         " (no speed flies a single lattice step per slot, so some lattice points are out of reach): allowed "
                         "speeds that include trajectory.d_fly_m / trajectory.slot_s = " + format_double(pitch_ / slot_s_) + " m/s");
    }
    return r;
  }

 protected:
  std::string moves_text() const override {
    return "trajectory.speeds_mps = " + speeds_text_ + " on the lattice of trajectory.d_fly_m = " + format_double(pitch_) + " m";
  }

 private:
  std::string speeds_text_;
};

}  // namespace

std::shared_ptr<const Dynamics> make_headings_dynamics(const Config& cfg) { return std::make_shared<HeadingsDynamics>(cfg); }

}  // namespace skyloop
