// skyloop: joint beamforming and trajectory optimisation for multi-UAV downlink networks.
// Exit codes: 0 success, 2 bad input (one line on stderr), 1 runtime failure.
#include <iostream>

#include "common.hpp"
#include "skyloop/core/error.hpp"

namespace skyloop::cli {

Config ConfigOptions::resolve(const std::vector<std::string>& extra) const {
  std::vector<std::string> all = sets;
  all.insert(all.end(), extra.begin(), extra.end());
  return resolve_config(path.empty() ? std::nullopt : std::optional<std::string>(path), all);
}

void add_config_options(CLI::App* cmd, ConfigOptions& o) {
  cmd->add_option("--config", o.path, "TOML configuration file (defaults: the paper's Section VI values)");
  cmd->add_option("--set", o.sets, "override one field, e.g. --set channel.p_max_dbm=40 (repeatable)")
      ->type_name("KEY=VALUE");
}

}  // namespace skyloop::cli

int main(int argc, char** argv) {
  using namespace skyloop;
  CLI::App app{"skyloop: joint beamforming and trajectory optimisation for multi-UAV downlink networks"};
  app.set_version_flag("--version", std::string("skyloop ") + SKYLOOP_VERSION);
  app.require_subcommand(1);
  cli::Action action;
  cli::add_beamform_command(app, action);
  cli::add_snapshot_command(app, action);
  cli::add_config_command(app, action);
  cli::add_plan_command(app, action);
#ifdef SKYLOOP_HAS_TORCH
  cli::add_marl_commands(app, action);
  cli::add_reproduce_command(app, action);
#endif
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    if (e.get_exit_code() == 0) return app.exit(e);  // --help, --version
    std::cerr << "skyloop: error: " << e.what() << "\n";
    return 2;
  }
  try {
    return action ? action() : 0;
  } catch (const InputError& e) {
    std::cerr << "skyloop: error: " << e.what() << "\n";
    return 2;
  } catch (const std::exception& e) {
    std::cerr << "skyloop: failed: " << e.what() << "\n";
    return 1;
  }
}
