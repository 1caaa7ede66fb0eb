// Stage kind "models": the learned beamformers the sweeps and the environment's oracle use.
// A label whose shipped model (models/<label>) was trained with the same settings is used as is;
// any other is trained into models/<label>-<hash of its training settings>.
#include <fmt/format.h>
#include <optional>

#include "context.hpp"
#include "skyloop/core/config_io.hpp"
#include "skyloop/core/io.hpp"
#include "skyloop/nn/learned.hpp"

namespace skyloop::repro {

namespace {

struct ModelSource {
  std::string path;                // model.pt
  std::string source;              // shipped | trained (in this run directory, now or by an earlier run)
  std::optional<Piece> piece;      // when it is trained here
};

ModelSource model_source(StageContext& ctx, const ExperimentSpec& s, const std::string& label) {
  Config cfg = ctx.base(s, model_labels().at(label).sets);
  ModelSource m;
  const fs::path shipped = fs::path(source_dir()) / "models" / label;
  if (s.reuse_shipped && fs::exists(shipped / "model.pt") && fs::exists(shipped / "config.toml")) {
    Config trained;
    apply_toml(trained, read_file((shipped / "config.toml").string()), (shipped / "config.toml").string());
    trained.run.threads = cfg.run.threads;
    if (training_key(trained) == training_key(cfg)) {
      m.path = (shipped / "model.pt").string();
      m.source = "shipped";
      return m;
    }
  }
  const std::string name = fmt::format("{}-{}", label, hex(hash_text(training_key(cfg))).substr(0, 12));
  const fs::path dir = ctx.out / "models" / name;
  m.path = (dir / "model.pt").string();
  m.source = "trained";
  Piece p;
  p.id = "models/" + name;
  p.kind = "model";
  p.label = label;
  p.cost = 0.002 * static_cast<double>(cfg.nn.epochs) * static_cast<double>(cfg.nn.train_samples) / 100.0;
  p.done = [&ctx, dir, id = p.id] { return fs::exists(dir / "test.json") && ctx.cache.sealed(id); };
  p.run = [&ctx, cfg, dir, label] {
    ctx.log << "  training " << label << " in " << dir.string() << "\n" << std::flush;
    TrainOptions t;
    t.out_dir = dir.string();
    t.resume = fs::exists(dir / "last.pt");
    t.force = !t.resume;  // the cache's own directory: a run killed before its first checkpoint restarts
    t.progress = &ctx.log;
    // One torch thread, whatever --threads: a float sum split over other threads rounds
    // differently and trains another model, and the cache key (like a --force rerun with other
    // --threads) must name one model.
    Config one = cfg;
    one.run.threads = 1;
    train_beamformer(one, t);
  };
  m.piece = std::move(p);
  return m;
}

std::vector<Piece> pieces(StageContext& ctx, const ExperimentSpec& s) {
  std::vector<Piece> out;
  for (const auto& label : s.models)
    if (auto m = model_source(ctx, s, label); m.piece) out.push_back(std::move(*m.piece));
  return out;
}

nlohmann::json assemble(StageContext& ctx, const ExperimentSpec& s) {
  std::string csv = "experiment,seed,model,source,path,best_val_sum_rate,epoch,parameters\n";
  for (const auto& label : s.models) {
    ModelSource m = model_source(ctx, s, label);
    if (m.piece) ctx.ensure(*m.piece);
    set_torch_threads(1);
    const auto model = LearnedBeamformer::load(m.path, ctx.base(s, model_labels().at(label).sets));
    ctx.model_paths[label] = fs::absolute(m.path).string();
    ctx.model_hashes[label] = hash_text(read_file(m.path, "model"));
    // Shown relative to the source tree or the run directory when under them.
    std::string shown = ctx.model_paths[label];
    for (const fs::path& root : {fs::absolute(source_dir()), fs::absolute(ctx.out)}) {
      const auto rel = fs::path(shown).lexically_relative(root.lexically_normal());
      if (!rel.empty() && rel.native().rfind("..", 0) != 0) {
        shown = (root == fs::absolute(ctx.out) ? "" : "<source>/") + rel.string();
        break;
      }
    }
    ctx.shown_models[label] = shown;
    csv += fmt::format("{},{},{},{},{},{},{},{}\n", s.name, ctx.base(s).run.seed, label, m.source, shown,
                       format_double(model->info().best_val_sum_rate), model->info().epoch, model->info().parameters);
    ctx.log << fmt::format("  {}: {} ({})\n", label, m.source, m.path) << std::flush;
  }
  ctx.write(fs::path(s.name) / "models.csv", csv);
  return nlohmann::json::array({s.name + "/models.csv"});
}

}  // namespace

StageKind models_stage() { return {0, pieces, assemble}; }

}  // namespace skyloop::repro
