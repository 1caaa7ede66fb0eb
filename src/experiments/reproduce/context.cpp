#include "context.hpp"

#include <chrono>
#include <cmath>
#include <fstream>
#include <mutex>
#include <fmt/format.h>

#include "skyloop/marl/learners.hpp"
#include "skyloop/core/config_io.hpp"
#include "skyloop/core/error.hpp"
#include "skyloop/core/io.hpp"
#include "skyloop/env/dynamics.hpp"
#include "skyloop/experiments/builtin.hpp"
#include "skyloop/experiments/planning_run.hpp"
#include "skyloop/marl/marl.hpp"
#include "skyloop/nn/learned.hpp"
#include "../../nn/fast_gemm.hpp"

namespace skyloop::repro {

double since(Clock::time_point t0) { return std::chrono::duration<double>(Clock::now() - t0).count(); }

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

StageContext::StageContext(const ReproduceOptions& o, std::ostream& l, int t)
    : opt(o), out(o.out_dir), log(l.rdbuf()), threads(t), cache(o.out_dir) {}

Config StageContext::resolve(const ExperimentSpec& s) const {
  // --threads first, so an experiment may pin its own (the latency figure runs on one core).
  return resolve_experiment(s, {"run.threads=" + std::to_string(threads)}, opt.sets);
}

Config StageContext::base(const ExperimentSpec& s, const std::vector<std::string>& extra) const {
  Config c = resolve(s);
  for (const auto& e : extra) apply_override(c, e);
  finalise(c);
  finalise_users_file(c);
  // The environment's oracle and the MARL runs use this run's models.
  if (auto it = model_paths.find(c.env.oracle); it != model_paths.end())
    c.env.oracle = model_labels().at(c.env.oracle).base + "=" + it->second;
  return c;
}

std::uint64_t StageContext::oracle_hash(const Config& c) const {
  for (const auto& [label, path] : model_paths)
    if (c.env.oracle == model_labels().at(label).base + "=" + path) return model_hashes.at(label);
  return 0;
}

Config StageContext::run_config(const ExperimentSpec& s, const std::string& algo, std::uint64_t seed, int users) const {
  // One thread per run (results do not depend on the core count); runs go in parallel instead.
  return base(s, {"marl.algo=" + algo, "run.seed=" + std::to_string(seed), "marl.total_steps=" + std::to_string(s.steps),
                  "scenario.users=" + std::to_string(users), "run.threads=1"});
}

fs::path StageContext::run_dir(const Config& cfg) const {
  return out / "runs" /
         fmt::format("{}_K{}_s{}-{}", cfg.marl.algo, cfg.scenario.users, cfg.run.seed,
                     hex(hash_text(config_key(cfg), oracle_hash(cfg))).substr(0, 12));
}

fs::path StageContext::eval_dir(const Config& cfg, const std::string& what, const std::vector<std::string>& planners) const {
  // Shared between experiments: the same planners on the same users run once.
  std::string key = config_key(cfg);
  for (const auto& p : planners) key += "|" + p;
  return out / "evals" / fmt::format("{}_K{}-{}", what, cfg.scenario.users, hex(hash_text(key, oracle_hash(cfg))).substr(0, 12));
}

namespace {
bool trained(const fs::path& dir) { return fs::exists(dir / "train.json") && fs::exists(dir / "policy.pt"); }

/// Runs planners and/or a policy on the users of cfg (seed marl.users_seed) into `dir`.
void evaluate(const Config& cfg, const fs::path& dir, const std::vector<std::string>& planners, const fs::path& policy) {
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

// Rough seconds on one core (the farm's order, --plan, the ETA, --time-limit; never a result),
// fitted to the paper profile's 63 runs in results/paper/timings.csv on a 2-core AMD EPYC VM
// with AVX2 (2026-12-05/06, two at a time, one thread each, 2e6 steps): per environment step at
// N = 3, MAPPO / IPPO 4e-5 s on the fast backend (K = 12: 77-98 s; 10x that on marl.backend =
// torch), VDN 4.2e-5 and QMIX 5.7e-5 (LibTorch; 94-95 s and 123-126 s), growing as N^1.3, plus
// 2.9e-7 per user (K = 8: 86-87 s, K = 24: 93-99 s; N = 16, K = 400: 897-931 s); the set encoder,
// its validation layouts and the larger networks it feeds add 1.4e-4 (354-431 s with the GNN as
// the oracle and new users every episode; 241-245 s behind WMMSE), its move gains
// (marl.lookahead) 8e-5 and each cell of its radio map 1e-5 (marl.rate_map = 3 and the UAVs in
// turn: 1,005-1,008 s), all three growing as N^1.4 above N = 3 (fleet16-v1's recipe, N = 16,
// K = 400, set encoder, move gains and the UAVs in turn: 1,702-1,727 s at 6e5 steps, 2026-12-06;
// at N = 2 they cost what they do at 3); the shared spectrum's interference-aware oracle 6e-6 (84-134 s beside
// 77-126 s); velocity commands 7e-5, growing as N^1.3 (positions off the lattice rarely repeat,
// so the oracle's rate cache seldom holds them: continuous-v1's recipe, N = 3, set encoder, took
// 469-573 s, two at a time, against 370-404 s estimated on the lattice, 2026-12-06); plus 3 s per
// run for the child process's start, its models and the policy's last evaluation. Where the
// kernels run on AVX-512, 0.7x (the AVX-512 VM trained the quick profile's 16 runs in 720 s two
// at a time, 2026-12-01).
constexpr double kMarlRunSetup = 3.0;
double marl_machine() {
  static const double f = nn::fast::kernel_isa() == "avx512" ? 0.7 : 1.0;
  return f;
}
double marl_cost(const Config& cfg) {
  const auto& m = cfg.marl;
  const auto& learner = find_learner(m.algo);
  const double base = learner.core == LearnerInfo::Core::ValueDecomposition ? (m.algo == "qmix" ? 5.7e-5 : 4.2e-5)
                      : m.backend == PpoBackend::Torch                    ? 4e-4
                                                                           : 4e-5;
  const bool set = m.encoder == ObservationKind::Set;
  const double cells = 2.0 * m.rate_map * (m.rate_map + 1);
  const double fleet = std::max(1.0, cfg.scenario.uavs / 3.0);
  const double per_step = base * std::pow(cfg.scenario.uavs / 3.0, 1.3) + 2.9e-7 * cfg.scenario.users +
                          (set ? (1.4e-4 + (m.lookahead ? 8e-5 : 0.0) + 1e-5 * cells) * std::pow(fleet, 1.4) : 0.0) +
                          (cfg.channel.spectrum == Spectrum::Shared ? 6e-6 : 0.0) +
                          (make_dynamics(cfg)->commands_velocities() ? 7e-5 * std::pow(cfg.scenario.uavs / 3.0, 1.3) : 0.0);
  return kMarlRunSetup + marl_machine() * per_step * static_cast<double>(m.total_steps);
}
/// The exact optimum of one layout: about 0.3 s per user on the paper's grid (1.77e6 joint
/// states; `skyloop plan --planner optimal --users 12`: 3.8 s on the AVX2 VM, 2026-11-26), in
/// proportion to the joint states; one shared-spectrum network per state (the interference-aware GNN's
/// fused pass, its user and edge rows from its caches) costs about 28x more (`--set
/// channel.spectrum=shared --set run.threads=1 --oracle ignn=models/ignn_structured` on
/// configs/generalise.toml at K = 12, seed 3, 2026-12-05 on a 2-core AVX2 VM: 155 s of CPU against
/// 5.7 s under orthogonal bands; 241 s without the row caches, 642 s served by LibTorch).
double dp_cost(const Config& cfg, int users) {
  const double cells = (std::floor(cfg.scenario.area_x_m / cfg.trajectory.d_fly_m) + 1) *
                       (std::floor(cfg.scenario.area_y_m / cfg.trajectory.d_fly_m) + 1);
  const double states = std::pow(cells, static_cast<double>(cfg.trajectory.starts.size())) / std::pow(121.0, 3);
  return 0.3 * users * states * (cfg.channel.spectrum == Spectrum::Shared ? 28.0 : 1.0) + 0.3;
}
double planner_cost(const Config& cfg, const std::string& p) {
  const double shared = cfg.channel.spectrum == Spectrum::Shared ? 3.0 : 1.0;
  if (p == "optimal") return dp_cost(cfg, cfg.scenario.users);
  if (p == "greedy") return 0.1 * shared;
  return 0.05;
}

std::string id_of(const fs::path& p, const fs::path& root) { return p.lexically_relative(root).generic_string(); }
}  // namespace

std::string restart_note(const fs::path& dir) {
  return "  " + dir.string() +
         ": an interrupted MARL run starts again from its first step (a resumed run would not give the numbers of an "
         "uninterrupted one: the environments' episodes are not checkpointed)\n";
}

Piece StageContext::marl_piece(const Config& cfg) const {
  Piece p;
  const fs::path dir = run_dir(cfg);
  p.id = id_of(dir, out);
  p.kind = "marl";
  p.label = fmt::format("{} K={} seed {}", cfg.marl.algo, cfg.scenario.users, cfg.run.seed);
  p.cost = marl_cost(cfg);
  p.train_config = cfg;
  p.done = [this, dir, id = p.id] { return trained(dir) && fs::exists(dir / "eval" / "summary.csv") && cache.sealed(id); };
  p.run = [this, cfg, dir] {
    if (!trained(dir)) {
      log << fmt::format("  training {} (K = {}, seed {}, {} steps) in {}\n", cfg.marl.algo, cfg.scenario.users, cfg.run.seed,
                         cfg.marl.total_steps, dir.string())
          << std::flush;
      MarlTrainOptions t;
      t.out_dir = dir.string();
      t.force = true;  // an interrupted run starts again (see restart_note)
      if (fs::exists(dir / "last.pt")) log << restart_note(dir) << std::flush;
      t.progress = &log;
      t.registry = &builtin_beamformers();
      const auto r = train_marl(cfg, t);
      nlohmann::json j = {{"seconds", r.seconds}, {"steps_per_second", r.steps_per_second}, {"env_steps", r.env_steps}};
      write_file_atomic((dir / "train.json").string(), j.dump(2) + "\n");
    }
    evaluate(cfg, dir / "eval", {}, dir);
  };
  return p;
}

Piece StageContext::eval_piece(const Config& cfg, const fs::path& dir, const std::vector<std::string>& planners,
                               const fs::path& policy_run, const Config* train) const {
  const Config train_cfg = train ? *train : cfg;
  Piece p;
  p.id = id_of(dir, out);
  p.kind = "eval";
  std::string names;
  for (const auto& n : planners) names += (names.empty() ? "" : "+") + n;
  p.label = fmt::format("{} K={}{}", names, cfg.scenario.users, policy_run.empty() ? "" : " + policy");
  for (const auto& n : planners) p.cost += planner_cost(cfg, n);
  if (!policy_run.empty()) p.deps.push_back(id_of(policy_run, out));
  p.done = [this, dir, id = p.id] { return fs::exists(dir / "summary.csv") && cache.sealed(id); };
  p.run = [this, cfg, dir, planners, policy_run, train_cfg] {
    if (!policy_run.empty()) ensure(marl_piece(train_cfg));
    evaluate(cfg, dir, planners, policy_run);
  };
  return p;
}

std::string StageContext::id(const fs::path& dir) const { return id_of(dir, out); }

Piece StageContext::layouts_piece(const Config& cfg, const fs::path& dir, const LayoutEvalOptions& o, const Config* train,
                                  std::vector<std::string> deps, std::vector<Piece> optima) const {
  for (const auto& q : optima) deps.push_back(q.id);
  const fs::path policy_run = train ? run_dir(*train) : fs::path();
  const Config train_cfg = train ? *train : cfg;
  Piece p;
  p.id = id_of(dir, out);
  p.kind = "eval";
  p.label = fmt::format("{} layouts K={}{}", o.layouts, cfg.scenario.users, policy_run.empty() ? "" : " policy");
  // The optima are the cost unless a dependency solved them (dp_cost per layout; K of a sampled
  // layout taken at the middle of its range), plus about 0.05 s per layout for the planners and
  // 0.15 s per layout for a policy's rollout (N = 3, BENCHMARKS "Decision-time rollout").
  const int k = cfg.env.users_min && cfg.env.users_max ? (cfg.env.users_min + cfg.env.users_max) / 2 : cfg.scenario.users;
  p.cost = (0.05 + (o.rollout ? 0.15 : 0.0)) * o.layouts + (deps.empty() ? dp_cost(cfg, k) * o.layouts : 0.0);
  if (!policy_run.empty()) deps.push_back(id_of(policy_run, out));
  p.deps = std::move(deps);
  p.done = [this, dir, id = p.id] { return fs::exists(dir / "summary.csv") && cache.sealed(id); };
  p.run = [this, cfg, dir, o, policy_run, train_cfg, optima = std::move(optima)] {
    for (const auto& q : optima) ensure(q);
    if (!policy_run.empty()) ensure(marl_piece(train_cfg));
    LayoutEvalOptions e = o;
    if (!policy_run.empty()) e.policies = {(policy_run / "policy.pt").string()};
    e.cache_dir = (out / "optima").string();
    e.threads = 1;
    const auto rows = evaluate_layouts(cfg, e, builtin_beamformers(), nullptr);
    fs::create_directories(dir);
    write_file_atomic((dir / "layouts.csv").string(), layout_rows_csv(rows, cfg.run.seed, e.split));
    write_file_atomic((dir / "summary.csv").string(), layout_summary_csv(summarise_layouts(rows), cfg.run.seed, e.split));
  };
  return p;
}

std::vector<Piece> StageContext::optima_pieces(const Config& cfg, const fs::path& dir, const LayoutEvalOptions& o) const {
  std::vector<Piece> out_pieces;
  if (!o.solve_reference) return out_pieces;
  const int k = cfg.env.users_min && cfg.env.users_max ? (cfg.env.users_min + cfg.env.users_max) / 2 : cfg.scenario.users;
  const double each = dp_cost(cfg, k);
  if (each * o.layouts <= opt.piece_seconds) return out_pieces;
  const int per = std::max(1, static_cast<int>(std::floor(opt.piece_seconds / each)));
  for (int a = 0; a < o.layouts; a += per) {
    const int n = std::min(per, o.layouts - a);
    LayoutEvalOptions e;
    e.split = o.split;
    e.layouts = n;
    if (o.users_seeds.empty()) e.first = o.first + static_cast<std::uint64_t>(a);
    else e.users_seeds.assign(o.users_seeds.begin() + a, o.users_seeds.begin() + a + n);
    e.cache_dir = (out / "optima").string();
    e.threads = 1;
    const fs::path chunk = fs::path(dir.string() + fmt::format(".optima-{}-{}", a, a + n - 1));  // beside, not under, dir
    Piece p;
    p.id = id_of(chunk, out);
    p.kind = "eval";
    p.label = fmt::format("optima of layouts {}-{} of {}, K={}", a, a + n - 1, o.layouts,
                          cfg.env.users_min && cfg.env.users_max ? fmt::format("{}-{}", cfg.env.users_min, cfg.env.users_max)
                                                                 : std::to_string(k));
    p.cost = each * n;
    p.done = [this, chunk, id = p.id] { return fs::exists(chunk / "layouts.csv") && cache.sealed(id); };
    p.run = [this, cfg, chunk, e] {
      const auto rows = evaluate_layouts(cfg, e, builtin_beamformers(), nullptr);
      fs::create_directories(chunk);
      write_file_atomic((chunk / "layouts.csv").string(), layout_rows_csv(rows, cfg.run.seed, e.split));
    };
    out_pieces.push_back(std::move(p));
  }
  return out_pieces;
}

StageContext::RunInfo StageContext::run_info(const Config& cfg) const {
  RunInfo info;
  info.dir = run_dir(cfg);
  ensure(marl_piece(cfg));
  const auto j = nlohmann::json::parse(read_file((info.dir / "train.json").string()));
  info.seconds = j.at("seconds").get<double>();
  info.steps_per_second = j.at("steps_per_second").get<double>();
  return info;
}

double StageContext::elapsed() const { return std::chrono::duration<double>(Clock::now() - started).count(); }

bool StageContext::fits(double cost) const {
  return fits_time_limit(elapsed(), cost, opt.time_limit);
}

bool StageContext::ensure(const Piece& p, bool limited) const {
  if (limited && !fits(p.cost) && !p.done()) throw TimeLimitReached(p.label);
  // The piece's own time (what it computed, less the pieces it ensured first) goes to
  // timings.csv beside its estimate: what calibrates the estimates of `reproduce --plan`.
  thread_local double nested = 0;
  const double outer = nested;
  nested = 0;
  const auto t0 = std::chrono::steady_clock::now();
  bool ran = false;
  try {
    ran = cache.ensure(p.id, p.done, p.run, &log);
  } catch (...) {
    nested = outer;
    throw;
  }
  const double total = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  if (ran) record_timing(p.id, p.kind, p.cost, total - nested);
  nested = outer + total;
  return ran;
}

void StageContext::record_timing(const std::string& id, const std::string& kind, double estimate, double seconds) const {
  static std::mutex mutex;
  std::lock_guard<std::mutex> lock(mutex);
  const fs::path file = out / "timings.csv";
  const bool fresh = !fs::exists(file);
  std::ofstream f(file, std::ios::app);
  if (fresh) f << "piece,kind,cost_estimate,seconds\n";
  f << fmt::format("{},{},{:.3f},{:.3f}\n", id, kind, estimate, seconds);
}

void AssemblyProgress::done(const std::string& what, bool computed) {
  ++done_;
  if (computed) computed_s_ += since(item_), ++computed_;
  const double per = computed_ ? computed_s_ / static_cast<double>(computed_) : 0.0;
  ctx_.log << fmt::format("  {} {}/{} ({:.0f} s{})\n", what, done_, total_, since(t0_),
                          computed_ && done_ < total_ ? fmt::format(", ETA {:.0f} s", per * static_cast<double>(total_ - done_))
                                                      : "")
           << std::flush;
}

std::string episode_columns(const CsvTable& e, std::size_t r) {
  return fmt::format("{},{},{},{},{},{},{}", e.at(r, "objective"), e.at(r, "T"), e.at(r, "success"), e.at(r, "arrivals"),
                     e.at(r, "collisions"), e.at(r, "boundary_events"), e.at(r, "reward"));
}

void StageContext::write(const fs::path& relative_path, const std::string& text) const {
  if (write_outputs) write_file_atomic((out / relative_path).string(), text);
}

}  // namespace skyloop::repro

namespace skyloop {
double marl_run_estimate(const Config& cfg) { return repro::marl_cost(cfg); }
}  // namespace skyloop
