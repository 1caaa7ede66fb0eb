// Runs the skyloop binary as a user would: exit codes, one-line errors, files written.
#include <gtest/gtest.h>

#include <array>
#include <chrono>
#include <csignal>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <sstream>
#include <fcntl.h>
#include <sys/wait.h>
#include <unistd.h>
#include "../scratch.hpp"

namespace {

struct Result {
  int code = -1;
  std::string out, err;
};

std::string slurp(const std::string& path) {
  std::ifstream in(path);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

std::string tmpdir(const std::string& name) { return skyloop::test::scratch_dir(name).string(); }

Result run(const std::string& args) {
  static int counter = 0;
  const std::string base = tmpdir("run" + std::to_string(counter++));
  const std::string cmd = std::string(SKYLOOP_BIN) + " " + args + " >" + base + "/out 2>" + base + "/err";
  const int status = std::system(cmd.c_str());
  Result r;
  r.code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  r.out = slurp(base + "/out");
  r.err = slurp(base + "/err");
  return r;
}

int lines(const std::string& s) {
  int n = 0;
  for (char c : s) n += c == '\n';
  return n;
}

const std::string kSrc = SKYLOOP_SOURCE_DIR;

}  // namespace

TEST(Cli, HelpAndVersion) {
  EXPECT_EQ(run("--help").code, 0);
  const auto v = run("--version");
  EXPECT_EQ(v.code, 0);
  EXPECT_NE(v.out.find("skyloop"), std::string::npos);
}

TEST(Cli, ConfigShowPrintsOverrides) {
  const auto r = run("config show --config " + kSrc + "/configs/paper.toml --set channel.p_max_dbm=40");
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.out.find("p_max_dbm = 40.0"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("[trajectory]"), std::string::npos);
}

TEST(Cli, BadInputIsOneLineAndExitTwo) {
  for (const std::string args :
       {"config show --set channel.p_max_dbm=400", "config show --set channel.nosuch=1",
        "config show --config /nonexistent.toml", "beamform eval --methods mrt,nosuch --samples 2",
        "beamform eval --uavs 0 --samples 2", "beamform eval --samples 0", "beamform eval --frobnicate",
        "snapshot --scenario /nonexistent.toml"}) {
    const auto r = run(args);
    EXPECT_EQ(r.code, 2) << args << "\n" << r.err;
    EXPECT_EQ(lines(r.err), 1) << args << "\n" << r.err;
    EXPECT_EQ(r.err.rfind("skyloop: error: ", 0), 0u) << r.err;
  }
  const auto r = run("config show --set channel.p_max_dbm=400");
  EXPECT_NE(r.err.find("channel.p_max_dbm = 400"), std::string::npos) << r.err;
  const auto u = run("beamform eval --uavs 0 --samples 2");
  EXPECT_NE(u.err.find("scenario.uavs = 0"), std::string::npos) << u.err;
}

// A shipped model named by its directory is served as its serve.toml says (models/gnn_large:
// ranked selection, the setting its N = 64 figure was measured with); named by its model.pt, as
// the configuration says. A serve.toml that sets more than serving is refused in one line.
TEST(Cli, AModelDirectoryIsServedAsItsServeTomlSays) {
  const std::string dir = tmpdir("serve");
  const std::string scene = " --uavs 4 --users 64 --samples 2 --seed 5 --quiet --set scenario.area_x_m=500 --set scenario.area_y_m=500"
                            " --set channel.pathloss=3gpp-uma-av --set channel.fading=rician --set channel.rician_k_db=10"
                            " --set channel.coverage_radius_m=400";
  const std::string model = kSrc + "/models/gnn_large";
  auto rates = [](const std::string& csv) {  // the sum_rate column (the one before latency_ms)
    std::stringstream in(csv), out;
    std::string line;
    std::getline(in, line);
    while (std::getline(in, line)) {
      const auto last = line.rfind(',');
      out << line.substr(line.rfind(',', last - 1) + 1, last - line.rfind(',', last - 1) - 1) << "\n";
    }
    return out.str();
  };
  ASSERT_EQ(run("beamform eval --methods gnn=" + model + scene + " --out " + dir + "/dir.csv").code, 0);
  ASSERT_EQ(run("beamform eval --methods gnn=" + model + "/model.pt" + scene + " --set nn.selection=ranked --out " + dir + "/ranked.csv").code, 0);
  ASSERT_EQ(run("beamform eval --methods gnn=" + model + "/model.pt" + scene + " --out " + dir + "/soft.csv").code, 0);
  EXPECT_EQ(rates(slurp(dir + "/dir.csv")), rates(slurp(dir + "/ranked.csv")));
  EXPECT_NE(rates(slurp(dir + "/dir.csv")), rates(slurp(dir + "/soft.csv")));
  // A directory whose serve.toml sets a training key.
  const std::string bad = dir + "/bad";
  std::filesystem::create_directories(bad);
  std::filesystem::copy_file(model + "/model.pt", bad + "/model.pt");
  std::ofstream(bad + "/serve.toml") << "[nn]\nselection = \"ranked\"\nepochs = 3\n";
  const auto r = run("beamform eval --methods gnn=" + bad + scene);
  EXPECT_EQ(r.code, 2) << r.err;
  EXPECT_EQ(lines(r.err), 1) << r.err;
  EXPECT_NE(r.err.find("allowed nn.selection and nn.precision only"), std::string::npos) << r.err;
}

TEST(Cli, BeamformEvalWritesTidyCsvAndConfigAndIsSeeded) {
  const std::string dir = tmpdir("eval");
  const std::string args = "beamform eval --methods mrt,zf,rzf,wmmse --uavs 3 --users 12 --samples 5 --seed 11 --quiet";
  const auto a = run(args + " --out " + dir + "/a.csv");
  ASSERT_EQ(a.code, 0) << a.err;
  const auto b = run(args + " --out " + dir + "/b.csv --threads 2");
  ASSERT_EQ(b.code, 0) << b.err;
  EXPECT_NE(a.out.find("wmmse"), std::string::npos);
  EXPECT_NE(a.out.find("median latency"), std::string::npos);
  const std::string csv_a = slurp(dir + "/a.csv"), csv_b = slurp(dir + "/b.csv");
  EXPECT_EQ(lines(csv_a), 1 + 5 * 4);
  EXPECT_EQ(csv_a.rfind("seed,sample,method", 0), 0u);
  // Same seed -> same sum rates (latency, the last column, differs).
  auto drop_latency = [](const std::string& csv) {
    std::stringstream in(csv), out;
    std::string line;
    while (std::getline(in, line)) out << line.substr(0, line.rfind(',')) << "\n";
    return out.str();
  };
  EXPECT_EQ(drop_latency(csv_a), drop_latency(csv_b));
  std::stringstream rows(csv_a);
  std::string line;
  std::getline(rows, line);
  while (std::getline(rows, line)) EXPECT_EQ(line.rfind("11,", 0), 0u) << line;
  EXPECT_NE(slurp(dir + "/a.config.toml").find("[channel]"), std::string::npos);
  // Another seed gives other snapshots.
  const auto c = run("beamform eval --methods mrt --samples 5 --seed 12 --quiet --out " + dir + "/c.csv");
  ASSERT_EQ(c.code, 0);
  EXPECT_NE(drop_latency(slurp(dir + "/c.csv")).substr(40), drop_latency(csv_a).substr(40));
}

TEST(Cli, FailedRunLeavesEarlierOutputIntact) {
  const std::string dir = tmpdir("keep");
  ASSERT_EQ(run("beamform eval --methods mrt --samples 2 --quiet --out " + dir + "/r.csv").code, 0);
  const std::string before = slurp(dir + "/r.csv");
  EXPECT_EQ(run("beamform eval --methods mrt,bogus --samples 2 --quiet --out " + dir + "/r.csv").code, 2);
  EXPECT_EQ(slurp(dir + "/r.csv"), before);
  for (const auto& e : std::filesystem::directory_iterator(dir))
    EXPECT_EQ(e.path().string().find(".tmp"), std::string::npos) << e.path();
}

// An input that asks for more memory than any machine has (a PPO rollout, a replay buffer, a
// beamformer's data sets, the safety mask's distance tables: terabytes here) is refused in one line naming the fields, before the run
// directory is touched (--force removes an earlier run only once the checks pass).
TEST(Cli, InputsBeyondMemoryAreRefusedBeforeTheRunDirectory) {
  const std::string dir = tmpdir("memory");
  {
    std::ofstream(dir + "/policy.pt") << "earlier run";
    std::ofstream(dir + "/model.pt") << "earlier model";
  }
  const std::pair<std::string, std::string> cases[] = {
      {"train --set marl.envs=4096 --set marl.rollout=1000000", "marl.rollout = 1000000 steps x marl.envs = 4096"},
      {"train --algo vdn --set marl.buffer_episodes=10000000 --set trajectory.t_max=10000", "marl.buffer_episodes = 10000000"},
      {"beamform train --set scenario.users=4096 --set nn.train_samples=100000000", "nn.train_samples = 100000000"},
      // 64 UAVs' clearance tables of 16e6 lattice points each, a set per environment: 16 TiB.
      {"train --set marl.envs=4096 --set marl.mask_clearance=destinations --set scenario.uavs=64 "
       "--set trajectory.layout=generated --set scenario.area_x_m=4000 --set scenario.area_y_m=4000 "
       "--set trajectory.d_fly_m=1 --set trajectory.t_max=10000",
       "the distance tables of marl.mask_clearance = \"destinations\" over 64 UAVs"},
  };
  for (const auto& [args, names] : cases) {
    const auto r = run(args + " --force --out " + dir);
    EXPECT_EQ(r.code, 2) << args << ": " << r.err;
    EXPECT_EQ(lines(r.err), 1) << r.err;
    EXPECT_NE(r.err.find(names), std::string::npos) << r.err;
    EXPECT_NE(r.err.find("of memory this process may use: allowed"), std::string::npos) << r.err;
  }
  EXPECT_EQ(slurp(dir + "/policy.pt"), "earlier run");
  EXPECT_EQ(slurp(dir + "/model.pt"), "earlier model");
}

// A lattice finer than 2^24 points (the planners, the headings model and the mask's clearances
// index positions by it in int) and a best-known rate table over 2^27 entries are refused in one
// line that names the fields and the largest value allowed, not met with std::bad_alloc.
TEST(Cli, LatticesAndPlannerTablesBeyondTheirLimitsAreRefused) {
  const std::string huge = "--set scenario.area_x_m=100000 --set scenario.area_y_m=100000 --set trajectory.d_fly_m=0.1 "
                           "--set trajectory.t_max=10000";
  const std::pair<std::string, std::string> cases[] = {
      {"plan --planner bestknown " + huge, "at trajectory.d_fly_m = 0.1 has 1e+12 points: allowed at most 2^24"},
      {"plan --planner greedy --set trajectory.mobility=headings --set trajectory.speeds_mps=[0,0.05] " + huge,
       "trajectory.d_fly_m >= "},
      {"plan --planner bestknown --set scenario.area_x_m=20000 --set scenario.area_y_m=20000 --set trajectory.t_max=2000",
       "the best-known planner's rate table has"},
  };
  for (const auto& [args, says] : cases) {
    const auto r = run(args);
    EXPECT_EQ(r.code, 2) << args << ": " << r.err;
    EXPECT_EQ(lines(r.err), 1) << r.err;
    EXPECT_NE(r.err.find(says), std::string::npos) << r.err;
  }
}

TEST(Cli, SnapshotJsonHasEveryPerUserQuantity) {
  const auto r = run("snapshot --scenario " + kSrc + "/configs/scenarios/two_uavs.toml --method zf --json");
  ASSERT_EQ(r.code, 0) << r.err;
  const auto j = nlohmann::json::parse(r.out);
  ASSERT_EQ(j["users"].size(), 6u);
  EXPECT_TRUE(j["users"][5]["serving_uav"].is_null());
  EXPECT_EQ(j["users"][0]["serving_uav"], 0);
  EXPECT_EQ(j["users"][0]["channel"].size(), 4u);
  EXPECT_EQ(j["users"][0]["beamformer"].size(), 4u);
  double total = 0;
  for (const auto& c : j["clusters"]) {
    total += c["sum_rate"].get<double>();
    EXPECT_LE(c["power_w"].get<double>(), 1.0 + 1e-9);
  }
  EXPECT_NEAR(total, j["total_sum_rate"].get<double>(), 1e-9);
  double users_total = 0;
  for (const auto& u : j["users"]) users_total += u["rate"].get<double>();
  EXPECT_NEAR(users_total, total, 1e-9);
}

TEST(Cli, SnapshotSingleUserBelowMatchesHandValue) {
  const std::string dir = tmpdir("single");
  std::ofstream(dir + "/s.toml") << "uavs = [[100, 100]]\nusers = [[100, 100]]\n";
  const auto r = run("snapshot --scenario " + dir + "/s.toml --method mrt --json");
  ASSERT_EQ(r.code, 0) << r.err;
  const auto j = nlohmann::json::parse(r.out);
  // d = H = 100 m: beta = 1e-6, ||h||^2 = L beta = 4e-6, P = 1 W, noise 1e-12 W -> SNR 4e6.
  EXPECT_NEAR(j["total_sum_rate"].get<double>(), std::log2(1 + 4e6), 1e-6);
  EXPECT_NEAR(j["users"][0]["path_loss_db"].get<double>(), 60.0, 1e-9);
}

TEST(Cli, SnapshotReportsEveryLinksLargeScaleStateUnderA3gppChannel) {
  const std::string dir = tmpdir("links");
  std::ofstream(dir + "/s.toml") << "uavs = [[50, 50], [150, 150]]\nusers = [[60, 40], [140, 170], [100, 100]]\n";
  const auto r = run("snapshot --scenario " + dir + "/s.toml --method zfsel --json --set channel.pathloss=3gpp-uma-av "
                     "--set channel.fading=rician --set channel.rician_k_db=10");
  ASSERT_EQ(r.code, 0) << r.err;
  const auto j = nlohmann::json::parse(r.out);
  EXPECT_EQ(j["settings"]["pathloss"], "3gpp-uma-av");
  for (const auto& u : j["users"]) {
    ASSERT_EQ(u["links"].size(), 2u);
    for (const auto& l : u["links"]) {
      const double p = l["p_los"].get<double>();
      EXPECT_GT(p, 0.0);
      EXPECT_LE(p, 1.0);
      // The path loss of the drawn state: UMa-AV LoS 28 + 22 log10 d + 20 log10 2 at d = distance_m.
      const double d = l["distance_m"].get<double>();
      if (l["los"].get<bool>()) {
        EXPECT_NEAR(l["path_loss_db"].get<double>(), 28 + 22 * std::log10(d) + 20 * std::log10(2.0), 1e-9);
        EXPECT_NEAR(l["k_factor_db"].get<double>(), 10.0, 1e-12);
      } else {
        EXPECT_EQ(l["k_factor_db"], "-inf");
      }
      EXPECT_TRUE(l["shadowing_db"].is_number());
      EXPECT_EQ(l["channel"].size(), 4u);
    }
  }
  // Outside the model's heights: one line, exit 2.
  const auto bad = run("snapshot --scenario " + dir + "/s.toml --set channel.pathloss=3gpp-uma-av --set scenario.altitude_m=20");
  EXPECT_EQ(bad.code, 2);
  EXPECT_NE(bad.err.find("scenario.altitude_m = 20"), std::string::npos) << bad.err;
  EXPECT_EQ(lines(bad.err), 1);
}

TEST(Cli, SnapshotRejectsBadScenario) {
  const std::string dir = tmpdir("badscen");
  std::ofstream(dir + "/a.toml") << "uavs = [[100, 100]]\nusers = [[300, 100]]\n";
  std::ofstream(dir + "/b.toml") << "uavs = [[100, 100]]\nusers = [[10, 10]]\nextra = 1\n";
  std::ofstream(dir + "/c.toml") << "uavs = [[100, 100]]\n";
  for (const auto& [f, needle] : std::vector<std::pair<std::string, std::string>>{
           {"a", "users[0] = [300, 100]"}, {"b", "'extra'"}, {"c", "users is missing"}}) {
    const auto r = run("snapshot --scenario " + dir + "/" + f + ".toml");
    EXPECT_EQ(r.code, 2) << f;
    EXPECT_NE(r.err.find(needle), std::string::npos) << r.err;
    EXPECT_EQ(lines(r.err), 1);
  }
}

TEST(Cli, BeamformListNamesEveryMethod) {
  const auto r = run("beamform list");
  ASSERT_EQ(r.code, 0);
  for (const char* m : {"mrt", "zf", "zfsel", "rzf", "wmmse"}) EXPECT_NE(r.out.find(m), std::string::npos) << m;
}

TEST(Cli, TrainWritesARunDirectoryAndEvalUsesIt) {
  const std::string dir = tmpdir("train");
  const std::string small = " --set nn.hidden=8 --set nn.layers=1 --set nn.epochs=1 --set nn.train_samples=16"
                            " --set nn.val_samples=4 --set nn.test_samples=4 --set nn.batch_samples=8 --threads 1";
  const auto t = run("beamform train --model deepsets --out " + dir + "/ds" + small);
  ASSERT_EQ(t.code, 0) << t.err;
  for (const char* f : {"model.pt", "last.pt", "metrics.csv", "config.toml", "test.json"})
    EXPECT_TRUE(std::filesystem::exists(dir + "/ds/" + f)) << f;
  const auto e = run("beamform eval --methods mrt,deepsets=" + dir + "/ds --samples 3 --quiet");
  ASSERT_EQ(e.code, 0) << e.err;
  EXPECT_NE(e.out.find("deepsets="), std::string::npos);
  // Resume continues to a second epoch.
  const auto r = run("beamform train --model deepsets --out " + dir + "/ds --resume" + small + " --set nn.epochs=2");
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_EQ(lines(slurp(dir + "/ds/metrics.csv")), 3);
}

TEST(Cli, LearnedInputErrors) {
  const std::string dir = tmpdir("trainbad");
  for (const std::string& args : std::vector<std::string>{"beamform eval --methods gnn=/nonexistent/model.pt --samples 2",
                                 "beamform train --model gnn --out " + dir + "/x --resume",
                                 "beamform train --model transformer --out " + dir + "/y",
                                 "beamform eval --methods deepsets=" + std::string(SKYLOOP_SOURCE_DIR) +
                                     "/models/gnn --samples 2"}) {
    const auto r = run(args);
    EXPECT_EQ(r.code, 2) << args << "\n" << r.err;
    EXPECT_EQ(lines(r.err), 1) << args << "\n" << r.err;
  }
}

TEST(Cli, PlanWritesTrajectoriesRatesAndSummary) {
  const std::string dir = tmpdir("plan");
  // A small area keeps the optimum fast; the oracle is ZF (no model needed).
  const std::string small =
      " --set scenario.area_x_m=120 --set scenario.area_y_m=120 --set trajectory.starts=[[0,0],[0,120],[120,120]]"
      " --set trajectory.destinations=[[120,60],[120,0],[0,60]] --set trajectory.t_max=14 --oracle zf";
  const auto r = run("plan --planner random,greedy,optimal --users 8 --seed 3 --out " + dir + small);
  ASSERT_EQ(r.code, 0) << r.err;
  for (const char* p : {"random", "greedy", "optimal"}) EXPECT_NE(r.out.find(p), std::string::npos) << p;
  for (const char* f : {"trajectory.csv", "rates.csv", "summary.csv", "users.csv", "config.toml"})
    EXPECT_TRUE(std::filesystem::exists(dir + "/" + f)) << f;
  const std::string traj = slurp(dir + "/trajectory.csv");
  EXPECT_EQ(traj.rfind("seed,planner,t,uav,x,y,z,action,speed_mps,power_w\n", 0), 0u);
  EXPECT_NE(traj.find("3,optimal,1,0,0,0,100,"), std::string::npos);  // UAV 0 at its start, at H = 100 m
  EXPECT_EQ(lines(slurp(dir + "/summary.csv")), 4);
  // Same seed, same files.
  const std::string dir2 = tmpdir("plan2");
  ASSERT_EQ(run("plan --planner random,greedy,optimal --users 8 --seed 3 --out " + dir2 + small).code, 0);
  EXPECT_EQ(slurp(dir2 + "/trajectory.csv"), traj);
}

TEST(Cli, PlanInputErrors) {
  for (const std::string& args : std::vector<std::string>{
           "plan --planner astar --oracle zf", "plan --set trajectory.t_max=5 --oracle zf",
           "plan --set trajectory.starts=[[20,20],[25,180],[180,180]] --planner optimal --oracle zf",
           "plan --set env.w_col=-1"}) {
    const auto r = run(args);
    EXPECT_EQ(r.code, 2) << args << "\n" << r.err;
    EXPECT_EQ(lines(r.err), 1) << args << "\n" << r.err;
  }
}

#ifdef SKYLOOP_LIBTORCH_BIN
namespace {
/// What the dynamic loader would load for `binary` (LD_TRACE_LOADED_OBJECTS: ldd's own switch).
std::string loaded_libraries(const std::string& binary) {
  const std::string out = tmpdir("ldtrace") + "/libs";
  const std::string cmd = "LD_TRACE_LOADED_OBJECTS=1 " + binary + " >" + out + " 2>&1";
  EXPECT_EQ(std::system(cmd.c_str()), 0);
  return slurp(out);
}

Result run_binary(const std::string& binary, const std::string& args) {
  const std::string base = tmpdir("bin" + std::to_string(std::hash<std::string>{}(binary + args)));
  const std::string cmd = binary + " " + args + " >" + base + "/out 2>" + base + "/err";
  const int status = std::system(cmd.c_str());
  return {WIFEXITED(status) ? WEXITSTATUS(status) : -1, slurp(base + "/out"), slurp(base + "/err")};
}
}  // namespace

// `skyloop` loads no LibTorch; what it runs itself prints what the LibTorch build prints, bit for
// bit; what needs a learned model it hands to `skyloop-torch` in the same process (same pid, as
// mpirun and a user's `kill` expect); and without `skyloop-torch` beside it, it says so in one line.
TEST(Cli, FrontEndRunsWithoutLibTorchAndHandsOverWhatNeedsIt) {
  const std::string front = SKYLOOP_BIN, full = SKYLOOP_LIBTORCH_BIN;
  EXPECT_EQ(loaded_libraries(front).find("libtorch"), std::string::npos);
  EXPECT_NE(loaded_libraries(full).find("libtorch_cpu"), std::string::npos);

  const std::string dir = tmpdir("front");
  std::ofstream(dir + "/scene.toml") << "uavs = [[60, 60]]\nusers = [[50, 40], [90, 70], [20, 110]]\n";
  const std::string plan = " --planner greedy,seqgreedy --oracle zfsel --users 6 --seed 5 --set trajectory.t_max=20 --out ";
  for (const std::string& args : {std::string("config show --set channel.p_max_dbm=35"), std::string("beamform list"),
                                  "snapshot --json --method zfsel --scenario " + dir + "/scene.toml",
                                  std::string("beamform eval --methods mrt,nosuch"), std::string("plan --planner astar --oracle zf"),
                                  std::string("snapshot --scenario /nonexistent.toml --method gnn")}) {
    const auto a = run_binary(front, args), b = run_binary(full, args);
    EXPECT_EQ(a.code, b.code) << args;
    EXPECT_EQ(a.out, b.out) << args;
    EXPECT_EQ(a.err, b.err) << args;
  }
  ASSERT_EQ(run_binary(front, "plan" + plan + dir + "/a").code, 0);
  ASSERT_EQ(run_binary(full, "plan" + plan + dir + "/b").code, 0);
  for (const char* f : {"trajectory.csv", "rates.csv", "users.csv", "energy.csv"})  // summary.csv holds times
    EXPECT_EQ(slurp(dir + "/a/" + f), slurp(dir + "/b/" + f)) << f;

  // A learned beamformer: the front end's process becomes the LibTorch build.
  const pid_t pid = ::fork();
  ASSERT_GE(pid, 0);
  if (pid == 0) {
    const int null = ::open("/dev/null", O_WRONLY);
    ::dup2(null, 1), ::dup2(null, 2);
    ::execl(front.c_str(), front.c_str(), "beamform", "eval", "--methods", "gnn", "--samples", "100000000", "--quiet",
            static_cast<char*>(nullptr));
    ::_exit(127);
  }
  std::string exe;
  const auto until = std::chrono::steady_clock::now() + std::chrono::seconds(60);
  while (std::chrono::steady_clock::now() < until) {
    std::error_code ec;
    exe = std::filesystem::read_symlink("/proc/" + std::to_string(pid) + "/exe", ec).string();
    if (!ec && exe == std::filesystem::canonical(full).string()) break;
    ::usleep(20000);
  }
  ::kill(pid, SIGKILL);
  int status = 0;
  ::waitpid(pid, &status, 0);
  EXPECT_EQ(exe, std::filesystem::canonical(full).string());

  // The front end alone: what it runs works, what it would hand over fails in one line.
  const std::string alone = tmpdir("alone");
  std::filesystem::copy_file(front, alone + "/skyloop");
  std::filesystem::permissions(alone + "/skyloop", std::filesystem::perms::owner_all);
  EXPECT_EQ(run_binary(alone + "/skyloop", "config show").code, 0);
  const auto r = run_binary(alone + "/skyloop", "beamform eval --methods gnn --samples 1");
  EXPECT_EQ(r.code, 1) << r.err;
  EXPECT_EQ(lines(r.err), 1) << r.err;
  EXPECT_NE(r.err.find("cannot start " + alone + "/skyloop-torch"), std::string::npos) << r.err;
}

// `cmake --install build --component cli --prefix P`: both programs in P/bin, the shipped models,
// configurations and figure script in P/share/skyloop; the installed programs read that copy (a
// model removed from it is missed, under its installed path), not the source tree they were built from.
TEST(Cli, InstalledProgramsReadTheirOwnSharedFiles) {
  namespace fs = std::filesystem;
  const std::string prefix = tmpdir("install");
  const std::string install = std::string("\"") + SKYLOOP_CMAKE + "\" --install \"" + SKYLOOP_BUILD_DIR +
                              "\" --component cli --prefix \"" + prefix + "\" >" + prefix + ".log 2>&1";
  ASSERT_EQ(std::system(install.c_str()), 0) << slurp(prefix + ".log");
  const fs::path share = fs::path(prefix) / "share" / "skyloop";
  for (const char* file : {"bin/skyloop", "bin/skyloop-torch"}) EXPECT_TRUE(fs::is_regular_file(fs::path(prefix) / file)) << file;
  for (const char* file : {"models/gnn/model.pt", "models/gnn_structured/config.toml", "configs/paper.toml",
                           "configs/generalise.toml", "configs/experiments", "scripts/plot_figures.py"})
    EXPECT_TRUE(fs::exists(share / file)) << file;
  const std::string bin = prefix + "/bin/skyloop";
  auto ok = run_binary(bin, "beamform eval --methods gnn,zf --samples 2 --seed 7");
  EXPECT_EQ(ok.code, 0) << ok.err;
  const auto same = run_binary(SKYLOOP_BIN, "beamform eval --methods gnn,zf --samples 2 --seed 7");
  auto without_timing = [](const std::string& table) {  // each row less its last column (milliseconds)
    std::istringstream in(table);
    std::string line, kept;
    while (std::getline(in, line)) kept += line.substr(0, line.find_last_of(' ')) + "\n";
    return kept;
  };
  EXPECT_EQ(without_timing(ok.out), without_timing(same.out)) << "the installed model is the shipped one";
  ok = run_binary(bin, "config show --config " + (share / "configs" / "generalise.toml").string());
  EXPECT_EQ(ok.code, 0) << ok.err;

  fs::remove(share / "models" / "gnn" / "model.pt");
  const auto missed = run_binary(bin, "beamform eval --methods gnn --samples 1");
  EXPECT_NE(missed.code, 0);
  EXPECT_EQ(lines(missed.err), 1) << missed.err;
  EXPECT_NE(missed.err.find((share / "models" / "gnn").string()), std::string::npos) << missed.err;
  const auto source = run_binary(SKYLOOP_BIN, "beamform eval --methods gnn --samples 1");
  EXPECT_EQ(source.code, 0) << "the build tree's program reads the source tree: " << source.err;
  fs::remove_all(prefix);
  fs::remove(prefix + ".log");
}
#endif
