#pragma once
// The multi-agent learners by name (marl.algo): one table that the config's allowed values, the
// CLI's help, the experiment files, `reproduce`, training and policy loading all read. Each learner
// runs on one of two cores (src/marl): the PPO core (MAPPO, IPPO) or the value-decomposition core
// (VDN, QMIX); a learner that varies a core is one entry here. Torch-free.
#include <string>
#include <vector>

#include "skyloop/core/registry.hpp"

namespace skyloop {

/// What a learner is, beside its name and help (its registry row).
struct LearnerInfo {
  enum class Core { Ppo, ValueDecomposition };
  enum class Mixer { None, Sum, Qmix };  // value decomposition: how the agents' Q values combine
  Core core;
  bool local_critic = false;  // PPO: the critic reads the agent's own observation (IPPO)
  Mixer mixer = Mixer::None;
  /// The network a trained policy acts with: the actor's logits (PPO) or the agent Q-network.
  bool acts_by_q() const { return core == Core::ValueDecomposition; }
};

/// Every learner, in display order (skyloop/core/registry.hpp).
inline const Registry<LearnerInfo>& learners() {
  using L = LearnerInfo;
  static const Registry<LearnerInfo> table(
      "marl.algo = \"{}\"",
      {
          {"mappo", "PPO with a centralised critic on the global or agent-specific state (the paper's learner)",
           {L::Core::Ppo, false, L::Mixer::None}},
          {"ippo", "PPO with each agent's critic on its own observation", {L::Core::Ppo, true, L::Mixer::None}},
          {"vdn", "value decomposition: the team Q is the sum of the agents' Q", {L::Core::ValueDecomposition, false, L::Mixer::Sum}},
          {"qmix", "value decomposition: a monotonic mixing network conditioned on the state",
           {L::Core::ValueDecomposition, false, L::Mixer::Qmix}},
      });
  return table;
}

/// The names, in display order.
inline std::vector<std::string> learner_names() { return learners().names(); }
/// "mappo, ippo, vdn, qmix".
inline std::string learner_names_text() { return learners().names_text(); }
/// The learner called `name`; throws InputError "marl.algo = "x" is unknown: allowed mappo, ...".
inline const LearnerInfo& find_learner(const std::string& name) { return learners().at(name); }

}  // namespace skyloop
