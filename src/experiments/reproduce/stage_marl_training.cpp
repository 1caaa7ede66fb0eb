// Stage kind "marl_training": learners trained on the paper's scenario (one run per algorithm and
// seed), their learning curves, their policies evaluated on the evaluation users, and the
// heuristic planners on the same users for reference.
#include <fmt/format.h>

#include "context.hpp"
#include "skyloop/core/csv.hpp"
#include "skyloop/core/io.hpp"

namespace skyloop::repro {

namespace {

Piece references(const StageContext& ctx, const ExperimentSpec& s) {
  const Config cfg = ctx.base(s);
  return ctx.eval_piece(cfg, ctx.eval_dir(cfg, "planners", s.planners), s.planners, {});
}

std::vector<Piece> pieces(StageContext& ctx, const ExperimentSpec& s) {
  std::vector<Piece> out;
  const int k = ctx.base(s).scenario.users;
  for (const auto& algo : s.algos)
    for (auto seed : s.seeds) out.push_back(ctx.marl_piece(ctx.run_config(s, algo, seed, k)));
  if (!s.planners.empty()) out.push_back(references(ctx, s));
  return out;
}

nlohmann::json assemble(StageContext& ctx, const ExperimentSpec& s) {
  const int k = ctx.base(s).scenario.users;
  std::string curves, finals =
      "experiment,algo,train_seed,users,users_seed,objective,T,success,arrivals,collisions,boundary_events,reward,"
      "train_seconds,steps_per_second,train_steps,uavs\n";
  AssemblyProgress progress(ctx, s.algos.size() * s.seeds.size());
  for (const auto& algo : s.algos)
    for (auto seed : s.seeds) {
      const Config cfg = ctx.run_config(s, algo, seed, k);
      progress.start();
      const bool fresh = ctx.ensure(ctx.marl_piece(cfg));
      const auto info = ctx.run_info(cfg);
      const std::string m = read_file((info.dir / "metrics.csv").string());
      if (curves.empty()) curves = "algo,users," + csv_header(m) + "\n";
      curves += csv_prefixed(m, fmt::format("{},{},", algo, k));
      const fs::path eval = info.dir / "eval" / "summary.csv";
      const CsvTable e = CsvTable::parse(read_file(eval.string()), eval.string());
      for (std::size_t r = 0; r < e.size(); ++r)
        finals += fmt::format("{},{},{},{},{},{},{},{},{},{}\n", s.name, algo, seed, k, e.at(r, "seed"), episode_columns(e, r),
                              format_double(info.seconds), format_double(info.steps_per_second), cfg.marl.total_steps,
                              cfg.trajectory.starts.size());
      progress.done(fmt::format("{} seed {}{}", algo, seed, fresh ? "" : " (ready)"), fresh);
    }
  // The heuristic references on the same users.
  std::string refs = "experiment,users,users_seed,planner,objective,T,success,arrivals,collisions,boundary_events,reward,seconds\n";
  if (!s.planners.empty()) {
    const Piece p = references(ctx, s);
    ctx.ensure(p);
    const fs::path file = ctx.out / p.id / "summary.csv";
    const CsvTable e = CsvTable::parse(read_file(file.string()), file.string());
    for (std::size_t r = 0; r < e.size(); ++r)
      refs += fmt::format("{},{},{},{},{},{}\n", s.name, k, e.at(r, "seed"), e.at(r, "planner"), episode_columns(e, r),
                          e.at(r, "seconds"));
  }
  ctx.write(fs::path(s.name) / "curves.csv", curves);
  ctx.write(fs::path(s.name) / (s.name + ".csv"), finals);
  ctx.write(fs::path(s.name) / "references.csv", refs);
  return {s.name + "/" + s.name + ".csv", s.name + "/curves.csv", s.name + "/references.csv"};
}

}  // namespace

StageKind marl_training_stage() { return {1, pieces, assemble}; }

}  // namespace skyloop::repro
