#pragma once
// Shared pieces of the learners: checkpoints, environment set-up, metrics, evaluation.
#include <chrono>
#include <filesystem>
#include <nlohmann/json.hpp>
#include <string>

#include "nets.hpp"
#include "skyloop/marl/marl.hpp"

namespace skyloop::marl {

constexpr const char* kFormat = "skyloop-marl";
constexpr int kVersion = 1;

/// Networks of a learner by role: "actor", "critic" (PPO) or "q", "mixer" (value decomposition).
struct Nets {
  MlpNet actor{nullptr}, critic{nullptr}, q{nullptr};
  QMixer mixer{nullptr};
};

/// Writes the archive atomically: meta JSON, the present networks, optionally the optimiser.
void save(const std::string& path, const nlohmann::json& meta, Nets& nets, torch::optim::Optimizer* opt);
/// Reads meta; builds nothing. Throws InputError for missing / corrupt / foreign files.
nlohmann::json read_meta(const std::string& path);
/// Loads the networks present in `nets` (and the optimiser if given) from `path`.
void load(const std::string& path, Nets& nets, torch::optim::Optimizer* opt);

/// The shared training scenario: oracle on env.oracle with users from marl.users_seed.
std::shared_ptr<RateOracle> make_oracle(const Config& cfg, const BeamformerRegistry& registry);

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

/// Local observation with the agent's context appended (the Q-network input): one-hot id
/// (11 + N reals) under env.state = "paper", nearest UAVs (11 + 8) under "compact".
std::vector<float> obs_with_id(const UavEnv& env, int n);

torch::Device device_of(const Config& cfg);

/// What every learner needs before its loop: torch threads set, the run's paths (checked for
/// --resume), the device, and M environments on the shared training scenario.
struct Run {
  Run(const Config& cfg, const MarlTrainOptions& opt);
  std::filesystem::path dir;
  std::string last, final_path;
  torch::Device device{torch::kCPU};
  std::shared_ptr<RateOracle> oracle;
  VecEnv vec;
  std::chrono::steady_clock::time_point start = std::chrono::steady_clock::now();
  /// For --resume: checks that last.pt holds a run of the same algo, hidden size and
  /// `size_key` = `size`, loads its networks and optimiser and the earlier metrics.csv into
  /// `metrics`, and returns its header.
  nlohmann::json resume(const Config& cfg, const std::string& size_key, int size, Nets& nets, torch::optim::Optimizer& opt,
                        std::string& metrics) const;
  /// Resumable checkpoint: last.pt (networks and optimiser) and metrics.csv, both atomically.
  void checkpoint(const nlohmann::json& meta, Nets& nets, torch::optim::Optimizer& opt, const std::string& metrics) const;
  /// After the loop: writes the final policy (final_path) and the last checkpoint, then returns
  /// the timings and the deterministic evaluation of the final policy.
  MarlTrainResult finish(const Config& cfg, const MarlTrainOptions& opt, const nlohmann::json& meta, Nets& nets,
                         torch::optim::Optimizer& optimizer, const std::string& metrics, std::int64_t steps,
                         std::int64_t start_steps) const;
};

}  // namespace skyloop::marl
