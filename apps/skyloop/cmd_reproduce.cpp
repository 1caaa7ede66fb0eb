// `skyloop reproduce`: every figure of the paper's Section VI from configs/experiments/.
// Under mpirun the pieces run on every rank (rank 0 assembles); --shard i/n runs one slice.
#include <iostream>

#include "common.hpp"
#include "skyloop/beamforming/registry.hpp"
#include "skyloop/core/error.hpp"
#include "skyloop/experiments/reproduce.hpp"

namespace skyloop::cli {

namespace {
struct Opts {
  ReproduceOptions r;
  std::string only, shard, time_limit;
  bool mpi = false, plan = false;
};

/// "i/n" -> (i, n); one error line otherwise.
void parse_shard(const std::string& text, int& i, int& n) {
  const auto slash = text.find('/');
  try {
    std::size_t a = 0, b = 0;
    if (slash == std::string::npos) throw std::invalid_argument(text);
    i = std::stoi(text.substr(0, slash), &a);
    n = std::stoi(text.substr(slash + 1), &b);
    if (a != slash || b != text.size() - slash - 1) throw std::invalid_argument(text);
  } catch (const std::exception&) {
    throw InputError("--shard '" + text + "' is invalid: allowed i/n with 1 <= i <= n, e.g. 3/8");
  }
  if (n < 1 || i < 1 || i > n || n > 100000)
    throw InputError("--shard '" + text + "' is invalid: allowed i/n with 1 <= i <= n <= 100000");
}
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
  cmd->add_option("--threads", o->r.threads,
                  "worker threads, 0 = the cores this process may use (under mpirun: shared by the ranks on a machine)")
      ->capture_default_str();
  cmd->add_option("--jobs", o->r.jobs, "MARL runs trained in parallel, one core each; 0 = --threads")->capture_default_str();
  cmd->add_option("--piece-seconds", o->r.piece_seconds,
                  "split an evaluation's exact optima into pieces of about this many estimated core-seconds (at least one "
                  "layout each), so that many workers or Slurm tasks share them")
      ->capture_default_str();
  cmd->add_option("--shard", o->shard,
                  "run only slice i of n of the pieces and assemble nothing (a Slurm array task: "
                  "--shard $((SLURM_ARRAY_TASK_ID+1))/$SLURM_ARRAY_TASK_COUNT); a later run without --shard assembles")
      ->type_name("I/N");
  cmd->add_option("--time-limit", o->time_limit,
                  "start no piece that its estimate (x1.3) says would end after this long from the start, e.g. 2h50m, "
                  "45m or a Slurm job's HH:MM:SS; pieces left: exit status 75, and the same command goes on from the cache")
      ->type_name("DURATION");
  cmd->add_flag("--mpi", o->mpi, "use MPI even when no MPI launcher is detected (under mpirun it is on by itself)");
  cmd->add_flag("--plan", o->plan,
                "compute nothing: print every piece (phase, id, kind, estimated seconds, done, dependencies) as CSV");
  cmd->add_flag("--force", o->r.force, "redo the selected experiments instead of reusing cached results");
  cmd->add_flag("--no-plots", [o](std::int64_t) { o->r.plots = false; }, "write the CSVs only (no figures, no report)");
  cmd->add_option("--python", o->r.python, "python interpreter with matplotlib")->capture_default_str();
  cmd->final_callback([&action, o] {
    action = [o] {
      set_interrupt_hint(kReproduceInterruptHint);
      if (!o->only.empty()) o->r.only = split_methods(o->only, "--only");
      if (!o->shard.empty()) parse_shard(o->shard, o->r.shard_index, o->r.shard_count);
      if (!o->time_limit.empty()) o->r.time_limit = parse_time_limit(o->time_limit);
      const auto transport = open_transport(o->mpi);
      const int rank = transport ? transport->rank() : 0;
      o->r.transport = transport.get();
      o->r.progress = &std::cerr;
      if (o->plan) {
        o->r.plan_out = &std::cout;
        return reproduce(o->r);
      }
      const int rc = on_every_rank(transport.get(), [&] { return reproduce(o->r); });
      if (rank != 0 || rc == kTimeLimitExit) return rc;
      const std::string out = o->r.out_dir.empty() ? "results/" + o->r.profile : o->r.out_dir;
      if (o->r.shard_count > 0)
        std::cout << "reproduce (" << o->r.profile << "): shard " << o->r.shard_index << "/" << o->r.shard_count
                  << " computed its pieces in " << out << "; run without --shard to assemble\n";
      else
        std::cout << "reproduce (" << o->r.profile << "): results in " << out
                  << (o->r.plots ? " (report.html, figures/, one CSV per figure)\n" : " (CSVs; plots skipped)\n");
      return rc;
    };
  });
}

}  // namespace skyloop::cli
