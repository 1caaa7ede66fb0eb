#pragma once
// env.objective: what a mission is scored by (docs/concepts/mobility-energy.md). One table, the
// allowed values and help of the configuration field and the parser both read it.
#include <string>
#include <vector>

namespace skyloop {

enum class Objective { SumRate, EnergyEfficiency, Weighted, Energy };

struct ObjectiveInfo {
  const char* name;
  Objective value;
  const char* help;
};
/// Every objective, the paper's first.
const std::vector<ObjectiveInfo>& objectives();
/// The objective named so (InputError naming env.objective and the allowed names otherwise).
Objective parse_objective(const std::string& s);

}  // namespace skyloop
