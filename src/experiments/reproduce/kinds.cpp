// The table of stage kinds: an experiment file's `kind` is looked up here.
#include "context.hpp"
#include "skyloop/core/error.hpp"

namespace skyloop::repro {

const std::vector<StageKind>& stage_kinds() {
  static const std::vector<StageKind> kinds = {models_stage(), sweep_stage(), marl_training_stage(), planning_users_stage(),
                                               trajectories_stage(), generalisation_stage(), rate_energy_stage(), altitude_profile_stage()};
  return kinds;
}

const StageKind& stage_kind(const std::string& name) {
  std::string all;
  for (const auto& k : stage_kinds()) {
    if (k.name == name) return k;
    all += (all.empty() ? "" : ", ") + k.name;
  }
  throw InputError("experiment kind '" + name + "' has no stage: allowed " + all);
}

}  // namespace skyloop::repro
