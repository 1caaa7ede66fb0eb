// `skyloop reproduce`: runs every experiment of configs/experiments/ for one profile.
//
// Caching: every piece of work (a trained model, one sweep point, one MARL run, one planning
// evaluation) lives in a directory or file named by the hash of everything that decides its
// result: the resolved configuration (threads excluded), the methods, the sample count and the
// bytes of the models it uses. A piece whose output exists is reused; an interrupted MARL or
// model training resumes from its last checkpoint; --force deletes the selected experiments'
// pieces first. The per-figure CSVs are re-assembled from the pieces on every run.
#include "skyloop/experiments/reproduce.hpp"

#include <chrono>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fmt/format.h>
#include <map>
#include <mutex>
#include <nlohmann/json.hpp>
#include <ostream>
#include <sstream>
#include <thread>

#include "skyloop/core/config_io.hpp"
#include "skyloop/core/error.hpp"
#include "skyloop/core/io.hpp"
#include "skyloop/core/process.hpp"
#include "skyloop/core/rng.hpp"
#include "skyloop/experiments/beamform_eval.hpp"
#include "skyloop/experiments/builtin.hpp"
#include "skyloop/experiments/planning_run.hpp"
#include "skyloop/marl/marl.hpp"
#include "skyloop/nn/learned.hpp"

namespace skyloop {

namespace {
namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;

double since(Clock::time_point t0) { return std::chrono::duration<double>(Clock::now() - t0).count(); }

std::string hex(std::uint64_t h) { return fmt::format("{:016x}", h); }
std::uint64_t hash_text(const std::string& s, std::uint64_t h = 0xcbf29ce484222325ULL) { return hash_bytes(s.data(), s.size(), h); }

/// The configuration text that decides a result: threads never change one.
std::string config_key(Config c) {
  c.run.threads = 0;
  return to_toml(c);
}

/// What decides a trained beamformer: everything but the trajectory-level sections.
std::string training_key(Config c) {
  const Config d;
  c.env = d.env;
  c.marl = d.marl;
  c.ga = d.ga;
  c.wmmse = d.wmmse;
  c.trajectory = d.trajectory;
  c.nn.device = d.nn.device;
  c.nn.precision = d.nn.precision;  // serving only
  return config_key(c);
}

std::string fmt_value(double v) { return format_double(v); }

/// Lines of a CSV text without its header.
std::string body(const std::string& csv) {
  const auto nl = csv.find('\n');
  return nl == std::string::npos ? std::string() : csv.substr(nl + 1);
}
std::string header(const std::string& csv) { return csv.substr(0, csv.find('\n')); }

/// Prefixes every data line of `csv` with `prefix` (which ends with a comma).
std::string prefixed(const std::string& csv, const std::string& prefix) {
  std::string out;
  std::istringstream in(body(csv));
  for (std::string line; std::getline(in, line);)
    if (!line.empty()) out += prefix + line + "\n";
  return out;
}

struct ModelLabel {
  std::string base;                 // registry name
  std::vector<std::string> sets;    // what makes it this model
};
const std::map<std::string, ModelLabel>& model_labels() {
  static const std::map<std::string, ModelLabel> m = {
      {"gnn", {"gnn", {"nn.model=gnn", "nn.readout=direct"}}},
      {"deepsets", {"deepsets", {"nn.model=deepsets", "nn.readout=direct"}}},
      {"mspointnet", {"mspointnet", {"nn.model=mspointnet", "nn.readout=direct"}}},
      {"gnn_structured", {"gnn", {"nn.model=gnn", "nn.readout=structured"}}},
      // The interference-aware GNN, trained on the network sum rate under the shared spectrum.
      {"ignn", {"ignn", {"nn.model=ignn", "nn.readout=direct", "channel.spectrum=shared", "nn.hidden=64", "nn.layers=2"}}},
      {"ignn_structured", {"ignn", {"nn.model=ignn", "nn.readout=structured", "channel.spectrum=shared", "nn.hidden=64", "nn.layers=2"}}},
  };
  return m;
}

class Runner {
 public:
  explicit Runner(const ReproduceOptions& o)
      : opt_(o), out_(o.out_dir), log_(o.progress ? *o.progress : null_), threads_(o.threads) {
    if (threads_ <= 0) threads_ = static_cast<int>(std::max(1u, std::thread::hardware_concurrency()));
    jobs_ = o.jobs > 0 ? o.jobs : threads_;
  }

