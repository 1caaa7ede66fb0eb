#include "skyloop/experiments/layout_eval.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <fmt/format.h>
#include <map>
#include <memory>
#include <mutex>
#include <ostream>

#include "skyloop/planning/registry.hpp"
#include "skyloop/core/config_io.hpp"
#include "skyloop/core/csv.hpp"
#include "skyloop/core/error.hpp"
#include "skyloop/core/io.hpp"
#include "skyloop/core/parallel.hpp"
#include "skyloop/core/progress.hpp"
#include "skyloop/core/rng.hpp"
#include "skyloop/env/vec_env.hpp"
#include "skyloop/marl/marl.hpp"
#include "skyloop/nn/learned.hpp"

namespace skyloop {

namespace {

LayoutRow row_of(const EpisodeRecord& r, const std::string& planner, double seconds) {
  LayoutRow x;
  x.planner = planner;
  x.objective = r.objective;
  x.T = r.T;
  x.uavs = static_cast<int>(r.positions.front().rows());
  x.arrivals = r.arrivals;
  x.home = r.steps.empty() ? (r.success ? x.uavs : 0) : r.steps.back().home;
  x.collisions = r.collisions;
  x.boundary = r.boundary;
  x.complete = r.success && r.collisions == 0 && r.boundary == 0;
  x.seconds = seconds;
  x.energy_j = r.energy_j;
  x.bits_per_joule = r.bits_per_joule;
  return x;
}

/// The reference of one layout (layout_reference), from the cache when it holds it.
LayoutRow reference_of(const Config& cfg, UavEnv& env, const std::string& cache_dir);

/// The reference of dynamics off the lattice: their lattice twin's (Dynamics::reference_twin) on
/// the same users, labelled with the twin's model (optimal-headings).
LayoutRow twin_reference(const Config& twin, UavEnv& env, const std::string& cache_dir) {
  const auto& o = env.oracle();
  UavEnv lattice(twin, std::make_shared<RateOracle>(twin, o.beamformer_ptr(), o.users()));
  LayoutRow r = reference_of(twin, lattice, cache_dir);
  r.planner += "-" + twin.trajectory.mobility;
  return r;
}

LayoutRow reference_of(const Config& cfg, UavEnv& env, const std::string& cache_dir) {
  if (const auto twin = env.dynamics().reference_twin(cfg)) return twin_reference(*twin, env, cache_dir);
  const std::string name = layout_reference(env);
  std::string path;
  if (!cache_dir.empty()) {
    // Everything the optimum depends on (optimum_key) and the users.
    const auto& u = env.oracle().users();
    std::string text = optimum_key(cfg);
    text.append(reinterpret_cast<const char*>(u.data()), sizeof(double) * static_cast<std::size_t>(u.size()));
    if (name != "optimal") text += "|reference " + name;  // the optimum's keys as before
    path = (std::filesystem::path(cache_dir) / fmt::format("{:016x}.csv", hash_bytes(text.data(), text.size()))).string();
  }
  // One computation per cached reference and process: reproduce evaluates on several threads, and
  // two evaluations of the same layouts (the planners' and the policy's) would solve it twice.
  std::unique_lock<std::mutex> computing;
  if (!path.empty()) {
    static std::mutex guard;
    static std::map<std::string, std::unique_ptr<std::mutex>> per_path;
    std::mutex* m = nullptr;
    {
      std::lock_guard<std::mutex> lock(guard);
      auto& slot = per_path[path];
      if (!slot) slot = std::make_unique<std::mutex>();
      m = slot.get();
    }
    computing = std::unique_lock<std::mutex>(*m);
    if (std::filesystem::exists(path)) {
      const auto t = CsvTable::parse(read_file(path, "optimum cache"), path);
      LayoutRow r;
      r.planner = name;
      r.objective = t.number(0, "objective");
      r.T = static_cast<int>(t.number(0, "T"));
      r.uavs = env.uavs();
      r.arrivals = r.home = static_cast<int>(t.number(0, "arrivals"));
      r.collisions = static_cast<int>(t.number(0, "collisions"));
      r.boundary = static_cast<int>(t.number(0, "boundary"));
      r.complete = t.number(0, "complete") > 0;
      r.seconds = t.number(0, "seconds");
      r.energy_j = t.number(0, "energy_j");
      r.bits_per_joule = t.number(0, "bits_per_joule");
      return r;
    }
  }
  const auto planner = builtin_planners().create(name);
  const auto t0 = std::chrono::steady_clock::now();
  const auto rec = run_episode(env, *planner);
  const double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  auto r = row_of(rec, name, s);
  if (!path.empty())
    write_file_atomic(path, fmt::format("objective,T,arrivals,collisions,boundary,complete,seconds,energy_j,bits_per_joule\n"
                                        "{},{},{},{},{},{},{},{},{}\n",
                                        format_double(r.objective), r.T, r.arrivals, r.collisions, r.boundary,
                                        r.complete ? 1 : 0, format_double(s), format_double(r.energy_j),
                                        format_double(r.bits_per_joule)));
  return r;
}

}  // namespace

double percentile(std::vector<double> v, double q) {
  if (v.empty()) return 0;
  std::sort(v.begin(), v.end());
  const double pos = q * static_cast<double>(v.size() - 1);
  const auto i = static_cast<std::size_t>(std::floor(pos));
  const double f = pos - static_cast<double>(i);
  return i + 1 < v.size() ? v[i] * (1 - f) + v[i + 1] * f : v[i];
}

std::vector<LayoutRow> evaluate_layouts(const Config& cfg, const LayoutEvalOptions& opt, const BeamformerRegistry& registry,
                                        std::ostream* progress) {
  if (opt.layouts < 1) throw InputError("--layouts = " + std::to_string(opt.layouts) + " is out of range: allowed at least 1");
  for (const auto& p : opt.planners) {
    if (p == "optimal" || p == "bestknown") continue;  // the reference (always solved)
    if (!builtin_planners().contains(p))
      throw InputError("--planner '" + p + "' is unknown: allowed " + builtin_planners().names_text());
  }
  // Policy labels, checked (and loaded once) before the work.
  std::vector<std::string> labels;
  std::map<std::string, int> seen;
  for (std::size_t i = 0; i < opt.policies.size(); ++i) {
    const auto policy = MarlPolicy::load(opt.policies[i]);
    std::string label = i < opt.policy_names.size() ? opt.policy_names[i] : policy->name();
    if (++seen[label] > 1) label += "-" + std::to_string(seen[label]);
    labels.push_back(label);
  }
  const bool given = !opt.users_seeds.empty();
  if (given && static_cast<int>(opt.users_seeds.size()) < opt.layouts)
    throw std::invalid_argument("evaluate_layouts: fewer users seeds than layouts");
  if (opt.layouts < 1) throw InputError("layouts = " + std::to_string(opt.layouts) + " is out of range: allowed at least 1");
  for (std::size_t i = 0; i < opt.planners.size(); ++i)
    for (std::size_t j = 0; j < i; ++j)
      if (opt.planners[i] == opt.planners[j])
        throw InputError("planner '" + opt.planners[i] + "' is given twice: allowed each planner at most once");
  if (!given) layout_seed(opt.split, opt.first + static_cast<std::uint64_t>(opt.layouts) - 1);  // in range
  if (!opt.cache_dir.empty()) {
    check_output_dir(opt.cache_dir, "--cache");
    std::filesystem::create_directories(opt.cache_dir);
  }
  std::shared_ptr<const Beamformer> bf;
  try {
    bf = registry.create(cfg.env.oracle, cfg);
  } catch (const InputError& e) {
    throw InputError("env.oracle = \"" + cfg.env.oracle + "\": " + e.what());
  }
  const int threads = resolve_threads(opt.threads ? opt.threads : cfg.run.threads);
  if (threads > 1) set_torch_threads(1);  // layouts in parallel; each policy on one thread
  std::vector<std::string> names;
  for (const auto& p : opt.planners)
    if (p != "optimal" && p != "bestknown") names.push_back(p);
  if (opt.rollout && !opt.policies.empty()) check_rollout_settings(cfg);
  const std::size_t per_layout =
      names.size() + labels.size() * (1 + (opt.unsafe ? 1 : 0) + (opt.rollout ? 1 : 0)) + (opt.solve_reference ? 1 : 0);
  if (per_layout == 0) throw InputError("nothing to evaluate: allowed planners, policies or the reference");
  std::vector<LayoutRow> rows(static_cast<std::size_t>(opt.layouts) * per_layout);
  std::unique_ptr<Progress> bar;
  std::mutex mu;
  if (progress) bar = std::make_unique<Progress>(fmt::format("layouts ({})", to_string(opt.split)), static_cast<std::size_t>(opt.layouts), *progress);
  // Each layout's environment is `like` over the layout's users (the lattice tables made once).
  UavEnv::require_table_memory(cfg, threads);
  auto seed_of = [&](std::size_t i) { return given ? opt.users_seeds[i] : layout_seed(opt.split, opt.first + i); };
  const UavEnv like(cfg, std::make_shared<RateOracle>(cfg, bf, layout_users(cfg, seed_of(0))));
  parallel_for(static_cast<std::size_t>(opt.layouts), threads, [&](std::size_t i) {
    const std::uint64_t index = given ? i : opt.first + i, seed = seed_of(i);
    UavEnv env(like, std::make_shared<RateOracle>(cfg, bf, layout_users(cfg, seed)));
    std::vector<LayoutRow> out;
    auto timed = [&](Planner& p, const std::string& label) {
      const auto t0 = std::chrono::steady_clock::now();
      const auto rec = run_episode(env, p);
      out.push_back(row_of(rec, label, std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count()));
    };
    for (const auto& name : names) {
      PlannerArgs args;
      args.seed = derive_seed(seed, 0x52414e44ULL);
      if (opt.planner_seed) args.seed = derive_seed(args.seed, opt.planner_seed);
      args.safety = safety_options(cfg);
      auto p = builtin_planners().create(name, args);
      timed(*p, name);
    }
    // The execution settings are the evaluation's: the reserve, and turns as trained or where asked.
    auto load = [&](std::size_t k) {
      auto policy = MarlPolicy::load(opt.policies[k]);
      policy->set_reserve_slack(cfg.marl.reserve_slack);
      if (cfg.marl.sequential) policy->set_sequential(true);
      if (cfg.marl.sequential_passes > 1) policy->set_sequential_passes(cfg.marl.sequential_passes);
      return policy;
    };
    for (std::size_t k = 0; k < labels.size(); ++k) {
      auto policy = load(k);
      timed(*policy, labels[k]);
      if (opt.unsafe) {
        auto raw = load(k);
        raw->set_safety(false, false);
        timed(*raw, labels[k] + "/raw");
      }
      if (opt.rollout) {
        RolloutPlanner rollout(std::move(policy), labels[k] + "+rollout");
        timed(rollout, labels[k] + "+rollout");
      }
    }
    double best = 0;
    std::string reference;
    if (opt.solve_reference) {
      out.push_back(reference_of(cfg, env, opt.cache_dir));
      best = out.back().objective;
      reference = out.back().planner;
    }
    for (std::size_t k = 0; k < out.size(); ++k) {
      auto& r = out[k];
      r.layout = index, r.users_seed = seed, r.users = env.users(), r.uavs = env.uavs();
      r.reference = reference;
      r.reference_objective = best;
      r.fraction = best > 0 ? r.objective / best : 0.0;
      rows[i * per_layout + k] = r;
    }
    if (bar) {
      std::lock_guard<std::mutex> lock(mu);
      bar->advance();
    }
  });
  if (bar) bar->finish();
  return rows;
}

void check_rollout_settings(const Config& cfg) {
  if (cfg.marl.reserve_slack >= 0)
    throw InputError("--rollout with marl.reserve_slack = " + std::to_string(cfg.marl.reserve_slack) +
                     ": allowed -1 (a rollout flies the policy from states it did not reach, while reserved ways are carried from "
                     "slot to slot)");
}

std::string layout_reference(const UavEnv& env) { return fits_optimal(env) ? "optimal" : "bestknown"; }

Config lattice_twin(const Config& cfg) {
  const auto twin = make_dynamics(cfg)->reference_twin(cfg);
  if (!twin)
    throw std::logic_error("lattice_twin: trajectory.mobility = " + cfg.trajectory.mobility + " is a lattice model (its own reference)");
  return *twin;
}

std::vector<std::uint64_t> training_layouts_of(const Config& run, int count) {
  // As make_training_envs and VecEnv: environment i's episode e has training_layout_seed(vec seed, i, e).
  const std::uint64_t vec_seed = training_envs_seed(run.run.seed);
  const int M = std::max(1, run.marl.envs);
  std::vector<std::uint64_t> out;
  for (int j = 0; j < count; ++j)
    out.push_back(training_layout_seed(vec_seed, static_cast<std::uint64_t>(j % M), static_cast<std::uint64_t>(j / M)));
  return out;
}

std::vector<LayoutSummary> summarise_layouts(const std::vector<LayoutRow>& rows) {
  std::vector<LayoutSummary> out;
  std::map<std::string, std::vector<const LayoutRow*>> by;
  for (const auto& r : rows) {
    if (!by.count(r.planner)) {
      LayoutSummary first;
      first.planner = r.planner;
      out.push_back(first);
    }
    by[r.planner].push_back(&r);
  }
  for (auto& s : out) {
    const auto& v = by[s.planner];
    std::vector<double> f;
    s.layouts = static_cast<int>(v.size());
    for (const auto* r : v) {
      if (s.reference.find(r->reference) == std::string::npos) s.reference += (s.reference.empty() ? "" : "+") + r->reference;
      s.complete += r->complete ? 1.0 : 0.0;
      s.collisions += r->collisions;
      s.boundary += r->boundary;
      s.arrivals += r->home;
      s.objective += r->objective;
      s.energy_j += r->energy_j;
      s.bits_per_joule += r->bits_per_joule;
      f.push_back(r->fraction);
    }
    const double n = std::max(1, s.layouts);
    s.complete /= n, s.arrivals /= n, s.objective /= n, s.energy_j /= n, s.bits_per_joule /= n;
    for (const double x : f) s.fraction_mean += x / n;
    s.fraction_p5 = percentile(f, 0.05);
    s.fraction_worst = f.empty() ? 0.0 : *std::min_element(f.begin(), f.end());
  }
  return out;
}

std::string layout_rows_csv(const std::vector<LayoutRow>& rows, std::uint64_t seed, LayoutSplit split) {
  std::string s = "seed,split,layout,users_seed,users,uavs,planner,objective,reference,reference_objective,fraction,T,home,"
                  "complete,collisions,boundary_events,seconds,energy_j,bits_per_joule\n";
  for (const auto& r : rows)
    s += fmt::format("{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{}\n", seed, to_string(split), r.layout, r.users_seed,
                     r.users, r.uavs, r.planner, format_double(r.objective), r.reference, format_double(r.reference_objective),
                     format_double(r.fraction), r.T, r.home, r.complete ? 1 : 0, r.collisions, r.boundary,
                     format_double(r.seconds), format_double(r.energy_j), format_double(r.bits_per_joule));
  return s;
}

std::string layout_summary_csv(const std::vector<LayoutSummary>& sum, std::uint64_t seed, LayoutSplit split) {
  std::string s = "seed,split,planner,layouts,complete_rate,collisions,boundary_events,mean_home,mean_objective,reference,"
                  "fraction_mean,fraction_p5,fraction_worst,mean_energy_j,mean_bits_per_joule\n";
  for (const auto& x : sum)
    s += fmt::format("{},{},{},{},{},{},{},{},{},{},{},{},{},{},{}\n", seed, to_string(split), x.planner, x.layouts,
                     format_double(x.complete), x.collisions, x.boundary, format_double(x.arrivals), format_double(x.objective),
                     x.reference, format_double(x.fraction_mean), format_double(x.fraction_p5), format_double(x.fraction_worst),
                     format_double(x.energy_j), format_double(x.bits_per_joule));
  return s;
}

std::string format_layout_summary(const std::vector<LayoutSummary>& sum) {
  // Fractions are of each layout's reference: the exact optimum, or the best-known planner where
  // the joint DP cannot go.
  const std::string ref = sum.empty() ? std::string("optimal") : sum.back().reference;
  std::string s = fmt::format("{:<14} {:>8} {:>9} {:>10} {:>9} {:>10} {:>11} {:>9} {:>9} {:>10} {:>8}\n", "planner", "layouts",
                              "complete", "collisions", "boundary", "objective", ref == "optimal" ? "% optimum" : "% " + ref,
                              "p5 %", "worst %", "energy kJ", "kbit/J");
  for (const auto& x : sum)
    s += fmt::format("{:<14} {:>8} {:>8.1f}% {:>10} {:>9} {:>10.3f} {:>11.2f} {:>9.2f} {:>9.2f} {:>10.2f} {:>8.1f}\n", x.planner,
                     x.layouts, 100 * x.complete, x.collisions, x.boundary, x.objective, 100 * x.fraction_mean,
                     100 * x.fraction_p5, 100 * x.fraction_worst, x.energy_j / 1e3, x.bits_per_joule / 1e3);
  return s;
}

}  // namespace skyloop
