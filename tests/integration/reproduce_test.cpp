// `skyloop reproduce`: the experiment files, and a whole run on the tiny profile.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <map>
#include <regex>
#include <set>
#include <sstream>
#include <sys/wait.h>
#include <unistd.h>

#include "skyloop/core/config_io.hpp"
#include "skyloop/core/error.hpp"
#include "skyloop/experiments/reproduce.hpp"
// The stage kind table (internal to the library).
#include "../../src/experiments/reproduce/context.hpp"
#include "../scratch.hpp"

namespace fs = std::filesystem;
using namespace skyloop;

namespace {

const std::string kSrc = SKYLOOP_SOURCE_DIR;
const std::string kExperiments = kSrc + "/configs/experiments";

/// The data rows of a CSV (no quoting in skyloop's CSVs), each split at the commas; the header
/// first with `header`.
std::vector<std::vector<std::string>> csv_rows(const std::string& csv, bool header = false) {
  std::vector<std::vector<std::string>> rows;
  std::istringstream in(csv);
  std::string line;
  if (!header) std::getline(in, line);
  while (std::getline(in, line)) {
    std::vector<std::string> f;
    std::stringstream ls(line);
    for (std::string x; std::getline(ls, x, ',');) f.push_back(x);
    rows.push_back(std::move(f));
  }
  return rows;
}

std::string slurp(const fs::path& p) {
  std::ifstream in(p);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

struct Result {
  int code = -1;
  std::string out, err;
};

Result run(const std::string& args, const fs::path& logs) {
  fs::create_directories(logs);
  const std::string cmd = std::string(SKYLOOP_BIN) + " " + args + " >" + (logs / "out").string() + " 2>" + (logs / "err").string();
  const int status = std::system(cmd.c_str());
  return {WIFEXITED(status) ? WEXITSTATUS(status) : -1, slurp(logs / "out"), slurp(logs / "err")};
}

fs::path tmp(const std::string& name) { return skyloop::test::scratch_path(name); }

}  // namespace

TEST(Experiments, EveryFileLoadsForEveryProfile) {
  for (const std::string profile : {"quick", "paper", "tiny"}) {
    const auto specs = load_experiments(kExperiments, profile);
    ASSERT_GE(specs.size(), 9u);
    EXPECT_EQ(specs.front().kind, "models");
    std::set<std::string> figures;
    for (const auto& s : specs) {
      figures.insert(s.figure);
      // Every override resolves against the configuration table.
      EXPECT_NO_THROW(resolve_experiment(s)) << s.path;
    }
    // Every figure of the paper's Section VI has its experiment.
    for (const std::string f : {"fig:power_sweep", "fig:noise_sweep", "fig:uav_gen", "fig:User_gen", "fig:runtime",
                                "fig:convergence", "fig:heuristic_comp", "fig:trajectory_vis"})
      EXPECT_EQ(figures.count(f), 1u) << profile << " lacks " << f;
  }
}

TEST(Experiments, PaperProfileUsesThePapersSettings) {
  const Config defaults;
  for (const auto& s : load_experiments(kExperiments, "paper")) {
    const Config c = resolve_experiment(s);
    EXPECT_EQ(c.ga.generations, 2000) << s.path;
    EXPECT_EQ(c.nn.train_samples, 10000) << s.path;
    EXPECT_EQ(c.nn.epochs, 25) << s.path;
    EXPECT_EQ(c.marl.rollout, defaults.marl.rollout) << s.path;
    if (s.kind == "marl_training" || s.kind == "planning_users") {
      EXPECT_EQ(s.steps, 2000000) << s.path;
      EXPECT_GE(s.seeds.size(), 3u) << s.path;
    }
    if (s.kind == "beamform_sweep") {
      EXPECT_TRUE(std::count(s.methods.begin(), s.methods.end(), "wmmse") && std::count(s.methods.begin(), s.methods.end(), "zf") &&
                  std::count(s.methods.begin(), s.methods.end(), "mrt"))
          << s.path << ": every beamforming figure shows WMMSE, ZF and MRT";
    }
    // The exact optimum beside every planning figure where the DP can solve it (the scale study's
    // 16 UAVs are far beyond it: 2401^16 joint states, which the DP refuses by name).
    if ((s.kind == "planning_users" || s.kind == "trajectories") && resolve_experiment(s).scenario.uavs <= 3) {
      EXPECT_TRUE(std::count(s.planners.begin(), s.planners.end(), "optimal")) << s.path;
    }
  }
}

TEST(Experiments, BadFilesGiveOneClearError) {
  const std::string ok = "[experiment]\nname = \"x\"\nkind = \"beamform_sweep\"\nsweep = \"channel.p_max_dbm\"\n"
                         "values = [10]\nmethods = [\"mrt\"]\n[profile.quick]\n";
  EXPECT_NO_THROW(parse_experiment(ok, "x.toml", "quick"));
  const std::vector<std::pair<std::string, std::string>> bad = {
      {ok + "frob = 1\n", "unknown key 'profile.quick.frob'"},
      {ok, "profile 'paper' is not defined"},
      {"[experiment]\nname = \"x\"\nkind = \"nosuch\"\n[profile.quick]\n", "experiment.kind = \"nosuch\" is invalid"},
      {"[experiment]\nname = \"x\"\nkind = \"beamform_sweep\"\n[profile.quick]\n", "experiment.sweep is missing"},
      {ok + "samples = 0\n", "samples = 0 is invalid: allowed an integer in [1, 1000000]"},
      {ok + "train_layouts = -1\n", "train_layouts = -1 is invalid: allowed an integer in [0, 1000000]"},
      {"[experiment\n", "invalid TOML"},
      {ok + "series = \"channel.environment\"\n", "experiment.series and experiment.series_values is missing"},
  };
  for (const auto& [text, want] : bad) {
    const std::string profile = text == ok ? "paper" : "quick";
    try {
      parse_experiment(text, "bad.toml", profile);
      ADD_FAILURE() << "accepted:\n" << text;
    } catch (const InputError& e) {
      const std::string msg = e.what();
      EXPECT_NE(msg.find("bad.toml"), std::string::npos) << msg;
      EXPECT_NE(msg.find(want), std::string::npos) << msg;
      EXPECT_EQ(msg.find('\n'), std::string::npos) << msg;
    }
  }
}

// An experiment trained with a recipe names the recipe's file (`config`, relative to the experiment
// file) instead of repeating its fields: the file's fields apply, the experiment's `set` over them,
// and a missing or bad file is one line at load.
TEST(Experiments, AConfigFileIsTheBaseOfTheExperimentsSettings) {
  const fs::path dir = tmp("recipe");
  fs::create_directories(dir / "experiments");
  std::ofstream(dir / "recipe.toml") << "[marl]\nencoder = \"set\"\nhidden = 32\n[env]\nstate = \"compact\"\nusers_min = 8\nusers_max = 16\n";
  std::ofstream(dir / "bad_recipe.toml") << "[marl]\nhidden = -1\n";
  const std::string head = "[experiment]\nname = \"g\"\nkind = \"generalisation\"\nseeds = [1]\nusers = [12]\n";
  const std::string source = (dir / "experiments" / "g.toml").string();
  const ExperimentSpec s = parse_experiment(head + "config = \"../recipe.toml\"\nset = [\"marl.hidden=48\"]\n[profile.quick]\n",
                                            source, "quick");
  EXPECT_TRUE(fs::equivalent(s.config, dir / "recipe.toml")) << s.config;
  const Config c = resolve_experiment(s, {"marl.hidden=16", "env.users_max=12"}, {"env.users_min=4"});
  EXPECT_EQ(c.marl.encoder, ObservationKind::Set);  // the file
  EXPECT_EQ(c.marl.hidden, 48);       // `set` over the file and over `before`
  EXPECT_EQ(c.env.users_max, 12);     // `before` over the file
  EXPECT_EQ(c.env.users_min, 4);      // `after` last
  EXPECT_EQ(c.marl.algo, Config{}.marl.algo);  // the defaults under everything
  // Without a file: the defaults and `set`, as before.
  const ExperimentSpec plain = parse_experiment(head + "set = [\"marl.hidden=48\"]\n[profile.quick]\n", source, "quick");
  EXPECT_TRUE(plain.config.empty());
  EXPECT_EQ(resolve_experiment(plain).marl.encoder, Config{}.marl.encoder);
  for (const auto& [line, want] : std::vector<std::pair<std::string, std::string>>{
           {"config = \"../nosuch.toml\"", "experiment.config = \"../nosuch.toml\" is invalid: allowed a configuration file"},
           {"config = \"\"", "experiment.config = \"\" is invalid"},
           {"config = 3", "experiment.config = 3 is invalid: allowed a string"},
           {"config = \"../bad_recipe.toml\"", "bad_recipe.toml"}}) {
    try {
      parse_experiment(head + line + "\n[profile.quick]\n", source, "quick");
      ADD_FAILURE() << "accepted " << line;
    } catch (const InputError& e) {
      const std::string msg = e.what();
      EXPECT_NE(msg.find(want), std::string::npos) << msg;
      EXPECT_EQ(msg.find('\n'), std::string::npos) << msg;
    }
  }
  // The shipped experiments trained with the recipe read it from configs/generalise.toml.
  int with_recipe = 0;
  for (const auto& e : load_experiments(kExperiments, "paper"))
    if (!e.config.empty()) {
      EXPECT_TRUE(fs::equivalent(e.config, kSrc + "/configs/generalise.toml")) << e.path;
      EXPECT_EQ(resolve_experiment(e).marl.encoder, ObservationKind::Set) << e.path;
      ++with_recipe;
    }
  EXPECT_GE(with_recipe, 5);
  fs::remove_all(dir);
}

// Every kind an experiment file may name is a stage of the registry, once, with its pieces and
// assembly; an unknown kind is an error naming the kinds there are, never a silent fall-through.
TEST(Reproduce, EveryExperimentKindHasAStage) {
  std::set<std::string> table;
  for (const auto& k : repro::stage_kinds().rows()) {
    EXPECT_TRUE(table.insert(k.name).second) << k.name << " twice";
    EXPECT_TRUE(k.entry.pieces && k.entry.assemble) << k.name;
  }
  EXPECT_EQ(repro::stage_kind("models").phase, 0);
  try {
    repro::stage_kind("beamform_swep");
    ADD_FAILURE() << "an unknown kind was accepted";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("beamform_swep"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("trajectories"), std::string::npos) << e.what();
  }
}

TEST(Reproduce, BadArgumentsAreOneLine) {
  const auto logs = tmp("bad");
  for (const std::string& args : {"reproduce --profile nosuch --no-plots --out " + (logs / "o").string(),
                                 "reproduce --profile tiny --only nosuch --no-plots --out " + (logs / "o").string(),
                                 "reproduce --profile tiny --experiments /nonexistent --out " + (logs / "o").string()}) {
    const auto r = run(args, logs);
    EXPECT_EQ(r.code, 2) << args << r.err;
    EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1) << r.err;
  }
}