  int run(const std::vector<ExperimentSpec>& specs) {
    const auto t_all = Clock::now();
    manifest_["profile"] = opt_.profile;
    manifest_["threads"] = threads_;
    manifest_["experiments"] = nlohmann::json::array();
    std::vector<const ExperimentSpec*> selected;
    for (const auto& s : specs)
      if (s.kind == "models" || opt_.only.empty() || std::find(opt_.only.begin(), opt_.only.end(), s.name) != opt_.only.end())
        selected.push_back(&s);
    for (const auto& name : opt_.only) {
      bool found = false;
      for (const auto& s : specs) found = found || s.name == name;
      if (!found) {
        std::string all;
        for (const auto& s : specs) all += (all.empty() ? "" : ", ") + s.name;
        throw InputError("--only '" + name + "' is not an experiment: allowed " + all);
      }
    }
    // Every experiment's configuration resolves before any work starts: a typo fails at once.
    for (const auto* s : selected) (void)base(*s);
    remove_stale_temporaries(out_.string(), true);  // debris of a run killed mid-write
    write_file_atomic((out_ / "config.toml").string(), to_toml(resolve({})));
    for (std::size_t i = 0; i < selected.size(); ++i) {
      const auto& s = *selected[i];
      if (i == 1) prefetch_marl(selected);
      log_ << fmt::format("[{}/{}] {} ({}{}{})\n", i + 1, selected.size(), s.name, s.kind, s.figure.empty() ? "" : ", ",
                          s.figure)
           << std::flush;
      if (opt_.force && s.kind == "models") forget(s);
      const auto t0 = Clock::now();
      nlohmann::json entry = {{"name", s.name}, {"kind", s.kind}, {"figure", s.figure}, {"title", s.title}};
      write_file_atomic((out_ / s.name / "experiment.toml").string(), s.text);
      write_file_atomic((out_ / s.name / "config.toml").string(), to_toml(base(s)));
      entry["files"] = stage(s);
      entry["seconds"] = since(t0);
      manifest_["experiments"].push_back(entry);
      log_ << fmt::format("[{}/{}] {} done in {:.1f} s\n", i + 1, selected.size(), s.name, since(t0)) << std::flush;
    }
    manifest_["seconds"] = since(t_all);
    // Earlier invocations on this directory stay listed: a cached re-run takes seconds, and the
    // report shows what the computing run took.
    nlohmann::json runs = nlohmann::json::array();
    if (fs::exists(out_ / "manifest.json")) {
      try {
        const auto old = nlohmann::json::parse(read_file((out_ / "manifest.json").string()));
        if (old.contains("runs")) runs = old["runs"];
      } catch (const std::exception&) {
      }
    }
    nlohmann::json names = nlohmann::json::array();
    for (const auto* s : selected) names.push_back(s->name);
    runs.push_back({{"seconds", manifest_["seconds"]}, {"threads", threads_}, {"jobs", jobs_}, {"force", opt_.force},
                    {"experiments", names}});
    manifest_["runs"] = runs;
    manifest_["models"] = shown_models_;
    write_file_atomic((out_ / "manifest.json").string(), manifest_.dump(2) + "\n");
    log_ << fmt::format("all stages done in {:.1f} s; wrote {}\n", since(t_all), (out_ / "manifest.json").string());
    return 0;
  }

 private:
  const ReproduceOptions& opt_;
  fs::path out_;
  std::ostringstream null_;
  std::ostream& log_;
  int threads_;
  std::map<std::string, std::string> model_paths_;
  std::map<std::string, std::uint64_t> model_hashes_;
  std::map<std::string, std::string> shown_models_;
  nlohmann::json manifest_;
  int jobs_ = 1;
  bool forgotten_ = false;  // --force already applied (before the parallel MARL runs)

  Config resolve(const std::vector<std::string>& sets) const {
    // --threads first, so an experiment may pin its own (the latency figure runs on one core).
    std::vector<std::string> all = {"run.threads=" + std::to_string(threads_)};
    all.insert(all.end(), sets.begin(), sets.end());
    all.insert(all.end(), opt_.sets.begin(), opt_.sets.end());
    return resolve_config(std::nullopt, all);
  }
  Config base(const ExperimentSpec& s, const std::vector<std::string>& extra = {}) const {
    std::vector<std::string> sets = s.set;
    Config c = resolve(sets);
    for (const auto& e : extra) apply_override(c, e);
    finalise(c);
    // The environment's oracle and the MARL runs use this run's models.
    if (auto it = model_paths_.find(c.env.oracle); it != model_paths_.end())
      c.env.oracle = model_labels().at(c.env.oracle).base + "=" + it->second;
    return c;
  }
  std::uint64_t oracle_hash(const Config& c) const {
    for (const auto& [label, path] : model_paths_)
      if (c.env.oracle == model_labels().at(label).base + "=" + path) return model_hashes_.at(label);
    return 0;
  }

