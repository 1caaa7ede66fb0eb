#include <iostream>

#include "common.hpp"
#include "skyloop/planning/registry.hpp"
#include "skyloop/beamforming/registry.hpp"
#include "skyloop/experiments/builtin.hpp"
#include "skyloop/experiments/planning_run.hpp"
#ifdef SKYLOOP_HAS_TORCH
#include "skyloop/nn/learned.hpp"
#endif

namespace skyloop::cli {

namespace {
struct PlanCliOptions {
  ConfigOptions config;
  std::string planners = "random,greedy,optimal";
  std::string users, oracle;
  std::string seed = "3";
  std::string out;
};
}  // namespace

void add_plan_command(CLI::App& app, Action& action) {
  auto o = std::make_shared<PlanCliOptions>();
  auto* cmd = app.add_subcommand("plan", "plan UAV trajectories (" + builtin_planners().names_text() + ") on one scenario");
  cmd->add_option("--planner", o->planners, "comma-separated: " + builtin_planners().names_text())->capture_default_str();
  cmd->add_option("--users", o->users, "number of users K (sets scenario.users)");
  cmd->add_option("--seed", o->seed, "seed of the users (and of the random planner)")->capture_default_str();
  cmd->add_option("--oracle", o->oracle, "beamformer behind R[t] (sets env.oracle; default the paper's GNN)");
  cmd->add_option("--out", o->out, "directory for trajectory.csv, rates.csv, summary.csv, users.csv, config.toml");
  add_config_options(cmd, o->config);
  cmd->final_callback([&action, o] {
    action = [o] {
      std::vector<std::string> extra;
      if (!o->users.empty()) extra.push_back("scenario.users=" + o->users);
      if (!o->oracle.empty()) extra.push_back("env.oracle=" + o->oracle);
      const Config cfg = o->config.resolve(extra);
#ifdef SKYLOOP_HAS_TORCH
      set_torch_threads(cfg.run.threads);
#endif
      PlanOptions opt;
      opt.planners = split_methods(o->planners, "--planner");
      opt.seed = parse_seed("--seed", o->seed);
      opt.out_dir = o->out;
      continue_with_libtorch_if(is_learned_beamformer(cfg.env.oracle));
      std::vector<double> seconds;
      const auto recs = run_planners(cfg, opt, builtin_beamformers(), &std::cerr, &seconds);
      std::cout << "plan: N = " << cfg.trajectory.starts.size() << " UAVs, K = " << cfg.scenario.users
                << " users (seed " << opt.seed << "), oracle " << cfg.env.oracle << ", T_max = " << cfg.trajectory.t_max << "\n"
                << format_plan_summary(recs, seconds);
      if (!o->out.empty()) std::cout << "wrote " << o->out << "/{trajectory,rates,summary,users,energy}.csv and config.toml\n";
      return 0;
    };
  });
}

}  // namespace skyloop::cli
