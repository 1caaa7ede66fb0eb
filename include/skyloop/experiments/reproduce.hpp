#pragma once
// `skyloop reproduce`: the paper's Section VI end to end. Every figure is one experiment file
// under configs/experiments/ (see the README there); a profile (quick, paper, tiny) picks its
// budget. Work is cached by the hash of its resolved configuration, so a re-run skips what is done
// and an interrupted run resumes.
#include <cstdint>
#include <iosfwd>
#include <string>
#include <vector>

namespace skyloop {

class Transport;
struct Config;

/// One experiment file after its profile has been applied.
struct ExperimentSpec {
  std::string path;     // the file it came from
  std::string text;     // its contents (copied into the run directory)
  std::string name;     // output directory under the run directory
  std::string kind;     // models | beamform_sweep | marl_training | planning_users | trajectories | generalisation
  std::string figure;   // the paper's \label, e.g. fig:power_sweep
  std::string title;
  std::string config;             // a configuration file (`config`, relative to the experiment file) under `set`; empty: defaults
  std::vector<std::string> set;  // config overrides ("section.key=value"), base then profile

  // models: labels gnn, deepsets, mspointnet, gnn_structured
  std::vector<std::string> models;
  bool reuse_shipped = true;     // use models/<label> when it was trained with the same settings

  // beamform_sweep
  std::string sweep;                 // the swept config key
  std::vector<std::string> values;   // the swept values as written (numbers in shortest form, or names such as "3gpp-uma-av")
  std::vector<std::string> methods;  // registry specs; learned labels resolve to the models stage
  std::string series;                // optional second config key: one curve per method and series value
  std::vector<std::string> series_values;
  int samples = 100;
  std::uint64_t seed = 1;            // snapshots (derive_seed(seed, i)); training seeds for MARL

  // marl_training, planning_users, trajectories
  std::vector<std::string> algos;
  std::vector<std::uint64_t> seeds;
  std::int64_t steps = 2'000'000;
  std::vector<int> users;            // K values (planning_users, trajectories)
  std::vector<std::string> planners; // random, greedy, optimal
  // trajectories: one policy trained on the experiment's layouts (its `set`), drawn at every K
  // (else one policy per K, the paper's figure)
  bool one_policy = false;
  // generalisation: `samples` = layouts per evaluation, `users` = the K of the test layouts;
  // `train_layouts`: the layouts each run is scored on among those it trained on (0 = `samples`;
  // fewer where each layout's optimum is costly: the gap to the test layouts needs fewer than the
  // test mean); `rollout`: each trained policy also flies as the base of a multiagent rollout on
  // the test layouts ("<algo>+rollout", skyloop eval --rollout)
  int train_layouts = 0;
  bool rollout = false;
};

/// Parses one experiment file for `profile`. The [experiment] table holds the defaults;
/// [profile.<name>] replaces keys of it (`set` is appended). [[reported]] (the paper's numbers),
/// [[reference]] (another experiment's curve drawn beside this one) and `reading` (the report's
/// text) are read by the report, not interpreted here. Unknown keys, wrong types and a profile the file does
/// not define throw InputError naming the file, the key and what is allowed.
ExperimentSpec parse_experiment(const std::string& toml_text, const std::string& source, const std::string& profile);

/// The configuration an experiment runs under: the defaults, its `config` file (a recipe such as
/// configs/generalise.toml, read once so that every experiment trained with it says so in one
/// place), then `before`, its `set` and `after`, finalised like resolve_config().
Config resolve_experiment(const ExperimentSpec& s, const std::vector<std::string>& before = {},
                          const std::vector<std::string>& after = {});

/// The kinds an experiment file may name: the names of reproduce's stage registry.
std::vector<std::string> experiment_kinds();

/// Every *.toml in `dir`, in file-name order.
std::vector<ExperimentSpec> load_experiments(const std::string& dir, const std::string& profile);

struct ReproduceOptions {
  std::string profile = "quick";
  std::string out_dir;                 // default results/<profile>
  std::string experiments_dir;         // default <source>/configs/experiments
  std::vector<std::string> only;       // experiment names to run (the models stage always runs)
  std::vector<std::string> sets;       // overrides applied to every experiment, after its own
  bool force = false;                  // drop the cache of the selected experiments first
  int threads = 0;                     // run.threads for every stage (0 = all cores)
  int jobs = 0;                        // MARL runs trained in parallel (child processes); 0 = threads
  double piece_seconds = 600;          // an evaluation's exact optima in pieces of about this many estimated
                                       // core-seconds (at least one layout each), spread over the workers
  bool plots = true;                   // run scripts/plot_figures.py at the end
  /// Seconds from the start (0 = none) past which no piece may run by its estimate: a piece starts
  /// only while the time left is at least its estimated core-seconds times kTimeLimitMargin. When
  /// pieces are left for that reason the run stops before the assembly (or at the assembly's next
  /// piece) with exit status kTimeLimitExit and one line; what finished is cached, and the same
  /// command goes on from there. For a batch job's wall-time limit (a Slurm job, a lent machine).
  double time_limit = 0;
  // Scale-out (farm.hpp). Under an MPI transport of several ranks every rank calls reproduce()
  // with the same options: the pieces run on all of them and rank 0 assembles. With shard_count
  // > 0 this process runs only slice shard_index (1-based) of the pieces and assembles nothing;
  // a later run without a shard assembles.
  Transport* transport = nullptr;
  int shard_index = 0, shard_count = 0;
  /// Compute nothing: write the pieces as CSV to `plan_out` (phase, piece, kind, label, estimated
  /// seconds on one core, done, dependencies), for scheduling projections (scripts/farm_projection.py).
  std::ostream* plan_out = nullptr;
  std::string python = "/usr/bin/python3";
  std::ostream* progress = nullptr;
};

/// `reproduce`'s exit status when --time-limit left pieces to do (EX_TEMPFAIL: run it again).
constexpr int kTimeLimitExit = 75;
/// How much longer than its estimate a piece is allowed to take (the estimates' stated error is 30%).
constexpr double kTimeLimitMargin = 1.3;
/// Whether work estimated at `cost` seconds may start `elapsed` seconds into a run limited to
/// `limit` seconds (0: no limit): the rule of every --time-limit.
inline bool fits_time_limit(double elapsed, double cost, double limit) {
  return limit <= 0 || elapsed + kTimeLimitMargin * cost <= limit;
}

/// Parses a --time-limit: seconds ("5400", "90.5"), a sum of hours, minutes and seconds ("2h50m",
/// "45m", "30s"), or Slurm's [D-]HH:MM:SS / MM:SS; throws InputError naming `what` otherwise.
double parse_time_limit(const std::string& text, const std::string& what = "--time-limit");

/// Reproduce's estimate of one MARL training run of `cfg` on one core, in seconds (its cost model,
/// fitted to the quick profile's runs; the order of its pieces, --plan and --time-limit use it).
double marl_run_estimate(const Config& cfg);

/// Runs the experiments, writes manifest.json, config.toml and every CSV under out_dir, then the
/// figures and report.html. Returns the process exit code of the plot step (0 if skipped).
int reproduce(const ReproduceOptions& opt);

/// The source tree's directory (configs/, models/, scripts/).
std::string source_dir();

}  // namespace skyloop
