// Stage kind "altitude_profile" (beyond the paper; altitude as a decision): the exact optimum of
// UAVs that choose their altitude (trajectory.mobility = "grid-3d") beside the fixed-altitude
// optimum (the paper's grid at H), under each air-to-ground channel of `values`
// (channel.pathloss). One evaluation of `planners` per (channel, mobility); the altitudes each UAV
// flies slot by slot, and each plan's objective and energy.
#include <fmt/format.h>

#include "context.hpp"
#include "skyloop/core/csv.hpp"
#include "skyloop/core/io.hpp"

namespace skyloop::repro {

namespace {

const std::vector<std::string>& mobilities() {
  static const std::vector<std::string> m = {"grid", "grid-3d"};  // fixed altitude, then chosen
  return m;
}

Config profile_config(const StageContext& ctx, const ExperimentSpec& s, const std::string& pathloss, const std::string& mobility) {
  return ctx.base(s, {"scenario.users=" + std::to_string(s.users.front()), "channel.pathloss=" + pathloss,
                      "trajectory.mobility=" + mobility});
}

Piece plan_piece(const StageContext& ctx, const ExperimentSpec& s, const std::string& pathloss, const std::string& mobility) {
  const Config cfg = profile_config(ctx, s, pathloss, mobility);
  return ctx.eval_piece(cfg, ctx.eval_dir(cfg, "altitude", s.planners), s.planners, {});
}

std::vector<Piece> pieces(StageContext& ctx, const ExperimentSpec& s) {
  std::vector<Piece> out;
  for (const auto& v : s.values)
    for (const auto& m : mobilities()) out.push_back(plan_piece(ctx, s, v, m));
  return out;
}

nlohmann::json assemble(StageContext& ctx, const ExperimentSpec& s) {
  std::string profile = "experiment,pathloss,mobility,planner,users_seed,t,uav,x,y,z\n";
  std::string summary = "experiment,pathloss,mobility,planner,users_seed,objective,T,success,arrivals,collisions,boundary_events,"
                        "reward,energy_j\n";
  AssemblyProgress progress(ctx, s.values.size() * mobilities().size());
  for (const auto& v : s.values)
    for (const auto& m : mobilities()) {
      progress.start();
      const Piece p = plan_piece(ctx, s, v, m);
      const bool fresh = ctx.ensure(p);
      const fs::path dir = ctx.out / p.id;
      const CsvTable t = CsvTable::parse(read_file((dir / "trajectory.csv").string()), (dir / "trajectory.csv").string());
      for (std::size_t r = 0; r < t.size(); ++r)
        profile += fmt::format("{},{},{},{},{},{},{},{},{},{}\n", s.name, v, m, t.at(r, "planner"), t.at(r, "seed"), t.at(r, "t"),
                               t.at(r, "uav"), t.at(r, "x"), t.at(r, "y"), t.at(r, "z"));
      const CsvTable e = CsvTable::parse(read_file((dir / "summary.csv").string()), (dir / "summary.csv").string());
      for (std::size_t r = 0; r < e.size(); ++r)
        summary += fmt::format("{},{},{},{},{},{},{}\n", s.name, v, m, e.at(r, "planner"), e.at(r, "seed"), episode_columns(e, r),
                               e.at(r, "energy_j"));
      progress.done(fmt::format("{} {}", v, m), fresh);
    }
  ctx.write(fs::path(s.name) / "profile.csv", profile);
  ctx.write(fs::path(s.name) / "summary.csv", summary);
  return {s.name + "/profile.csv", s.name + "/summary.csv"};
}

}  // namespace

StageKind altitude_profile_stage() { return {1, pieces, assemble}; }

}  // namespace skyloop::repro