// The whole pipeline on the tiny profile: every stage, every figure, a report whose links all
// resolve; a second run reuses everything; --force redoes what it names.
// A cached piece cut at a line boundary (no CSV reader notices: every row is whole) or edited is
// computed again, never read: power_sweep.csv used to hold 2 methods of 8 at one point, exit 0.
TEST(Reproduce, APieceChangedOnDiskIsComputedAgain) {
  const fs::path out = tmp("sealed");
  const std::string args = "reproduce --profile tiny --only power_sweep --no-plots --threads 2 --out " + out.string();
  ASSERT_EQ(run(args, out / "logs1").code, 0);
  const std::string whole = slurp(out / "power_sweep" / "power_sweep.csv");
  std::vector<fs::path> chunks;
  for (const auto& e : fs::recursive_directory_iterator(out / "power_sweep" / "points"))
    if (e.is_regular_file() && e.path().extension() == ".csv") chunks.push_back(e.path());
  ASSERT_FALSE(chunks.empty());
  std::sort(chunks.begin(), chunks.end());
  const std::string text = slurp(chunks.front());
  const auto cut = text.find('\n', text.find('\n') + 1);  // the header and one row
  ASSERT_NE(cut, std::string::npos);
  std::ofstream(chunks.front(), std::ios::binary | std::ios::trunc) << text.substr(0, cut + 1);
  const auto again = run(args, out / "logs2");
  ASSERT_EQ(again.code, 0) << again.err;
  EXPECT_NE(again.err.find("changed on disk"), std::string::npos) << again.err;
  // The chunk computed again (its last column, latency_ms, is a timing: compare the rest).
  auto untimed_chunk = [](const std::string& csv) {
    std::string o;
    for (auto& row : csv_rows(csv, true)) {
      for (std::size_t i = 0; i + 1 < row.size(); ++i) o += row[i] + ",";
      o += "\n";
    }
    return o;
  };
  EXPECT_EQ(untimed_chunk(slurp(chunks.front())), untimed_chunk(text));
  // The summary again (its latency columns are timings: compare the rest).
  auto untimed = [](const std::string& csv) {
    std::string o;
    for (auto& row : csv_rows(csv, true)) o += row[0] + row[1] + row[2] + row[3] + row[4] + row[5] + row[6] + row[7] + "\n";
    return o;
  };
  EXPECT_EQ(untimed(slurp(out / "power_sweep" / "power_sweep.csv")), untimed(whole));
  // A third run reads the cache: nothing changed on disk.
  const auto third = run(args, out / "logs3");
  ASSERT_EQ(third.code, 0) << third.err;
  EXPECT_EQ(third.err.find("changed on disk"), std::string::npos) << third.err;
}