  void forget(const ExperimentSpec& s) {
    // Pieces of this experiment: its directory; MARL runs are shared, so only the ones it names.
    std::error_code ec;
    if (s.kind == "models") {
      fs::remove_all(out_ / "models", ec);
    } else {
      for (const auto& dir : marl_dirs(s)) fs::remove_all(dir, ec);
      for (const auto& dir : eval_dirs(s)) fs::remove_all(dir, ec);
    }
    fs::remove_all(out_ / s.name, ec);
  }

  nlohmann::json stage(const ExperimentSpec& s) {
    if (s.kind == "models") return models(s);
    if (s.kind == "beamform_sweep") return sweep(s);
    if (s.kind == "marl_training") return marl_training(s);
    if (s.kind == "planning_users") return planning_users(s);
    return trajectories(s);
  }

  void eta(const std::string& what, std::size_t done, std::size_t total, double elapsed, double computed_s,
           std::size_t computed) {
    const double per = computed ? computed_s / static_cast<double>(computed) : 0.0;
    log_ << fmt::format("  {} {}/{} ({:.0f} s{})\n", what, done, total, elapsed,
                        computed && done < total ? fmt::format(", ETA {:.0f} s", per * static_cast<double>(total - done)) : "")
         << std::flush;
  }

  // --- models -------------------------------------------------------------------------------
  nlohmann::json models(const ExperimentSpec& s) {
    nlohmann::json files = nlohmann::json::array();
    std::string csv = "experiment,seed,model,source,path,best_val_sum_rate,epoch,parameters\n";
    for (const auto& label : s.models) {
      Config cfg = base(s, model_labels().at(label).sets);
      const fs::path shipped = fs::path(source_dir()) / "models" / label;
      std::string path, source;
      if (s.reuse_shipped && fs::exists(shipped / "model.pt") && fs::exists(shipped / "config.toml")) {
        Config trained;
        apply_toml(trained, read_file((shipped / "config.toml").string()), (shipped / "config.toml").string());
        trained.run.threads = cfg.run.threads;
        if (training_key(trained) == training_key(cfg)) path = (shipped / "model.pt").string(), source = "shipped";
      }
      if (path.empty()) {
        const fs::path dir = out_ / "models" / fmt::format("{}-{}", label, hex(hash_text(training_key(cfg))).substr(0, 12));
        path = (dir / "model.pt").string();
        if (fs::exists(dir / "test.json")) {
          source = "cached";
        } else {
          log_ << "  training " << label << " in " << dir.string() << "\n" << std::flush;
          TrainOptions t;
          t.out_dir = dir.string();
          t.resume = fs::exists(dir / "last.pt");
          t.force = !t.resume;  // the cache's own directory: a run killed before its first checkpoint restarts
          t.progress = &log_;
          // One torch thread, whatever --threads: a float sum split over other threads rounds
          // differently and trains another model, and the cache key (like a --force rerun with
          // other --threads) must name one model.
          Config one = cfg;
          one.run.threads = 1;
          train_beamformer(one, t);
          source = "trained";
        }
      }
      set_torch_threads(1);
      const auto model = LearnedBeamformer::load(path, cfg);
      model_paths_[label] = fs::absolute(path).string();
      model_hashes_[label] = hash_text(read_file(path, "model"));
      // Shown relative to the source tree or the run directory when under them.
      std::string shown = model_paths_[label];
      for (const fs::path& root : {fs::absolute(source_dir()), fs::absolute(out_)}) {
        const auto rel = fs::path(shown).lexically_relative(root.lexically_normal());
        if (!rel.empty() && rel.native().rfind("..", 0) != 0) {
          shown = (root == fs::absolute(out_) ? "" : "<source>/") + rel.string();
          break;
        }
      }
      shown_models_[label] = shown;
      csv += fmt::format("{},{},{},{},{},{},{},{}\n", s.name, cfg.run.seed, label, source, shown,
                         format_double(model->info().best_val_sum_rate), model->info().epoch, model->info().parameters);
      log_ << fmt::format("  {}: {} ({})\n", label, source, path) << std::flush;
    }
    write_file_atomic((out_ / s.name / "models.csv").string(), csv);
    files.push_back(s.name + "/models.csv");
    return files;
  }

