#pragma once
// Shared pieces of the learners: checkpoints, environment set-up, metrics, evaluation.
#include <algorithm>
#include <chrono>
#include <cstdint>
#include <cmath>
#include <functional>
#include <filesystem>
#include <nlohmann/json.hpp>
#include <string>

#include "nets.hpp"
#include "skyloop/core/io.hpp"
#include "skyloop/env/vec_env.hpp"
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
  /// Threads that may write different environments' inputs at once (collect's lanes): cfg.run.threads.
  int threads = 1;
  /// The observation asks the rate oracle (the set observation's marl.lookahead and
  /// marl.rate_map): environments that share one oracle (its memo) are then written on one
  /// thread, environments with oracles of their own in the lanes.
  bool asks_oracle = false;
  /// marl.sequential (discrete PPO): the UAVs choose one after another in shield order, each
  /// agent's observation written just before it chooses, with the landings chosen before it shown
  /// (UavEnv::show_decided).
  bool sequential = false;
  /// marl.sequential_passes: the turns taken this many times a slot (take_turns).
  int passes = 1;
  int width(const UavEnv& env) const;
  void write(const UavEnv& env, int n, float* out) const;
};
Encoder encoder_of(const Config& cfg, bool context);


/// A coefficient over training (marl.lr_schedule, marl.entropy_schedule), resolved once: its
/// factor at `steps` of `total` environment steps, 1 throughout (constant) or 1 - steps / total
/// (linear; a function of the steps alone, so --resume continues it).
struct Schedule {
  bool linear = false;
  static Schedule of(StepSchedule s) { return Schedule{s == StepSchedule::Linear}; }
  double factor(std::int64_t steps, std::int64_t total) const {
    return linear ? std::max(0.0, 1.0 - static_cast<double>(steps) / static_cast<double>(std::max<std::int64_t>(1, total))) : 1.0;
  }
};

/// A learner's networks and optimiser as the run's archives see them (last.pt, policy.pt).
class Learned {
 public:
  virtual ~Learned() = default;
  /// Writes the networks, and with `optimiser` the optimiser's state, to a policy archive
  /// (atomically).
  virtual void save(const std::string& path, const nlohmann::json& meta, bool optimiser) = 0;
  /// Reads them back (--resume).
  virtual void load(const std::string& path, bool optimiser) = 0;
};

/// Learned over LibTorch modules and a LibTorch optimiser.
class TorchLearned final : public Learned {
 public:
  TorchLearned(Nets& nets, torch::optim::Optimizer& optimiser) : nets_(nets), optimiser_(optimiser) {}
  void save(const std::string& path, const nlohmann::json& meta, bool optimiser) override;
  void load(const std::string& path, bool optimiser) override;

 private:
  Nets& nets_;
  torch::optim::Optimizer& optimiser_;
};

/// Writes `module`'s parameters and buffers as the archive entry `key`.
void write_module(torch::serialize::OutputArchive& archive, const char* key, torch::nn::Module& module);

/// Writes the archive atomically: meta JSON, the present networks, optionally the optimiser.
/// `extra` (if set) writes more entries (a backend's own optimiser state).
void save(const std::string& path, const nlohmann::json& meta, Nets& nets, torch::optim::Optimizer* opt,
          const std::function<void(torch::serialize::OutputArchive&)>& extra = {});
/// Reads meta; builds nothing. Throws InputError for missing / corrupt / foreign files.
nlohmann::json read_meta(const std::string& path);
/// Loads the networks present in `nets` (and the optimiser if given) from `path`.
/// `extra` (if set) reads the entries `save` wrote with it.
void load(const std::string& path, Nets& nets, torch::optim::Optimizer* opt,
          const std::function<void(torch::serialize::InputArchive&)>& extra = {});

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
  /// Merges the batch x[0..n-1] (its mean and population variance).
  void update(const float* x, std::size_t n);
  double normalise(double x) const { return (x - mean) / std::sqrt(var + 1e-8); }
  double denormalise(double x) const { return x * std::sqrt(var + 1e-8) + mean; }
};

