#include <iostream>

#include "common.hpp"

namespace skyloop::cli {

void add_config_command(CLI::App& app, Action& action) {
  auto* config = app.add_subcommand("config", "inspect the configuration");
  config->require_subcommand(1);
  auto* show = config->add_subcommand("show", "print the resolved configuration as TOML");
  auto opts = std::make_shared<ConfigOptions>();
  add_config_options(show, *opts);
  show->final_callback([&action, opts] {
    action = [opts] {
      std::cout << to_toml(opts->resolve());
      return 0;
    };
  });
}

}  // namespace skyloop::cli
