// Stage kind "rate_energy" (beyond the paper): the rate-power front of the exact optimum, traced
// by sweeping energy.weight under env.objective = "weighted" (each point maximises R-bar - w P-bar,
// P-bar the mean fleet propulsion power), with the experiment's objective (its `set`, e.g.
// energy-efficiency) flown by the heuristics, the optimum and the trained policies placed on it;
// the speeds the optimum chooses at each weight; and the trajectories at the two ends of the front.
#include <fmt/format.h>

#include <map>

#include "context.hpp"
#include "skyloop/core/csv.hpp"
#include "skyloop/core/io.hpp"

namespace skyloop::repro {

namespace {

int users_of(const ExperimentSpec& s) { return s.users.front(); }

Config front_config(const StageContext& ctx, const ExperimentSpec& s, const std::string& w) {
  return ctx.base(s, {"scenario.users=" + std::to_string(users_of(s)), "env.objective=weighted", "energy.weight=" + w});
}

Piece front_point(const StageContext& ctx, const ExperimentSpec& s, const std::string& w) {
  const Config cfg = front_config(ctx, s, w);
  return ctx.eval_piece(cfg, ctx.eval_dir(cfg, "front", {"optimal"}), {"optimal"}, {});
}

std::vector<std::string> placed_planners(const ExperimentSpec& s) {
  std::vector<std::string> p = s.planners;
  p.push_back("optimal");
  return p;
}

Piece placed(const StageContext& ctx, const ExperimentSpec& s) {
  const Config cfg = ctx.base(s, {"scenario.users=" + std::to_string(users_of(s))});
  return ctx.eval_piece(cfg, ctx.eval_dir(cfg, "placed", placed_planners(s)), placed_planners(s), {});
}

std::vector<Piece> pieces(StageContext& ctx, const ExperimentSpec& s) {
  std::vector<Piece> out;
  for (const auto& w : s.values) out.push_back(front_point(ctx, s, w));
  out.push_back(placed(ctx, s));
  for (const auto& algo : s.algos)
    for (auto seed : s.seeds) out.push_back(ctx.marl_piece(ctx.run_config(s, algo, seed, users_of(s))));
  return out;
}

nlohmann::json assemble(StageContext& ctx, const ExperimentSpec& s) {
  const int k = users_of(s);
  std::string front = "experiment,role,weight,planner,train_seed,users_seed,objective,sum_rate_objective,mean_power_w,energy_j,"
                      "bits_per_joule,T,success,collisions\n";
  std::string speeds = "experiment,weight,users_seed,speed_mps,slots\n";
  std::string paths = "experiment,weight,users_seed,t,uav,x,y,action,speed_mps\n";
  AssemblyProgress progress(ctx, s.values.size() + 1 + s.algos.size() * s.seeds.size());
  // role: front (the optimum at weight w), placed (a planner flying the experiment's objective).
  auto add = [&](const std::string& role, const std::string& w, const std::string& seed, const fs::path& dir, double slot_s) {
    const fs::path f = dir / "summary.csv";
    const CsvTable e = CsvTable::parse(read_file(f.string()), f.string());
    for (std::size_t r = 0; r < e.size(); ++r) {
      const double T = e.number(r, "T"), energy = e.number(r, "energy_j");
      front += fmt::format("{},{},{},{},{},{},{},{},{},{},{},{},{},{}\n", s.name, role, w, e.at(r, "planner"), seed, e.at(r, "seed"),
                           e.at(r, "objective"), e.at(r, "sum_rate_objective"), format_double(energy / (T * slot_s)),
                           e.at(r, "energy_j"), e.at(r, "bits_per_joule"), e.at(r, "T"), e.at(r, "success"),
                           e.at(r, "collisions"));
    }
  };
  for (const auto& w : s.values) {
    progress.start();
    const Piece p = front_point(ctx, s, w);
    const bool fresh = ctx.ensure(p);
    const Config cfg = front_config(ctx, s, w);
    add("front", w, "", ctx.out / p.id, cfg.trajectory.slot_s);
    // The optimum's speeds and its path at this weight.
    const fs::path tf = ctx.out / p.id / "trajectory.csv";
    const CsvTable t = CsvTable::parse(read_file(tf.string()), tf.string());
    std::map<std::string, int> count;
    for (std::size_t r = 0; r < t.size(); ++r) {
      if (t.at(r, "speed_mps").empty()) continue;
      ++count[format_double(std::round(t.number(r, "speed_mps") * 100) / 100)];
      paths += fmt::format("{},{},{},{},{},{},{},{},{}\n", s.name, w, t.at(r, "seed"), t.at(r, "t"), t.at(r, "uav"), t.at(r, "x"),
                           t.at(r, "y"), t.at(r, "action"), t.at(r, "speed_mps"));
    }
    for (const auto& [v, n] : count) speeds += fmt::format("{},{},{},{},{}\n", s.name, w, cfg.marl.users_seed, v, n);
    progress.done(fmt::format("front w = {}", w), fresh);
  }
  {
    progress.start();
    const Piece p = placed(ctx, s);
    const bool fresh = ctx.ensure(p);
    add("placed", "", "", ctx.out / p.id, ctx.base(s).trajectory.slot_s);
    progress.done("planners on the experiment's objective", fresh);
  }
  for (const auto& algo : s.algos)
    for (auto seed : s.seeds) {
      const Config cfg = ctx.run_config(s, algo, seed, k);
      progress.start();
      const bool fresh = ctx.ensure(ctx.marl_piece(cfg));
      add("placed", "", std::to_string(seed), ctx.run_dir(cfg) / "eval", cfg.trajectory.slot_s);
      progress.done(fmt::format("{} seed {}{}", algo, seed, fresh ? "" : " (ready)"), fresh);
    }
  ctx.write(fs::path(s.name) / "front.csv", front);
  ctx.write(fs::path(s.name) / "speeds.csv", speeds);
  ctx.write(fs::path(s.name) / "paths.csv", paths);
  return {s.name + "/front.csv", s.name + "/speeds.csv", s.name + "/paths.csv"};
}

}  // namespace

StageKind rate_energy_stage() { return {1, pieces, assemble}; }

}  // namespace skyloop::repro
