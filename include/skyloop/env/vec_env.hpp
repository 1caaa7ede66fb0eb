#pragma once
// VecEnv: M environments (skyloop/env/uav_env.hpp) stepped as one batch, their rate oracles asked
// together, finished environments reset automatically (EnvPool's protocol, batch first).
#include <cstdint>
#include <functional>
#include <memory>
#include <vector>

#include "skyloop/env/uav_env.hpp"

namespace skyloop {

/// M environments stepped as one batch: every environment's R[t] in one batched oracle call.
/// Environment i's users come from derive_seed(seed, i) (env.users_file overrides); with
/// env.resample_users every episode of environment i is a new training layout
/// (skyloop/env/layouts.hpp: training_layout_seed(seed, i, episode), K in env.users_min..max).
class VecEnv {
 public:
  VecEnv(const Config& cfg, std::shared_ptr<const Beamformer> beamformer, int count, std::uint64_t seed);
  /// One environment per layout (skyloop/env/layouts.hpp): environment i flies the users of
  /// layouts[i] in every episode (the benchmark's test layouts; layout_users).
  VecEnv(const Config& cfg, std::shared_ptr<const Beamformer> beamformer, const std::vector<std::uint64_t>& layouts);
  /// M environments on one scenario: they share `oracle` (its users and its cache).
  VecEnv(const Config& cfg, std::shared_ptr<RateOracle> oracle, int count);
  int size() const { return static_cast<int>(envs_.size()); }
  /// The configuration's environment as made, never stepped: what the environments here are
  /// copies of, and what a caller makes its own like (UavEnv(like(), oracle): validation and
  /// evaluation layouts), sharing its lattice tables.
  const UavEnv& like() const { return *like_; }
  UavEnv& env(int i) { return *envs_[static_cast<std::size_t>(i)]; }
  const UavEnv& env(int i) const { return *envs_[static_cast<std::size_t>(i)]; }
  /// Whether the environments share one rate oracle (the second constructor); otherwise each
  /// environment's oracle is its own and no other environment touches it.
  bool shares_oracle() const { return shared_; }
  /// actions[i] = joint action of environment i. Finished environments are reset automatically
  /// after their final step (the returned info is the final step's); `before_reset(i)`, when
  /// given, sees environment i in its final state first (e.g. to record its last observation).
  std::vector<StepInfo> step(const std::vector<std::vector<int>>& actions,
                             const std::function<void(std::size_t)>& before_reset = {});
  /// The continuous model's step: velocities[i] = environment i's commands (UavEnv::step_velocities).
  std::vector<StepInfo> step_velocities(const std::vector<Positions>& velocities,
                                        const std::function<void(std::size_t)>& before_reset = {});
  void reset();

  /// step() in its two phases, for a caller that prepares each environment's move on threads of
  /// its own (the PPO learner's collect): begin(i, ...) moves environment i alone and touches no
  /// other (calls for different i may run at once); finish() then asks the rate oracles for every
  /// environment (in one batch per thread of run.threads where each environment has an oracle of
  /// its own), then ends each step and resets the finished environments on the calling thread.
  /// step(actions) is begin for every i, then finish.
  Positions begin(int i, const std::vector<int>& actions, StepInfo& info);
  Positions begin_velocities(int i, const Positions& velocities, StepInfo& info);
  /// Environments settled since their begin are skipped.
  std::vector<StepInfo> finish(std::vector<Positions>& next, std::vector<StepInfo>& info,
                               const std::function<void(std::size_t)>& before_reset = {});
  /// Ends environment i's step at once, after begin(i, ...), when its own oracle's memo holds every
  /// rate the step needs, and resets it when its episode ends (no before_reset: a caller that
  /// needs one leaves it to finish). Touches no other environment, so calls for different i may
  /// run at once. Returns false, having changed nothing, when the environments share an oracle or
  /// a rate is missing: finish() then ends the step with the others' misses in its batch (and
  /// weighs the environment by its misses when it shares them out among the threads). The
  /// same numbers as finish() (a memoised rate is the same doubles; a reset's rate is designed
  /// per cluster, the same on any thread).
  bool settle(int i, const Positions& next, StepInfo& info);

 private:
  void reset_env(std::size_t i);
  bool sampling() const;                 // a new training layout every episode
  Positions users_of(std::size_t i, std::uint64_t episode) const;  // environment i's users in that episode
  /// Environment i's oracle for its next episode (sampling() only), its start's rate asked in
  /// the batch of the step that ends the episode; reset_env takes it.
  std::shared_ptr<RateOracle> next_oracle(std::size_t i) const;
  Config cfg_;
  std::shared_ptr<const Beamformer> beamformer_;
  std::uint64_t seed_;
  std::unique_ptr<const UavEnv> like_;
  std::vector<std::unique_ptr<UavEnv>> envs_;
  std::vector<std::uint64_t> episodes_;
  std::vector<char> settled_;  // settle()d since begin, per environment
  std::vector<double> cost_;   // per environment, what its misses will take (settle's count; -1 unknown)
  struct Prepared {
    std::shared_ptr<RateOracle> oracle;  // next_oracle(i), made by finish()
    double start_rate = 0;               // R at the start under it
  };
  std::vector<Prepared> prepared_;
  bool shared_ = false;
  std::vector<std::uint64_t> layouts_;   // the layouts constructor's: environment i's users seed
};

}  // namespace skyloop
