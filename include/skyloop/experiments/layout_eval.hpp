#pragma once
// Trajectory planners judged on many user layouts (skyloop/env/layouts.hpp): `skyloop eval
// --layouts N`, skyloop.evaluate_layouts in Python, and the generalisation experiment.
//
// Every layout is scored against the best reference available for it: its exact optimum
// (solve_optimal) where the joint DP fits (fits_optimal), else the best-known planner
// (solve_best_known), named in every row and cached on disk per (resolved scenario, users,
// reference), so a second evaluation of the same layouts solves nothing.
#include <cstdint>
#include <iosfwd>
#include <string>
#include <vector>

#include "skyloop/beamforming/registry.hpp"
#include "skyloop/env/layouts.hpp"
#include "skyloop/env/uav_env.hpp"

namespace skyloop {

struct LayoutEvalOptions {
  int layouts = 100;                    // layouts first .. first + layouts - 1 of `split`
  std::uint64_t first = 0;
  LayoutSplit split = LayoutSplit::Test;
  std::vector<std::uint64_t> users_seeds;  // when not empty: these layouts instead (e.g. those a run trained on)
  std::vector<std::string> planners;    // names of skyloop/planning/registry.hpp (the reference is always solved)
  std::vector<std::string> policies;    // directories (or policy.pt files) of `skyloop train`; each flies with the
                                        // evaluation config's marl.reserve_slack (an execution setting), sequentially
                                        // where trained so or where it sets marl.sequential, its own safety otherwise
  std::vector<std::string> policy_names;  // their labels (default: the algorithm, then "-2", "-3" if repeated)
  bool unsafe = false;                  // also run every policy without mask and shield ("<label>/raw")
  bool rollout = false;                 // also fly every policy as the base of a multiagent rollout ("<label>+rollout",
                                        // RolloutPlanner in skyloop/planning/planners.hpp)
  bool solve_reference = true;          // false: no reference row (the benchmark reads its shipped references)
  std::uint64_t planner_seed = 0;       // non-zero: the random planners' stream is also keyed by it (a benchmark seed)
  std::string cache_dir;                // optimum cache; empty = none
  int threads = 0;                      // layouts in parallel (0 = run.threads)
};

struct LayoutRow {
  std::string planner;
  std::uint64_t layout = 0, users_seed = 0;
  int users = 0, uavs = 0;
  std::string reference;                // "optimal" or "bestknown": what `fraction` divides by
  double objective = 0, reference_objective = 0, fraction = 0;  // fraction = objective / reference_objective
  int T = 0, home = 0, arrivals = 0, collisions = 0, boundary = 0;
  bool complete = false;                // every UAV home by T_max, no collision, no boundary event
  double seconds = 0;
  double energy_j = 0, bits_per_joule = 0;  // the fleet's propulsion energy and bits per joule
};

struct LayoutSummary {
  std::string planner;
  std::string reference;                // the layouts' reference ("optimal", "bestknown", or both joined by '+')
  int layouts = 0;
  double complete = 0;                  // share of missions complete
  int collisions = 0, boundary = 0;     // totals over the layouts
  double arrivals = 0;                  // mean UAVs home per layout
  double objective = 0;                 // mean
  double energy_j = 0, bits_per_joule = 0;  // means
  double fraction_mean = 0, fraction_p5 = 0, fraction_worst = 0;
};

/// The users seeds of the first `count` layouts a training run met (env.resample_users): episode e
/// of environment i, in the order the environments started them (i fastest).
std::vector<std::uint64_t> training_layouts_of(const Config& run, int count);

/// The reference planner for a scenario on the lattice: "optimal" where the joint DP fits, else
/// "bestknown". Dynamics off the lattice are measured against their lattice twin's reference,
/// labelled with the twin's model ("optimal-headings").
std::string layout_reference(const UavEnv& env);
/// The lattice twin of dynamics off the lattice (Dynamics::reference_twin; continuous: headings at
/// speeds 0, v_max / 2 and v_max, no acceleration limit), the reference that evaluations of their
/// missions measure against (refused in one line where those speeds leave the D_fly lattice).
Config lattice_twin(const Config& cfg);

/// Refuses (InputError) flying policies as rollout bases with marl.reserve_slack >= 0: a rollout
/// flies a policy from states it did not reach, while its reserved ways are carried from slot to slot.
void check_rollout_settings(const Config& cfg);

/// Rows in layout order, each layout's planners in the order given, policies next, the reference last.
std::vector<LayoutRow> evaluate_layouts(const Config& cfg, const LayoutEvalOptions& opt, const BeamformerRegistry& registry,
                                        std::ostream* progress = nullptr);
/// The q-quantile of v (0 <= q <= 1), interpolating linearly between order statistics (numpy's
/// default); 0 for no values. The layout summaries' and the benchmark's percentiles.
double percentile(std::vector<double> v, double q);

/// One summary per planner, in the rows' order. The 5th percentile interpolates linearly.
std::vector<LayoutSummary> summarise_layouts(const std::vector<LayoutRow>& rows);

/// Tidy CSV (run seed and split in every row) and a table for people.
std::string layout_rows_csv(const std::vector<LayoutRow>& rows, std::uint64_t seed, LayoutSplit split);
std::string layout_summary_csv(const std::vector<LayoutSummary>& s, std::uint64_t seed, LayoutSplit split);
std::string format_layout_summary(const std::vector<LayoutSummary>& s);

}  // namespace skyloop
