#include <iostream>

#include "common.hpp"
#include "skyloop/beamforming/registry.hpp"
#include "skyloop/experiments/builtin.hpp"
#include "skyloop/experiments/snapshot_report.hpp"

namespace skyloop::cli {

namespace {
struct SnapshotOptions {
  ConfigOptions config;
  std::string scenario;
  std::string method = "wmmse";
  bool json = false;
};
}  // namespace

void add_snapshot_command(CLI::App& app, Action& action) {
  auto o = std::make_shared<SnapshotOptions>();
  auto* cmd = app.add_subcommand("snapshot", "evaluate explicit UAV and user positions and show every per-user quantity");
  cmd->add_option("--scenario", o->scenario, "TOML file with uavs = [[x, y], ...] and users = [[x, y], ...]")->required();
  cmd->add_option("--method", o->method, "beamformer spec (mrt, zf, rzf, wmmse, ga, ga=pso, ...)")->capture_default_str();
  cmd->add_flag("--json", o->json, "print JSON instead of tables");
  add_config_options(cmd, o->config);
  cmd->final_callback([&action, o] {
    action = [o] {
      const Config cfg = o->config.resolve();
      const Snapshot snap = load_scenario_file(o->scenario, cfg);
      continue_with_libtorch_if(is_learned_beamformer(o->method));
      const auto bf = builtin_beamformers().create(o->method, cfg);
      const SnapshotReport r = evaluate_snapshot(cfg, snap, *bf);
      std::cout << (o->json ? snapshot_json(r, cfg) : snapshot_text(r));
      return 0;
    };
  });
}

}  // namespace skyloop::cli