  // --- beamforming sweeps -----------------------------------------------------------------------
  nlohmann::json sweep(const ExperimentSpec& s) {
    // Learned labels become "base=path"; the CSV keeps the label.
    std::vector<std::string> specs;
    std::uint64_t mh = hash_text(fmt::format("{}|{}", s.samples, s.seed));
    for (const auto& m : s.methods) {
      if (auto it = model_paths_.find(m); it != model_paths_.end()) {
        specs.push_back(model_labels().at(m).base + "=" + it->second);
        mh = hash_text(fmt::format("{}:{}", m, model_hashes_.at(m)), mh);
      } else {
        if (model_labels().count(m)) throw InputError(s.path + ": method '" + m + "' needs the models stage to list it");
        specs.push_back(m);
        mh = hash_text(m, mh);
      }
    }
    std::string samples, summary;
    std::size_t computed = 0;
    double computed_s = 0;
    const auto t0 = Clock::now();
    set_torch_threads(1);  // decisions are timed on one core each; snapshots run in parallel
    for (std::size_t i = 0; i < s.values.size(); ++i) {
      const std::string v = fmt_value(s.values[i]);
      const Config cfg = base(s, {s.sweep + "=" + v});
      const std::string id = fmt::format("{}-{}", v, hex(hash_text(config_key(cfg), mh)).substr(0, 12));
      const fs::path raw = out_ / s.name / "points" / (id + ".csv");
      const fs::path sum = out_ / s.name / "points" / (id + ".summary.csv");
      const bool cached = fs::exists(sum);
      if (!cached) {
        const auto tp = Clock::now();
        BeamformEvalOptions o;
        o.methods = specs;
        o.uavs = cfg.scenario.uavs;
        o.users = cfg.scenario.users;
        o.samples = static_cast<std::size_t>(s.samples);
        o.seed = s.seed;
        o.threads = cfg.run.threads;
        auto rows = run_beamform_eval(cfg, o, builtin_beamformers(), &log_);
        for (auto& r : rows)
          for (std::size_t m = 0; m < specs.size(); ++m)
            if (r.method == specs[m]) r.method = s.methods[m];
        std::string ps = "seed,experiment,x_name,x,method,samples,mean,std,sem,median_latency_ms,mean_latency_ms\n";
        for (const auto& m : summarise(rows))
          ps += fmt::format("{},{},{},{},{},{},{},{},{},{},{}\n", s.seed, s.name, s.sweep, v, m.method, m.samples,
                            format_double(m.mean), format_double(m.std),
                            format_double(m.samples > 1 ? m.std / std::sqrt(static_cast<double>(m.samples)) : 0.0),
                            format_double(m.median_latency_ms), format_double(m.mean_latency_ms));
        write_file_atomic((raw.string()), beamform_eval_csv(rows, cfg));
        write_file_atomic(sum.string(), ps);  // last: its presence marks the point done
        computed_s += since(tp);
        ++computed;
      }
      const std::string r = read_file(raw.string()), m = read_file(sum.string());
      if (samples.empty()) samples = header(r) + "\n";
      if (summary.empty()) summary = header(m) + "\n";
      samples += body(r);
      summary += body(m);
      eta(s.sweep + " = " + v + (cached ? " (cached)" : ""), i + 1, s.values.size(), since(t0),
          computed_s, computed);
    }
    write_file_atomic((out_ / s.name / "samples.csv").string(), samples);
    write_file_atomic((out_ / s.name / (s.name + ".csv")).string(), summary);
    return {s.name + "/" + s.name + ".csv", s.name + "/samples.csv"};
  }

  // --- MARL ------------------------------------------------------------------------------------
  static bool trained(const fs::path& dir) { return fs::exists(dir / "train.json") && fs::exists(dir / "policy.pt"); }

