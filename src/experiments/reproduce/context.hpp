#pragma once
// What the stages of `skyloop reproduce` share: the run's options and directory, the models the
// models stage resolved, and the pieces every stage kind is made of. One file per stage kind
// (stage_*.cpp) defines its pieces (what can run anywhere, in any order its dependencies allow)
// and its assembly (the figure's CSVs, read back from the pieces by column name); the kinds are
// looked up in one table (kinds.cpp).
#include <chrono>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <map>
#include <nlohmann/json.hpp>
#include <ostream>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

#include "piece_cache.hpp"
#include "skyloop/core/config.hpp"
#include "skyloop/core/csv.hpp"
#include "skyloop/core/registry.hpp"
#include "skyloop/experiments/layout_eval.hpp"
#include "skyloop/experiments/reproduce.hpp"

namespace skyloop::repro {

namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;
double since(Clock::time_point t0);

/// One cached unit of work. run() computes it unless it is done (under the piece's lock);
/// nothing else writes its files.
struct Piece {
  std::string id;                  // its path under the run directory: unique and stable
  std::string kind;                // model | chunk | marl | eval
  std::string label;               // for the log
  double cost = 1.0;               // estimated seconds on one core
  std::vector<std::string> deps;   // ids of pieces it reads
  std::function<bool()> done;
  std::function<void()> run;
  Config train_config;             // marl pieces: what a child `skyloop train` process gets
};

/// Thrown where --time-limit leaves no time for a piece that must run next (its label).
struct TimeLimitReached : std::runtime_error {
  using std::runtime_error::runtime_error;
};

/// The log line of a MARL run that was interrupted and starts again from scratch: the cache
/// holds only results equal to an uninterrupted run's (a resumed beamformer training is exact and
/// resumes; a resumed MARL run is not).
std::string restart_note(const fs::path& dir);

/// A learned-model label of the models stage: registry name and the overrides that make it.
struct ModelLabel {
  std::string base;
  std::vector<std::string> sets;
};
const std::map<std::string, ModelLabel>& model_labels();

class StageContext {
 public:
  StageContext(const ReproduceOptions& opt, std::ostream& log, int threads);

  const ReproduceOptions& opt;
  const fs::path out;
  mutable std::ostream log;        // progress of the pieces and the assembly (its buffer can be redirected)
  const int threads;
  const PieceCache cache;
  const Clock::time_point started = Clock::now();
  bool write_outputs = true;       // false on MPI ranks other than 0: they compute, rank 0 assembles

  // Filled by the models stage: label -> absolute path, hash of the bytes, path shown in reports.
  std::map<std::string, std::string> model_paths;
  std::map<std::string, std::uint64_t> model_hashes;
  std::map<std::string, std::string> shown_models;

  /// The config of experiment `s` in this run: its file and `set` after --threads, before the command line's --set.
  Config resolve(const ExperimentSpec& s) const;
  /// An experiment's config (+ extra overrides), finalised; a learned env.oracle names this run's model.
  Config base(const ExperimentSpec& s, const std::vector<std::string>& extra = {}) const;
  /// Hash of the model env.oracle names (0 for a classical oracle).
  std::uint64_t oracle_hash(const Config& c) const;

  // --- MARL runs and planner evaluations (shared by the three trajectory-level kinds) ---------
  /// One training run of `algo` on K = users: one thread, its own seed and step budget.
  Config run_config(const ExperimentSpec& s, const std::string& algo, std::uint64_t seed, int users) const;
  fs::path run_dir(const Config& cfg) const;
  /// Where the planners (and/or a policy) are evaluated on the users of cfg.
  fs::path eval_dir(const Config& cfg, const std::string& what, const std::vector<std::string>& planners) const;
  /// The piece that trains one MARL run and evaluates its policy on its users (<run>/eval).
  Piece marl_piece(const Config& cfg) const;
  /// The piece that runs `planners` (and the policy of `policy_run`, if not empty) into `dir`.
  /// `train`: the policy's run configuration when it is not cfg (a policy drawn at another K).
  Piece eval_piece(const Config& cfg, const fs::path& dir, const std::vector<std::string>& planners,
                   const fs::path& policy_run, const Config* train = nullptr) const;

