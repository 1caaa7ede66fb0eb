#pragma once
// The benchmark: named, versioned trajectory tasks scored against each test layout's exact optimum
// (or the best-known reference where the joint DP does not fit), with one protocol and one scorer
// for skyloop's planners and policies (`skyloop bench`) and for any policy from Python
// (skyloop.bench.evaluate). docs/concepts/benchmark.md states the protocol.
//
// A task is a folder tasks/<name>-v<version>/ holding
//   task.toml      what the task is: its title, protocol (budget, seeds, metric), test layouts,
//                  reference tolerance, and two checksums: the fingerprint of its resolved
//                  configuration and the reference file's checksum;
//   config.toml    the frozen, resolved configuration (every field: `skyloop config show`), which
//                  is also what a learner trains on (`skyloop train --config tasks/T/config.toml`);
//   reference.csv  one row per test layout: its users seed, K, the reference's name ("optimal",
//                  "bestknown", "optimal-headings") and objective.
// Any change in skyloop that moves a task's configuration (a new field, a new default) changes its
// fingerprint, and one that moves its numbers changes its references: `skyloop bench reference
// --check` and the test suite fail on either, and the task is given a new version.
#include <cstdint>
#include <string>
#include <vector>

#include "skyloop/core/config.hpp"
#include "skyloop/experiments/layout_eval.hpp"

