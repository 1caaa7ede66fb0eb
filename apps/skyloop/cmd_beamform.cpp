#include <algorithm>
#include <filesystem>
#include <fmt/format.h>
#include <iostream>

#include "common.hpp"
#include "skyloop/beamforming/registry.hpp"
#include "skyloop/core/io.hpp"
#include "skyloop/core/rng.hpp"
#include "skyloop/experiments/beamform_eval.hpp"
#include "skyloop/experiments/builtin.hpp"
#include "skyloop/experiments/farm.hpp"
#ifdef SKYLOOP_HAS_TORCH
#include "skyloop/nn/learned.hpp"
#endif

namespace skyloop::cli {

namespace {
struct EvalOptions;
int run_eval_here(const EvalOptions& o, Transport* transport);

struct EvalOptions {
  ConfigOptions config;
  std::string methods = "mrt,zf,rzf,wmmse,ga";
  std::string uavs, users, seed, threads;  // sugar for --set scenario.uavs=... etc. (validated there)
  std::size_t samples = 200;
  std::string out;
  bool quiet = false;
  bool test_set = false;
  bool samples_given = false;
  bool mpi = false;
};

/// The snapshots cut into chunks over the ranks of an MPI job; rank 0 gets the rows back in
/// snapshot order (the same rows as one process: snapshot i is seeded by its index alone).
std::vector<BeamformEvalRow> eval_on_ranks(Transport& t, const Config& cfg, const BeamformEvalOptions& opt, bool quiet) {
  const std::size_t chunk =
      std::clamp<std::size_t>((opt.samples + 4 * static_cast<std::size_t>(t.size()) - 1) / (4 * static_cast<std::size_t>(t.size())), 1, 100);
  std::vector<FarmTask> tasks;
  for (std::size_t first = 0; first < opt.samples; first += chunk) {
    const std::size_t last = std::min(opt.samples, first + chunk) - 1;
    tasks.push_back({fmt::format("snapshots {}-{}", first, last), "chunk", fmt::format("snapshots {}-{}", first, last),
                     static_cast<double>(last - first + 1), {}});
  }
  std::vector<std::vector<BeamformEvalRow>> parts(tasks.size());
  const auto records = farm_run(
      &t, tasks,
      [&](std::size_t i) {
        BeamformEvalOptions part = opt;
        part.first = opt.first + i * chunk;
        part.samples = std::min(opt.samples, (i + 1) * chunk) - i * chunk;
        return beamform_eval_csv(run_beamform_eval(cfg, part, builtin_beamformers(), nullptr), cfg);
      },
      [&](std::size_t i, const std::string& csv) { parts[i] = parse_beamform_eval_csv(csv, tasks[i].id); },
      quiet ? nullptr : &std::cerr);
  std::vector<BeamformEvalRow> rows;
  for (const auto& r : records)
    if (!r.ok) throw std::runtime_error(tasks[r.task].id + " failed: " + r.error);
  for (auto& p : parts) rows.insert(rows.end(), p.begin(), p.end());
  return rows;
}

int run_eval(const EvalOptions& o) {
  const auto methods = split_methods(o.methods);
  continue_with_libtorch_if(std::any_of(methods.begin(), methods.end(), is_learned_beamformer));
  const auto transport = open_transport(o.mpi);
  if (transport && transport->size() == 1) return run_eval_here(o, nullptr);
  return on_every_rank(transport.get(), [&] { return run_eval_here(o, transport.get()); });
}

int run_eval_here(const EvalOptions& o, Transport* transport) {
  std::vector<std::string> extra;
  if (!o.uavs.empty()) extra.push_back("scenario.uavs=" + o.uavs);
  if (!o.users.empty()) extra.push_back("scenario.users=" + o.users);
  if (!o.seed.empty()) extra.push_back("run.seed=" + o.seed);
  if (!o.threads.empty()) extra.push_back("run.threads=" + o.threads);
  Config cfg = o.config.resolve(extra);
  if (transport) cfg.run.threads = threads_per_rank(cfg.run.threads, transport);
  const bool rank0 = !transport || transport->rank() == 0;
  std::filesystem::path csv_path(o.out), config_path(o.out);
  config_path.replace_extension(".config.toml");
  if (!o.out.empty() && rank0) check_output_path(csv_path.string()), check_output_path(config_path.string());
#ifdef SKYLOOP_HAS_TORCH
  set_torch_threads(1);  // decisions are timed on one core each; samples run in parallel instead
#endif

  BeamformEvalOptions opt;
  opt.methods = split_methods(o.methods);
  opt.uavs = cfg.scenario.uavs;
  opt.users = cfg.scenario.users;
  opt.samples = o.samples;
  opt.seed = cfg.run.seed;
  opt.threads = cfg.run.threads;
  if (o.test_set) {
    // The learned models' held-out test split: snapshot i = derive_seed(derive_seed(nn.data_seed, 3), i).
    opt.seed = derive_seed(cfg.nn.data_seed, 3);
    if (!o.samples_given) opt.samples = static_cast<std::size_t>(cfg.nn.test_samples);
    if (rank0) std::cout << "evaluating on the test split of nn.data_seed = " << cfg.nn.data_seed << "\n";
  }
  if (rank0)
    std::cout << fmt::format("beamform eval: N = {} UAVs, K = {} users, L = {}, P_max = {} dBm, noise = {} dBm, "
                             "{} samples, seed {}{}\n",
                             opt.uavs, opt.users, cfg.channel.antennas, cfg.channel.p_max_dbm, cfg.channel.noise_dbm,
                             opt.samples, opt.seed, transport ? fmt::format(", {} ranks", transport->size()) : "")
              << std::flush;
  const auto rows = transport ? eval_on_ranks(*transport, cfg, opt, o.quiet)
                              : run_beamform_eval(cfg, opt, builtin_beamformers(), o.quiet ? nullptr : &std::cerr);
  if (!rank0) return 0;
  if (!o.out.empty()) {
    const auto& csv = csv_path;
    const auto& resolved = config_path;
    // The CSV and its resolved config change together or not at all.
    write_files_atomic({{csv.string(), beamform_eval_csv(rows, cfg)}, {resolved.string(), to_toml(cfg)}});
    std::cout << "wrote " << csv.string() << " and " << resolved.string() << "\n";
  }
  std::cout << format_summary(summarise(rows));
  return 0;
}
#ifdef SKYLOOP_HAS_TORCH
struct TrainCliOptions {
  ConfigOptions config;
  std::string model, out, device, seed, threads;
  bool resume = false, force = false;
};

int run_train(const TrainCliOptions& o) {
  std::vector<std::string> extra;
  if (!o.model.empty()) extra.push_back("nn.model=" + o.model);
  if (!o.device.empty()) extra.push_back("nn.device=" + o.device);
  if (!o.seed.empty()) extra.push_back("run.seed=" + o.seed);
  if (!o.threads.empty()) extra.push_back("run.threads=" + o.threads);
  const Config cfg = o.config.resolve(extra);
  TrainOptions opt;
  opt.out_dir = o.out;
  opt.resume = o.resume;
  opt.force = o.force;
  opt.progress = &std::cerr;
  set_interrupt_hint(kTrainInterruptHint);
  const TrainResult r = train_beamformer(cfg, opt);
  std::cout << fmt::format("{}: best validation sum rate {:.3f} bit/s/Hz (epoch {}), test sum rate {:.3f} bit/s/Hz, "
                           "{} parameters, {:.0f} clusters/s, {:.1f} s\nwrote {}/model.pt, last.pt, metrics.csv, "
                           "config.toml, test.json\n",
                           r.info.model, r.info.best_val_sum_rate, r.info.epoch, r.test_sum_rate, r.info.parameters,
                           r.clusters_per_second, r.wall_seconds, o.out);
  return 0;
}
#endif
}  // namespace

void add_beamform_command(CLI::App& app, Action& action) {
  auto* beamform = app.add_subcommand("beamform", "beamforming experiments");
  beamform->require_subcommand(1);

  auto o = std::make_shared<EvalOptions>();
  auto* eval = beamform->add_subcommand("eval", "compare beamformers on seeded random snapshots");
  eval->add_option("--methods", o->methods, "comma-separated beamformer specs")->capture_default_str();
  eval->add_option("--uavs", o->uavs, "number of UAVs N (sets scenario.uavs)");
  eval->add_option("--users", o->users, "number of users K (sets scenario.users)");
  eval->add_option("--samples", o->samples, "number of random snapshots")->capture_default_str()->check(CLI::Range(1, 100000000));
  eval->add_option("--seed", o->seed, "base seed (sets run.seed)");
  eval->add_option("--threads", o->threads, "worker threads, 0 = all (sets run.threads)");
  eval->add_option("--out", o->out, "tidy CSV output; the resolved config is written beside it (.config.toml)");
  eval->add_flag("--quiet", o->quiet, "no progress lines");
  eval->add_flag("--mpi", o->mpi,
                 "spread the snapshots over the ranks of an MPI job (on by itself under mpirun; rank 0 writes the output)");
  eval->add_flag("--test-set", o->test_set,
                 "evaluate on the learned models' held-out test snapshots (nn.data_seed, nn.test_samples)");
  add_config_options(eval, o->config);
  eval->final_callback([&action, o, eval] {
    o->samples_given = eval->count("--samples") > 0;
    action = [o] { return run_eval(*o); };
  });

#ifdef SKYLOOP_HAS_TORCH
  auto t = std::make_shared<TrainCliOptions>();
  auto* train = beamform->add_subcommand("train", "train a learned beamformer (unsupervised, on sum rate)");
  train->add_option("--model", t->model, "gnn | deepsets | mspointnet (sets nn.model)");
  train->add_option("--out", t->out, "run directory: model.pt, last.pt, metrics.csv, config.toml, test.json")->required();
  train->add_flag("--resume", t->resume, "continue from OUT/last.pt");
  train->add_flag("--force", t->force, "replace the run already in OUT (refused otherwise)");
  train->add_option("--device", t->device, "cpu | cuda (sets nn.device)");
  train->add_option("--seed", t->seed, "training seed (sets run.seed)");
  train->add_option("--threads", t->threads, "torch threads, 0 = all (sets run.threads)");
  add_config_options(train, t->config);
  train->final_callback([&action, t] { action = [t] { return run_train(*t); }; });
#endif

  auto* list = beamform->add_subcommand("list", "list the available beamformers");
  list->final_callback([&action] {
    action = [] {
      const auto all = builtin_beamformers().list();
      std::size_t width = 0;
      for (const auto& [name, desc] : all) width = std::max(width, name.size());
      for (const auto& [name, desc] : all) std::cout << fmt::format("{:<{}}  {}\n", name, width, desc);
      return 0;
    };
  });
}

}  // namespace skyloop::cli
