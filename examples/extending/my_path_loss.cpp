// A path-loss model of your own, implementing the interface every channel reads
// (docs/extending/channel-model.md). Built and run by the test suite (ctest -R examples.my_path_loss).
//
// The model: log-distance path loss with exponent n and the paper's reference loss at d0,
// beta(d) = beta0 (d0 / d)^n, always in line of sight, no shadowing. With n = 2 it is the paper's
// free-space model, which the example checks against the built-in one; with n = 2.5 it checks the
// formula at a point computed by hand.
#include <cmath>
#include <cstdio>
#include <memory>

#include "skyloop/channel/channel_model.hpp"

namespace {

class LogDistance final : public skyloop::PathLossModel {
 public:
  LogDistance(double beta0_db, double d0_m, double exponent) : beta0_db_(beta0_db), d0_(d0_m), n_(exponent) {}
  double p_los(const skyloop::LinkGeometry&) const override { return 1.0; }
  // Positive dB: -10 log10(beta) = -beta0_dB + 10 n log10(d / d0).
  double path_loss_db(const skyloop::LinkGeometry& g, bool) const override {
    return -beta0_db_ + 10.0 * n_ * std::log10(g.distance_m / d0_);
  }
  double shadowing_std_db(const skyloop::LinkGeometry&, bool) const override { return 0.0; }

 private:
  double beta0_db_, d0_, n_;
};

}  // namespace

int main() {
  const skyloop::Config cfg;  // the paper's channel: beta0 = -20 dB at d0 = 1 m (configs/paper.toml)
  const auto free_space = skyloop::make_path_loss(cfg.channel);
  const LogDistance square(cfg.channel.beta0_db, cfg.channel.d0_m, 2.0), urban(cfg.channel.beta0_db, cfg.channel.d0_m, 2.5);
  bool ok = true;
  for (double d2 : {0.0, 50.0, 100.0, 150.0}) {
    skyloop::LinkGeometry g;
    g.horizontal_m = d2, g.height_m = cfg.scenario.altitude_m, g.distance_m = std::hypot(d2, g.height_m);
    g.elevation_deg = std::asin(g.height_m / g.distance_m) * 180.0 / std::acos(-1.0);
    const double a = square.path_loss_db(g, true), b = free_space->path_loss_db(g, true);
    std::printf("d_2D = %5.1f m: log-distance n = 2 %.3f dB, built-in free space %.3f dB, n = 2.5 %.3f dB\n", d2, a, b,
                urban.path_loss_db(g, true));
    ok = ok && std::abs(a - b) < 1e-9;  // n = 2 is the paper's model
  }
  // By hand: d_3D = 100 m (right below the UAV at 100 m), n = 2.5: 20 + 25 log10(100) = 70 dB.
  skyloop::LinkGeometry below;
  below.height_m = below.distance_m = 100.0, below.elevation_deg = 90.0;
  ok = ok && std::abs(urban.path_loss_db(below, true) - 70.0) < 1e-9;
  return ok ? 0 : 1;
}
