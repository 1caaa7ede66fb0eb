// The registry of stage kinds: an experiment file's `kind` is looked up here. Adding a kind: its
// stage_*.cpp (a StageKind: pieces, assemble) and its row below (docs/extending/experiment-kind.md).
#include "context.hpp"
#include "skyloop/experiments/reproduce.hpp"

namespace skyloop {
namespace repro {

const Registry<StageKind>& stage_kinds() {
  static const Registry<StageKind> kinds(
      "experiment kind '{}'",
      {
          {"models", "trains (or reuses) the learned beamformers the other experiments name", models_stage()},
          {"beamform_sweep", "every method's sum rate over a swept setting (power, users, antennas, ...)", sweep_stage()},
          {"marl_training", "trains the learners over seeds and scores their policies beside the planners", marl_training_stage()},
          {"planning_users", "every planner's objective and the exact optimum over the number of users", planning_users_stage()},
          {"trajectories", "one layout's flown trajectories, planner by planner", trajectories_stage()},
          {"generalisation", "trained policies on held-out layouts, sizes and user counts", generalisation_stage()},
          {"rate_energy", "the rate-energy front: the optimum of R-bar - w P-bar over the weight w", rate_energy_stage()},
          {"altitude_profile", "the exact optimum's altitudes under each channel beside the fixed-altitude optimum",
           altitude_profile_stage()},
      });
  return kinds;
}

}  // namespace repro

std::vector<std::string> experiment_kinds() { return repro::stage_kinds().names(); }

}  // namespace skyloop
