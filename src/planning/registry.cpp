#include "skyloop/planning/registry.hpp"

#include "skyloop/core/error.hpp"

namespace skyloop {

PlannerRegistry& builtin_planners() {
  static PlannerRegistry reg = [] {
    PlannerRegistry r;
    r.add("random", "uniform over each UAV's feasible moves (the paper's Random)",
          [](const PlannerArgs& a) { return std::make_unique<RandomPlanner>(a.seed); });
    r.add("greedy", "best next-slot sum rate over all 5^N joint moves, collision-free first (the paper's Greedy; N <= 8)",
          [](const PlannerArgs&) { return std::make_unique<GreedyPlanner>(); });
    r.add("seqgreedy", "greedy one UAV at a time (least slack first), with a search for a collision-free joint move; linear in N; the "
          "mask keeps marl.slack_margin and marl.mask_clearance",
          [](const PlannerArgs& a) { return std::make_unique<SequentialGreedyPlanner>(a.safety); });
    r.add("rollout", "multiagent rollout over seqgreedy: each UAV in turn tries its moves, each scored by flying the rest of "
          "the mission with seqgreedy; never worse than seqgreedy",
          [](const PlannerArgs& a) {
            return std::make_unique<RolloutPlanner>(std::make_unique<SequentialGreedyPlanner>(a.safety), "rollout");
          });
    r.add("bestknown", "each UAV's exact trajectory given the others', iterated until no UAV improves (scales to large N)",
          [](const PlannerArgs& a) { return std::make_unique<BestKnownPlanner>(a.progress); });
    r.add("optimal", "the exact optimum of P2.2 by dynamic programming over the joint grid state (small N)",
          [](const PlannerArgs& a) { return std::make_unique<OptimalPlanner>(a.progress, a.memo_key); });
    return r;
  }();
  return reg;
}

}  // namespace skyloop
