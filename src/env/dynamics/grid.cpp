// The paper's grid (Section V-B): UP, DOWN, LEFT, RIGHT by D_fly, or STAY, at V = D_fly / delta_t.
#include <cmath>

#include "skyloop/core/error.hpp"
#include "skyloop/core/io.hpp"
#include "skyloop/env/dynamics.hpp"

namespace skyloop {

const ActionSpec& grid_actions() {
  static const ActionSpec spec{{"UP", "DOWN", "LEFT", "RIGHT", "STAY"}, kStay};
  return spec;
}

namespace {

/// Manhattan slots on the D_fly grid: ceil(|dx| / D_fly) + ceil(|dy| / D_fly), no tables.
class GridReachability : public Reachability {
 public:
  GridReachability(const Mission& m, double pitch) : dest_(m.destinations), pitch_(pitch) {}
  int slots(int n, const Flight& from, int) const override {
    const double dx = std::abs(dest_(n, 0) - from.x), dy = std::abs(dest_(n, 1) - from.y);
    return static_cast<int>(std::ceil(dx / pitch_ - 1e-9)) + static_cast<int>(std::ceil(dy / pitch_ - 1e-9));
  }

 private:
  Positions dest_;
  double pitch_;
};

class GridDynamics : public LatticeDynamics {
 public:
  explicit GridDynamics(const Config& cfg) : LatticeDynamics(cfg) {
    const auto& t = cfg.trajectory;
    if (cfg.energy.model != Propulsion::None && t.d_fly_m / t.slot_s >= cfg.energy.u_tip_mps)
      throw InputError("trajectory.d_fly_m = " + format_double(t.d_fly_m) + " m per trajectory.slot_s = " + format_double(t.slot_s) +
                       " s flies " + format_double(t.d_fly_m / t.slot_s) + " m/s, at or above energy.u_tip_mps = " +
                       format_double(cfg.energy.u_tip_mps) + ": allowed a ground speed below the tip speed (the power model's range)");
    const LatticeStep steps[kGridActions] = {{0, 1}, {0, -1}, {-1, 0}, {1, 0}, {0, 0}};  // spec.hpp's Action order
    for (int a = 0; a < kGridActions; ++a)
      add(grid_actions().names[static_cast<std::size_t>(a)], steps[a], steps[a].dx || steps[a].dy ? pitch_ / slot_s_ : 0.0);
    actions_.hover = kStay;
    reach_ = pitch_;
  }
  std::shared_ptr<const Reachability> reachability(const Mission& m) const override {
    return std::make_shared<GridReachability>(m, pitch_);
  }
  double reachability_bytes(double) const override { return 0; }

 protected:
  std::string moves_text() const override { return "moves of trajectory.d_fly_m = " + format_double(pitch_) + " m"; }
};

}  // namespace

std::shared_ptr<const Dynamics> make_grid_dynamics(const Config& cfg) { return std::make_shared<GridDynamics>(cfg); }

}  // namespace skyloop
