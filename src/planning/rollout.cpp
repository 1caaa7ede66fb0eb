// Multiagent rollout over a base planner (planners.hpp, RolloutPlanner).
#include "skyloop/core/error.hpp"
#include "skyloop/planning/planners.hpp"

namespace skyloop {

RolloutPlanner::RolloutPlanner(std::unique_ptr<Planner> base, std::string label) : base_(std::move(base)), name_(std::move(label)) {
  if (!base_) throw std::invalid_argument("RolloutPlanner: no base planner");
  if (name_.empty()) name_ = base_->name() + "+rollout";
  if (base_->commands_velocities())
    throw InputError("rollout over " + base_->name() + ", which commands velocities (trajectory.mobility = \"continuous\"): allowed "
                     "a base planner on the grid or headings model");
}

void RolloutPlanner::reset(UavEnv& env) {
  if (env.mobility().continuous())
    throw InputError("planner " + name_ + " under trajectory.mobility = \"continuous\": allowed \"grid\" or \"headings\" (the "
                     "rollout tries each UAV's discrete moves)");
  base_->reset(env);
  simulated_ = 0;
}

RolloutPlanner::Score RolloutPlanner::simulate(const UavEnv& env, const std::vector<int>& joint) {
  UavEnv sim = env;  // positions, history, rates so far; the oracle (and its memo) shared
  std::vector<int> a = joint;
  while (!sim.done()) {
    for (int n = 0; n < sim.uavs(); ++n)
      if (sim.arrived(n)) a[static_cast<std::size_t>(n)] = sim.hover();
    sim.step(a);
    ++simulated_;
    if (!sim.done()) a = base_->act(sim);
  }
  Score s;
  for (int n = 0; n < sim.uavs(); ++n) s.failures += sim.arrived(n) ? 0 : 1;
  s.failures += sim.total_collisions() + sim.total_boundary() + sim.over_budget();
  s.objective = sim.objective();
  return s;
}

std::vector<int> RolloutPlanner::act(UavEnv& env) {
  std::vector<int> joint = base_->act(env);
  const int N = env.uavs(), A = env.actions();
  for (int n = 0; n < N; ++n)
    if (env.arrived(n)) joint[static_cast<std::size_t>(n)] = env.hover();
  Score best = simulate(env, joint);
  for (int n = 0; n < N; ++n) {
    if (env.arrived(n)) continue;
    const int held = joint[static_cast<std::size_t>(n)];
    int choice = held;
    for (int a = 0; a < A; ++a) {
      if (a == held || !env.feasible(n, a)) continue;
      std::vector<int> trial = joint;
      trial[static_cast<std::size_t>(n)] = a;
      // The UAVs after n keep the base's moves of this slot; from the next slot on the base flies all.
      const Score s = simulate(env, trial);
      if (s.better_than(best)) best = s, choice = a;
    }
    joint[static_cast<std::size_t>(n)] = choice;
  }
  return joint;
}

}  // namespace skyloop