/// Episode statistics gathered between two log lines.
struct EpisodeStats {
  int episodes = 0;
  double reward = 0, objective = 0, home = 0, collisions = 0, boundary = 0;
  double sum_rate = 0, energy_j = 0, bits_per_joule = 0;  // P2.2's objective, propulsion energy, bit/J
  void add(const StepInfo& s, int uavs);
  void clear() { *this = EpisodeStats{}; }
};

/// The learner's side of a metrics row (CleanRL's names); NaN leaves a column empty (a learner
/// without that quantity).
struct LearnerLog {
  double policy_loss = NAN, value_loss = NAN, entropy = NAN, old_approx_kl = NAN, approx_kl = NAN, clipfrac = NAN,
         explained_variance = NAN, grad_norm = NAN, epsilon = NAN;
};

/// metrics.csv: the header, and one row.
std::string metrics_header();
std::string metrics_row(std::uint64_t seed, std::int64_t steps, const EpisodeStats& e, const LearnerLog& log, double steps_per_s);

torch::Device device_of(const Config& cfg);
/// The network library a run of cfg trains with: marl.backend for the PPO learners, torch for
/// the value-decomposition ones (recorded in the policy header as "backend").
PpoBackend learner_backend(const Config& cfg);

/// What every learner needs before its loop: torch threads set, the run's paths (checked for
/// --resume), the device, and M environments on the shared training scenario. `check`, when
/// given, sees the environments before the run directory is touched (--force removes an earlier
/// run only once it has passed): the learner's checks of what its sizes need (require_memory).
struct Run {
  Run(const Config& cfg, const MarlTrainOptions& opt, const std::function<void(const VecEnv&)>& check = {});
  std::filesystem::path dir;
  std::string last, final_path;
  /// cfg.run.threads: skyloop's own threads (the environments' lanes, the fast learner's
  /// chunks). LibTorch and its BLAS get one, set before the environments compute their first rate:
  /// a sum or GEMM split over other threads rounds otherwise (a learned network oracle's, the
  /// torch learners'), and run.threads would change the numbers.
  int threads = 0;
  torch::Device device{torch::kCPU};
  VecEnv vec;
  RunDirLock lock;  // the run directory's, for the whole run
  std::chrono::steady_clock::time_point start = std::chrono::steady_clock::now();
  // Model selection on validation layouts (marl.val_layouts > 0).
  double best_complete = -1, best_objective = -1;
  std::string validation_csv;
  /// For --resume: checks that last.pt holds a run of the same algo, hidden size and
  /// `size_key` = `size`, loads its networks and optimiser and the earlier metrics.csv into
  /// `metrics`, and returns its header.
  /// With marl.val_layouts, the earlier validation.csv is kept and its best row (policy.pt) stays
  /// the one to beat.
  nlohmann::json resume(const Config& cfg, const std::string& size_key, int size, Learned& learned, std::string& metrics);
  /// validation.csv's rows up to `steps` (last.pt's) into validation_csv, and the best of those
  /// scored on as many layouts as cfg's into best_complete / best_objective.
  void restore_validation(const Config& cfg, std::int64_t steps);
  /// Resumable checkpoint: last.pt (networks and optimiser) and metrics.csv, both atomically.
  void checkpoint(const nlohmann::json& meta, Learned& learned, const std::string& metrics) const;
  /// After the loop: writes the final policy (final_path) and the last checkpoint, then returns
  /// the timings and the deterministic evaluation of the final policy.
  /// With marl.val_layouts: scores the policy just checkpointed (last.pt) on the validation
  /// layouts, appends a row to validation.csv and keeps it as policy.pt if it is the best so far
  /// (more missions complete, then a higher mean objective).
  void validate(const Config& cfg, const MarlTrainOptions& opt, const nlohmann::json& meta, Learned& learned, std::int64_t steps);
  MarlTrainResult finish(const Config& cfg, const MarlTrainOptions& opt, const nlohmann::json& meta, Learned& learned,
                         const std::string& metrics, std::int64_t steps, std::int64_t start_steps);
};

}  // namespace skyloop::marl