TEST(Reproduce, AnEvaluationsOptimaSpreadOverPiecesWithTheSameResults) {
  // --piece-seconds below one layout's estimate: every exact optimum of a layouts evaluation is a
  // piece of its own (beside the evaluation's directory), the evaluation depends on each, and the
  // results are those of the run that solves them inside the evaluation (the default at this size).
  const fs::path whole = tmp("optima_whole"), split = tmp("optima_split");
  const std::string args = "reproduce --profile tiny --only generalisation_shared --no-plots --threads 2";
  const auto a = run(args + " --out " + whole.string(), whole / "logs");
  ASSERT_EQ(a.code, 0) << a.err;
  const auto b = run(args + " --piece-seconds 1e-9 --out " + split.string(), split / "logs");
  ASSERT_EQ(b.code, 0) << b.err;
  // The plan once the models exist (the pieces after them are keyed by their bytes).
  const auto plan = run(args + " --piece-seconds 1e-9 --plan --out " + split.string(), split / "logs_plan");
  ASSERT_EQ(plan.code, 0) << plan.err;
  std::map<std::string, std::vector<std::string>> deps;  // piece -> its dependencies
  for (const auto& row : csv_rows(plan.out)) {
    ASSERT_GE(row.size(), 6u);
    std::vector<std::string> d;
    if (row.size() > 6) {
      std::stringstream ds(row[6]);
      for (std::string x; std::getline(ds, x, ';');) d.push_back(x);
    }
    deps[row[1]] = d;
  }
  int layouts_pieces = 0;
  for (const auto& [id, d] : deps) {
    if (id.find(".optima-") != std::string::npos || id.find("_n2_") == std::string::npos) continue;
    std::vector<std::string> chunks;
    for (const auto& [other, unused] : deps)
      if (other.rfind(id + ".optima-", 0) == 0) chunks.push_back(other);
    if (id.find("layouts_test") == std::string::npos && id.find("_train_") == std::string::npos) {
      EXPECT_TRUE(chunks.empty()) << id << ": a policy's test layouts read the planners' optima";
      continue;
    }
    ++layouts_pieces;
    EXPECT_EQ(chunks.size(), 2u) << id << ": one piece per layout (the tiny profile's 2)";
    for (const auto& c : chunks) EXPECT_NE(std::find(d.begin(), d.end(), c), d.end()) << id << " does not wait for " << c;
  }
  EXPECT_EQ(layouts_pieces, 2) << plan.out;  // the test layouts' planners and the run's training layouts
  // The pieces solved exactly the evaluations' layouts: no optimum beside them.
  auto files = [](const fs::path& d) {
    std::size_t n = 0;
    for (const auto& e : fs::directory_iterator(d)) n += e.is_regular_file();
    return n;
  };
  ASSERT_TRUE(fs::exists(whole / "optima") && fs::exists(split / "optima"));
  EXPECT_EQ(files(split / "optima"), files(whole / "optima"));
  EXPECT_GE(files(whole / "optima"), 4u);  // 2 test and 2 training layouts
  auto untimed = [](const std::string& csv) {  // every column but the timings
    auto rows = csv_rows(csv, true);
    std::vector<std::size_t> keep;
    for (std::size_t i = 0; i < rows.front().size(); ++i)
      if (rows.front()[i] != "seconds") keep.push_back(i);
    std::string o;
    for (const auto& r : rows) {
      for (std::size_t i : keep) o += (i < r.size() ? r[i] : "") + ",";
      o += "\n";
    }
    return o;
  };
  const std::string layouts = "generalisation_shared/layouts.csv";
  ASSERT_TRUE(fs::exists(whole / layouts) && fs::exists(split / layouts));
  EXPECT_EQ(untimed(slurp(split / layouts)), untimed(slurp(whole / layouts)));
  EXPECT_NE(slurp(split / layouts).find("optimal"), std::string::npos) << "the optima are in the results";
  // Shards, the second first: a layouts piece whose optima pieces fell to the other shard computes
  // them (or waits for them) under their locks; the assembly then equals the one-process run.
  const fs::path sharded = tmp("optima_shards");
  for (const std::string shard : {"2/2", "1/2", ""}) {
    const auto r = run(args + " --piece-seconds 1e-9" + (shard.empty() ? "" : " --shard " + shard) + " --out " + sharded.string(),
                       sharded / ("logs" + std::to_string(shard.size())));
    ASSERT_EQ(r.code, 0) << shard << ": " << r.err;
  }
  EXPECT_EQ(untimed(slurp(sharded / layouts)), untimed(slurp(whole / layouts)));
  const auto bad = run(args + " --piece-seconds 0 --out " + split.string(), split / "logs_bad");
  EXPECT_EQ(bad.code, 2);
  EXPECT_NE(bad.err.find("--piece-seconds = 0 is out of range"), std::string::npos) << bad.err;
}

