#pragma once
// Multi-agent trajectory learning (Section V and the baselines of Section VI-C): MAPPO and IPPO on
// one PPO core, VDN and QMIX on one value-decomposition core. Torch-free API; the learners live
// in src/marl (target skyloop_marl).
#include <cstdint>
#include <iosfwd>
#include <memory>
#include <string>
#include <vector>

#include "skyloop/beamforming/registry.hpp"
#include "skyloop/planning/planners.hpp"

namespace skyloop {

struct MarlTrainOptions {
  std::string out_dir;    // config.toml, metrics.csv, last.pt (resumable), policy.pt (final)
  bool resume = false;    // continue from out_dir/last.pt
  bool force = false;     // replace a run already in out_dir (refused otherwise)
  std::ostream* progress = nullptr;
  const BeamformerRegistry* registry = nullptr;  // resolves env.oracle (required)
};

struct MarlTrainResult {
  std::int64_t env_steps = 0;
  double seconds = 0;
  double steps_per_second = 0;
  EpisodeRecord evaluation;  // the final deterministic policy on the training scenario
};

/// Trains cfg.marl.algo on the paper scenario of cfg (users from marl.users_seed, oracle
/// env.oracle), seeded by run.seed.
MarlTrainResult train_marl(const Config& cfg, const MarlTrainOptions& opt);

/// A trained policy as a planner: each active UAV takes its greedy action (argmax of the actor's
/// logits for PPO, of the agent Q-values for VDN/QMIX) from its local observation, among the
/// moves its safety settings allow (shielded_argmax).
class MarlPolicy final : public Planner {
 public:
  /// Loads DIR/policy.pt (or a .pt file). Missing, corrupt or foreign files throw InputError.
  static std::unique_ptr<MarlPolicy> load(const std::string& path);
  ~MarlPolicy() override;
  std::string name() const override;
  /// Forgets the ways home reserved (marl.reserve_slack) in the episode before.
  void reset(UavEnv& env) override;
  std::vector<int> act(UavEnv& env) override;
  /// Policies trained on the continuous model command velocities: the mean of their squashed
  /// Gaussian, tanh(mu), through the safety layer (safe_velocities).
  bool commands_velocities() const override;
  Positions act_velocities(UavEnv& env) override;
  /// The configuration the policy was trained with.
  const std::string& config_toml() const;
  /// Safety at execution (skyloop/planning/safety.hpp): as trained (marl.action_mask,
  /// marl.shield) unless set here. Without the mask and the shield a UAV takes the argmax of
  /// every action, as the paper's policy does.
  bool action_mask() const;
  bool shield() const;
  void set_safety(bool action_mask, bool shield);
  /// marl.sequential at execution: the UAVs choose one after another in shield order, each seeing
  /// the landings chosen before it (UavEnv::show_decided): as trained unless set here; refused
  /// (InputError) for the value-decomposition learners, the paper's observation and continuous commands.
  bool sequential() const;
  void set_sequential(bool sequential);
  /// marl.sequential_passes at execution (1 .. kMaxSequentialPasses): the turns taken that many
  /// times a slot, the last pass flown; as trained unless set here; more than 1 needs sequential().
  int sequential_passes() const;
  void set_sequential_passes(int passes);
  /// marl.reserve_slack at execution (safety.hpp; -1: none): as trained unless set here. An
  /// execution-only setting: a policy trained without it may fly with it.
  int reserve_slack() const;
  void set_reserve_slack(int slack);

  struct Impl;

 private:
  explicit MarlPolicy(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

/// The training configuration a policy (a run directory or its policy.pt) holds, resolved: what
/// `skyloop eval --policy` starts from, skyloop.policy_config, and the benchmark's protocol check.
Config policy_config(const std::string& path);

/// Generalised advantage estimates of one agent's sequence (eq. in Section V-C):
/// delta_t = r_t + gamma (1 - done_t) V_{t+1} - V_t, A_t = delta_t + gamma lambda (1 - done_t) A_{t+1},
/// where done_t = 1 if the episode ended with step t. `values` has T + 1 entries (bootstrap last).
std::vector<double> gae(const std::vector<double>& rewards, const std::vector<double>& values,
                        const std::vector<int>& dones, double gamma, double lambda);

}  // namespace skyloop
