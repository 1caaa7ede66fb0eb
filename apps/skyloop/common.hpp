#pragma once
#include <CLI/CLI.hpp>
#include <functional>
#include <string>
#include <vector>

#include "skyloop/core/config_io.hpp"

namespace skyloop::cli {

/// --config FILE and repeated --set section.key=value, shared by every command.
struct ConfigOptions {
  std::string path;
  std::vector<std::string> sets;
  /// Defaults <- file <- --set <- `extra` overrides (from command flags such as --uavs).
  Config resolve(const std::vector<std::string>& extra = {}) const;
};

void add_config_options(CLI::App* cmd, ConfigOptions& o);

/// The command chosen on the command line, run after parsing succeeds.
using Action = std::function<int()>;

void add_beamform_command(CLI::App& app, Action& action);
void add_snapshot_command(CLI::App& app, Action& action);
void add_config_command(CLI::App& app, Action& action);
void add_plan_command(CLI::App& app, Action& action);
void add_marl_commands(CLI::App& app, Action& action);
void add_reproduce_command(CLI::App& app, Action& action);

}  // namespace skyloop::cli