  /// Trains every MARL run the selected experiments need that is not done yet, `jobs` at a time,
  /// each as a child `skyloop train` process on one thread (the models stage has run by now).
  void prefetch_marl(const std::vector<const ExperimentSpec*>& selected) {
    if (opt_.force)
      for (const auto* s : selected)
        if (s->kind != "models") forget(*s);
    forgotten_ = true;
    if (jobs_ <= 1) return;
    std::vector<Config> need;
    std::vector<fs::path> dirs;
    for (const auto* s : selected) {
      if (s->kind == "models" || s->kind == "beamform_sweep") continue;
      const std::vector<int> ks = s->kind == "marl_training" ? std::vector<int>{base(*s).scenario.users} : s->users;
      const auto algos = s->kind == "trajectories" ? std::vector<std::string>{s->algos.front()} : s->algos;
      const auto seeds = s->kind == "trajectories" ? std::vector<std::uint64_t>{s->seeds.front()} : s->seeds;
      for (int k : ks)
        for (const auto& a : algos)
          for (auto seed : seeds) {
            const Config cfg = run_config(*s, a, seed, k);
            const fs::path dir = run_dir(cfg);
            if (trained(dir) || std::find(dirs.begin(), dirs.end(), dir) != dirs.end()) continue;
            need.push_back(cfg);
            dirs.push_back(dir);
          }
    }
    if (need.empty()) return;
    const std::string exe = fs::read_symlink("/proc/self/exe").string();
    log_ << fmt::format("training {} MARL runs, {} at a time (logs: <run>/train.log)\n", need.size(), jobs_) << std::flush;
    std::mutex mu;
    std::size_t next = 0, done = 0;
    double busy = 0;
    std::vector<std::string> failed;
    const auto t0 = Clock::now();
    auto worker = [&] {
      for (;;) {
        std::size_t i;
        {
          std::lock_guard<std::mutex> lock(mu);
          if (next >= need.size()) return;
          i = next++;
        }
        const Config& cfg = need[i];
        const fs::path& dir = dirs[i];
        write_file_atomic((dir / "request.toml").string(), to_toml(cfg));
        std::vector<std::string> argv = {exe, "train", "--config", (dir / "request.toml").string(), "--out", dir.string()};
        argv.push_back(fs::exists(dir / "last.pt") ? "--resume" : "--force");
        const auto tr = Clock::now();
        const int rc = run_process(argv, (dir / "train.log").string());
        const double sec = since(tr);
        std::lock_guard<std::mutex> lock(mu);
        if (rc != 0) {
          failed.push_back(fmt::format("{} (exit status {})", (dir / "train.log").string(), rc));
          continue;
        }
        nlohmann::json j = {{"seconds", sec},
                            {"steps_per_second", static_cast<double>(cfg.marl.total_steps) / sec},
                            {"env_steps", cfg.marl.total_steps},
                            {"process", true}};
        write_file_atomic((dir / "train.json").string(), j.dump(2) + "\n");
        busy += sec;
        ++done;
        const double per = busy / static_cast<double>(done) / static_cast<double>(jobs_);
        log_ << fmt::format("  {} K = {} seed {}: {:.0f} s ({}/{}, {:.0f} s elapsed{})\n", cfg.marl.algo, cfg.scenario.users,
                            cfg.run.seed, sec, done, need.size(), since(t0),
                            done < need.size() ? fmt::format(", ETA {:.0f} s", per * static_cast<double>(need.size() - done)) : "")
             << std::flush;
      }
    };
    std::vector<std::thread> pool;
    for (int j = 0; j < jobs_; ++j) pool.emplace_back(worker);
    for (auto& t : pool) t.join();
    if (!failed.empty())
      throw std::runtime_error(fmt::format("{} of {} MARL runs failed; see {}", failed.size(), need.size(), failed.front()));
  }

  Config run_config(const ExperimentSpec& s, const std::string& algo, std::uint64_t seed, int users) const {
    // One thread per run (results do not depend on the core count); runs go in parallel instead.
    return base(s, {"marl.algo=" + algo, "run.seed=" + std::to_string(seed), "marl.total_steps=" + std::to_string(s.steps),
                    "scenario.users=" + std::to_string(users), "run.threads=1"});
  }
  fs::path run_dir(const Config& cfg) const {
    return out_ / "runs" /
           fmt::format("{}_K{}_s{}-{}", cfg.marl.algo, cfg.scenario.users, cfg.run.seed,
                       hex(hash_text(config_key(cfg), oracle_hash(cfg))).substr(0, 12));
  }
  std::vector<fs::path> marl_dirs(const ExperimentSpec& s) const {
    std::vector<fs::path> dirs;
    if (s.kind == "models" || s.kind == "beamform_sweep") return dirs;
    const std::vector<int> ks = s.kind == "marl_training" ? std::vector<int>{base(s).scenario.users} : s.users;
    for (int k : ks)
      for (const auto& a : s.algos)
        for (auto seed : s.seeds) dirs.push_back(run_dir(run_config(s, a, seed, k)));
    return dirs;
  }

