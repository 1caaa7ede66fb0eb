#pragma once
// `skyloop beamform eval`: beamformers compared on seeded random snapshots.
// A decision is one snapshot: every cluster of it designed by one method, timed single-threaded.
#include <cstdint>
#include <iosfwd>
#include <string>
#include <vector>

#include "skyloop/beamforming/registry.hpp"
#include "skyloop/core/config.hpp"

namespace skyloop {

struct BeamformEvalOptions {
  std::vector<std::string> methods;  // registry specs
  int uavs = 3;
  int users = 12;
  std::size_t samples = 200;
  std::uint64_t seed = 1;            // snapshot i uses derive_seed(seed, i)
  std::size_t first = 0;             // snapshots first .. first + samples - 1 (a slice of a longer run)
  int threads = 1;                   // samples run in parallel; each decision is timed on one thread
};

struct BeamformEvalRow {
  std::uint64_t seed = 0;
  std::size_t sample = 0;
  std::string method;
  int uavs = 0, users = 0, clusters = 0, served_users = 0;
  double sum_rate = 0.0;    // bits/s/Hz, network total
  double latency_ms = 0.0;  // wall time of the decision (all clusters of the snapshot)
};

struct MethodSummary {
  std::string method;
  std::size_t samples = 0;
  double mean = 0.0, std = 0.0;         // sum rate over samples (std: sample standard deviation)
  double median_latency_ms = 0.0, mean_latency_ms = 0.0;
};

/// Runs the evaluation; rows are ordered by (sample, method). Progress goes to `progress` if set.
std::vector<BeamformEvalRow> run_beamform_eval(const Config& cfg, const BeamformEvalOptions& opt,
                                               const BeamformerRegistry& registry, std::ostream* progress);

/// Tidy CSV, one row per (snapshot, method), with the seed and the channel settings in every row.
std::string beamform_eval_csv(const std::vector<BeamformEvalRow>& rows, const Config& cfg);

/// Rows back from beamform_eval_csv() text (columns found by name; `source` names it in errors).
std::vector<BeamformEvalRow> parse_beamform_eval_csv(const std::string& csv, const std::string& source);

/// Per-method summary in the order methods first appear in `rows`.
std::vector<MethodSummary> summarise(const std::vector<BeamformEvalRow>& rows);

/// Fixed-width table of the summaries.
std::string format_summary(const std::vector<MethodSummary>& s);

}  // namespace skyloop
