// Stage kind "planning_users": planners and trained policies at several user counts K (the
// paper's comparison of trajectory planners vs. the number of users).
#include <fmt/format.h>

#include "context.hpp"
#include "skyloop/core/csv.hpp"
#include "skyloop/core/io.hpp"

namespace skyloop::repro {

namespace {

Piece planners_at(const StageContext& ctx, const ExperimentSpec& s, int k) {
  const Config cfg = ctx.base(s, {"scenario.users=" + std::to_string(k)});
  return ctx.eval_piece(cfg, ctx.eval_dir(cfg, "planners", s.planners), s.planners, {});
}

std::vector<Piece> pieces(StageContext& ctx, const ExperimentSpec& s) {
  std::vector<Piece> out;
  for (int k : s.users) {
    if (!s.planners.empty()) out.push_back(planners_at(ctx, s, k));
    for (const auto& algo : s.algos)
      for (auto seed : s.seeds) out.push_back(ctx.marl_piece(ctx.run_config(s, algo, seed, k)));
  }
  return out;
}

nlohmann::json assemble(StageContext& ctx, const ExperimentSpec& s) {
  std::string out = "experiment,users,planner,train_seed,users_seed,objective,T,success,arrivals,collisions,boundary_events,reward\n";
  AssemblyProgress progress(ctx, s.users.size() * (1 + s.algos.size() * s.seeds.size()));
  auto add = [&](int k, const std::string& train_seed, const fs::path& summary) {
    const CsvTable e = CsvTable::parse(read_file(summary.string()), summary.string());
    for (std::size_t r = 0; r < e.size(); ++r)
      out += fmt::format("{},{},{},{},{},{}\n", s.name, k, e.at(r, "planner"), train_seed, e.at(r, "seed"),
                         episode_columns(e, r));
  };
  for (int k : s.users) {
    progress.start();
    bool computed = false;
    if (!s.planners.empty()) {
      const Piece p = planners_at(ctx, s, k);
      computed = ctx.ensure(p);
      add(k, "", ctx.out / p.id / "summary.csv");
    }
    progress.done(fmt::format("K = {} planners", k), computed);
    for (const auto& algo : s.algos)
      for (auto seed : s.seeds) {
        const Config cfg = ctx.run_config(s, algo, seed, k);
        progress.start();
        const bool fresh = ctx.ensure(ctx.marl_piece(cfg));
        add(k, std::to_string(seed), ctx.run_dir(cfg) / "eval" / "summary.csv");
        progress.done(fmt::format("K = {} {} seed {}{}", k, algo, seed, fresh ? "" : " (ready)"), fresh);
      }
  }
  ctx.write(fs::path(s.name) / (s.name + ".csv"), out);
  return {s.name + "/" + s.name + ".csv"};
}

}  // namespace

StageKind planning_users_stage() { return {1, pieces, assemble}; }

}  // namespace skyloop::repro
