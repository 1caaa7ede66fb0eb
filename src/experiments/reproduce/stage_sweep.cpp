// Stage kind "beamform_sweep": the beamformers on seeded snapshots at every value of one config
// key. A point's snapshots are cut into chunks of kChunk (the pieces: a sweep spreads over as many
// ranks as it has chunks); the point's summary is computed from its chunks' rows at assembly, so
// the CSVs do not depend on how the chunks were computed.
#include <cmath>
#include <fmt/format.h>

#include "context.hpp"
#include "skyloop/core/csv.hpp"
#include "skyloop/core/error.hpp"
#include "skyloop/core/io.hpp"
#include "skyloop/experiments/beamform_eval.hpp"
#include "skyloop/experiments/builtin.hpp"
#include "skyloop/nn/learned.hpp"

namespace skyloop::repro {

namespace {

constexpr std::size_t kChunk = 10;  // snapshots per piece: fine enough that the last pieces of a run balance the ranks

/// Rough seconds of one snapshot on one core for `method` (the farm's order and the projections
/// depend on it, never a result). Calibrated on this project's measurements: a decision costs
/// about linearly in the users served (BENCHMARKS.md, "Scale and fast inference"); the GA about
/// 1.2 s per paper snapshot at 2000 x 100 and the coordinated methods 2.5e-4 s per user (both
/// measured from a quick-profile run's timings.csv, 2026-11-23).
double method_cost(const Config& cfg, const std::string& method) {
  const double users = cfg.scenario.users;
  if (method == "ga") return 1.2 * users / 12.0 * (cfg.ga.generations * cfg.ga.population) / 200000.0;
  if (method.rfind("nwmmse", 0) == 0 || method.rfind("crzf", 0) == 0 || method.rfind("czf", 0) == 0) return 2.5e-4 * users;
  if (method.rfind("wmmse", 0) == 0) return 2.5e-6 * users;
  return 1.5e-6 * users;
}
constexpr double kChunkSetup = 0.05;  // seconds: a chunk loads its models and builds its beamformers

struct Point {
  std::string series;              // the series value ("" without experiment.series)
  std::string value;               // the swept value as written in the CSVs
  Config cfg;
  fs::path dir;                    // <experiment>/points/<value>-<hash>
  std::vector<Piece> chunks;
};

struct Sweep {
  std::vector<std::string> specs;  // registry specs (learned labels -> base=path)
  std::vector<Point> points;
};

Sweep plan(StageContext& ctx, const ExperimentSpec& s) {
  Sweep w;
  std::uint64_t mh = hash_text(fmt::format("{}|{}", s.samples, s.seed));
  for (const auto& m : s.methods) {
    if (auto it = ctx.model_paths.find(m); it != ctx.model_paths.end()) {
      w.specs.push_back(model_labels().at(m).base + "=" + it->second);
      mh = hash_text(fmt::format("{}:{}", m, ctx.model_hashes.at(m)), mh);
    } else {
      if (model_labels().count(m)) throw InputError(s.path + ": method '" + m + "' needs the models stage to list it");
      w.specs.push_back(m);
      mh = hash_text(m, mh);
    }
  }
  const auto samples = static_cast<std::size_t>(s.samples);
  const std::vector<std::string> series = s.series.empty() ? std::vector<std::string>{""} : s.series_values;
  for (const std::string& sv : series)
  for (const std::string& x : s.values) {
    Point p;
    p.series = sv;
    p.value = x;
    std::vector<std::string> sets{s.sweep + "=" + p.value};
    if (!sv.empty()) sets.insert(sets.begin(), s.series + "=" + sv);
    p.cfg = ctx.base(s, sets);
    const std::string id = fmt::format("{}{}-{}", sv.empty() ? "" : sv + "-", p.value, hex(hash_text(config_key(p.cfg), mh)).substr(0, 12));
    p.dir = fs::path(s.name) / "points" / id;
    double per_snapshot = 0;
    for (const auto& m : s.methods) per_snapshot += method_cost(p.cfg, m);
    for (std::size_t first = 0; first < samples; first += kChunk) {
      const std::size_t count = std::min(kChunk, samples - first);
      const fs::path file = ctx.out / p.dir / fmt::format("{}-{}.csv", first, first + count - 1);
      Piece c;
      c.id = (p.dir / file.filename()).generic_string();
      c.kind = "chunk";
      c.label = fmt::format("{} {}{} = {} snapshots {}-{}", s.name, sv.empty() ? "" : s.series + " = " + sv + ", ", s.sweep, p.value,
                            first, first + count - 1);
      c.cost = kChunkSetup + (per_snapshot + 1e-6 * p.cfg.scenario.users) * static_cast<double>(count);
      c.done = [&ctx, file, id = c.id] { return fs::exists(file) && ctx.cache.sealed(id); };
      c.run = [&ctx, cfg = p.cfg, specs = w.specs, labels = s.methods, file, first, count, seed = s.seed] {
        BeamformEvalOptions o;
        o.methods = specs;
        o.uavs = cfg.scenario.uavs;
        o.users = cfg.scenario.users;
        o.samples = count;
        o.first = first;
        o.seed = seed;
        o.threads = cfg.run.threads;
        set_torch_threads(1);  // decisions are timed on one core each; snapshots run in parallel
        auto rows = run_beamform_eval(cfg, o, builtin_beamformers(), &ctx.log);
        for (auto& r : rows)
          for (std::size_t m = 0; m < specs.size(); ++m)
            if (r.method == specs[m]) r.method = labels[m];  // the CSV keeps the label
        write_file_atomic(file.string(), beamform_eval_csv(rows, cfg));
      };
      p.chunks.push_back(std::move(c));
    }
    w.points.push_back(std::move(p));
  }
  return w;
}

std::vector<Piece> pieces(StageContext& ctx, const ExperimentSpec& s) {
  std::vector<Piece> out;
  for (auto& p : plan(ctx, s).points)
    for (auto& c : p.chunks) out.push_back(std::move(c));
  return out;
}

nlohmann::json assemble(StageContext& ctx, const ExperimentSpec& s) {
  const Sweep w = plan(ctx, s);
  std::string samples,
      summary = "seed,experiment,x_name,x,method,samples,mean,std,sem,median_latency_ms,mean_latency_ms,series_name,series\n";
  AssemblyProgress progress(ctx, w.points.size());
  for (std::size_t i = 0; i < w.points.size(); ++i) {
    const Point& p = w.points[i];
    progress.start();
    bool cached = true;
    for (const auto& c : p.chunks) cached = !ctx.ensure(c) && cached;
    std::vector<BeamformEvalRow> rows;
    for (const auto& c : p.chunks) {
      const std::string text = read_file((ctx.out / c.id).string());
      // Each sample row says which point it belongs to (the swept key and the series may not be
      // among beamform eval's columns, e.g. channel.pathloss).
      if (samples.empty()) samples = "x_name,x,series_name,series," + csv_header(text) + "\n";
      samples += csv_prefixed(text, s.sweep + "," + p.value + "," + s.series + "," + p.series + ",");
      const auto part = parse_beamform_eval_csv(text, c.id);
      rows.insert(rows.end(), part.begin(), part.end());
    }
    for (const auto& m : summarise(rows))
      summary += fmt::format("{},{},{},{},{},{},{},{},{},{},{},{},{}\n", s.seed, s.name, s.sweep, p.value, m.method, m.samples,
                             format_double(m.mean), format_double(m.std),
                             format_double(m.samples > 1 ? m.std / std::sqrt(static_cast<double>(m.samples)) : 0.0),
                             format_double(m.median_latency_ms), format_double(m.mean_latency_ms), s.series, p.series);
    progress.done((p.series.empty() ? "" : s.series + " = " + p.series + ", ") + s.sweep + " = " + p.value + (cached ? " (cached)" : ""),
                  !cached);
  }
  ctx.write(fs::path(s.name) / "samples.csv", samples);
  ctx.write(fs::path(s.name) / (s.name + ".csv"), summary);
  return {s.name + "/" + s.name + ".csv", s.name + "/samples.csv"};
}

}  // namespace

StageKind sweep_stage() { return {1, pieces, assemble}; }

}  // namespace skyloop::repro