  /// The piece that evaluates the policy of `policy_run` (if not empty) and `opt.planners` on
  /// many layouts into `dir` (layouts.csv, summary.csv; skyloop/experiments/layout_eval.hpp),
  /// with the exact optima cached under optima/ for every experiment of the run. `deps`: pieces
  /// that must finish first (e.g. the one that solves the same layouts' optima).
  /// `train` is the configuration of the policy's run (it is trained first if it is missing).
  /// `optima`: the pieces that solve its layouts' optima (optima_pieces), which it depends on and
  /// ensures first (a shard that reaches it before another shard's chunk waits for that chunk or
  /// computes it under the chunk's lock, never beside it).
  Piece layouts_piece(const Config& cfg, const fs::path& dir, const LayoutEvalOptions& opt, const Config* train = nullptr,
                      std::vector<std::string> deps = {}, std::vector<Piece> optima = {}) const;
  /// The pieces that solve the exact optima of opt's layouts into optima/, in chunks of about
  /// --piece-seconds each (at least one layout), for a layouts piece to depend on: one
  /// evaluation's optima then spread over the workers (and resume chunk by chunk). Empty when the
  /// whole set is estimated under one chunk (the layouts piece solves them itself) or opt solves
  /// no reference. Their ids are `dir`'s with ".optima-<first>-<last>" appended.
  std::vector<Piece> optima_pieces(const Config& cfg, const fs::path& dir, const LayoutEvalOptions& opt) const;
  std::string id(const fs::path& dir) const;

  struct RunInfo {
    fs::path dir;
    double seconds = 0, steps_per_second = 0;
  };
  /// A finished run's directory and timing (computing it first if needed).
  RunInfo run_info(const Config& cfg) const;

  /// Runs a piece now (if it is not done) and says whether it computed anything. `limited`:
  /// throws TimeLimitReached instead of starting a piece that does not fit() (a piece the pool
  /// admitted already, or whose training it has finished, is not judged again).
  bool ensure(const Piece& p, bool limited = true) const;
  /// Whether a piece of `cost` estimated core-seconds may start now under --time-limit (always
  /// without one): the time left is at least kTimeLimitMargin times its cost.
  bool fits(double cost) const;
  /// Seconds since this run started.
  double elapsed() const;
  /// Appends (piece, kind, estimate, seconds) to OUT/timings.csv (one process's pieces).
  void record_timing(const std::string& id, const std::string& kind, double estimate, double seconds) const;

  /// Writes a file of the assembled results (on the rank that assembles).
  void write(const fs::path& relative, const std::string& text) const;
};

/// An assembly's progress lines, "  what done/total (elapsed s, ETA s)": the ETA comes from the
/// mean time of the items that had to compute something.
class AssemblyProgress {
 public:
  AssemblyProgress(const StageContext& ctx, std::size_t total) : ctx_(ctx), total_(total) {}
  /// Starts timing the next item.
  void start() { item_ = Clock::now(); }
  /// Ends it (`computed`: it computed a piece, rather than reading the cache) and prints its line.
  void done(const std::string& what, bool computed);

 private:
  const StageContext& ctx_;
  std::size_t total_, done_ = 0, computed_ = 0;
  double computed_s_ = 0;
  Clock::time_point t0_ = Clock::now(), item_ = Clock::now();
};

/// "objective,T,success,arrivals,collisions,boundary_events,reward" of row `r` of a planner or
/// policy evaluation's summary.csv (read by column name).
std::string episode_columns(const CsvTable& summary, std::size_t r);

/// One kind of experiment: the pieces it needs and how its CSVs are assembled from them.
struct StageKind {
  int phase = 1;  // 0: its pieces decide others' cache keys (the models), so they run first
  std::function<std::vector<Piece>(StageContext&, const ExperimentSpec&)> pieces;
  /// Writes the experiment's CSVs (computing any piece that is missing); returns their paths.
  /// (--force deletes the experiment's directory and its pieces before it runs again.)
  std::function<nlohmann::json(StageContext&, const ExperimentSpec&)> assemble;
};

/// Every kind, by name (skyloop/core/registry.hpp): experiment.kind's allowed values.
const Registry<StageKind>& stage_kinds();
/// The kind named `name`; an unknown kind throws InputError naming the kinds there are.
inline const StageKind& stage_kind(const std::string& name) { return stage_kinds().at(name); }

// Defined in stage_*.cpp.
StageKind models_stage();
StageKind sweep_stage();
StageKind marl_training_stage();
StageKind planning_users_stage();
StageKind rate_energy_stage();
StageKind altitude_profile_stage();
StageKind trajectories_stage();
StageKind generalisation_stage();

}  // namespace skyloop::repro