  /// The shared planner evaluations an experiment reads (see eval_dir()).
  std::vector<fs::path> eval_dirs(const ExperimentSpec& s) const {
    std::vector<fs::path> dirs;
    if (s.kind == "marl_training" && !s.planners.empty()) dirs.push_back(eval_dir(s, base(s), "planners", s.planners));
    if (s.kind == "planning_users" && !s.planners.empty())
      for (int k : s.users) dirs.push_back(eval_dir(s, base(s, {"scenario.users=" + std::to_string(k)}), "planners", s.planners));
    if (s.kind == "trajectories")
      for (int k : s.users)
        dirs.push_back(eval_dir(s, run_config(s, s.algos.front(), s.seeds.front(), k),
                                s.algos.front() + "_s" + std::to_string(s.seeds.front()), s.planners));
    return dirs;
  }

  struct RunInfo {
    fs::path dir;
    double seconds = 0, steps_per_second = 0;
    bool computed = false;
  };
  /// train(), adding its time to the stage's ETA estimate when it computed something.
  RunInfo train_timed(const Config& cfg, double& computed_s, std::size_t& computed) {
    const auto t0 = Clock::now();
    RunInfo info = train(cfg);
    if (info.computed) computed_s += since(t0), ++computed;
    return info;
  }

  RunInfo train(const Config& cfg) {
    RunInfo info;
    info.dir = run_dir(cfg);
    const fs::path done = info.dir / "train.json";
    if (!fs::exists(done) || !fs::exists(info.dir / "policy.pt")) {
      log_ << fmt::format("  training {} (K = {}, seed {}, {} steps) in {}\n", cfg.marl.algo, cfg.scenario.users,
                          cfg.run.seed, cfg.marl.total_steps, info.dir.string())
           << std::flush;
      set_torch_threads(cfg.run.threads);
      MarlTrainOptions t;
      t.out_dir = info.dir.string();
      t.resume = fs::exists(info.dir / "last.pt");
      t.force = !t.resume;
      t.progress = &log_;
      t.registry = &builtin_beamformers();
      const auto r = train_marl(cfg, t);
      nlohmann::json j = {{"seconds", r.seconds}, {"steps_per_second", r.steps_per_second}, {"env_steps", r.env_steps},
                          {"resumed", t.resume}};
      write_file_atomic(done.string(), j.dump(2) + "\n");
      info.computed = true;
    }
    const auto j = nlohmann::json::parse(read_file(done.string()));
    info.seconds = j.at("seconds").get<double>();
    info.steps_per_second = j.at("steps_per_second").get<double>();
    return info;
  }

  /// Runs planners and/or a policy on the users of cfg (seed marl.users_seed) into `dir`, once.
  std::string evaluate(const Config& cfg, const fs::path& dir, const std::vector<std::string>& planners,
                       const fs::path& policy) {
    if (!fs::exists(dir / "summary.csv")) {
      PlanOptions p;
      p.planners = planners;
      p.seed = cfg.marl.users_seed;
      p.out_dir = dir.string();
      if (!policy.empty()) p.extra.push_back(std::shared_ptr<Planner>(MarlPolicy::load(policy.string())));
      set_torch_threads(1);
      std::ostringstream quiet;
      std::vector<double> seconds;
      run_planners(cfg, p, builtin_beamformers(), &quiet, &seconds);
    }
    return read_file((dir / "summary.csv").string());
  }
  fs::path eval_dir(const ExperimentSpec& s, const Config& cfg, const std::string& what,
                    const std::vector<std::string>& planners) const {
    std::string key = config_key(cfg);
    for (const auto& p : planners) key += "|" + p;
    (void)s;  // shared between experiments: the same planners on the same users run once
    return out_ / "evals" /
           fmt::format("{}_K{}-{}", what, cfg.scenario.users, hex(hash_text(key, oracle_hash(cfg))).substr(0, 12));
  }

