// Stage kind "trajectories": the paths of one trained policy and of the planners on the same
// users, at each user count K (the paper's trajectory figures).
#include <fmt/format.h>

#include "context.hpp"
#include "skyloop/core/csv.hpp"
#include "skyloop/core/io.hpp"

namespace skyloop::repro {

namespace {

struct Paths {
  Config cfg;        // the policy's training run
  Piece run, eval;   // train it; evaluate it beside the planners
};

Paths paths_at(const StageContext& ctx, const ExperimentSpec& s, int k) {
  Paths p;
  const auto seed = s.seeds.front();
  if (s.one_policy) {
    // One policy, trained on the experiment's layouts (its own K or K range), drawn at K users.
    p.cfg = ctx.run_config(s, s.algos.front(), seed, ctx.base(s).scenario.users);
    Config at = p.cfg;
    at.scenario.users = k;
    at.env.users_min = at.env.users_max = 0;
    p.run = ctx.marl_piece(p.cfg);
    p.eval = ctx.eval_piece(at, ctx.eval_dir(at, s.algos.front() + "_s" + std::to_string(seed) + "_one", s.planners), s.planners,
                            ctx.run_dir(p.cfg), &p.cfg);
    return p;
  }
  p.cfg = ctx.run_config(s, s.algos.front(), seed, k);
  p.run = ctx.marl_piece(p.cfg);
  p.eval = ctx.eval_piece(p.cfg, ctx.eval_dir(p.cfg, s.algos.front() + "_s" + std::to_string(seed), s.planners), s.planners,
                          ctx.run_dir(p.cfg));
  return p;
}

std::vector<Piece> pieces(StageContext& ctx, const ExperimentSpec& s) {
  std::vector<Piece> out;
  for (int k : s.users) {
    Paths p = paths_at(ctx, s, k);
    if (!s.one_policy || k == s.users.front()) out.push_back(std::move(p.run));  // one run for every K
    out.push_back(std::move(p.eval));
  }
  return out;
}

nlohmann::json assemble(StageContext& ctx, const ExperimentSpec& s) {
  std::string traj, users, summary;
  AssemblyProgress progress(ctx, s.users.size());
  const auto seed = s.seeds.front();
  for (int k : s.users) {
    const Paths p = paths_at(ctx, s, k);
    progress.start();
    const bool trained = ctx.ensure(p.run);
    const bool evaluated = ctx.ensure(p.eval);
    const fs::path dir = ctx.out / p.eval.id;
    const std::string t = read_file((dir / "trajectory.csv").string()), u = read_file((dir / "users.csv").string()),
                      e = read_file((dir / "summary.csv").string());
    if (traj.empty()) {
      traj = "experiment,users,train_seed," + csv_header(t) + "\n";
      users = "experiment,users," + csv_header(u) + "\n";
      summary = "experiment,users,train_seed," + csv_header(e) + "\n";
    }
    traj += csv_prefixed(t, fmt::format("{},{},{},", s.name, k, seed));
    users += csv_prefixed(u, fmt::format("{},{},", s.name, k));
    summary += csv_prefixed(e, fmt::format("{},{},{},", s.name, k, seed));
    progress.done(fmt::format("K = {}", k), trained || evaluated);
  }
  // Starts and destinations for the plots.
  const Config c = ctx.base(s);
  std::string ends = "experiment,seed,uav,start_x,start_y,dest_x,dest_y\n";  // seed: the users seed of the plots
  for (std::size_t n = 0; n < c.trajectory.starts.size(); ++n)
    ends += fmt::format("{},{},{},{},{},{},{}\n", s.name, c.marl.users_seed, n, format_double(c.trajectory.starts[n].x),
                        format_double(c.trajectory.starts[n].y), format_double(c.trajectory.destinations[n].x),
                        format_double(c.trajectory.destinations[n].y));
  ctx.write(fs::path(s.name) / (s.name + ".csv"), traj);
  ctx.write(fs::path(s.name) / "users.csv", users);
  ctx.write(fs::path(s.name) / "summary.csv", summary);
  ctx.write(fs::path(s.name) / "endpoints.csv", ends);
  return {s.name + "/" + s.name + ".csv", s.name + "/users.csv", s.name + "/summary.csv", s.name + "/endpoints.csv"};
}

}  // namespace

StageKind trajectories_stage() { return {1, pieces, assemble}; }

}  // namespace skyloop::repro
