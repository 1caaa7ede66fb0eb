// `skyloop train` (the learners of skyloop/marl/learners.hpp) and `skyloop eval --policy DIR`.
#include <fmt/format.h>
#include <iostream>

#include "common.hpp"
#include "skyloop/marl/learners.hpp"
#include "skyloop/planning/registry.hpp"
#include "skyloop/core/error.hpp"
#include "skyloop/core/io.hpp"
#include "skyloop/core/config_io.hpp"
#include "skyloop/experiments/builtin.hpp"
#include "skyloop/experiments/layout_eval.hpp"
#include "skyloop/experiments/planning_run.hpp"
#include "skyloop/marl/marl.hpp"

namespace skyloop::cli {

namespace {
struct TrainOpts {
  ConfigOptions config;
  std::string algo, seed, steps, out;
  bool resume = false, force = false;
};
struct EvalOpts {
  ConfigOptions config;
  std::vector<std::string> policies;
  std::string users, out, planners;
  std::string seed, layouts, first;
  std::string split = "test", cache;
  bool unsafe = false, rollout = false;
};

int run_train(const TrainOpts& t) {
  std::vector<std::string> extra;
  if (!t.algo.empty()) extra.push_back("marl.algo=" + t.algo);
  if (!t.seed.empty()) extra.push_back("run.seed=" + t.seed);
  if (!t.steps.empty()) extra.push_back("marl.total_steps=" + t.steps);
  const Config cfg = t.config.resolve(extra);
  MarlTrainOptions opt;
  opt.out_dir = t.out;
  opt.resume = t.resume;
  opt.force = t.force;
  opt.progress = &std::cerr;
  opt.registry = &builtin_beamformers();
  set_interrupt_hint(kTrainInterruptHint);
  const auto r = train_marl(cfg, opt);
  const auto& e = r.evaluation;
  std::cout << fmt::format("{} (seed {}): {} environment steps in {:.1f} s ({:.0f} steps/s)\n"
                           "evaluation (deterministic policy, users seed {}): objective {:.3f}, T = {}, arrived {}/{}, "
                           "collisions {}, boundary events {}{}\nwrote {}/policy.pt, last.pt, metrics.csv, config.toml\n",
                           cfg.marl.algo, cfg.run.seed, r.env_steps, r.seconds, r.steps_per_second, cfg.marl.users_seed,
                           e.objective, e.T, e.arrivals, e.positions.front().rows(), e.collisions, e.boundary,
                           e.over_budget > 0 ? fmt::format(", mission failed: {} UAVs over energy.budget_j", e.over_budget) : "",
                           t.out);
  return 0;
}

/// The first policy's own configuration (its policy, when there is one, into `policy`), then the
/// command line's.
Config eval_config(const EvalOpts& v, std::unique_ptr<MarlPolicy>& policy) {
  Config cfg;
  if (!v.policies.empty()) {
    policy = MarlPolicy::load(v.policies.front());
    apply_toml(cfg, policy->config_toml(), v.policies.front() + " (training config)");
  }
  ConfigOptions over = v.config;
  std::vector<std::string> extra;
  if (!v.users.empty()) {
    extra.push_back("scenario.users=" + v.users);
    extra.push_back("env.users_min=0");
    extra.push_back("env.users_max=0");
  }
  if (!over.path.empty()) apply_toml(cfg, read_file(over.path, "config file"), over.path);
  for (const auto& s : over.sets) apply_override(cfg, s);
  for (const auto& s : extra) apply_override(cfg, s);
  finalise(cfg);
  finalise_users_file(cfg);
  return cfg;
}

/// `eval --layouts`: every policy and planner on held-out layouts against each one's optimum.
int eval_layouts(const EvalOpts& v, const Config& cfg, int layouts, std::uint64_t first) {
  LayoutEvalOptions opt;
  opt.layouts = layouts;
  opt.first = first;
  opt.split = parse_layout_split(v.split, "--split");
  if (!v.planners.empty()) opt.planners = split_methods(v.planners, "--planner");
  opt.policies = v.policies;
  opt.unsafe = v.unsafe;
  opt.rollout = v.rollout;
  opt.cache_dir = !v.cache.empty() ? v.cache : !v.out.empty() ? v.out + "/optimum" : "";
  RunDirLock lock;  // one run at a time into --out (a single layout: run_planners takes it)
  if (!v.out.empty()) lock = RunDirLock(v.out);
  const auto rows = evaluate_layouts(cfg, opt, builtin_beamformers(), &std::cerr);
  const auto sum = summarise_layouts(rows);
  if (!v.out.empty()) {
    // The directory's config changes with its results or not at all.
    write_files_atomic({{v.out + "/config.toml", to_toml(cfg)},
                        {v.out + "/layouts.csv", layout_rows_csv(rows, cfg.run.seed, opt.split)},
                        {v.out + "/summary.csv", layout_summary_csv(sum, cfg.run.seed, opt.split)}});
  }
  std::cout << fmt::format("eval: {} {} layouts from {} ({} UAVs, K = {}), oracle {}\n", opt.layouts, to_string(opt.split),
                           opt.first, cfg.trajectory.starts.size(),
                           cfg.env.users_min && cfg.env.users_max ? fmt::format("{}..{}", cfg.env.users_min, cfg.env.users_max)
                                                                  : std::to_string(cfg.scenario.users),
                           cfg.env.oracle)
            << format_layout_summary(sum);
  if (!v.out.empty()) std::cout << "wrote " << v.out << "/layouts.csv, summary.csv, config.toml\n";
  return 0;
}

/// `eval` on one layout: the policy (and its rollout, and planners) on the same users.
int eval_one(const EvalOpts& v, const Config& cfg, std::unique_ptr<MarlPolicy> policy) {
  PlanOptions opt;
  if (!v.planners.empty()) opt.planners = split_methods(v.planners, "--planner");
  opt.seed = v.seed.empty() ? cfg.marl.users_seed : parse_seed("--seed", v.seed);
  opt.out_dir = v.out;
  policy->set_reserve_slack(cfg.marl.reserve_slack);  // an execution setting: the evaluation's
  opt.extra.push_back(std::shared_ptr<Planner>(std::move(policy)));
  if (v.rollout) {
    check_rollout_settings(cfg);
    auto base = MarlPolicy::load(v.policies.front());
    base->set_reserve_slack(cfg.marl.reserve_slack);  // as the policy flies above (-1 here)
    opt.extra.push_back(std::make_shared<RolloutPlanner>(std::move(base)));
  }
  std::vector<double> seconds;
  const auto recs = run_planners(cfg, opt, builtin_beamformers(), &std::cerr, &seconds);
  std::cout << "eval: N = " << cfg.trajectory.starts.size() << " UAVs, K = " << cfg.scenario.users << " users (seed "
            << opt.seed << "), oracle " << cfg.env.oracle << "\n"
            << format_plan_summary(recs, seconds);
  return 0;
}

int run_eval(const EvalOpts& v) {
  const bool many = !v.layouts.empty();
  const int layouts = many ? static_cast<int>(parse_count("--layouts", v.layouts, 1, 1000000)) : 0;
  const std::uint64_t first = v.first.empty() ? 0 : parse_count("--first", v.first, 0, (1ULL << 62) - 1);
  if (!many && !v.first.empty()) throw InputError("--first without --layouts: allowed with --layouts N");
  if (v.policies.empty() && !many) throw InputError("--policy is missing: allowed a run directory of `skyloop train`");
  if (!many && v.policies.size() > 1)
    throw InputError("--policy is given " + std::to_string(v.policies.size()) + " times: allowed once without --layouts");
  if (many && !v.seed.empty()) throw InputError("--seed with --layouts: allowed --first to choose the layouts");
  if (!v.out.empty()) check_output_dir(v.out);
  std::unique_ptr<MarlPolicy> policy;
  const Config cfg = eval_config(v, policy);
  if (many) return eval_layouts(v, cfg, layouts, first);
  return eval_one(v, cfg, std::move(policy));
}

}  // namespace

void add_marl_commands(CLI::App& app, Action& action) {
  auto t = std::make_shared<TrainOpts>();
  auto* train = app.add_subcommand("train", "train a multi-agent trajectory planner (" + learner_names_text() + ")");
  train->add_option("--algo", t->algo, learner_names_text() + " (sets marl.algo)");
  train->add_option("--seed", t->seed, "training seed (sets run.seed)");
  train->add_option("--steps", t->steps, "environment steps (sets marl.total_steps)");
  train->add_option("--out", t->out, "run directory: config.toml, metrics.csv, last.pt, policy.pt")->required();
  train->add_flag("--resume", t->resume, "continue from OUT/last.pt");
  train->add_flag("--force", t->force, "replace the run already in OUT (refused otherwise)");
  add_config_options(train, t->config);
  train->final_callback([&action, t] {
    action = [t] { return run_train(*t); };
  });

  auto v = std::make_shared<EvalOpts>();
  auto* eval = app.add_subcommand("eval", "run trained policies (deterministic) on one layout, or on many held-out layouts (--layouts)");
  eval->add_option("--policy", v->policies, "run directory (or policy.pt) of `skyloop train`; repeat for several");
  eval->add_option("--users", v->users, "number of users K (default: as trained)");
  eval->add_option("--seed", v->seed, "one layout: users seed (default: the training scenario's marl.users_seed)");
  eval->add_option("--planner", v->planners, "also run these planners on the same users: " + builtin_planners().names_text());
  eval->add_option("--layouts", v->layouts, "evaluate on this many layouts of --split, each against its exact optimum");
  eval->add_option("--split", v->split, "layouts from: test (default), validation or train (skyloop/env/layouts.hpp)");
  eval->add_option("--first", v->first, "index of the first layout (default 0)");
  eval->add_flag("--unsafe", v->unsafe, "with --layouts: also run every policy without action mask and shield (\"<algo>/raw\")");
  eval->add_flag("--rollout", v->rollout, "also fly every policy as the base of a multiagent rollout (\"<algo>+rollout\"; "
                                          "each slot, each UAV's moves scored by flying the rest of the mission with the policy)");
  eval->add_option("--cache", v->cache, "with --layouts: directory of cached optima (default OUT/optimum)");
  eval->add_option("--out", v->out, "one layout: trajectory.csv, rates.csv, summary.csv, users.csv, config.toml; "
                                    "--layouts: layouts.csv, summary.csv, config.toml");
  add_config_options(eval, v->config);
  eval->final_callback([&action, v] {
    action = [v] { return run_eval(*v); };
  });
}

}  // namespace skyloop::cli