  nlohmann::json marl_training(const ExperimentSpec& s) {
    const int k = base(s).scenario.users;
    std::string curves, finals =
        "experiment,algo,train_seed,users,users_seed,objective,T,success,arrivals,collisions,boundary_events,reward,"
        "train_seconds,steps_per_second\n";
    const std::size_t total = s.algos.size() * s.seeds.size();
    std::size_t done = 0, computed = 0;
    double computed_s = 0;
    const auto t0 = Clock::now();
    for (const auto& algo : s.algos)
      for (auto seed : s.seeds) {
        const Config cfg = run_config(s, algo, seed, k);
        const RunInfo info = train_timed(cfg, computed_s, computed);
        const std::string m = read_file((info.dir / "metrics.csv").string());
        if (curves.empty()) curves = "algo,users," + header(m) + "\n";
        curves += prefixed(m, fmt::format("{},{},", algo, k));
        const std::string e = evaluate(cfg, info.dir / "eval", {}, info.dir);
        for (const std::string& line : lines(body(e))) {
          const auto f = split(line);  // seed,planner,objective,T,success,arrivals,collisions,boundary_events,reward,seconds
          finals += fmt::format("{},{},{},{},{},{},{},{},{},{},{},{},{},{}\n", s.name, algo, seed, k, f[0], f[2], f[3], f[4],
                                f[5], f[6], f[7], f[8], format_double(info.seconds), format_double(info.steps_per_second));
        }
        eta(fmt::format("{} seed {}{}", algo, seed, info.computed ? "" : " (ready)"), ++done, total, since(t0), computed_s,
            computed);
      }
    // The heuristic references on the same users.
    std::string refs = "experiment,users,users_seed,planner,objective,T,success,arrivals,collisions,boundary_events,reward,seconds\n";
    if (!s.planners.empty()) {
      const Config cfg = base(s);
      const std::string e = evaluate(cfg, eval_dir(s, cfg, "planners", s.planners), s.planners, {});
      for (const std::string& line : lines(body(e))) refs += fmt::format("{},{},{}\n", s.name, k, line);
    }
    write_file_atomic((out_ / s.name / "curves.csv").string(), curves);
    write_file_atomic((out_ / s.name / (s.name + ".csv")).string(), finals);
    write_file_atomic((out_ / s.name / "references.csv").string(), refs);
    return {s.name + "/" + s.name + ".csv", s.name + "/curves.csv", s.name + "/references.csv"};
  }

  nlohmann::json planning_users(const ExperimentSpec& s) {
    std::string out = "experiment,users,planner,train_seed,users_seed,objective,T,success,arrivals,collisions,boundary_events,reward\n";
    const std::size_t total = s.users.size() * (1 + s.algos.size() * s.seeds.size());
    std::size_t done = 0, computed = 0;
    double computed_s = 0;
    const auto t0 = Clock::now();
    auto add = [&](int k, const std::string& train_seed, const std::string& summary) {
      for (const std::string& line : lines(body(summary))) {
        const auto f = split(line);
        out += fmt::format("{},{},{},{},{},{},{},{},{},{},{},{}\n", s.name, k, f[1], train_seed, f[0], f[2], f[3], f[4], f[5],
                           f[6], f[7], f[8]);
      }
    };
    for (int k : s.users) {
      if (!s.planners.empty()) {
        const Config cfg = base(s, {"scenario.users=" + std::to_string(k)});
        const auto tp = Clock::now();
        const fs::path dir = eval_dir(s, cfg, "planners", s.planners);
        const bool cached = fs::exists(dir / "summary.csv");
        add(k, "", evaluate(cfg, dir, s.planners, {}));
        if (!cached) computed_s += since(tp), ++computed;
      }
      eta(fmt::format("K = {} planners", k), ++done, total, since(t0), computed_s, computed);
      for (const auto& algo : s.algos)
        for (auto seed : s.seeds) {
          const Config cfg = run_config(s, algo, seed, k);
          const RunInfo info = train_timed(cfg, computed_s, computed);
          add(k, std::to_string(seed), evaluate(cfg, info.dir / "eval", {}, info.dir));
          eta(fmt::format("K = {} {} seed {}{}", k, algo, seed, info.computed ? "" : " (ready)"), ++done, total, since(t0),
              computed_s, computed);
        }
    }
    write_file_atomic((out_ / s.name / (s.name + ".csv")).string(), out);
    return {s.name + "/" + s.name + ".csv"};
  }

