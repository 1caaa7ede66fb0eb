#include "skyloop/core/objective.hpp"

#include "skyloop/core/error.hpp"

namespace skyloop {

const std::vector<ObjectiveInfo>& objectives() {
  static const std::vector<ObjectiveInfo> table = {
      {"sum-rate", Objective::SumRate, "P2.2's (1/T) sum R[t]"},
      {"energy-efficiency", Objective::EnergyEfficiency, "bits per joule (kbit/J)"},
      {"weighted", Objective::Weighted, "R-bar - energy.weight x mean fleet propulsion power"},
      {"energy", Objective::Energy, "-kJ (the rate term off)"},
  };
  return table;
}

Objective parse_objective(const std::string& s) {
  std::string allowed;
  for (const auto& o : objectives()) {
    if (s == o.name) return o.value;
    allowed += (allowed.empty() ? "" : ", ") + std::string(o.name);
  }
  throw InputError("env.objective = \"" + s + "\" is not allowed: allowed one of " + allowed);
}

}  // namespace skyloop
