// A dynamics model of your own, implementing the interface the environment, the masks, the
// planners, the DP and the learners ask (docs/extending/mobility-model.md). Built and run by the
// test suite (ctest -R examples.my_dynamics).
//
// The model: the paper's grid with the four diagonals added ("grid8"): a move of D_fly along x, y
// or both, or STAY. Ground speed D_fly / delta_t along the axes and sqrt(2) of it on a diagonal.
// Its reachability is the Chebyshev distance max(|dx|, |dy|) / D_fly (the breadth-first tables of
// LatticeDynamics find it), and its moves are those of the built-in headings model at the one
// speed D_fly / delta_t: the example checks that the exact optimum (the DP) of the two is the same
// plan value, that it is at least the grid's, and that Greedy flies it home.
#include <cmath>
#include <cstdio>
#include <memory>

#include "skyloop/env/dynamics.hpp"
#include "skyloop/env/uav_env.hpp"
#include "skyloop/experiments/builtin.hpp"
#include "skyloop/planning/planners.hpp"
#include "skyloop/planning/registry.hpp"

namespace {

class Grid8 final : public skyloop::LatticeDynamics {
 public:
  explicit Grid8(const skyloop::Config& cfg) : LatticeDynamics(cfg) {
    name_ = "grid8";
    const double v = pitch_ / slot_s_;  // D_fly per slot
    add("E", {1, 0}, v), add("NE", {1, 1}, std::sqrt(2.0) * v), add("N", {0, 1}, v), add("NW", {-1, 1}, std::sqrt(2.0) * v);
    add("W", {-1, 0}, v), add("SW", {-1, -1}, std::sqrt(2.0) * v), add("S", {0, -1}, v), add("SE", {1, -1}, std::sqrt(2.0) * v);
    add("STAY", {0, 0}, 0.0);
    actions_.hover = count() - 1;
    reach_ = pitch_;  // the longest move along one axis: T_min = ceil(distance / D_fly)
  }

 protected:
  std::string moves_text() const override { return "the 8 grid moves of trajectory.d_fly_m"; }
};

/// The exact optimum of the paper scenario's users (seed 3) under `dynamics`, and Greedy's flight.
struct Scores {
  double optimum = 0, greedy = 0;
  bool greedy_home = false;
};
Scores solve(const skyloop::Config& cfg, std::shared_ptr<const skyloop::Dynamics> dynamics) {
  const auto oracle = std::make_shared<skyloop::RateOracle>(cfg, skyloop::builtin_beamformers().create(cfg.env.oracle, cfg),
                                                            skyloop::make_users(cfg, cfg.scenario.users, 3));
  skyloop::UavEnv env(cfg, oracle, std::move(dynamics));
  Scores s;
  s.optimum = skyloop::solve_optimal(env).objective;
  auto greedy = skyloop::builtin_planners().create("greedy");
  const auto r = skyloop::run_episode(env, *greedy);
  s.greedy = r.objective, s.greedy_home = r.success;
  return s;
}

}  // namespace

int main() {
  skyloop::Config cfg;  // the paper scenario, two of its UAVs (the DP's 9^2 joint moves stay quick)
  cfg.env.oracle = "zf";
  cfg.trajectory.starts.resize(2), cfg.trajectory.destinations.resize(2);
  skyloop::Config headings = cfg;
  headings.trajectory.mobility = "headings", headings.trajectory.speeds_mps = {0.0, 10.0};  // 10 m/s x 2 s = D_fly
  const Scores mine = solve(cfg, std::make_shared<Grid8>(cfg));
  const Scores king = solve(headings, skyloop::make_dynamics(headings));
  const Scores grid = solve(cfg, skyloop::make_dynamics(cfg));
  std::printf("optimum: grid8 %.6f, headings at D_fly per slot %.6f, grid %.6f\n", mine.optimum, king.optimum, grid.optimum);
  std::printf("greedy:  grid8 %.6f (home: %s)\n", mine.greedy, mine.greedy_home ? "yes" : "no");
  // What the example claims: the same moves give the same optimum; more moves never a worse one.
  const bool ok = std::abs(mine.optimum - king.optimum) <= 1e-9 * std::abs(king.optimum) && mine.optimum >= grid.optimum - 1e-9 &&
                  mine.greedy_home;
  return ok ? 0 : 1;
}
