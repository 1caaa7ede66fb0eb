#pragma once
// Trajectory planners by name, like the beamformer registry: the CLI (`plan --planner`, `eval
// --planner`), the experiment files (experiment.planners), `reproduce` and Python all read this
// one list. A user adds their own:
//
//   skyloop::builtin_planners().add("mine", "my heuristic", [](const skyloop::PlannerArgs& a) {
//     return std::make_unique<MyPlanner>(a.seed);
//   });
#include <cstdint>
#include <functional>
#include <iosfwd>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "skyloop/core/registry.hpp"
#include "skyloop/planning/planners.hpp"

namespace skyloop {

struct PlannerArgs {
  std::uint64_t seed = 0;           // randomised planners
  std::ostream* progress = nullptr; // long-running planners report here
  std::string memo_key;             // optimal: plans kept for the process under this key (OptimalPlanner)
  SafetyOptions safety;             // seqgreedy: the slack margin and clearance its mask keeps (safety_options(cfg))
};

using PlannerFactory = std::function<std::unique_ptr<Planner>(const PlannerArgs&)>;

/// The planners by name, in registration order (skyloop/core/registry.hpp).
class PlannerRegistry : public Registry<PlannerFactory> {
 public:
  PlannerRegistry() : Registry("planner '{}'") {}
  /// Builds the planner; throws InputError "planner 'x' is unknown: allowed a, b, c".
  std::unique_ptr<Planner> create(const std::string& name, const PlannerArgs& args = {}) const { return at(name)(args); }
};

/// The built-in planners: random, greedy, seqgreedy, bestknown, optimal.
PlannerRegistry& builtin_planners();

}  // namespace skyloop