TEST(Reproduce, TinyRunWritesEveryFigureAndReport) {
  const fs::path out = tmp("tiny");
  const auto r = run("reproduce --profile tiny --threads 2 --out " + out.string(), out / "logs1");
  ASSERT_EQ(r.code, 0) << r.err;

  const auto manifest = nlohmann::json::parse(slurp(out / "manifest.json"));
  // One stage per experiment file (the files are the list).
  std::size_t files = 0;
  for (const auto& f : fs::directory_iterator(kExperiments)) files += f.path().extension() == ".toml";
  ASSERT_EQ(manifest["experiments"].size(), files);
  for (const auto& e : manifest["experiments"]) {
    const std::string name = e["name"];
    EXPECT_TRUE(fs::exists(out / name / "config.toml")) << name;
    EXPECT_TRUE(fs::exists(out / name / "experiment.toml")) << name;
    for (const auto& f : e["files"]) {
      const fs::path p = out / f.get<std::string>();
      ASSERT_TRUE(fs::exists(p)) << p;
      // Tidy CSV: a header naming a seed column and at least one row.
      const std::string csv = slurp(p);
      const std::string head = csv.substr(0, csv.find('\n'));
      EXPECT_NE(head.find("seed"), std::string::npos) << p << ": " << head;
      EXPECT_GE(std::count(csv.begin(), csv.end(), '\n'), 2) << p;
    }
  }
  for (const std::string fig : {"power_sweep", "noise_sweep", "uav_sweep", "user_sweep", "latency", "marl_episode_reward",
                                "marl_sum_rate", "planning_users", "trajectories", "shared_power_sweep", "split_power_sweep",
                                "shared_uav_sweep", "shared_marl_episode_reward", "shared_marl_sum_rate", "shared_trajectories",
                                "generalisation", "generalisation_wmmse", "generalisation_shared", "one_policy_trajectories",
                                "channel_models", "channel_environments", "rician_k", "altitude", "generalisation_3gpp",
                                "rate_energy", "ranked_selection"})
    for (const std::string ext : {".png", ".pdf"}) EXPECT_GT(fs::file_size(out / "figures" / (fig + ext)), 1000u) << fig << ext;

  const std::string report = slurp(out / "report.html");
  const std::regex link(R"((?:href|src)=\"([^\"#]+)\")");
  int links = 0;
  for (auto it = std::sregex_iterator(report.begin(), report.end(), link); it != std::sregex_iterator(); ++it, ++links)
    EXPECT_TRUE(fs::exists(out / (*it)[1].str())) << "report links a missing file: " << (*it)[1].str();
  EXPECT_GE(links, 30);
  EXPECT_EQ(report.find("(missing)"), std::string::npos);
  EXPECT_NE(report.find("fig:power_sweep"), std::string::npos);
  // UAVs home out of the experiment's own fleet: 25_scale_marl flies N = 16 (one seed per planner),
  // 22_trajectories N = 3 (the optimum brings all three home).
  const auto table_of = [&report](const std::string& id) {
    const auto at = report.find("<h2 id=\"" + id + "\">");
    return at == std::string::npos ? std::string() : report.substr(at, report.find("</table>", at) - at);
  };
  const std::string scale = table_of("scale_marl"), paths = table_of("trajectories");
  EXPECT_NE(scale.find("/16 home"), std::string::npos) << scale;
  EXPECT_EQ(scale.find("/3 home"), std::string::npos) << scale;
  EXPECT_NE(paths.find("<td>3/3</td>"), std::string::npos) << paths;

  // A sweep over named channel models: every sample row names its point; the summary has a row
  // per model and method; a series sweep has one curve per series value.
  {
    const std::string samples = slurp(out / "channel_models" / "samples.csv");
    EXPECT_EQ(samples.rfind("x_name,x,series_name,series,seed,", 0), 0u) << samples.substr(0, 80);
    EXPECT_NE(samples.find("channel.pathloss,3gpp-uma-av,,,"), std::string::npos);
    EXPECT_NE(samples.find("channel.pathloss,free-space,,,"), std::string::npos);
    std::map<std::string, std::map<std::string, double>> mean;  // x -> method -> mean
    for (const auto& f : csv_rows(slurp(out / "channel_models" / "channel_models.csv"))) mean[f.at(3)][f.at(4)] = std::stod(f.at(6));
    ASSERT_EQ(mean.size(), 2u);
    for (const auto& [x, m] : mean) EXPECT_EQ(m.size(), 6u) << x;
    const std::string altitude = slurp(out / "altitude" / "altitude.csv");
    EXPECT_NE(altitude.find("channel.environment,highrise-urban"), std::string::npos);
  }
  // The rate-power front: a larger energy weight never buys more power or more rate (exact optima
  // of R-bar - w P-bar), and the energy-efficiency optimum has the most bits per joule of the
  // planners placed on it.
  {
    std::vector<std::vector<std::string>> front, placed;
    for (const auto& f : csv_rows(slurp(out / "rate_energy" / "front.csv"))) (f.at(1) == "front" ? front : placed).push_back(f);
    ASSERT_EQ(front.size(), 2u);
    std::sort(front.begin(), front.end(), [](const auto& a, const auto& b) { return std::stod(a.at(2)) < std::stod(b.at(2)); });
    EXPECT_LE(std::stod(front[1].at(8)), std::stod(front[0].at(8)) * (1 + 1e-12));  // mean power
    EXPECT_LE(std::stod(front[1].at(7)), std::stod(front[0].at(7)) * (1 + 1e-12));  // mean sum rate
    double best = 0, optimum = 0;
    for (const auto& f : placed) {
      (f.at(3) == "optimal" ? optimum : best) = std::max(f.at(3) == "optimal" ? optimum : best, std::stod(f.at(10)));
      EXPECT_EQ(f.at(12), "1") << f.at(3) << ": every mission complete";
    }
    EXPECT_GE(placed.size(), 4u);  // greedy, random, optimal, mappo
    EXPECT_GE(optimum, best * (1 - 1e-12));
    EXPECT_GT(csv_rows(slurp(out / "rate_energy" / "speeds.csv")).size(), 1u);
  }
  // The shared-spectrum sweep: coordinated WMMSE starts from per-cluster WMMSE and only climbs, so
  // its mean is at least per-cluster WMMSE's at every power.
  {
    std::map<std::string, std::map<std::string, double>> mean;  // x -> method -> mean
    for (const auto& f : csv_rows(slurp(out / "shared_power_sweep" / "shared_power_sweep.csv")))
      mean[f.at(3)][f.at(4)] = std::stod(f.at(6));
    ASSERT_EQ(mean.size(), 2u);
    for (const auto& [x, m] : mean) EXPECT_GE(m.at("nwmmse"), m.at("wmmse")) << "x = " << x;
  }

  // Second run, on the directory as a copy without its lock files would have it (a git clone, an
  // rsync that leaves them out): nothing is recomputed (no training, every sweep point cached),
  // same CSVs. The seals used to list the runs' .skyloop.lock, so every MARL run trained again.
  {
    std::vector<fs::path> locks;
    for (const auto& e : fs::recursive_directory_iterator(out))
      if (e.path().filename() == ".skyloop.lock") locks.push_back(e.path());
    ASSERT_FALSE(locks.empty());
    for (const auto& p : locks) fs::remove(p);
    fs::remove_all(out / "locks");
  }
  const std::string before = slurp(out / "power_sweep" / "power_sweep.csv");
  const std::string curves = slurp(out / "marl_training" / "curves.csv");
  const auto again = run("reproduce --profile tiny --threads 2 --no-plots --out " + out.string(), out / "logs2");
  ASSERT_EQ(again.code, 0) << again.err;
  EXPECT_EQ(again.err.find("  training "), std::string::npos) << again.err;
  EXPECT_EQ(again.err.find("MARL runs"), std::string::npos) << again.err;
  EXPECT_EQ(again.err.find("changed on disk"), std::string::npos) << again.err;
  EXPECT_NE(again.err.find("channel.p_max_dbm = 10 (cached)"), std::string::npos) << again.err;
  EXPECT_EQ(slurp(out / "power_sweep" / "power_sweep.csv"), before);
  EXPECT_EQ(slurp(out / "marl_training" / "curves.csv"), curves);

  // --force redoes the named experiment, and the seeded sweep gives the same sum rates.
  const auto forced = run("reproduce --profile tiny --threads 1 --no-plots --only power_sweep --force --out " + out.string(),
                          out / "logs3");
  ASSERT_EQ(forced.code, 0) << forced.err;
  EXPECT_EQ(forced.err.find("(cached)"), std::string::npos) << forced.err;
  // Bit for bit, although this run has other --threads: reproduce trains every model on one torch
  // thread and times every decision on one core, so no float sum is split differently.
  const auto means = [](const std::string& csv) {
    std::vector<std::pair<std::string, double>> m;
    for (const auto& f : csv_rows(csv)) m.emplace_back(f.at(4), std::stod(f.at(6)));  // method, mean
    return m;
  };
  // --force on a MARL experiment retrains its runs and re-evaluates its planners.
  const std::string traj = slurp(out / "trajectories" / "trajectories.csv");
  const auto forced_traj = run("reproduce --profile tiny --threads 2 --no-plots --only trajectories --force --out " + out.string(),
                               out / "logs4");
  ASSERT_EQ(forced_traj.code, 0) << forced_traj.err;
  EXPECT_NE(forced_traj.err.find("training 1 MARL runs"), std::string::npos) << forced_traj.err;
  EXPECT_EQ(slurp(out / "trajectories" / "trajectories.csv"), traj);  // seeded: the same paths again

  // The evaluations ran two at a time beside the MARL runs (--jobs = --threads = 2): the layout
  // evaluations and the planners' (exact optima, a policy) one at a time in another directory give
  // the same CSVs, less the columns that time them.
  {
    const fs::path one = tmp("tiny_one_job");
    const auto serial = run("reproduce --profile tiny --threads 1 --jobs 1 --no-plots --only generalisation,rate_energy --out " +
                                one.string(),
                            one / "logs");
    ASSERT_EQ(serial.code, 0) << serial.err;
    EXPECT_EQ(serial.err.find("evaluations, "), std::string::npos) << "--jobs 1 computes in the assembly";
    const auto untimed = [](const std::string& csv) {
      std::vector<std::vector<std::string>> rows;
      const auto all = csv_rows(csv, true);
      std::vector<std::size_t> keep;
      for (std::size_t c = 0; c < all.at(0).size(); ++c)
        if (all[0][c] != "seconds") keep.push_back(c);
      for (const auto& line : all) {
        rows.emplace_back();
        for (auto c : keep) rows.back().push_back(line.at(c));
      }
      return rows;
    };
    for (const std::string f : {"generalisation/generalisation.csv", "generalisation/layouts.csv", "rate_energy/front.csv",
                                "rate_energy/paths.csv"})
      EXPECT_EQ(untimed(slurp(one / f)), untimed(slurp(out / f))) << f;
    // The tiny profile scores each run on `train_layouts` = 1 of the layouts it trained on and on
    // `samples` = 2 test layouts.
    const auto rows = csv_rows(slurp(out / "generalisation" / "layouts.csv"), true);
    const auto col = [&](const std::string& name) {
      return static_cast<std::size_t>(std::find(rows[0].begin(), rows[0].end(), name) - rows[0].begin());
    };
    std::map<std::string, std::set<std::string>> layouts;  // eval -> the layouts mappo flew
    for (std::size_t i = 1; i < rows.size(); ++i)
      if (rows[i].at(col("algo")) == "mappo" && rows[i].at(col("planner")).rfind("mappo", 0) == 0)
        layouts[rows[i].at(col("eval")) + " K=" + rows[i].at(col("eval_users"))].insert(rows[i].at(col("layout")));
    ASSERT_EQ(layouts.size(), 3u);  // train, test K = 6, test K = 9
    for (const auto& [eval, set] : layouts) EXPECT_EQ(set.size(), eval.rfind("train", 0) == 0 ? 1u : 2u) << eval;
  }

  const auto a = means(slurp(out / "power_sweep" / "power_sweep.csv")), b = means(before);
  ASSERT_EQ(a.size(), b.size());
  for (std::size_t i = 0; i < a.size(); ++i) {
    EXPECT_EQ(a[i].first, b[i].first);
    EXPECT_EQ(a[i].second, b[i].second) << a[i].first;
  }
}

