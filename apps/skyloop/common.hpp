#pragma once
#include <CLI/CLI.hpp>
#include <functional>
#include <string>
#include <vector>

#include "skyloop/core/config_io.hpp"
#include "skyloop/core/process.hpp"
#include "skyloop/experiments/farm.hpp"

namespace skyloop::cli {

/// --config FILE and repeated --set section.key=value, shared by every command.
struct ConfigOptions {
  std::string path;
  std::vector<std::string> sets;
  /// Defaults <- file <- --set <- `extra` overrides (from command flags such as --uavs).
  Config resolve(const std::vector<std::string>& extra = {}) const;
};

void add_config_options(CLI::App* cmd, ConfigOptions& o);

/// What the interruption line tells the user of each kind of command (set_interrupt_hint): a
/// train command's rerun needs --resume (without it the run directory is refused); reproduce's
/// rerun resumes by itself. Every other command leaves no half-written file and reruns as is.
inline constexpr const char* kTrainInterruptHint =
    "stopped; the last checkpoint is kept: rerun the same command with --resume to continue";
inline constexpr const char* kReproduceInterruptHint = "stopped; finished work is kept: rerun the same command to resume";

/// Runs `body` on this rank of an MPI job (`transport` null: one process). Every rank reads the
/// same input, so a bad input fails alike everywhere: rank 0 says it in one line, the others
/// exit with the same status quietly. Any other failure ends every rank at once (the others may
/// be waiting for this one).
int on_every_rank(Transport* transport, const std::function<int()>& body);

/// `skyloop` is a LibTorch-free front end where the build has LibTorch: loading Debian's LibTorch
/// costs about a second per process, and most commands need none of it. The front end parses,
/// resolves the configuration and makes the command's own checks; a command that needs a learned
/// model (a learned beamformer, a MARL policy, the learners, `reproduce`) then calls this, which
/// replaces the process by the LibTorch build (`skyloop-torch`, beside it) with the same arguments:
/// same pid, nothing written yet, and the LibTorch build parses and checks again. Call it before
/// anything is written. In the LibTorch build (and in a build without LibTorch) it does nothing.
void continue_with_libtorch_if(bool needed);

/// The command chosen on the command line, run after parsing succeeds.
using Action = std::function<int()>;

void add_beamform_command(CLI::App& app, Action& action);
void add_snapshot_command(CLI::App& app, Action& action);
void add_config_command(CLI::App& app, Action& action);
void add_plan_command(CLI::App& app, Action& action);
void add_marl_commands(CLI::App& app, Action& action);
void add_reproduce_command(CLI::App& app, Action& action);
void add_bench_command(CLI::App& app, Action& action);

}  // namespace skyloop::cli
