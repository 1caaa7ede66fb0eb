// Stage kind "generalisation": learners trained on a new user layout every episode (the
// experiment's `set`, e.g. configs/generalise.toml's recipe), judged on layouts they trained on and
// on held-out test layouts (skyloop/env/layouts.hpp), also at user counts K they never saw, each
// layout against its own exact optimum, beside the heuristic planners on the same layouts.
#include <fmt/format.h>

#include "context.hpp"
#include "skyloop/core/csv.hpp"
#include "skyloop/core/io.hpp"

namespace skyloop::repro {

namespace {

/// A configuration pinned to K users on every layout.
Config at_users(Config c, int k) {
  c.scenario.users = k;
  c.env.users_min = c.env.users_max = 0;
  return c;
}

LayoutEvalOptions options(const ExperimentSpec& s, LayoutSplit split, std::vector<std::string> planners) {
  LayoutEvalOptions o;
  o.layouts = s.samples;
  o.split = split;
  o.planners = std::move(planners);
  o.unsafe = true;  // the policies with and without the mask and the shield
  return o;
}

LayoutEvalOptions with_rollout(LayoutEvalOptions o, bool rollout) {
  o.rollout = rollout;
  return o;
}

struct Item {
  std::string algo, seed, eval, users;  // the CSV's key columns
  Piece piece;
  bool optima = false;                  // a chunk of another item's optima: computed, not assembled
};

/// The layouts piece of `o`, after the chunks of its optima (StageContext::optima_pieces), on
/// which it then depends.
void add_layouts(std::vector<Item>& out, const StageContext& ctx, const Config& cfg, const fs::path& dir,
                 const LayoutEvalOptions& o, const Config* train, Item item) {
  auto optima = ctx.optima_pieces(cfg, dir, o);
  for (const auto& p : optima) out.push_back({item.algo, item.seed, item.eval, item.users, p, true});
  item.piece = ctx.layouts_piece(cfg, dir, o, train, {}, std::move(optima));
  out.push_back(std::move(item));
}

std::vector<Item> items(const StageContext& ctx, const ExperimentSpec& s) {
  std::vector<Item> out;
  const Config base = ctx.base(s, {"run.threads=1"});
  const std::string trained_k = base.env.users_min && base.env.users_max
                                    ? fmt::format("{}-{}", base.env.users_min, base.env.users_max)
                                    : std::to_string(base.scenario.users);
  // The planners and the optima on the test layouts, once per K.
  std::map<int, std::string> refs;
  for (int k : s.users) {
    const Config c = at_users(base, k);
    add_layouts(out, ctx, c, ctx.eval_dir(c, fmt::format("layouts_test_n{}", s.samples), s.planners),
                options(s, LayoutSplit::Test, s.planners), nullptr, {"", "", "test", std::to_string(k), {}});
    refs[k] = out.back().piece.id;
  }
  for (const auto& algo : s.algos)
    for (auto seed : s.seeds) {
      const Config run = ctx.run_config(s, algo, seed, base.scenario.users);
      const std::string tag = fmt::format("{}_s{}", algo, seed);
      out.push_back({algo, std::to_string(seed), "", "", ctx.marl_piece(run)});
      // The layouts this run trained on (its first episodes), with the planners on them.
      const int n_train = s.train_layouts > 0 ? s.train_layouts : s.samples;
      LayoutEvalOptions tr = options(s, LayoutSplit::Train, s.planners);
      tr.layouts = n_train;
      tr.users_seeds = training_layouts_of(run, n_train);
      add_layouts(out, ctx, run, ctx.eval_dir(run, tag + fmt::format("_train_n{}", n_train), s.planners), tr, &run,
                  {algo, std::to_string(seed), "train", trained_k, {}});
      for (int k : s.users) {
        const Config c = at_users(run, k);
        out.push_back({algo, std::to_string(seed), "test", std::to_string(k),
                       ctx.layouts_piece(c, ctx.eval_dir(c, tag + fmt::format(s.rollout ? "_test_rollout_n{}" : "_test_n{}", s.samples), {}),
                                         with_rollout(options(s, LayoutSplit::Test, {}), s.rollout), &run, {refs[k]})});
      }
    }
  return out;
}

std::vector<Piece> pieces(StageContext& ctx, const ExperimentSpec& s) {
  std::vector<Piece> out;
  for (auto& i : items(ctx, s)) out.push_back(std::move(i.piece));
  return out;
}

nlohmann::json assemble(StageContext& ctx, const ExperimentSpec& s) {
  const auto all = items(ctx, s);
  std::string summary, layouts;
  AssemblyProgress progress(ctx, all.size());
  for (const auto& i : all) {
    progress.start();
    const bool fresh = ctx.ensure(i.piece);
    if (i.optima) {  // read by the layouts piece after it
      progress.done(fmt::format("{} {} {}", i.algo.empty() ? "planners" : i.algo + " seed " + i.seed, i.eval, i.piece.label), fresh);
      continue;
    }
    if (i.eval.empty()) {  // a training run
      progress.done(fmt::format("{} seed {} trained", i.algo, i.seed), fresh);
      continue;
    }
    const fs::path dir = ctx.out / i.piece.id;
    const std::string sum = read_file((dir / "summary.csv").string()), rows = read_file((dir / "layouts.csv").string());
    const std::string prefix = fmt::format("{},{},{},{},{},", s.name, i.algo, i.seed, i.eval, i.users);
    if (summary.empty()) {
      summary = "experiment,algo,train_seed,eval,eval_users," + csv_header(sum) + "\n";
      layouts = "experiment,algo,train_seed,eval,eval_users," + csv_header(rows) + "\n";
    }
    summary += csv_prefixed(sum, prefix);
    layouts += csv_prefixed(rows, prefix);
    progress.done(fmt::format("{} {} layouts, K = {}", i.algo.empty() ? "planners" : i.algo + " seed " + i.seed, i.eval, i.users),
                  fresh);
  }
  ctx.write(fs::path(s.name) / (s.name + ".csv"), summary);
  ctx.write(fs::path(s.name) / "layouts.csv", layouts);
  return {s.name + "/" + s.name + ".csv", s.name + "/layouts.csv"};
}

}  // namespace

StageKind generalisation_stage() { return {1, pieces, assemble}; }

}  // namespace skyloop::repro
