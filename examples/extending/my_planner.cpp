// A trajectory planner of your own, registered by name and flown beside the built-in ones on the
// same users (docs/extending/planner.md). Built and run by the test suite
// (ctest -R examples.my_planner).
//
// The planner: every UAV takes, of its feasible moves, the one that leaves it the fewest moves
// home (ties: the mobility model's first); an arrived UAV hovers. It ignores the users.
#include <cstdio>
#include <limits>
#include <memory>

#include "skyloop/experiments/builtin.hpp"
#include "skyloop/experiments/planning_run.hpp"
#include "skyloop/planning/registry.hpp"

namespace {

class StraightHome final : public skyloop::Planner {
 public:
  std::string name() const override { return "straighthome"; }
  std::vector<int> act(skyloop::UavEnv& env) override {
    std::vector<int> joint(env.uavs(), env.hover());
    for (int n = 0; n < env.uavs(); ++n) {
      int best = std::numeric_limits<int>::max();
      for (int a = 0; a < env.actions(); ++a) {
        if (!env.feasible(n, a)) continue;  // inside the area, destination still reachable in time
        const int left = env.min_moves(n, env.landing(n, a));
        if (left < best) best = left, joint[n] = a;
      }
    }
    return joint;
  }
};

}  // namespace

int main() {
  // Registered by name: `plan --planner straighthome` and experiment files could now name it.
  skyloop::builtin_planners().add("straighthome", "each UAV on its shortest way home",
                                  [](const skyloop::PlannerArgs&) { return std::make_unique<StraightHome>(); });
  skyloop::Config cfg;  // the paper scenario
  cfg.env.oracle = "zf";
  skyloop::PlanOptions opt;
  opt.planners = {"straighthome", "greedy", "random"};
  opt.seed = 3;  // the users of `skyloop plan --seed 3`
  const auto records = skyloop::run_planners(cfg, opt, skyloop::builtin_beamformers(), nullptr);
  for (const auto& r : records)
    std::printf("%-13s objective %8.3f  home %s  T = %zu\n", r.planner.c_str(), r.objective, r.success ? "yes" : "no ",
                r.positions.size());
  // What the example claims: the shortest way home arrives, and serving the users on the way
  // (Greedy) gives the higher average sum rate.
  return records[0].success && records[1].objective > records[0].objective ? 0 : 1;
}
