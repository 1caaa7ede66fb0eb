#include <algorithm>
#include "skyloop/experiments/planning_run.hpp"

#include <chrono>
#include <filesystem>
#include <fmt/format.h>
#include <ostream>

#include "skyloop/planning/registry.hpp"
#include "skyloop/core/config_io.hpp"
#include "skyloop/core/error.hpp"
#include "skyloop/core/io.hpp"

namespace skyloop {

std::vector<EpisodeRecord> run_planners(const Config& cfg, const PlanOptions& opt, const BeamformerRegistry& registry,
                                        std::ostream* progress, std::vector<double>* seconds) {
  if (opt.planners.empty() && opt.extra.empty()) throw InputError("--planner is empty: allowed " + builtin_planners().names_text());
  std::vector<std::shared_ptr<Planner>> planners;
  const Positions users = make_users(cfg, cfg.scenario.users, opt.seed);
  // The exact optimum depends on optimum_key's settings and the users only: solved once per
  // process for every run with the same (reproduce's stages share it).
  const std::string memo = optimum_key(cfg) + "|users " +
                           std::to_string(hash_bytes(users.data(), sizeof(double) * static_cast<std::size_t>(users.size())));
  for (const auto& p : opt.planners) {
    PlannerArgs args;
    args.seed = derive_seed(opt.seed, 0x52414e44ULL), args.progress = progress, args.memo_key = memo;
    args.safety = safety_options(cfg);
    planners.push_back(builtin_planners().create(p, args));  // InputError naming the known planners
  }
  planners.insert(planners.end(), opt.extra.begin(), opt.extra.end());
  RunDirLock lock;  // before the work, not after it: one run at a time into --out
  if (!opt.out_dir.empty()) lock = RunDirLock(opt.out_dir);
  std::shared_ptr<const Beamformer> bf;
  try {
    bf = registry.create(cfg.env.oracle, cfg);
  } catch (const InputError& e) {
    throw InputError("env.oracle = \"" + cfg.env.oracle + "\": " + e.what());
  }
  auto oracle = std::make_shared<RateOracle>(cfg, bf, users);
  UavEnv env(cfg, oracle);
  std::vector<EpisodeRecord> out;
  for (auto& p : planners) {
    const auto t0 = std::chrono::steady_clock::now();
    out.push_back(run_episode(env, *p));
    const double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    if (seconds) seconds->push_back(s);
  }
  if (!opt.out_dir.empty()) {
    const std::filesystem::path dir(opt.out_dir);
    std::vector<double> secs = seconds ? *seconds : std::vector<double>(out.size(), 0.0);
    std::string users_csv = "seed,user,x,y\n";
    for (Eigen::Index k = 0; k < oracle->users().rows(); ++k)
      users_csv += fmt::format("{},{},{},{}\n", opt.seed, k, format_double(oracle->users()(k, 0)), format_double(oracle->users()(k, 1)));
    // The run directory changes whole or not at all: its config beside its own results only.
    write_files_atomic({{(dir / "config.toml").string(), to_toml(cfg)},
                        {(dir / "trajectory.csv").string(), trajectory_csv(out, opt.seed)},
                        {(dir / "rates.csv").string(), rates_csv(out, opt.seed)},
                        {(dir / "users.csv").string(), users_csv},
                        {(dir / "summary.csv").string(), summary_csv(out, opt.seed, secs)},
                        {(dir / "energy.csv").string(), energy_csv(out, opt.seed)}});
  }
  return out;
}

std::string trajectory_csv(const std::vector<EpisodeRecord>& recs, std::uint64_t seed) {
  // z: UAV n's altitude (m); speed_mps and power_w: what UAV n flies and spends in slot t (empty
  // at the last slot).
  std::string s = "seed,planner,t,uav,x,y,z,action,speed_mps,power_w\n";
  for (const auto& r : recs)
    for (std::size_t t = 0; t < r.positions.size(); ++t)
      for (Eigen::Index n = 0; n < r.positions[t].rows(); ++n) {
        const auto i = static_cast<std::size_t>(n);
        const bool moved = t < r.actions.size();
        const Positions& p = r.positions[t];
        s += fmt::format("{},{},{},{},{},{},{},{},{},{}\n", seed, r.planner, t + 1, n, format_double(p(n, 0)), format_double(p(n, 1)),
                         p.cols() > 2 ? format_double(p(n, 2)) : "", !moved ? "END" : r.actions[t][i] < 0 ? "VELOCITY" : r.action_names.name(r.actions[t][i]),
                         moved && t < r.speeds.size() ? format_double(r.speeds[t][i]) : "",
                         moved && t < r.powers.size() ? format_double(r.powers[t][i]) : "");
      }
  return s;
}

std::string energy_csv(const std::vector<EpisodeRecord>& recs, std::uint64_t seed) {
  std::string s = "seed,planner,uav,energy_j\n";
  for (const auto& r : recs)
    for (std::size_t n = 0; n < r.uav_energy_j.size(); ++n)
      s += fmt::format("{},{},{},{}\n", seed, r.planner, n, format_double(r.uav_energy_j[n]));
  return s;
}

std::string rates_csv(const std::vector<EpisodeRecord>& recs, std::uint64_t seed) {
  std::string s = "seed,planner,t,sum_rate,avg_rate,reward,arrivals,boundary,collisions,feasibility\n";
  for (const auto& r : recs) {
    // Slot 1 is the start: no action led to it, so its reward columns are empty.
    const double r1 = r.rates.front();
    s += fmt::format("{},{},1,{},{},,,,,\n", seed, r.planner, format_double(r1), format_double(r1));
    for (std::size_t t = 0; t < r.steps.size(); ++t) {
      const auto& st = r.steps[t];
      s += fmt::format("{},{},{},{},{},{},{},{},{},{}\n", seed, r.planner, t + 2, format_double(st.sum_rate),
                       format_double(st.avg_rate), format_double(st.reward), st.arrivals, st.boundary, st.collisions,
                       st.feasibility);
    }
  }
  return s;
}

std::string summary_csv(const std::vector<EpisodeRecord>& recs, std::uint64_t seed, const std::vector<double>& seconds) {
  std::string s =
      "seed,planner,objective,T,success,arrivals,collisions,boundary_events,reward,seconds,sum_rate_objective,energy_j,"
      "bits_per_joule,over_budget\n";
  for (std::size_t i = 0; i < recs.size(); ++i) {
    const auto& r = recs[i];
    s += fmt::format("{},{},{},{},{},{},{},{},{},{},{},{},{},{}\n", seed, r.planner, format_double(r.objective), r.T,
                     r.success ? 1 : 0, r.arrivals, r.collisions, r.boundary, format_double(r.reward),
                     format_double(i < seconds.size() ? seconds[i] : 0.0), format_double(r.sum_rate_objective),
                     format_double(r.energy_j), format_double(r.bits_per_joule), r.over_budget);
  }
  return s;
}

std::string format_plan_summary(const std::vector<EpisodeRecord>& recs, const std::vector<double>& seconds) {
  std::size_t w = 10;  // the planner column: as wide as its longest name
  for (const auto& r : recs) w = std::max(w, r.planner.size());
  std::string s = fmt::format("{:<{}} {:>10} {:>4} {:>9} {:>9} {:>11} {:>9} {:>10} {:>10} {:>10}\n", "planner", w, "objective",
                              "T", "arrived", "collided", "boundary", "reward", "time (s)", "energy kJ", "kbit/J");
  std::string notes;
  for (std::size_t i = 0; i < recs.size(); ++i) {
    const auto& r = recs[i];
    s += fmt::format("{:<{}} {:>10.3f} {:>4} {:>9} {:>9} {:>11} {:>9.2f} {:>10.2f} {:>10.3f} {:>10.3f}\n", r.planner, w,
                     r.objective, r.T, fmt::format("{}/{}", r.arrivals, r.positions.front().rows()), r.collisions, r.boundary,
                     r.reward, i < seconds.size() ? seconds[i] : 0.0, r.energy_j / 1e3, r.bits_per_joule / 1e3);
    // A fleet home over its energy budget is a failed mission (success = 0 in summary.csv): said, not left to the CSV.
    if (r.over_budget > 0)
      notes += fmt::format("{}: mission failed: {} UAV{} over energy.budget_j\n", r.planner, r.over_budget, r.over_budget > 1 ? "s" : "");
  }
  return s + notes;
}

}  // namespace skyloop