namespace skyloop {

/// One row of a task's reference.csv.
struct BenchReference {
  std::uint64_t layout = 0, users_seed = 0;
  int users = 0;
  std::string reference;  // "optimal", "bestknown" or "optimal-headings"
  double objective = 0;
  double seconds = 0;     // what computing it took (informative; not part of the checksum)
};

/// The protocol a submission follows (task.toml's [protocol]).
struct BenchProtocol {
  std::int64_t budget_steps = 0;  // environment steps of training (the sum over the parallel environments)
  int seeds = 5;                  // independent training runs (training seeds), each scored on every test layout
  std::string train_split = "train";  // the layouts a policy may train on (skyloop/env/layouts.hpp)
};

struct BenchTask {
  std::string name;         // "paper"
  int version = 1;
  std::string id;           // "paper-v1"
  std::string dir;          // the task's folder
  std::string title;
  std::string reference_note;  // why the reference is what it is (its cost, fewer layouts)
  Config config;            // config.toml, resolved
  BenchProtocol protocol;
  double reference_rtol = 1e-9;    // relative tolerance of a recomputed reference (from the oracle's arithmetic)
  std::vector<std::string> fixed_keys;  // the fields config.toml sets (what the fingerprint covers)
  std::string fingerprint;         // as stated in task.toml
  std::string reference_checksum;  // as stated in task.toml
  std::vector<BenchReference> references;  // reference.csv (empty before the first `bench reference --write`)
};

/// The folder the tasks live in: <data dir>/tasks.
std::string bench_tasks_dir();
/// A task version withdrawn from skyloop (tasks/withdrawn.toml): naming it is refused with both.
struct WithdrawnTask {
  std::string id, reason, successor;
};
/// Every withdrawn version, sorted by id.
std::vector<WithdrawnTask> withdrawn_tasks();
/// Every task id under bench_tasks_dir(), sorted.
std::vector<std::string> bench_task_ids();
/// A task by id ("paper-v1"), by name (its highest version) or by folder. InputError naming the
/// allowed ids otherwise; a reference file whose checksum differs from task.toml's is refused.
/// `fresh`: the reference file is not read (its layouts are layouts 0..test_layouts-1 of the test
/// split, to be computed: `bench reference --write`).
BenchTask load_bench_task(const std::string& id_or_dir, bool fresh = false);

/// The fingerprint of a resolved configuration: "fnv1a64-values:<16 hex>" of the lines
/// "key = value" of the fields named in `keys` (a task's: every field its config.toml fixes), in
/// the field table's order, values as config.toml writes them. Help text and fields added to the
/// table after the task froze (which it meets at their defaults) do not enter it; what moves
/// under those is caught by the references' recomputation.
std::string config_fingerprint(const Config& cfg, const std::vector<std::string>& keys);
/// The checksum of reference rows (users seeds, K, names and objectives, as reference.csv writes them).
std::string reference_checksum(const std::vector<BenchReference>& rows);
std::string reference_csv(const BenchTask& task, const std::vector<BenchReference>& rows);

/// Computes the references of the task's test layouts `indices` (positions in task.references, or
/// 0..test_layouts-1 for a task with no reference yet), on `threads` threads.
std::vector<BenchReference> compute_references(const BenchTask& task, const std::vector<std::size_t>& indices, int threads,
                                               std::ostream* progress);
/// `count` indices spread evenly over the task's layouts (the first and the last among them).
std::vector<std::size_t> sample_layouts(std::size_t layouts, std::size_t count);

/// One scored episode: (task, policy, seed, layout).
struct BenchRow {
  std::string task, policy;
  int version = 1;
  std::uint64_t seed = 0, layout = 0, users_seed = 0;
  int users = 0;
  double objective = 0, reference_objective = 0, fraction = 0;
  std::string reference;
  bool complete = false;
  int home = 0, collisions = 0, boundary = 0;
  double energy_j = 0;
  std::string protocol = "ok";  // "ok", or why the run does not follow the task's protocol
};

/// One (task, policy) over its seeds x layouts.
struct BenchSummary {
  std::string task, policy;
  int version = 1;
  int seeds = 0, layouts = 0;
  double mean = 0, iqm = 0, iqm_low = 0, iqm_high = 0;  // of `fraction`; the interval is 95%
  double p5 = 0, complete_rate = 0;
  std::string reference;
  std::string protocol = "ok";
};

/// Scores of runs x layouts (fractions of the reference), the statistics of the protocol:
/// the interquartile mean (the mean of the middle half: floor(n / 4) scores trimmed from each end of
/// all n = runs x layouts, as scipy.stats.trim_mean(0.25)); its 95% stratified bootstrap interval
/// (each layout's runs resampled with replacement, `reps` times, percentile method: Agarwal et al.,
/// NeurIPS 2021); the 5th percentile (linear interpolation).
double interquartile_mean(std::vector<double> scores);
void iqm_interval(const std::vector<std::vector<double>>& runs_by_layout, int reps, std::uint64_t seed, double& low,
                  double& high);

/// Summaries per policy, in the rows' order.
std::vector<BenchSummary> summarise_bench(const BenchTask& task, const std::vector<BenchRow>& rows);
/// The fraction of runs whose score reaches each tau in 0, 0.01, ..., max(1.05, best) per policy
/// (the performance profile, CSV: task,version,policy,tau,fraction_of_runs).
std::string bench_profile_csv(const std::vector<BenchRow>& rows);
std::string bench_rows_csv(const std::vector<BenchRow>& rows);
std::string bench_summary_csv(const std::vector<BenchSummary>& s);
/// marl-eval's JSON: {"skyloop": {task id: {policy: {"seed_S": {"step_0": {...}, "absolute_metrics": {...}}}}}},
/// each metric a list over the test layouts.
std::string bench_marl_eval_json(const BenchTask& task, const std::vector<BenchRow>& rows);
std::string format_bench_summary(const std::vector<BenchSummary>& s);

/// What `skyloop bench run` scores.
struct BenchRunOptions {
  std::vector<std::string> planners;        // registered planners, each flown once per seed
  std::vector<std::uint64_t> seeds;         // the planners' seeds (random planners); default the protocol's 1..seeds
  std::vector<std::string> policies;        // run directories of `skyloop train`: one training seed each
  std::string policy_label;                 // their label (default the algorithm)
  int threads = 0;
};

/// Rows in (policy, seed, layout) order, each checked against the protocol.
std::vector<BenchRow> run_bench(const BenchTask& task, const BenchRunOptions& opt, std::ostream* progress);
/// Why a policy trained with `trained` breaks the task's protocol ("ok" when it does not).
std::string policy_protocol(const BenchTask& task, const Config& trained);

}  // namespace skyloop