  nlohmann::json trajectories(const ExperimentSpec& s) {
    std::string traj, users, summary;
    const std::size_t total = s.users.size();
    std::size_t done = 0, computed = 0;
    double computed_s = 0;
    const auto t0 = Clock::now();
    for (int k : s.users) {
      const auto seed = s.seeds.front();
      const Config cfg = run_config(s, s.algos.front(), seed, k);
      const auto tr = Clock::now();
      const RunInfo info = train(cfg);
      const fs::path dir = eval_dir(s, cfg, s.algos.front() + "_s" + std::to_string(seed), s.planners);
      const bool cached = fs::exists(dir / "summary.csv");
      const std::string e = evaluate(cfg, dir, s.planners, info.dir);
      if (info.computed || !cached) computed_s += since(tr), ++computed;
      const std::string t = read_file((dir / "trajectory.csv").string()), u = read_file((dir / "users.csv").string());
      if (traj.empty()) {
        traj = "experiment,users,train_seed," + header(t) + "\n";
        users = "experiment,users," + header(u) + "\n";
        summary = "experiment,users,train_seed," + header(e) + "\n";
      }
      traj += prefixed(t, fmt::format("{},{},{},", s.name, k, seed));
      users += prefixed(u, fmt::format("{},{},", s.name, k));
      summary += prefixed(e, fmt::format("{},{},{},", s.name, k, seed));
      eta(fmt::format("K = {}", k), ++done, total, since(t0), computed_s, computed);
    }
    // Starts and destinations for the plots.
    const Config c = base(s);
    std::string ends = "experiment,seed,uav,start_x,start_y,dest_x,dest_y\n";  // seed: the users seed of the plots
    for (std::size_t n = 0; n < c.trajectory.starts.size(); ++n)
      ends += fmt::format("{},{},{},{},{},{},{}\n", s.name, c.marl.users_seed, n, format_double(c.trajectory.starts[n].x),
                          format_double(c.trajectory.starts[n].y), format_double(c.trajectory.destinations[n].x),
                          format_double(c.trajectory.destinations[n].y));
    write_file_atomic((out_ / s.name / (s.name + ".csv")).string(), traj);
    write_file_atomic((out_ / s.name / "users.csv").string(), users);
    write_file_atomic((out_ / s.name / "summary.csv").string(), summary);
    write_file_atomic((out_ / s.name / "endpoints.csv").string(), ends);
    return {s.name + "/" + s.name + ".csv", s.name + "/users.csv", s.name + "/summary.csv", s.name + "/endpoints.csv"};
  }

  static std::vector<std::string> lines(const std::string& text) {
    std::vector<std::string> out;
    std::istringstream in(text);
    for (std::string line; std::getline(in, line);)
      if (!line.empty()) out.push_back(line);
    return out;
  }
  static std::vector<std::string> split(const std::string& line) {
    std::vector<std::string> f;
    std::string cur;
    for (char ch : line) {
      if (ch == ',') f.push_back(cur), cur.clear();
      else cur += ch;
    }
    f.push_back(cur);
    return f;
  }
};

}  // namespace

int reproduce(const ReproduceOptions& o) {
  ReproduceOptions opt = o;
  if (opt.profile != "quick" && opt.profile != "paper" && opt.profile != "tiny")
    throw InputError("--profile '" + opt.profile + "' is unknown: allowed quick, paper, tiny");
  if (opt.threads < 0 || opt.threads > 1024)
    throw InputError("--threads = " + std::to_string(opt.threads) + " is out of range: allowed an integer in [0, 1024] (0 = all cores)");
  if (opt.jobs < 0 || opt.jobs > 1024)
    throw InputError("--jobs = " + std::to_string(opt.jobs) + " is out of range: allowed an integer in [0, 1024] (0 = --threads)");
  if (opt.out_dir.empty()) opt.out_dir = "results/" + opt.profile;
  check_output_dir(opt.out_dir);
  if (opt.experiments_dir.empty()) opt.experiments_dir = (fs::path(source_dir()) / "configs" / "experiments").string();
  const auto specs = load_experiments(opt.experiments_dir, opt.profile);
  Runner(opt).run(specs);
  if (!opt.plots) return 0;
  const std::string script = (fs::path(source_dir()) / "scripts" / "plot_figures.py").string();
  const std::string cmd = fmt::format("'{}' '{}' '{}'", opt.python, script, opt.out_dir);
  if (opt.progress) *opt.progress << "plots and report: " << cmd << "\n" << std::flush;
  const int rc = run_process({opt.python, script, opt.out_dir});
  if (rc != 0) throw std::runtime_error("the plot step failed (" + cmd + "); the CSVs under " + opt.out_dir + " are complete");
  return 0;
}

}  // namespace skyloop
