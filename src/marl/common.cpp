#include "common.hpp"

#include "../nn/archive.hpp"
#include "../nn/models.hpp"

#include <filesystem>
#include <fmt/format.h>
#include <sstream>

#include "skyloop/core/csv.hpp"
#include "skyloop/core/error.hpp"
#include "skyloop/core/io.hpp"
#include "skyloop/core/parallel.hpp"
#include "skyloop/core/rng.hpp"
#include "skyloop/env/layouts.hpp"
#include "skyloop/env/vec_env.hpp"
#include "skyloop/marl/learners.hpp"
#include "skyloop/nn/learned.hpp"

namespace skyloop::marl {

namespace {
constexpr const char* kValidationHeader = "seed,env_steps,layouts,complete,objective,best\n";
}  // namespace

const nn::ArchiveKind& policy_kind() {
  static const nn::ArchiveKind k{"policy", "a policy.pt written by `skyloop train`", kFormat, kVersion};
  return k;
}

void write_module(torch::serialize::OutputArchive& archive, const char* key, torch::nn::Module& module) {
  torch::serialize::OutputArchive sub;
  module.save(sub);
  archive.write(key, sub);
}

void save(const std::string& path, const nlohmann::json& meta, Nets& nets, torch::optim::Optimizer* opt,
          const std::function<void(torch::serialize::OutputArchive&)>& extra) {
  torch::serialize::OutputArchive archive;
  auto put = [&](const char* key, torch::nn::Module* m) {
    if (m) write_module(archive, key, *m);
  };
  put("actor", nets.actor ? nets.actor.get() : nullptr);
  put("critic", nets.critic ? nets.critic.get() : nullptr);
  put("q", nets.q ? nets.q.get() : nullptr);
  put("mixer", nets.mixer ? nets.mixer.get() : nullptr);
  if (opt) {
    torch::serialize::OutputArchive sub;
    opt->save(sub);
    archive.write("optimizer", sub);
  }
  if (extra) extra(archive);
  nn::write_archive(path, policy_kind(), meta, archive);
}

nlohmann::json read_meta(const std::string& path) { return nn::open_archive(path, policy_kind()).meta; }

void load(const std::string& path, Nets& nets, torch::optim::Optimizer* opt,
          const std::function<void(torch::serialize::InputArchive&)>& extra) {
  auto a = nn::open_archive(path, policy_kind()).archive;
  auto get = [&](const char* key, torch::nn::Module* m) {
    if (!m) return;
    torch::serialize::InputArchive sub;
    if (!a.try_read(key, sub)) throw InputError("policy '" + path + "' has no '" + key + "' network");
    try {
      m->load(sub);
    } catch (const std::exception& e) {
      std::string w = e.what();
      throw InputError("policy '" + path + "' does not match its header: " + w.substr(0, w.find('\n')));
    }
  };
  get("actor", nets.actor ? nets.actor.get() : nullptr);
  get("critic", nets.critic ? nets.critic.get() : nullptr);
  get("q", nets.q ? nets.q.get() : nullptr);
  get("mixer", nets.mixer ? nets.mixer.get() : nullptr);
  if (opt) {
    torch::serialize::InputArchive sub;
    if (!a.try_read("optimizer", sub)) throw InputError("policy '" + path + "' holds no optimiser state: cannot resume from it");
    opt->load(sub);
  }
  if (extra) extra(a);
}

void TorchLearned::save(const std::string& path, const nlohmann::json& meta, bool optimiser) {
  marl::save(path, meta, nets_, optimiser ? &optimiser_ : nullptr);
}

void TorchLearned::load(const std::string& path, bool optimiser) { marl::load(path, nets_, optimiser ? &optimiser_ : nullptr); }

std::shared_ptr<const Beamformer> make_oracle_beamformer(const Config& cfg, const BeamformerRegistry& registry) {
  try {
    return registry.create(cfg.env.oracle, cfg);
  } catch (const InputError& e) {
    throw InputError("env.oracle = \"" + cfg.env.oracle + "\": " + e.what());
  }
}

std::shared_ptr<RateOracle> make_oracle(const Config& cfg, const BeamformerRegistry& registry) {
  return std::make_shared<RateOracle>(cfg, make_oracle_beamformer(cfg, registry), make_users(cfg, cfg.scenario.users, cfg.marl.users_seed));
}

VecEnv make_training_envs(const Config& cfg, const BeamformerRegistry& registry) {
  if (cfg.env.resample_users && cfg.env.users_file.empty())
    return VecEnv(cfg, make_oracle_beamformer(cfg, registry), cfg.marl.envs, training_envs_seed(cfg.run.seed));
  return VecEnv(cfg, make_oracle(cfg, registry), cfg.marl.envs);
}

int Encoder::width(const UavEnv& env) const {
  if (set) return env.set_observation_size();
  return env.observation_size() + (context ? env.agent_context_size() : 0);
}

void Encoder::write(const UavEnv& env, int n, float* out) const {
  if (set) return env.write_set_observation(n, out);
  env.write_observation(n, out);
  if (context) env.write_agent_context(n, out + env.observation_size());
}

Encoder encoder_of(const Config& cfg, bool context) {
  Encoder e;
  e.set = cfg.marl.encoder == ObservationKind::Set;
  e.context = context && !e.set;
  e.threads = resolve_threads(cfg.run.threads);
  e.asks_oracle = e.set && (cfg.marl.lookahead || cfg.marl.rate_map > 0);
  e.sequential = e.set && cfg.marl.sequential;
  e.passes = e.sequential ? cfg.marl.sequential_passes : 1;
  return e;
}


void RunningStats::update(const float* x, std::size_t count_x) {
  if (count_x == 0) return;
  const double n = static_cast<double>(count_x);
  double m = 0, v = 0;
  for (std::size_t i = 0; i < count_x; ++i) m += x[i];
  m /= n;
  for (std::size_t i = 0; i < count_x; ++i) v += (x[i] - m) * (x[i] - m);
  v /= n;
  const double delta = m - mean, total = count + n;
  mean += delta * n / total;
  var = (var * count + v * n + delta * delta * count * n / total) / total;
  count = total;
}

void EpisodeStats::add(const StepInfo& s, int uavs) {
  ++episodes;
  reward += s.episode_reward;
  objective += s.objective;
  sum_rate += s.sum_rate_objective;
  energy_j += s.episode_energy_j;
  bits_per_joule += s.bits_per_joule;
  home += static_cast<double>(s.home) / uavs;
  collisions += s.episode_collisions;
  boundary += s.episode_boundary;
}

std::string metrics_header() {
  return "seed,env_steps,episodes,charts/episode_reward,charts/sum_rate,charts/arrival_rate,charts/collisions,"
         "charts/boundary_events,losses/policy,losses/value,losses/entropy,losses/old_approx_kl,losses/approx_kl,"
         "losses/clipfrac,losses/explained_variance,losses/grad_norm,charts/epsilon,charts/objective,charts/energy_j,"
         "charts/bits_per_joule,charts/steps_per_s\n";
}

std::string metrics_row(std::uint64_t seed, std::int64_t steps, const EpisodeStats& e, const LearnerLog& log, double sps) {
  const double n = std::max(1, e.episodes);
  auto f = [&](double x) { return e.episodes ? format_double(x / n) : std::string(""); };
  auto g = [](double x) { return std::isnan(x) ? std::string("") : format_double(x); };
  // charts/sum_rate: P2.2's (1/T) sum R[t]; charts/objective: env.objective's J (the same under sum-rate).
  return fmt::format("{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{}\n", seed, steps, e.episodes, f(e.reward),
                     f(e.sum_rate), f(e.home), f(e.collisions), f(e.boundary), g(log.policy_loss), g(log.value_loss),
                     g(log.entropy), g(log.old_approx_kl), g(log.approx_kl), g(log.clipfrac), g(log.explained_variance),
                     g(log.grad_norm), g(log.epsilon), f(e.objective), f(e.energy_j), f(e.bits_per_joule), format_double(sps));
}

Run::Run(const Config& cfg, const MarlTrainOptions& opt, const std::function<void(const VecEnv&)>& check)
    : dir(opt.out_dir),
      last((dir / "last.pt").string()),
      final_path((dir / "policy.pt").string()),
      threads([&] {
        set_torch_threads(1);
        return cfg.run.threads;
      }()),
      device(device_of(cfg)),
      vec(make_training_envs(cfg, *opt.registry)) {
  if (check) check(vec);
  check_resume_or_force(opt.resume, opt.force);
  if (opt.resume && !std::filesystem::exists(last))
    throw InputError("--resume: '" + last + "' does not exist: allowed a directory of an earlier training run");
  lock = check_fresh_run_dir(opt.out_dir, {"policy.pt", "last.pt", "metrics.csv"}, opt.resume, opt.force);
  remove_stale_temporaries(opt.out_dir);
}

nlohmann::json Run::resume(const Config& cfg, const std::string& size_key, int size, Learned& learned,
                           std::string& metrics) {
  const auto old = read_meta(last);
  if (old.value("algo", "") != cfg.marl.algo || old.value("hidden", 0) != cfg.marl.hidden || old.value(size_key, 0) != size)
    throw InputError("--resume: '" + last + "' holds a " + old.value("algo", std::string("?")) +
                     " run of other sizes: allowed the same algo, hidden size and scenario as the config");
  if (old.value("backend", std::string("torch")) != name_of(learner_backend(cfg)))
    throw InputError("--resume: '" + last + "' was trained with marl.backend = \"" + old.value("backend", std::string("torch")) +
                     "\": allowed the same backend as the run it continues");
  const std::int64_t done = old.value("env_steps", std::int64_t{0});
  if (done >= cfg.marl.total_steps)
    throw InputError("--resume: '" + last + "' has already run " + std::to_string(done) + " environment steps, marl.total_steps = " +
                     std::to_string(cfg.marl.total_steps) + ": allowed marl.total_steps (--steps) above " + std::to_string(done) +
                     " to continue it");
  learned.load(last, true);
  if (std::filesystem::exists(dir / "metrics.csv")) {
    metrics = read_file((dir / "metrics.csv").string());
    // Written just before last.pt at every checkpoint (checkpoint()): its rows run to last.pt's
    // step count, or one checkpoint beyond it when the run stopped between the two files; those
    // rows are of updates the resumed run does again, and are dropped. A log that ends before
    // last.pt, or mid-row, was cut or edited since (a resumed run would append to a broken log).
    const auto table = CsvTable::parse(metrics, (dir / "metrics.csv").string());
    const bool whole = metrics.empty() || metrics.back() == '\n';
    std::size_t keep = 0;  // the rows up to last.pt's step count
    while (keep < table.size() && static_cast<std::int64_t>(table.number(keep, "env_steps")) <= done) ++keep;
    const std::int64_t logged = keep ? static_cast<std::int64_t>(table.number(keep - 1, "env_steps")) : 0;
    if (whole && logged == done && keep < table.size()) {
      std::size_t end = 0;  // the header line and `keep` rows
      for (std::size_t line = 0; line <= keep; ++line) end = metrics.find('\n', end) + 1;
      metrics.resize(end);
    }
    if (!whole || logged != done)
      throw InputError("--resume: '" + (dir / "metrics.csv").string() + "' ends at " + std::to_string(logged) +
                       " environment steps but '" + last + "' at " + std::to_string(done) +
                       " (the file was changed since the checkpoint): allowed --force to start the run again");
  }
  restore_validation(cfg, old.value("env_steps", std::int64_t{0}));
  return old;
}

void Run::restore_validation(const Config& cfg, std::int64_t steps) {
  const auto path = dir / "validation.csv";
  if (cfg.marl.val_layouts <= 0 || !std::filesystem::exists(path)) return;
  // Model selection goes on where it stopped: the earlier rows stay in validation.csv, and the
  // best of them (policy.pt) is what a later checkpoint must beat. Rows scored on another number
  // of layouts are kept but not compared: selection starts over on the new validation set.
  const auto table = CsvTable::parse(read_file(path.string(), "validation.csv"), path.string());
  validation_csv = kValidationHeader;
  for (std::size_t i = 0; i < table.size(); ++i) {
    const auto at = static_cast<std::int64_t>(table.number(i, "env_steps"));
    if (at > steps) continue;  // scored after last.pt was written (a run stopped in between): redone
    validation_csv += fmt::format("{},{},{},{},{},{}\n", table.at(i, "seed"), table.at(i, "env_steps"), table.at(i, "layouts"),
                                  table.at(i, "complete"), table.at(i, "objective"), table.at(i, "best"));
    if (table.number(i, "layouts") == cfg.marl.val_layouts && table.number(i, "best") > 0)
      best_complete = table.number(i, "complete"), best_objective = table.number(i, "objective");
  }
}

void Run::checkpoint(const nlohmann::json& meta, Learned& learned, const std::string& metrics) const {
  // The log first: a run stopped between the two files leaves the log one checkpoint ahead of
  // last.pt, which resume() cuts back, never behind it (a log that cannot be continued).
  write_file_atomic((dir / "metrics.csv").string(), metrics);
  learned.save(last, meta, true);
}

void Run::validate(const Config& cfg, const MarlTrainOptions& opt, const nlohmann::json& meta, Learned& learned, std::int64_t steps) {
  if (cfg.marl.val_layouts <= 0) return;
  // The policy as policy.pt would hold it (under marl.average_decay the actor's average, not last.pt's weights).
  const std::string candidate = (dir / "candidate.pt").string();
  learned.save(candidate, meta, false);
  auto policy = MarlPolicy::load(candidate);
  const auto bf = make_oracle_beamformer(cfg, *opt.registry);
  double complete = 0, objective = 0;
  const int V = cfg.marl.val_layouts;
  for (int i = 0; i < V; ++i) {
    // The training environments' configuration (sharing their lattice tables) over the layout's users.
    UavEnv env(vec.like(), std::make_shared<RateOracle>(cfg, bf, layout_users(cfg, layout_seed(LayoutSplit::Validation, static_cast<std::uint64_t>(i)))));
    const auto r = run_episode(env, *policy);
    complete += (r.success && r.collisions == 0 && r.boundary == 0) ? 1.0 / V : 0.0;
    objective += r.objective / V;
  }
  if (validation_csv.empty()) validation_csv = kValidationHeader;
  const bool best = complete > best_complete + 1e-12 || (std::abs(complete - best_complete) <= 1e-12 && objective > best_objective);
  if (best) {
    best_complete = complete, best_objective = objective;
    std::filesystem::rename(candidate, final_path);  // atomic: policy.pt is the old best or the new, never half
  } else {
    std::filesystem::remove(candidate);
  }
  validation_csv += fmt::format("{},{},{},{},{},{}\n", cfg.run.seed, steps, V, format_double(complete), format_double(objective), best ? 1 : 0);
  write_file_atomic((dir / "validation.csv").string(), validation_csv);
}

MarlTrainResult Run::finish(const Config& cfg, const MarlTrainOptions& opt, const nlohmann::json& meta, Learned& learned,
                            const std::string& metrics, std::int64_t steps, std::int64_t start_steps) {
  checkpoint(meta, learned, metrics);
  if (cfg.marl.val_layouts > 0) validate(cfg, opt, meta, learned, steps);  // policy.pt = the best
  else learned.save(final_path, meta, false);
  MarlTrainResult result;
  result.env_steps = steps;
  result.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  result.steps_per_second = static_cast<double>(steps - start_steps) / std::max(result.seconds, 1e-9);
  auto policy = MarlPolicy::load(final_path);
  UavEnv env(vec.like(), make_oracle(cfg, *opt.registry));  // the evaluation users, the training's lattice tables
  result.evaluation = run_episode(env, *policy);
  return result;
}

PpoBackend learner_backend(const Config& cfg) {
  return find_learner(cfg.marl.algo).core == LearnerInfo::Core::Ppo ? cfg.marl.backend : PpoBackend::Torch;
}

torch::Device device_of(const Config& cfg) { return nn::resolve_device(cfg.nn.device); }

}  // namespace skyloop::marl
