// Altitude as a decision (beyond the paper): the grid's five moves, each holding the altitude,
// climbing or descending by trajectory.climb_m, on the levels altitude_min_m, altitude_min_m +
// climb_m, ..., altitude_max_m. Missions start and end at scenario.altitude_m (one of the
// levels); a move out of the band is cancelled like one out of the area. The channel reads each
// UAV's altitude (elevation, LoS probability, path loss, Rician K, coverage); a climb costs m g dz
// on top of the level-flight power (skyloop/env/energy.hpp).
#include <cmath>
#include <string>

#include "skyloop/channel/path_loss.hpp"
#include "skyloop/core/error.hpp"
#include "skyloop/core/io.hpp"
#include "skyloop/env/dynamics.hpp"

namespace skyloop {

const ActionSpec& grid_actions();

namespace {

class Grid3dDynamics : public LatticeDynamics {
 public:
  explicit Grid3dDynamics(const Config& cfg) : LatticeDynamics(cfg) {
    const auto& t = cfg.trajectory;
    check(cfg);
    const LatticeStep moves[kGridActions] = {{0, 1}, {0, -1}, {-1, 0}, {1, 0}, {0, 0}};  // the grid's order
    const char* suffix[3] = {"", "+CLIMB", "+DESCEND"};
    const int dz[3] = {0, 1, -1};
    for (int v = 0; v < 3; ++v)
      for (int a = 0; a < kGridActions; ++a) {
        const LatticeStep s{moves[a].dx, moves[a].dy, dz[v]};
        add(grid_actions().names[static_cast<std::size_t>(a)] + suffix[v], s, s.dx || s.dy ? pitch_ / slot_s_ : 0.0);
      }
    actions_.hover = kStay;
    reach_ = pitch_;
    floor_ = t.altitude_min_m, climb_ = t.climb_m;
    levels_ = static_cast<int>(std::lround((t.altitude_max_m - t.altitude_min_m) / t.climb_m)) + 1;
  }

 protected:
  std::string moves_text() const override {
    return "moves of trajectory.d_fly_m = " + format_double(pitch_) + " m and climbs of trajectory.climb_m = " + format_double(climb_) + " m";
  }

 private:
  /// The band's settings, each refused in one line naming the field.
  static void check(const Config& cfg) {
    const auto& t = cfg.trajectory;
    const double lo = t.altitude_min_m, hi = t.altitude_max_m, h = cfg.scenario.altitude_m;
    auto whole = [](double x) { return std::abs(x - std::round(x)) < 1e-9 * std::max(1.0, std::abs(x)); };
    if (!(lo < hi))
      throw InputError("trajectory.altitude_min_m = " + format_double(lo) + " is not below trajectory.altitude_max_m = " + format_double(hi) +
                       ": allowed altitude_min_m < altitude_max_m (trajectory.mobility = \"grid-3d\")");
    if (!whole((hi - lo) / t.climb_m))
      throw InputError("trajectory.altitude_max_m - altitude_min_m = " + format_double(hi - lo) + " m is not a whole number of trajectory.climb_m = " +
                       format_double(t.climb_m) + " m: allowed a band of whole climbs (trajectory.mobility = \"grid-3d\")");
    if (h < lo - 1e-9 || h > hi + 1e-9 || !whole((h - lo) / t.climb_m))
      throw InputError("scenario.altitude_m = " + format_double(h) + " (where missions start and end) is not one of the altitude levels " +
                       format_double(lo) + ", " + format_double(lo + t.climb_m) + ", ..., " + format_double(hi) +
                       " (trajectory.altitude_min_m + k trajectory.climb_m): allowed an altitude_m on the levels");
    const double user = cfg.scenario.user_height_m;
    if (lo - user < cfg.channel.d0_m)
      throw InputError("trajectory.altitude_min_m = " + format_double(lo) + " is " + format_double(lo - user) +
                       " m above scenario.user_height_m, less than channel.d0_m = " + format_double(cfg.channel.d0_m) +
                       ": allowed altitude_min_m >= user_height_m + d0_m (the path loss holds from the reference distance on)");
    if (const PathLossInfo* pl = find_path_loss(cfg.channel.pathloss); pl && (lo <= pl->min_height_m || hi > pl->max_height_m))
      throw InputError("trajectory.altitude_min_m .. altitude_max_m = " + format_double(lo) + " .. " + format_double(hi) +
                       " m leaves channel.pathloss = \"" + cfg.channel.pathloss + "\"'s range: allowed " + format_double(pl->min_height_m) +
                       " < altitude <= " + format_double(pl->max_height_m) + " m");
    if (cfg.energy.model != Propulsion::None && t.d_fly_m / t.slot_s >= cfg.energy.u_tip_mps)
      throw InputError("trajectory.d_fly_m = " + format_double(t.d_fly_m) + " m per trajectory.slot_s = " + format_double(t.slot_s) + " s flies " +
                       format_double(t.d_fly_m / t.slot_s) + " m/s, at or above energy.u_tip_mps = " + format_double(cfg.energy.u_tip_mps) +
                       ": allowed a ground speed below the tip speed (the power model's range)");
  }
};

}  // namespace

std::shared_ptr<const Dynamics> make_grid3d_dynamics(const Config& cfg) { return std::make_shared<Grid3dDynamics>(cfg); }

}  // namespace skyloop
