// Multiagent rollout over a base planner (planners.hpp, RolloutPlanner).
#include "skyloop/core/error.hpp"
#include "skyloop/planning/planners.hpp"

namespace skyloop {

RolloutPlanner::RolloutPlanner(std::unique_ptr<Planner> base, std::string label) : base_(std::move(base)), name_(std::move(label)) {
  if (!base_) throw std::invalid_argument("RolloutPlanner: no base planner");
  if (name_.empty()) name_ = base_->name() + "+rollout";
}

void RolloutPlanner::reset(UavEnv& env) {
  base_->reset(env);
  simulated_ = 0;
}

RolloutPlanner::Score RolloutPlanner::score(const UavEnv& sim) const {
  Score s;
  for (int n = 0; n < sim.uavs(); ++n) s.failures += sim.arrived(n) ? 0 : 1;
  s.failures += sim.total_collisions() + sim.total_boundary() + sim.over_budget();
  s.objective = sim.objective();
  return s;
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
  return score(sim);
}

RolloutPlanner::Score RolloutPlanner::simulate(const UavEnv& env, const Positions& commands) {
  UavEnv sim = env;
  Positions v = commands;
  while (!sim.done()) {
    sim.step_velocities(v);
    ++simulated_;
    if (!sim.done()) v = base_->act_velocities(sim);
  }
  return score(sim);
}

Positions RolloutPlanner::act_velocities(UavEnv& env) {
  if (!base_->commands_velocities()) return Planner::act_velocities(env);
  Positions joint = base_->act_velocities(env);
  Score best = simulate(env, joint);
  for (int pass = 0; pass < kMaxPasses; ++pass) {
    bool changed = false;
    for (int n = 0; n < env.uavs(); ++n) {
      if (env.arrived(n)) continue;
      const double held_x = joint(n, 0), held_y = joint(n, 1);
      double choice_x = held_x, choice_y = held_y;
      for (int a = 0; a < env.actions(); ++a) {
        if (!env.feasible(n, a)) continue;
        Positions trial = joint;
        env.primitive_velocity(n, a, trial(n, 0), trial(n, 1));
        if (trial(n, 0) == held_x && trial(n, 1) == held_y) continue;
        const Score s = simulate(env, trial);
        if (s.better_than(best)) best = s, choice_x = trial(n, 0), choice_y = trial(n, 1);
      }
      changed |= choice_x != held_x || choice_y != held_y;
      joint(n, 0) = choice_x, joint(n, 1) = choice_y;
    }
    if (!changed) break;
  }
  return joint;
}

std::vector<int> RolloutPlanner::act(UavEnv& env) {
  std::vector<int> joint = base_->act(env);
  const int N = env.uavs(), A = env.actions();
  for (int n = 0; n < N; ++n)
    if (env.arrived(n)) joint[static_cast<std::size_t>(n)] = env.hover();
  Score best = simulate(env, joint);
  for (int pass = 0; pass < kMaxPasses; ++pass) {
    bool changed = false;
    for (int n = 0; n < N; ++n) {
      if (env.arrived(n)) continue;
      const int held = joint[static_cast<std::size_t>(n)];
      int choice = held;
      for (int a = 0; a < A; ++a) {
        if (a == held || !env.feasible(n, a)) continue;
        std::vector<int> trial = joint;
        trial[static_cast<std::size_t>(n)] = a;
        // The others keep the moves held for this slot; from the next slot on the base flies all.
        const Score s = simulate(env, trial);
        if (s.better_than(best)) best = s, choice = a;
      }
      changed |= choice != held;
      joint[static_cast<std::size_t>(n)] = choice;
    }
    if (!changed) break;
  }
  return joint;
}

}  // namespace skyloop
