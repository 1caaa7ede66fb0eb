#pragma once
// Shared pieces of the learners: checkpoints, environment set-up, metrics, evaluation.
#include <chrono>
#include <filesystem>
#include <nlohmann/json.hpp>
#include <string>

#include "nets.hpp"
#include "skyloop/marl/marl.hpp"
#include "skyloop/planning/safety.hpp"

namespace skyloop::marl {

constexpr const char* kFormat = "skyloop-marl";
constexpr int kVersion = 1;

/// Networks of a learner by role: "actor", "critic" (PPO) or "q", "mixer" (value decomposition).
struct Nets {
  MlpNet actor{nullptr}, critic{nullptr}, q{nullptr};
  QMixer mixer{nullptr};
};

/// What an agent network reads, for every learner: the paper's observation (marl.encoder = mlp;
/// `context` appends the agent context for the Q-networks) or the set observation (set: already
/// tells the agents apart, so no context).
struct Encoder {
  bool set = false;
  bool context = false;
  int width(const UavEnv& env) const;
  void write(const UavEnv& env, int n, float* out) const;
};
Encoder encoder_of(const Config& cfg, bool context);
SafetyOptions safety_of(const Config& cfg);

/// Writes the archive atomically: meta JSON, the present networks, optionally the optimiser.
void save(const std::string& path, const nlohmann::json& meta, Nets& nets, torch::optim::Optimizer* opt);
/// Reads meta; builds nothing. Throws InputError for missing / corrupt / foreign files.
nlohmann::json read_meta(const std::string& path);
/// Loads the networks present in `nets` (and the optimiser if given) from `path`.
void load(const std::string& path, Nets& nets, torch::optim::Optimizer* opt);

/// The beamformer behind R[t] (env.oracle), errors naming the field.
std::shared_ptr<const Beamformer> make_oracle_beamformer(const Config& cfg, const BeamformerRegistry& registry);
/// The shared training scenario: oracle on env.oracle with users from marl.users_seed.
std::shared_ptr<RateOracle> make_oracle(const Config& cfg, const BeamformerRegistry& registry);
/// The training environments: M on the shared scenario, or (env.resample_users) each episode a
/// new training layout (skyloop/env/layouts.hpp) drawn from the run seed.
VecEnv make_training_envs(const Config& cfg, const BeamformerRegistry& registry);

/// Running mean / variance (Welford over batches), for value normalisation.
struct RunningStats {
  double mean = 0, var = 1, count = 1e-4;
  void update(const torch::Tensor& x);
  torch::Tensor normalise(const torch::Tensor& x) const { return (x - mean) / std::sqrt(var + 1e-8); }
  torch::Tensor denormalise(const torch::Tensor& x) const { return x * std::sqrt(var + 1e-8) + mean; }
};

/// Episode statistics gathered between two log lines.
struct EpisodeStats {
  int episodes = 0;
  double reward = 0, objective = 0, home = 0, collisions = 0, boundary = 0;
  void add(const StepInfo& s, int uavs);
  void clear() { *this = EpisodeStats{}; }
};

/// Appends one metrics row and rewrites metrics.csv atomically.
std::string metrics_header();
std::string metrics_row(std::uint64_t seed, std::int64_t steps, const EpisodeStats& e, double policy_loss, double value_loss,
                        double entropy, double epsilon, double steps_per_s);

/// Evaluates `planner` on the training scenario (deterministic) and returns the record.
EpisodeRecord evaluate(const Config& cfg, const BeamformerRegistry& registry, Planner& planner);

torch::Device device_of(const Config& cfg);

/// What every learner needs before its loop: torch threads set, the run's paths (checked for
/// --resume), the device, and M environments on the shared training scenario.
struct Run {
  Run(const Config& cfg, const MarlTrainOptions& opt);
  std::filesystem::path dir;
  std::string last, final_path;
  torch::Device device{torch::kCPU};
  VecEnv vec;
  std::chrono::steady_clock::time_point start = std::chrono::steady_clock::now();
  // Model selection on validation layouts (marl.val_layouts > 0).
  double best_complete = -1, best_objective = -1;
  std::string validation_csv;
  /// For --resume: checks that last.pt holds a run of the same algo, hidden size and
  /// `size_key` = `size`, loads its networks and optimiser and the earlier metrics.csv into
  /// `metrics`, and returns its header.
  nlohmann::json resume(const Config& cfg, const std::string& size_key, int size, Nets& nets, torch::optim::Optimizer& opt,
                        std::string& metrics) const;
  /// Resumable checkpoint: last.pt (networks and optimiser) and metrics.csv, both atomically.
  void checkpoint(const nlohmann::json& meta, Nets& nets, torch::optim::Optimizer& opt, const std::string& metrics) const;
  /// After the loop: writes the final policy (final_path) and the last checkpoint, then returns
  /// the timings and the deterministic evaluation of the final policy.
  /// With marl.val_layouts: scores the policy just checkpointed (last.pt) on the validation
  /// layouts, appends a row to validation.csv and keeps it as policy.pt if it is the best so far
  /// (more missions complete, then a higher mean objective).
  void validate(const Config& cfg, const MarlTrainOptions& opt, const nlohmann::json& meta, Nets& nets, std::int64_t steps);
  MarlTrainResult finish(const Config& cfg, const MarlTrainOptions& opt, const nlohmann::json& meta, Nets& nets,
                         torch::optim::Optimizer& optimizer, const std::string& metrics, std::int64_t steps,
                         std::int64_t start_steps);
};

}  // namespace skyloop::marl
