#pragma once
// `skyloop plan`: run planners on one scenario and write tidy files.
#include <iosfwd>
#include <string>
#include <vector>

#include "skyloop/beamforming/registry.hpp"
#include "skyloop/planning/planners.hpp"

namespace skyloop {

struct PlanOptions {
  std::vector<std::string> planners;  // random | greedy | optimal
  std::uint64_t seed = 3;             // users (and the random planner) come from this seed
  std::string out_dir;                // trajectory.csv, rates.csv, summary.csv, config.toml
  std::vector<std::shared_ptr<Planner>> extra;  // further planners (e.g. trained policies), run after `planners`
};

/// Runs each planner on the same users and oracle; writes the files; returns the records.
std::vector<EpisodeRecord> run_planners(const Config& cfg, const PlanOptions& opt, const BeamformerRegistry& registry,
                                        std::ostream* progress, std::vector<double>* seconds = nullptr);

/// CSV texts (seed and planner in every row).
std::string trajectory_csv(const std::vector<EpisodeRecord>& r, std::uint64_t seed);
/// seed,planner,uav,energy_j: each UAV's propulsion energy over the mission.
std::string energy_csv(const std::vector<EpisodeRecord>& r, std::uint64_t seed);
std::string rates_csv(const std::vector<EpisodeRecord>& r, std::uint64_t seed);
std::string summary_csv(const std::vector<EpisodeRecord>& r, std::uint64_t seed, const std::vector<double>& seconds);
std::string format_plan_summary(const std::vector<EpisodeRecord>& r, const std::vector<double>& seconds);

}  // namespace skyloop
