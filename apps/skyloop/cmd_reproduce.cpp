// `skyloop reproduce`: every figure of the paper's Section VI from configs/experiments/.
#include <iostream>

#include "common.hpp"
#include "skyloop/beamforming/registry.hpp"
#include "skyloop/experiments/reproduce.hpp"

namespace skyloop::cli {

namespace {
struct Opts {
  ReproduceOptions r;
  std::string only;
};
}  // namespace

void add_reproduce_command(CLI::App& app, Action& action) {
  auto o = std::make_shared<Opts>();
  auto* cmd = app.add_subcommand("reproduce", "run every experiment of configs/experiments/, then the figures and report.html");
  cmd->add_option("--profile", o->r.profile, "quick (minutes) | paper (the paper's settings) | tiny (CI smoke run)")
      ->capture_default_str();
  cmd->add_option("--out", o->r.out_dir, "output directory (default results/<profile>)");
  cmd->add_option("--experiments", o->r.experiments_dir, "directory of experiment files (default configs/experiments)");
  cmd->add_option("--only", o->only, "comma-separated experiment names to run (the models stage always runs)");
  cmd->add_option("--set", o->r.sets, "override one config field in every experiment (repeatable)")->type_name("KEY=VALUE");
  cmd->add_option("--threads", o->r.threads, "worker threads, 0 = all cores")->capture_default_str();
  cmd->add_option("--jobs", o->r.jobs, "MARL runs trained in parallel, one core each; 0 = --threads")->capture_default_str();
  cmd->add_flag("--force", o->r.force, "redo the selected experiments instead of reusing cached results");
  cmd->add_flag("--no-plots", [o](std::int64_t) { o->r.plots = false; }, "write the CSVs only (no figures, no report)");
  cmd->add_option("--python", o->r.python, "python interpreter with matplotlib")->capture_default_str();
  cmd->final_callback([&action, o] {
    action = [o] {
      if (!o->only.empty()) o->r.only = split_methods(o->only, "--only");
      o->r.progress = &std::cerr;
      const int rc = reproduce(o->r);
      std::cout << "reproduce (" << o->r.profile << "): results in "
                << (o->r.out_dir.empty() ? "results/" + o->r.profile : o->r.out_dir)
                << (o->r.plots ? " (report.html, figures/, one CSV per figure)\n" : " (CSVs; plots skipped)\n");
      return rc;
    };
  });
}

}  // namespace skyloop::cli
