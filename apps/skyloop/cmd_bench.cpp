// `skyloop bench`: the benchmark's tasks (skyloop/experiments/bench.hpp), their references, and
// scoring planners and trained policies under the task's protocol.
#include <chrono>
#include <cmath>
#include <ctime>
#include <filesystem>
#include <fmt/format.h>
#include <fmt/ranges.h>
#include <iostream>
#include <mutex>

#include "common.hpp"
#include "skyloop/beamforming/registry.hpp"
#include "skyloop/core/config_io.hpp"
#include "skyloop/core/csv.hpp"
#include "skyloop/core/error.hpp"
#include "skyloop/core/io.hpp"
#include "skyloop/core/parallel.hpp"
#include "skyloop/core/process.hpp"
#include "skyloop/experiments/bench.hpp"
#include "skyloop/env/layouts.hpp"
#include "skyloop/env/spec.hpp"
#include "skyloop/experiments/builtin.hpp"
#include "skyloop/experiments/reproduce.hpp"
#include "skyloop/marl/learners.hpp"
#include "skyloop/marl/marl.hpp"
#include "skyloop/nn/learned.hpp"
#include "skyloop/planning/registry.hpp"

namespace skyloop::cli {

namespace {

namespace fs = std::filesystem;

std::vector<std::uint64_t> parse_seeds(const std::string& s) {
  std::vector<std::uint64_t> out;
  for (const auto& x : split_methods(s, "--seeds")) out.push_back(parse_seed("--seeds", x));
  return out;
}

/// Replaces `key = "..."` in task.toml's text (the file stays as people wrote it otherwise).
std::string set_toml_string(std::string text, const std::string& key, const std::string& value) {
  const std::string line = key + " = \"" + value + "\"";
  std::size_t at = 0;
  while ((at = text.find(key, at)) != std::string::npos) {
    const bool line_start = at == 0 || text[at - 1] == '\n';
    const std::size_t after = at + key.size();
    if (line_start && text.find_first_not_of(' ', after) != std::string::npos && text[text.find_first_not_of(' ', after)] == '=') {
      const std::size_t end = text.find('\n', at);
      return text.replace(at, (end == std::string::npos ? text.size() : end) - at, line);
    }
    at = after;
  }
  // Not there: after the [task] header.
  const std::size_t task = text.find("[task]\n");
  if (task == std::string::npos) throw InputError("task.toml has no [task] table");
  return text.insert(task + 7, line + "\n");
}

/// The planners that apply to a task: greedy enumerates every joint move (GreedyPlanner's bound).
std::vector<std::pair<std::string, std::string>> baseline_planners(const BenchTask& t) {
  std::vector<std::pair<std::string, std::string>> out;  // (planner, why not; empty = runs)
  const int n = static_cast<int>(t.config.trajectory.starts.size());
  const int a = make_env_spec(t.config, n, max_layout_users(t.config)).action.count();
  const double joint = std::pow(static_cast<double>(a), n);
  for (const std::string p : {"random", "greedy", "seqgreedy", "rollout"}) {
    std::string why;
    if (p == "greedy" && joint > static_cast<double>(GreedyPlanner::kMaxJointActions))
      why = fmt::format("greedy enumerates {}^{} joint moves, allowed at most {}", a, n, GreedyPlanner::kMaxJointActions);
    out.emplace_back(p, why);
  }
  return out;
}

/// Whether the run in `dir` has trained its whole budget: its log's last row has `steps` steps
/// (policy.pt alone does not say so: model selection writes it while training goes on).
bool trained_to(const std::string& dir, std::int64_t steps) {
  const fs::path log = fs::path(dir) / "metrics.csv";
  if (!fs::exists(log) || !fs::exists(fs::path(dir) / "policy.pt")) return false;
  const auto t = CsvTable::parse(read_file(log.string(), "training log"), log.string());
  return t.size() > 0 && t.number(t.size() - 1, "env_steps") >= static_cast<double>(steps);
}

struct BenchCliOptions {
  std::string task, sample = "5", planners, seeds, label, out, threads, learners, steps, jobs, time_limit;
  std::vector<std::string> policies;
  bool all = false, write = false, force = false;
};

int bench_list() {
  const auto ids = bench_task_ids();
  std::cout << fmt::format("{:<22} {:>7} {:>16} {:>10}  {}\n", "task", "layouts", "reference", "budget", "title");
  for (const auto& id : ids) {
    const auto t = load_bench_task(id);
    std::string ref;
    for (const auto& r : t.references)
      if (!r.reference.empty() && ref.find(r.reference) == std::string::npos) ref += (ref.empty() ? "" : "+") + r.reference;
    std::cout << fmt::format("{:<22} {:>7} {:>16} {:>10.0e}  {}\n", t.id, t.references.size(), ref.empty() ? "(none yet)" : ref,
                             static_cast<double>(t.protocol.budget_steps), t.title);
  }
  for (const auto& w : withdrawn_tasks())
    std::cout << fmt::format("{:<22} withdrawn, successor {} (`skyloop bench reference {}` says why)\n", w.id, w.successor, w.id);
  return 0;
}

int bench_reference(const BenchCliOptions& o) {
  const auto t = load_bench_task(o.task, o.write);
  const int threads = o.threads.empty() ? 0 : static_cast<int>(parse_count("--threads", o.threads, 1, 1024));
  const bool shipped = !t.references.front().reference.empty();
  std::vector<std::size_t> idx;
  if (o.write || o.all || !shipped) {
    for (std::size_t i = 0; i < t.references.size(); ++i) idx.push_back(i);
  } else {
    idx = sample_layouts(t.references.size(), parse_count("--sample", o.sample, 1, t.references.size()));
  }
  if (!shipped && !o.write) throw InputError("task " + t.id + " has no reference.csv yet: allowed --write to compute it");
  const std::string fp = config_fingerprint(t.config, t.fixed_keys);
  std::cerr << fmt::format("bench reference {}: {} of {} layouts\n", t.id, idx.size(), t.references.size());
  const auto got = compute_references(t, idx, threads, &std::cerr);
  if (o.write) {
    const std::string task_toml = (fs::path(t.dir) / "task.toml").string();
    std::string text = read_file(task_toml, "task file");
    text = set_toml_string(text, "fingerprint", fp);
    text = set_toml_string(text, "reference_checksum", reference_checksum(got));
    write_files_atomic({{(fs::path(t.dir) / "reference.csv").string(), reference_csv(t, got)}, {task_toml, text}});
    double seconds = 0;
    for (const auto& r : got) seconds += r.seconds;
    std::cout << fmt::format("wrote {}/reference.csv ({} layouts, {:.1f} s of references) and task.toml's checksums\n", t.dir,
                             got.size(), seconds);
    return 0;
  }
  int bad = 0;
  std::cout << fmt::format("{:>6} {:>10} {:>18} {:>18} {:>10} {:>9}\n", "layout", "reference", "shipped", "recomputed", "rel diff", "seconds");
  for (std::size_t k = 0; k < got.size(); ++k) {
    const auto& s = t.references[idx[k]];
    const auto& g = got[k];
    const double rel = std::abs(g.objective - s.objective) / std::max(1e-300, std::abs(s.objective));
    const bool ok = rel <= t.reference_rtol && g.reference == s.reference;
    bad += ok ? 0 : 1;
    std::cout << fmt::format("{:>6} {:>10} {:>18.12g} {:>18.12g} {:>10.2e} {:>9.2f}{}\n", s.layout, g.reference, s.objective,
                             g.objective, rel, g.seconds, ok ? "" : "  DIFFERS");
  }
  const bool fp_ok = fp == t.fingerprint;
  std::cout << fmt::format("fingerprint {} {}\n", fp, fp_ok ? "(as shipped)" : "DIFFERS from task.fingerprint = " + t.fingerprint);
  if (bad || !fp_ok) {
    std::cout << fmt::format("{}: {} of {} references differ beyond reference_rtol = {}{}: the task's numbers moved; give it a new "
                             "version\n", t.id, bad, got.size(), format_double(t.reference_rtol), fp_ok ? "" : ", and its configuration changed");
    return 1;
  }
  std::cout << fmt::format("{}: {} references reproduced within {}\n", t.id, got.size(), format_double(t.reference_rtol));
  return 0;
}

void write_outputs(const BenchTask& t, const std::vector<BenchRow>& rows, const std::string& out) {
  const auto sum = summarise_bench(t, rows);
  std::cout << fmt::format("bench {} ({}): {} test layouts against {}\n", t.id, t.title, t.references.size(),
                           sum.empty() ? std::string("?") : sum.front().reference)
            << format_bench_summary(sum);
  if (out.empty()) return;
  write_files_atomic({{out + "/rows.csv", bench_rows_csv(rows)},
                      {out + "/summary.csv", bench_summary_csv(sum)},
                      {out + "/profile.csv", bench_profile_csv(rows)},
                      {out + "/marl_eval.json", bench_marl_eval_json(t, rows)},
                      {out + "/config.toml", to_toml(t.config)}});
  std::cout << "wrote " << out << "/{rows,summary,profile}.csv, marl_eval.json, config.toml\n";
}

int bench_run(const BenchCliOptions& o) {
  const auto t = load_bench_task(o.task);
  BenchRunOptions opt;
  if (!o.planners.empty()) opt.planners = split_methods(o.planners, "--planner");
  if (!o.seeds.empty()) opt.seeds = parse_seeds(o.seeds);
  opt.policies = o.policies;
  opt.policy_label = o.label;
  opt.threads = o.threads.empty() ? 0 : static_cast<int>(parse_count("--threads", o.threads, 1, 1024));
  if (!o.out.empty()) check_output_dir(o.out);
  std::unique_ptr<RunDirLock> lock;
  if (!o.out.empty()) lock = std::make_unique<RunDirLock>(o.out);
  const auto rows = run_bench(t, opt, &std::cerr);
  write_outputs(t, rows, o.out);
  return 0;
}

int bench_baselines(const BenchCliOptions& o) {
  const auto t = load_bench_task(o.task);
  if (o.out.empty()) throw InputError("--out is missing: allowed a directory for the trained runs and the leaderboard");
  const std::size_t max_jobs = o.jobs.empty() ? 1 : parse_count("--jobs", o.jobs, 1, 256);
  std::vector<std::string> algos = o.learners.empty() ? learner_names() : split_methods(o.learners, "--learners");
  if (algos == std::vector<std::string>{"none"}) algos.clear();  // the planners alone
  for (const auto& a : algos) {
    try {
      find_learner(a);
    } catch (const InputError&) {
      throw InputError("--learners = '" + a + "' is unknown: allowed " + learner_names_text() + " (comma-separated), or none");
    }
  }
  std::vector<std::uint64_t> seeds = o.seeds.empty() ? std::vector<std::uint64_t>{} : parse_seeds(o.seeds);
  if (seeds.empty())
    for (int s = 1; s <= t.protocol.seeds; ++s) seeds.push_back(static_cast<std::uint64_t>(s));
  const std::int64_t steps = o.steps.empty() ? t.protocol.budget_steps
                                              : static_cast<std::int64_t>(parse_count("--steps", o.steps, 1, std::uint64_t{1} << 40));
  const double time_limit = o.time_limit.empty() ? 0.0 : parse_time_limit(o.time_limit);
  const auto started = std::chrono::steady_clock::now();
  check_output_dir(o.out);  // every argument checked before anything is written
  RunDirLock lock(o.out);
  BenchRunOptions planners;
  planners.seeds = seeds;
  std::string skipped;
  for (const auto& [p, why] : baseline_planners(t)) {
    if (why.empty()) planners.planners.push_back(p);
    else skipped += fmt::format("{}: not run ({})\n", p, why);
  }
  // Each learner's configuration is checked first: one that cannot run the task's settings is a
  // row of its own, saying why (and is not trained).
  auto learner_config = [&](const std::string& algo, std::uint64_t seed) {
    Config cfg = t.config;
    apply_override(cfg, "marl.algo=\"" + algo + "\"");
    apply_override(cfg, "run.seed=" + std::to_string(seed));
    apply_override(cfg, "marl.total_steps=" + std::to_string(steps));
    return cfg;
  };
  std::vector<std::string> runnable;
  for (const auto& algo : algos) {
    try {
      validate(learner_config(algo, seeds.front()));
      runnable.push_back(algo);
    } catch (const InputError& e) {
      skipped += fmt::format("{}: not run ({})\n", algo, e.what());
    }
  }
  // The runs not yet trained to the budget, each by a child `skyloop train` (resuming from its
  // last.pt), `jobs` at a time on an equal share of the hardware threads.
  struct Job {
    std::string algo, dir;
    std::uint64_t seed;
  };
  std::vector<Job> pending;
  for (const auto& algo : runnable)
    for (const auto seed : seeds) {
      const std::string dir = fmt::format("{}/train/{}-s{}", o.out, algo, seed);
      if (!trained_to(dir, steps)) pending.push_back({algo, dir, seed});
    }
  const int jobs = static_cast<int>(std::min<std::size_t>(max_jobs, std::max<std::size_t>(pending.size(), 1)));
  const int threads = std::max(1, resolve_threads(0) / jobs);
  // OUT/trainings.csv: a row per training this command ran, kept across invocations (a board
  // trained over several sessions lists each part): how long it took, beside what, and where.
  const std::string record = o.out + "/trainings.csv";
  const std::string machine = machine_label();
  // --time-limit: a training starts only while 1.3 x its expected seconds fit in the time left.
  // Expected: the longest uninterrupted training of the same learner and budget this board has
  // recorded (beside as many others, if any such), else reproduce's estimate for one core.
  auto expected = [&](const Job& j, const Config& cfg) {
    double same_jobs = 0, any = 0;
    if (fs::exists(record)) {
      const auto table = CsvTable::parse(read_file(record, "training record"), record);
      for (std::size_t r = 0; r < table.size(); ++r) {
        if (table.at(r, "task") != t.id || table.at(r, "algo") != j.algo || table.at(r, "steps") != std::to_string(steps) ||
            table.at(r, "resumed") != "0")
          continue;
        const double sec = table.number(r, "seconds");
        any = std::max(any, sec);
        if (table.at(r, "jobs") == std::to_string(jobs)) same_jobs = std::max(same_jobs, sec);
      }
    }
    return same_jobs > 0 ? same_jobs : any > 0 ? any : marl_run_estimate(cfg);
  };
  auto elapsed = [&] { return std::chrono::duration<double>(std::chrono::steady_clock::now() - started).count(); };
  std::vector<std::string> left;  // trainings the time limit kept from starting
  auto record_training = [&](const Job& j, double seconds, bool resumed) {
    std::string csv = fs::exists(record) ? read_file(record, "training record")
                                         : "task,algo,seed,steps,seconds,resumed,jobs,threads,finished_utc,machine,skyloop\n";
    const std::time_t now = std::time(nullptr);
    std::tm utc{};
    gmtime_r(&now, &utc);
    char at[32];
    std::strftime(at, sizeof at, "%Y-%m-%dT%H:%M:%SZ", &utc);
    csv += fmt::format("{},{},{},{},{:.1f},{},{},{},{},\"{}\",{}\n", t.id, j.algo, j.seed, steps, seconds, resumed ? 1 : 0, jobs,
                       threads, at, machine, SKYLOOP_VERSION);
    write_file_atomic(record, csv);
  };
  std::mutex mu;
  std::vector<std::string> failed;
  std::size_t finished = 0;  // trainings that ran to their end (trained or failed)
  parallel_for(pending.size(), jobs, [&](std::size_t i) {
    const Job& j = pending[i];
    Config cfg = learner_config(j.algo, j.seed);
    cfg.run.threads = threads;
    if (time_limit > 0) {
      std::lock_guard<std::mutex> hold(mu);
      const double need = expected(j, cfg);
      if (!fits_time_limit(elapsed(), need, time_limit)) {
        left.push_back(fmt::format("{} seed {} (about {:.0f} s)", j.algo, j.seed, need));
        return;  // not started: not counted in the progress below
      }
    }
    fs::create_directories(fs::path(j.dir).parent_path());
    const std::string request = j.dir + ".request.toml", log = j.dir + ".log";
    write_file_atomic(request, to_toml(cfg));
    std::vector<std::string> argv = {self_path(), "train", "--config", request, "--out", j.dir};
    const bool resume = fs::exists(fs::path(j.dir) / "last.pt");
    if (resume) argv.push_back("--resume");
    {
      std::lock_guard<std::mutex> hold(mu);
      std::cerr << fmt::format("bench baselines {}: training {} seed {} ({} steps{}; log {})\n", t.id, j.algo, j.seed, steps,
                               resume ? ", resumed" : "", log);
    }
    const auto t0 = std::chrono::steady_clock::now();
    const int rc = run_process(argv, log);
    const double sec = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    std::lock_guard<std::mutex> hold(mu);
    ++finished;
    if (rc != 0) failed.push_back(fmt::format("{} seed {} (exit status {}; see {})", j.algo, j.seed, rc, log));
    else record_training(j, sec, resume);
    std::cerr << fmt::format("bench baselines {}: {} seed {} {} in {:.0f} s ({}/{} runs)\n", t.id, j.algo, j.seed,
                             rc == 0 ? "trained" : "failed", sec, finished, pending.size());
  });
  if (!failed.empty())
    throw std::runtime_error(fmt::format("bench baselines {}: {} of {} trainings failed: {}; a rerun resumes every run", t.id,
                                         failed.size(), pending.size(), fmt::join(failed, ", ")));
  if (!left.empty()) {
    std::cerr << fmt::format("time limit: stopped after {:.0f} s of --time-limit {:.0f} s with {} of {} trainings left ({}); "
                             "nothing is scored yet: run the same command again to go on\n",
                             elapsed(), time_limit, left.size(), pending.size(), fmt::join(left, ", "));
    return kTimeLimitExit;
  }
  // The planners are scored once every training is done (a board trained over several calls
  // scores them once, last).
  std::vector<BenchRow> rows = run_bench(t, planners, &std::cerr);
  for (const auto& algo : runnable) {
    BenchRunOptions p;
    for (const auto seed : seeds) p.policies.push_back(fmt::format("{}/train/{}-s{}", o.out, algo, seed));
    p.policy_label = algo;
    const auto r = run_bench(t, p, &std::cerr);
    rows.insert(rows.end(), r.begin(), r.end());
  }
  write_outputs(t, rows, o.out);
  if (!skipped.empty()) {
    std::cout << skipped;
    write_file_atomic(o.out + "/not_run.txt", skipped);
  }
  return 0;
}

}  // namespace

void add_bench_command(CLI::App& app, Action& action) {
  auto o = std::make_shared<BenchCliOptions>();
  auto* bench = app.add_subcommand("bench", "the benchmark: named tasks scored against each test layout's exact optimum");
  bench->require_subcommand(1);
  auto* list = bench->add_subcommand("list", "every task, one line each");
  list->final_callback([&action] { action = [] { return bench_list(); }; });

  // Every command but list names its task first.
  auto with_task = [&](CLI::App* cmd) {
    cmd->add_option("task", o->task, "task id (e.g. paper-v1), name or folder")->required();
    return cmd;
  };
  auto* ref = with_task(bench->add_subcommand("reference", "recompute a task's references and compare them with the shipped ones"));
  ref->add_option("--sample", o->sample, "how many layouts, spread over the test layouts")->capture_default_str();
  ref->add_flag("--all", o->all, "every test layout");
  ref->add_flag("--write", o->write, "compute every layout and write reference.csv and task.toml's checksums (a new task)");
  ref->add_option("--threads", o->threads, "layouts in parallel (default run.threads)");
  ref->final_callback([&action, o] { action = [o] { return bench_reference(*o); }; });

  auto* run = with_task(bench->add_subcommand("run", "score planners or trained policies on a task's test layouts"));
  run->add_option("--planner", o->planners, "comma-separated: " + builtin_planners().names_text());
  run->add_option("--policy", o->policies, "run directories of `skyloop train`, one per training seed");
  run->add_option("--seeds", o->seeds, "the planners' seeds, comma-separated (default 1..the protocol's seeds)");
  run->add_option("--label", o->label, "the policies' name in the outputs (default the algorithm)");
  run->add_option("--threads", o->threads, "layouts in parallel (default run.threads)");
  run->add_option("--out", o->out, "rows.csv, summary.csv, profile.csv, marl_eval.json, config.toml");
  run->final_callback([&action, o] { action = [o] { return bench_run(*o); }; });

  auto* base = with_task(bench->add_subcommand("baselines", "train and score every baseline under the task's protocol: the leaderboard"));
  base->add_option("--out", o->out, "the trained runs (train/ALGO-sS) and the outputs of `bench run`")->required();
  base->add_option("--learners", o->learners, "comma-separated: " + learner_names_text() + " (default all), or none (the planners alone)");
  base->add_option("--seeds", o->seeds, "training seeds (default 1..the protocol's seeds)");
  base->add_option("--steps", o->steps, "training steps (default the protocol's budget; another is labelled off-protocol)");
  base->add_option("--jobs", o->jobs, "trainings at a time, each a child process on its share of the hardware threads (default 1)");
  base->add_option("--time-limit", o->time_limit,
                   "start no training that would end after this long (e.g. 2h45m, or HH:MM:SS), judged by the board's "
                   "trainings.csv (else reproduce's estimate) x1.3; trainings left: exit status 75, nothing scored")
      ->type_name("DURATION");
  base->final_callback([&action, o] { action = [o] { return bench_baselines(*o); }; });
}

}  // namespace skyloop::cli