// The committed paper-profile report is whole: every file it links is in the repository (a fresh
// clone has only what git tracks; the run's caches are ignored).
TEST(Reproduce, CommittedReportLinksResolveInTheRepository) {
  const fs::path src = SKYLOOP_SOURCE_DIR;
  const fs::path dir = src / "results" / "paper";
  ASSERT_TRUE(fs::exists(dir / "report.html"));
  std::set<std::string> tracked;
  const std::string cmd = "git -C '" + src.string() + "' ls-files results/paper 2>/dev/null";
  if (FILE* p = ::popen(cmd.c_str(), "r")) {
    char line[4096];
    while (std::fgets(line, sizeof line, p)) {
      std::string f = line;
      while (!f.empty() && (f.back() == '\n' || f.back() == '\r')) f.pop_back();
      tracked.insert(f);
    }
    ::pclose(p);
  }
  const bool in_git = !tracked.empty();  // a source tarball without .git: the files themselves
  const std::string report = slurp(dir / "report.html");
  const std::regex link(R"((?:href|src)=\"([^\"#]+)\")");
  int links = 0;
  for (auto it = std::sregex_iterator(report.begin(), report.end(), link); it != std::sregex_iterator(); ++it, ++links) {
    const std::string target = (*it)[1].str();
    if (target.find("://") != std::string::npos) continue;
    if (in_git) EXPECT_TRUE(tracked.count("results/paper/" + target)) << "report.html links an untracked file: " << target;
    else EXPECT_TRUE(fs::exists(dir / target)) << "report.html links a missing file: " << target;
  }
  EXPECT_GE(links, 50);
}
