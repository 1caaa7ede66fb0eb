// The CLI probed the way a careful tester would: a corpus of malformed configs, scenario files,
// checkpoints, policies and arguments (each one clear line on stderr and exit 2, never a crash,
// an abort or a silent acceptance); special files as outputs; stdout write errors; kill -9 in the
// middle of training, then --resume; signals to `reproduce` and its child processes. Every case
// here was a defect once (see the README's "Errors and faults").
#include <gtest/gtest.h>

#include <chrono>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <map>
#include <set>
#include <sstream>
#include <sys/stat.h>
#include <sys/wait.h>
#include <thread>
#include <unistd.h>
#include "../scratch.hpp"

namespace fs = std::filesystem;

namespace {

struct Result {
  int code = -1;
  std::string out, err;
};

std::string slurp(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

void spit(const fs::path& p, const std::string& text) {
  fs::create_directories(p.parent_path());
  std::ofstream(p, std::ios::binary) << text;
}

fs::path tmpdir(const std::string& name) { return skyloop::test::scratch_dir(name); }

const std::string kBin = SKYLOOP_BIN;
const std::string kSrc = SKYLOOP_SOURCE_DIR;

/// Runs `skyloop ARGS` through the shell; stdout to `stdout_to` when given.
Result run(const std::string& args, const std::string& stdout_to = "") {
  static int counter = 0;
  const fs::path base = tmpdir("run" + std::to_string(counter++));
  const std::string out = stdout_to.empty() ? (base / "out").string() : stdout_to;
  const std::string cmd = kBin + " " + args + " >" + out + " 2>" + (base / "err").string();
  const int status = std::system(cmd.c_str());
  Result r;
  r.code = WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status);
  if (stdout_to.empty()) r.out = slurp(base / "out");
  r.err = slurp(base / "err");
  return r;
}

int lines(const std::string& s) { return static_cast<int>(std::count(s.begin(), s.end(), '\n')); }

/// Starts `skyloop ARGS` in the background (stdout/stderr to files in `dir`); returns its PID.
pid_t spawn(const std::string& args, const fs::path& dir) {
  const pid_t pid = ::fork();
  if (pid == 0) {
    ::setpgid(0, 0);
    const std::string cmd = "exec " + kBin + " " + args + " >" + (dir / "out").string() + " 2>" + (dir / "err").string();
    ::execl("/bin/sh", "sh", "-c", cmd.c_str(), static_cast<char*>(nullptr));
    ::_exit(127);
  }
  return pid;
}

/// Waits for `pid` up to `seconds`; returns its wait status, or -1 on timeout.
int wait_for(pid_t pid, double seconds) {
  const auto end = std::chrono::steady_clock::now() + std::chrono::duration<double>(seconds);
  int status = 0;
  while (std::chrono::steady_clock::now() < end) {
    if (::waitpid(pid, &status, WNOHANG) == pid) return status;
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  }
  return -1;
}

/// Waits until `pred` holds (polling), up to `seconds`.
template <class Pred>
bool eventually(Pred pred, double seconds) {
  const auto end = std::chrono::steady_clock::now() + std::chrono::duration<double>(seconds);
  while (std::chrono::steady_clock::now() < end) {
    if (pred()) return true;
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  }
  return pred();
}

/// PIDs of running processes whose command line mentions `needle`.
std::vector<pid_t> processes_mentioning(const std::string& needle) {
  std::vector<pid_t> out;
  for (const auto& e : fs::directory_iterator("/proc")) {
    const std::string name = e.path().filename().string();
    if (name.find_first_not_of("0123456789") != std::string::npos) continue;
    std::string cmdline = slurp(e.path() / "cmdline");
    for (auto& ch : cmdline)
      if (ch == '\0') ch = ' ';
    const std::string stat = slurp(e.path() / "stat");
    const bool zombie = stat.find(") Z ") != std::string::npos;
    if (!zombie && cmdline.find(needle) != std::string::npos && std::stoi(name) != ::getpid()) out.push_back(std::stoi(name));
  }
  return out;
}

std::vector<fs::path> temporaries_under(const fs::path& dir) {
  std::vector<fs::path> out;
  for (const auto& e : fs::recursive_directory_iterator(dir)) {
    const std::string n = e.path().filename().string();
    if (n.find(".tmp.") != std::string::npos || n.find(".bak.") != std::string::npos) out.push_back(e.path());
  }
  return out;
}

const std::string kTinyNn =
    " --set nn.hidden=8 --set nn.layers=1 --set nn.train_samples=16 --set nn.val_samples=4 --set nn.test_samples=4"
    " --set nn.batch_samples=4 --threads 1";

/// A tiny trained model (one per test binary run).
const fs::path& tiny_model() {
  static const fs::path dir = [] {
    const fs::path d = tmpdir("model") / "gnn";
    const auto r = run("beamform train --model gnn --out " + d.string() + kTinyNn + " --set nn.epochs=1");
    EXPECT_EQ(r.code, 0) << r.err;
    return d;
  }();
  return dir;
}

/// A tiny trained MARL policy (one per test binary run).
const fs::path& tiny_policy() {
  static const fs::path dir = [] {
    const fs::path d = tmpdir("policy") / "mappo";
    const auto r = run("train --algo mappo --steps 512 --out " + d.string() +
                       " --set env.oracle=zf --set marl.envs=2 --set marl.rollout=64 --set run.threads=1");
    EXPECT_EQ(r.code, 0) << r.err;
    return d;
  }();
  return dir;
}

/// 64 bytes flipped in the middle of the archive's largest entry (the weights), between two local
/// headers, so that the damage is in stored data (found by the checksums), not in a header.
std::string flipped(const std::string& good) {
  std::string s = good;
  const std::string sig("PK\x03\x04", 4);
  std::size_t best = 0, best_len = 0;
  for (std::size_t at = s.find(sig); at != std::string::npos;) {
    const std::size_t next = s.find(sig, at + 4);
    const std::size_t end = next == std::string::npos ? s.size() : next;
    if (end - at > best_len) best = at, best_len = end - at;
    at = next;
  }
  const std::size_t mid = best + best_len / 2;
  for (std::size_t i = 0; i < 64; ++i) s[mid + i] = static_cast<char>(~s[mid + i]);
  return s;
}

}  // namespace

// Every malformed input: exit 2, exactly one line "skyloop: error: ...", naming what is wrong.
TEST(Probe, MalformedInputsGiveOneLineAndExitTwo) {
  const fs::path d = tmpdir("corpus");
  const std::string good_model = slurp(tiny_model() / "model.pt");
  const std::string good_policy = slurp(tiny_policy() / "policy.pt");
  // Files of the corpus.
  spit(d / "invalid.toml", "[channel\np_max_dbm = 30\n");
  spit(d / "unknown.toml", "[channel]\nfrob = 1\n");
  spit(d / "type.toml", "[channel]\np_max_dbm = \"high\"\n");
  spit(d / "range.toml", "[channel]\np_max_dbm = 400\n");
  spit(d / "nan.toml", "[channel]\np_max_dbm = nan\n");
  spit(d / "inf.toml", "[scenario]\narea_x_m = inf\n");
  spit(d / "bigseed.toml", "[run]\nseed = 4611686018427387905\n");
  spit(d / "negseed.toml", "[run]\nseed = -1\n");
  spit(d / "starts.toml", "[trajectory]\nstarts = [[20, 20]]\n");
  spit(d / "pair.toml", "[trajectory]\nstarts = [[20, 20, 3], [1, 2], [3, 4]]\n");
  spit(d / "nanstart.toml", "[trajectory]\nstarts = [[nan, 20], [20, 180], [180, 180]]\n");
  spit(d / "binary.toml", std::string("\x00\x01\xff\xfe", 4));
  fs::create_directories(d / "adir");
  spit(d / "nan_user.toml", "uavs = [[60, 60]]\nusers = [[nan, 10]]\n");
  spit(d / "nan_uav.toml", "uavs = [[60, nan]]\nusers = [[10, 10]]\n");
  spit(d / "inf_user.toml", "uavs = [[60, 60]]\nusers = [[inf, 10]]\n");
  spit(d / "outside.toml", "uavs = [[60, 60]]\nusers = [[500, 10]]\n");
  spit(d / "missing.toml", "uavs = [[60, 60]]\n");
  spit(d / "empty_list.toml", "uavs = [[60, 60]]\nusers = []\n");
  spit(d / "extra_key.toml", "uavs = [[60, 60]]\nusers = [[1, 1]]\nfoo = 1\n");
  spit(d / "users_nan.toml", "users = [[nan, 1], [2, 2]]\n");
  spit(d / "garbage.pt", "this is not a model");
  spit(d / "empty.pt", "");
  spit(d / "truncated.pt", good_model.substr(0, good_model.size() / 2));
  spit(d / "flipped.pt", flipped(good_model));
  spit(d / "pol_garbage" / "policy.pt", "not a policy");
  spit(d / "pol_flipped" / "policy.pt", flipped(good_policy));
  spit(d / "pol_truncated" / "policy.pt", good_policy.substr(0, good_policy.size() - 50));

  const std::string D = d.string();
  const std::vector<std::pair<std::string, std::string>> corpus = {
      // configs
      {"config show --config " + D + "/invalid.toml", "invalid TOML"},
      {"config show --config " + D + "/unknown.toml", "unknown key 'channel.frob'"},
      {"config show --config " + D + "/type.toml", "channel.p_max_dbm"},
      {"config show --config " + D + "/range.toml", "out of range"},
      {"config show --config " + D + "/nan.toml", "channel.p_max_dbm = nan"},
      {"config show --config " + D + "/inf.toml", "scenario.area_x_m"},
      {"config show --config " + D + "/bigseed.toml", "run.seed = 4611686018427387905 is out of range"},
      {"config show --config " + D + "/negseed.toml", "run.seed = -1 is out of range"},
      {"config show --config " + D + "/starts.toml", "trajectory.destinations"},
      {"config show --config " + D + "/pair.toml", "trajectory.starts"},
      {"config show --config " + D + "/nanstart.toml", "trajectory.starts"},
      {"config show --config " + D + "/binary.toml", "binary.toml"},
      {"config show --config " + D + "/adir", "is a directory"},
      {"config show --config /nonexistent/x.toml", "cannot be read"},
      {"config show --set run.seed=4611686018427387905", "out of range"},
      {"config show --set run.seed=1180591620717411303424", "run.seed = 1180591620717411303424 is out of range"},
      {"config show --set nosuchkey", "malformed"},
      // scenario files
      {"snapshot --scenario " + D + "/nan_user.toml", "users[0] = [nan, 10] is outside the area"},
      {"snapshot --json --scenario " + D + "/nan_user.toml", "users[0] = [nan, 10]"},
      {"snapshot --scenario " + D + "/nan_uav.toml", "uavs[0] = [60, nan]"},
      {"snapshot --scenario " + D + "/inf_user.toml", "users[0] = [inf, 10]"},
      {"snapshot --scenario " + D + "/outside.toml", "outside the area"},
      {"snapshot --scenario " + D + "/missing.toml", "users is missing"},
      {"snapshot --scenario " + D + "/empty_list.toml", "users is missing or empty"},
      {"snapshot --scenario " + D + "/extra_key.toml", "unknown key 'foo'"},
      {"snapshot --scenario " + D + "/adir", "is a directory"},
      {"plan --planner random --set env.users_file=" + D + "/users_nan.toml --out " + D + "/plan_nan", "[nan, 1]"},
      // checkpoints and policies
      {"beamform eval --samples 1 --methods gnn=" + D + "/garbage.pt", "garbage.pt"},
      {"beamform eval --samples 1 --methods gnn=" + D + "/empty.pt", "empty.pt"},
      {"beamform eval --samples 1 --methods gnn=" + D + "/truncated.pt", "truncated.pt"},
      {"beamform eval --samples 1 --methods deepsets=" + D + "/flipped.pt", "checksum"},
      {"beamform eval --samples 1 --methods gnn=" + D + "/adir", "adir"},
      {"eval --policy " + D + "/pol_garbage", "pol_garbage"},
      {"eval --policy " + D + "/pol_flipped", "corrupt"},
      {"eval --policy " + D + "/pol_truncated", "corrupt"},
      {"beamform train --model gnn --resume --out " + D + "/nothing_here", "--resume"},
      // arguments
      {"plan --planner random --seed -1", "--seed = '-1' is invalid"},
      {"plan --planner random --seed 18446744073709551616", "--seed"},
      {"plan --planner random --seed 9223372036854775808", "--seed"},
      {"plan --planner random --seed 12abc", "--seed = '12abc'"},
      {"eval --policy " + tiny_policy().string() + " --seed -1", "--seed = '-1'"},
      {"eval --policy " + tiny_policy().string() + " --seed abc", "--seed = 'abc'"},
      {"eval --policy " + tiny_policy().string() + " --seed 99999999999999999999999", "--seed"},
      {"eval --policy " + tiny_policy().string() + " --seed 12abc", "--seed = '12abc'"},
      {"eval --policy " + tiny_policy().string() + " --layouts 2 --split holdout", "--split = 'holdout' is not a layout split"},
      {"eval --policy " + tiny_policy().string() + " --layouts 2 --seed 4", "--seed with --layouts"},
      {"eval --policy " + tiny_policy().string() + " --layouts 2 --planner teleport", "--planner 'teleport' is unknown"},
      {"eval --policy " + tiny_policy().string() + " --policy " + tiny_policy().string(), "--policy is given 2 times"},
      {"eval --layouts 2 --first 4611686018427387903", "layout index"},
      {"eval", "--policy is missing"},
      {"train --algo mappo --out " + D + "/k_range --set env.users_min=8 --set env.users_max=16", "allowed env.state = \"compact\""},
      {"config show --set marl.encoder=gnn", "marl.encoder = \"gnn\" is not allowed: allowed one of mlp, set"},
      {"beamform eval --samples 1 --seed -1", "run.seed = -1"},
      {"beamform eval --samples 1 --seed 12abc", "run.seed"},
      {"reproduce --profile tiny --threads -1 --out " + D + "/rep", "--threads = -1"},
      {"reproduce --profile tiny --jobs -3 --out " + D + "/rep", "--jobs = -3"},
      {"beamform eval --samples 1 --methods gnn=", "empty argument"},
      {"beamform eval --samples 1 --methods mrt,mrt", "'mrt' twice"},
      {"plan --planner ''", "--planner: an empty value is not allowed"},
      {"plan --planner ,", "--planner ',' has an empty item"},
      // found by probing: each used to run, hang or report nonsense
      {"train --seed '' --out " + D + "/empty_seed", "--seed: an empty value is not allowed"},
      {"config show --set trajectory.destinations=[[20,20],[180,20],[20,100]]", "equals trajectory.starts[0]"},
      {"plan --planner random --set trajectory.destinations=[[185,100],[180,20],[20,100]]", "is not on the D_fly grid"},
      {"config show --set env.users_max=100000", "env.users_max = 100000 is out of range"},
      {"plan --planner optimal --set trajectory.t_max=500", "trajectory.t_max <= 75"},
      {"config show --set 'channel.p_max_dbm=50 # x'", "'#' starts a comment"},
      {"eval --policy " + tiny_policy().string() + " --layouts 0", "--layouts = '0' is invalid"},
      {"eval --policy " + tiny_policy().string() + " --layouts 1 --first -1", "--first = '-1' is invalid"},
      {"eval --policy " + tiny_policy().string() + " --layouts 1 --cache /dev/null", "--cache '/dev/null' exists and is not a directory"},
      {"eval --policy " + tiny_policy().string() + " --layouts 1 --planner random,random", "'random' twice"},
      {"frobnicate", "unknown command 'frobnicate': allowed beamform"},
      {"beamform frobnicate", "unknown command 'frobnicate' for 'beamform': allowed"},
      // outputs that are not regular files
      {"beamform eval --samples 1 --methods mrt --out " + D + "/adir", "is a directory"},
      {"beamform eval --samples 1 --methods mrt --out /dev/null", "character device"},
      {"plan --planner random --out " + D + "/garbage.pt", "is not a directory"},
      {"plan --planner random --out " + D + "/garbage.pt/sub", "is not a directory"},
      {"beamform train --model gnn --out " + D + "/garbage.pt", "is not a directory"},
      {"train --algo mappo --out " + D + "/garbage.pt", "is not a directory"},
      {"reproduce --profile tiny --no-plots --out " + D + "/garbage.pt", "is not a directory"},
  };
  for (const auto& [args, want] : corpus) {
    const auto r = run(args);
    EXPECT_EQ(r.code, 2) << args << "\n" << r.err;
    EXPECT_EQ(lines(r.err), 1) << args << "\n" << r.err;
    EXPECT_EQ(r.err.rfind("skyloop: error: ", 0), 0u) << args << "\n" << r.err;
    EXPECT_NE(r.err.find(want), std::string::npos) << args << "\nwanted '" << want << "' in: " << r.err;
  }
  // Nothing was written by a refused run.
  EXPECT_FALSE(fs::exists(d / "plan_nan"));
  EXPECT_FALSE(fs::exists(d / "rep"));
  EXPECT_FALSE(fs::exists(d / "adir.config.toml"));
  EXPECT_TRUE(fs::is_empty(d / "adir"));
}

// Settings that make a run meaningless, and the causes the errors name. Each case below once ran
// (every planner scoring 0 kbit/J, a reward identically 0) or named the wrong cause (a move count
// capped at t_max + 1 whatever the true need).
TEST(Probe, MeaninglessSettingsAreRefusedNamingTheirCause) {
  const std::string base = "plan --planner random --set env.oracle=zf ";
  const std::vector<std::pair<std::string, std::vector<std::string>>> corpus = {
      {base + "--set env.objective=energy-efficiency --set energy.model=none", {"env.objective", "energy.model = \"none\""}},
      {base + "--set env.objective=energy --set energy.p0_w=0 --set energy.pi_w=0 --set energy.d0=0", {"env.objective", "energy.p0_w = 0"}},
      {base + "--set env.objective=weighted --set energy.weight=1 --set energy.model=none", {"energy.weight"}},
      {base + "--set energy.budget_j=1000 --set energy.model=none", {"energy.budget_j"}},
      {base + "--set channel.rician_k_min_db=20 --set channel.rician_k_max_db=10", {"rician_k_min_db"}},
      {base + "--set scenario.user_height_m=99.999", {"channel.d0_m", "user_height_m"}},
      // the true need of a slow UAV (890 slots), and the settings that decide it
      {base + "--set trajectory.mobility=continuous --set trajectory.v_max_mps=0.1", {"v_max_mps = 0.1", "a_max_mps2", "slot_s"}},
      {base + "--set trajectory.mobility=continuous --set trajectory.v_max_mps=0.1 --set trajectory.t_max=26", {"v_max_mps = 0.1"}},
      {base + "--set trajectory.t_max=10", {"needs 12 moves", "trajectory.d_fly_m = 20", "t_max >= 13"}},
      {"train --resume --force --out /tmp/skyloop_never_made", {"--resume and --force together"}},
  };
  for (const auto& [args, wants] : corpus) {
    const auto r = run(args);
    EXPECT_EQ(r.code, 2) << args << "\n" << r.err;
    EXPECT_EQ(lines(r.err), 1) << args << "\n" << r.err;
    for (const auto& want : wants) EXPECT_NE(r.err.find(want), std::string::npos) << args << "\nwanted '" << want << "' in: " << r.err;
  }
  // The slow UAV's count is the HOME flight's own, not t_max + 1.
  const auto slow = run(base + "--set trajectory.mobility=continuous --set trajectory.v_max_mps=0.1");
  const auto at = slow.err.find(" needs ");
  ASSERT_NE(at, std::string::npos) << slow.err;
  EXPECT_GT(std::stol(slow.err.substr(at + 7)), 500) << slow.err;
}

// A VDN or QMIX policy trained under continuous mobility (it chooses among the model's discrete
// primitives) is evaluated by its own run, by `eval --policy` and on layouts; it used to be refused
// with "trained with continuous (18 actions) but the environment has continuous (18 actions)".
TEST(Probe, QLearnersTrainedOnContinuousMobilityCanBeEvaluated) {
  const fs::path d = tmpdir("q_continuous");
  for (const char* algo : {"vdn", "qmix"}) {
    const fs::path out = d / algo;
    const auto t = run(std::string("train --seed 1 --steps 2000 --set env.oracle=zf --set marl.envs=2 --set marl.rollout=64 ") +
                       "--set marl.algo=" + algo + " --set trajectory.mobility=continuous --out " + out.string());
    ASSERT_EQ(t.code, 0) << algo << "\n" << t.err;
    EXPECT_TRUE(fs::exists(out / "policy.pt"));
    const auto e = run("eval --policy " + out.string());
    EXPECT_EQ(e.code, 0) << algo << "\n" << e.err;
    EXPECT_NE(e.out.find(algo), std::string::npos) << e.out;
  }
  // A policy on another action set is refused naming what differs.
  const auto other = run("eval --policy " + (d / "vdn").string() + " --set trajectory.v_max_mps=12");
  EXPECT_EQ(other.code, 2) << other.err;
  EXPECT_NE(other.err.find("actions"), std::string::npos) << other.err;
}

// Two runs into one --out at once: the second is refused in one line (it used to overwrite the
// first's policy.pt silently, both exiting 0); the first finishes. A run killed with SIGKILL leaves
// no lock behind.
TEST(Probe, OneRunAtATimePerRunDirectory) {
  const fs::path d = tmpdir("concurrent");
  const fs::path out = d / "run";
  const std::string args = " --algo mappo --set env.oracle=zf --set marl.envs=2 --set marl.rollout=64 --set run.threads=1 --out " +
                           out.string();
  const pid_t first = spawn("train --steps 20000000" + args, d);  // killed below, long before its end
  ASSERT_TRUE(eventually([&] { return fs::exists(out / ".skyloop.lock") && fs::exists(out / "config.toml"); }, 120)) << slurp(d / "err");
  for (const std::string& second : {"train --steps 512" + args, "train --steps 512 --force" + args,
                                    "beamform train --model gnn" + kTinyNn + " --out " + out.string(),
                                    "plan --planner random --set env.oracle=zf --out " + out.string()}) {
    const auto r = run(second);
    EXPECT_EQ(r.code, 2) << second << "\n" << r.err;
    EXPECT_NE(r.err.find("is in use by another skyloop run"), std::string::npos) << r.err;
    EXPECT_EQ(lines(r.err), 1) << r.err;
  }
  ::kill(first, SIGKILL);
  ASSERT_NE(wait_for(first, 30), -1);
  const auto after = run("train --steps 512 --force" + args);
  EXPECT_EQ(after.code, 0) << after.err;
}

// SIGTERM in the middle of a train command says how to go on (--resume), and that works; the line
// used to say "rerun the same command", which is refused for a run directory holding a run.
TEST(Probe, InterruptedTrainingSaysHowToResume) {
  const fs::path d = tmpdir("sigterm_train");
  const fs::path out = d / "run";
  const std::string args = " --model gnn" + kTinyNn + " --set nn.train_samples=400 --set nn.epochs=40 --out " + out.string();
  const pid_t pid = spawn("beamform train" + args, d);
  ASSERT_TRUE(eventually([&] { return fs::exists(out / "last.pt"); }, 120)) << slurp(d / "err");
  ::kill(pid, SIGTERM);
  const int status = wait_for(pid, 30);
  ASSERT_TRUE(status != -1 && WIFSIGNALED(status)) << slurp(d / "err");
  const std::string err = slurp(d / "err");
  EXPECT_NE(err.find("interrupted by SIGTERM"), std::string::npos) << err;
  EXPECT_NE(err.find("--resume"), std::string::npos) << err;
  EXPECT_EQ(run("beamform train" + args).code, 2);  // as the line says: not without --resume
  const auto resumed = run("beamform train --resume" + args);
  EXPECT_EQ(resumed.code, 0) << resumed.err;
}

// A run that fails half-way through writing (here: past a file-size limit, as on a full disk)
// leaves the directory's earlier run whole: its config.toml beside its own CSVs. `plan` used to
// have replaced config.toml already.
TEST(Probe, AFailedWriteLeavesTheEarlierRunWhole) {
  const fs::path d = tmpdir("full_disk");
  const fs::path out = d / "plan";
  const std::string plan = "plan --planner random,greedy --set env.oracle=zf --set trajectory.t_max=200 --out " + out.string();
  ASSERT_EQ(run(plan + " --seed 3").code, 0);
  std::map<std::string, std::string> before;
  std::uintmax_t config_size = 0, largest = 0;
  for (const auto& e : fs::directory_iterator(out)) {
    if (e.path().filename() == ".skyloop.lock") continue;
    before[e.path().filename().string()] = slurp(e.path());
    if (e.path().filename() == "config.toml") config_size = fs::file_size(e.path());
    largest = std::max(largest, fs::file_size(e.path()));
  }
  ASSERT_GT(largest, config_size + 2048);  // a limit that config.toml fits under and the largest CSV does not
  const std::uintmax_t kb = (config_size + 1023) / 1024 + 1;
  const int status = std::system(("bash -c 'trap \"\" XFSZ; ulimit -f " + std::to_string(kb) + "; exec " + kBin + " " + plan +
                                  " --seed 4' >/dev/null 2>" + (d / "err").string()).c_str());
  EXPECT_TRUE(WIFEXITED(status) && WEXITSTATUS(status) != 0) << slurp(d / "err");
  for (const auto& [name, text] : before) EXPECT_EQ(slurp(out / name), text) << name << " changed";
  EXPECT_TRUE(temporaries_under(out).empty());
}

// --resume on a run whose metrics.csv was cut at a line boundary, or with fewer steps than done:
// refused in one line, nothing rewritten (config.toml used to be rewritten, the log appended to).
TEST(Probe, ResumeRefusesABrokenLogAndABudgetAlreadySpent) {
  const fs::path out = tmpdir("resume_checks") / "run";
  const std::string args = " --algo mappo --set env.oracle=zf --set marl.envs=2 --set marl.rollout=64 --set run.threads=1 --out " +
                           out.string();
  ASSERT_EQ(run("train --steps 2048" + args).code, 0);
  const std::string config = slurp(out / "config.toml"), metrics = slurp(out / "metrics.csv");
  const auto fewer = run("train --resume --steps 1024" + args);
  EXPECT_EQ(fewer.code, 2) << fewer.err;
  EXPECT_NE(fewer.err.find("already run"), std::string::npos) << fewer.err;
  EXPECT_EQ(slurp(out / "config.toml"), config);
  const auto cut = metrics.rfind('\n', metrics.size() - 2);
  spit(out / "metrics.csv", metrics.substr(0, cut + 1));
  const auto broken = run("train --resume --steps 4096" + args);
  EXPECT_EQ(broken.code, 2) << broken.err;
  EXPECT_NE(broken.err.find("metrics.csv"), std::string::npos) << broken.err;
  EXPECT_EQ(slurp(out / "config.toml"), config);
}

// A run stopped after a checkpoint's log was written and before its last.pt (the two files are
// written one after the other): the log is one checkpoint ahead, and --resume cuts it back to
// last.pt and goes on, leaving one row per update, each step count once.
TEST(Probe, AStopBetweenTheLogAndTheCheckpointResumes) {
  const fs::path out = tmpdir("resume_between") / "run";
  const std::string args = " --algo mappo --set env.oracle=zf --set marl.envs=2 --set marl.rollout=64 --set run.threads=1 --out " +
                           out.string();
  ASSERT_EQ(run("train --steps 1024" + args).code, 0);
  const std::string earlier = slurp(out / "last.pt");
  ASSERT_EQ(run("train --resume --steps 2048" + args).code, 0);
  spit(out / "last.pt", earlier);  // the state a stop between metrics.csv and last.pt leaves
  const auto r = run("train --resume --steps 3072" + args);
  ASSERT_EQ(r.code, 0) << r.err;
  std::istringstream log(slurp(out / "metrics.csv"));
  std::string line;
  std::getline(log, line);
  const auto col = [&] {
    std::istringstream h(line);
    std::string name;
    int i = 0;
    while (std::getline(h, name, ',') && name != "env_steps") ++i;
    return i;
  }();
  long long previous = -1;
  int rows = 0;
  while (std::getline(log, line)) {
    std::istringstream row(line);
    std::string cell;
    for (int i = 0; i <= col; ++i) std::getline(row, cell, ',');
    const long long steps = std::stoll(cell);
    EXPECT_GT(steps, previous) << "step count " << steps << " logged twice or out of order";
    previous = steps, ++rows;
  }
  EXPECT_EQ(previous, 3072);
  EXPECT_EQ(rows, 3072 / 128);  // one row per update of 2 x 64 steps
}

// `config show` says its output is a valid config file: it is, whatever the strings hold.
TEST(Probe, ConfigShowAlwaysReloads) {
  const fs::path d = tmpdir("show");
  for (const std::string& value : {std::string("a\"quote"), std::string("back\\slash"), std::string("new\nline"),
                                   std::string("tab\tand \x01 control"), std::string("üñïcödé")}) {
    // The value goes in through a TOML file (basic string with escapes).
    std::string escaped;
    for (char ch : value) {
      if (ch == '"') escaped += "\\\"";
      else if (ch == '\\') escaped += "\\\\";
      else if (ch == '\n') escaped += "\\n";
      else if (ch == '\t') escaped += "\\t";
      else if (ch == '\x01') escaped += "\\u0001";
      else escaped += ch;
    }
    spit(d / "in.toml", "[env]\noracle = \"" + escaped + "\"\n");  // a free-text field nothing reads at load
    const auto a = run("config show --config " + (d / "in.toml").string());
    ASSERT_EQ(a.code, 0) << a.err;
    spit(d / "shown.toml", a.out);
    const auto b = run("config show --config " + (d / "shown.toml").string());
    ASSERT_EQ(b.code, 0) << "config show output does not reload:\n" << b.err;
    EXPECT_EQ(a.out, b.out);
  }
}

// Output paths that are not plain files: a FIFO is refused and left alone; a symlink to a file is
// written through (the link stays a link).
TEST(Probe, SpecialFilesAsOutput) {
  const fs::path d = tmpdir("special");
  ASSERT_EQ(::mkfifo((d / "fifo.csv").c_str(), 0644), 0);
  const auto f = run("beamform eval --samples 1 --methods mrt --out " + (d / "fifo.csv").string());
  EXPECT_EQ(f.code, 2) << f.err;
  EXPECT_NE(f.err.find("FIFO"), std::string::npos) << f.err;
  EXPECT_TRUE(fs::is_fifo(fs::symlink_status(d / "fifo.csv")));
  EXPECT_FALSE(fs::exists(d / "fifo.config.toml"));

  spit(d / "real.csv", "old");
  fs::create_symlink(d / "real.csv", d / "link.csv");
  const auto l = run("beamform eval --samples 1 --methods mrt --out " + (d / "link.csv").string());
  EXPECT_EQ(l.code, 0) << l.err;
  EXPECT_TRUE(fs::is_symlink(d / "link.csv"));
  EXPECT_NE(slurp(d / "real.csv").find("sum_rate_bps_hz"), std::string::npos);
  EXPECT_TRUE(temporaries_under(d).empty());
}

// A CSV and its resolved config change together: a refused run changes neither, and the pair
// always describes one run.
TEST(Probe, CsvAndConfigPairStayConsistent) {
  const fs::path d = tmpdir("pair");
  const std::string out = (d / "x.csv").string();
  ASSERT_EQ(run("beamform eval --samples 1 --methods mrt --out " + out).code, 0);
  const std::string csv = slurp(d / "x.csv"), cfg = slurp(d / "x.config.toml");
  // The config side of the pair cannot be written (a directory took its name): nothing changes.
  fs::remove(d / "x.config.toml");
  fs::create_directories(d / "x.config.toml");
  const auto r = run("beamform eval --samples 1 --methods mrt --set channel.p_max_dbm=40 --out " + out);
  EXPECT_EQ(r.code, 2) << r.err;
  EXPECT_EQ(slurp(d / "x.csv"), csv);
  fs::remove_all(d / "x.config.toml");
  // A successful rerun replaces both.
  ASSERT_EQ(run("beamform eval --samples 1 --methods mrt --set channel.p_max_dbm=40 --out " + out).code, 0);
  EXPECT_NE(slurp(d / "x.csv"), csv);
  EXPECT_NE(slurp(d / "x.config.toml").find("p_max_dbm = 40.0"), std::string::npos);
  EXPECT_NE(slurp(d / "x.csv").find(",40,"), std::string::npos);
  (void)cfg;
  EXPECT_TRUE(temporaries_under(d).empty());
}

// Standard output that cannot be written (a full disk) is a failure: exit 1 and one line.
TEST(Probe, StdoutWriteErrorsFail) {
  if (!fs::exists("/dev/full")) GTEST_SKIP() << "no /dev/full";
  const auto scenario = kSrc + "/configs/scenarios/two_uavs.toml";
  for (const std::string& args : {std::string("config show"), std::string("beamform list"),
                                 "snapshot --json --method zf --scenario " + scenario,
                                 std::string("beamform eval --samples 2 --methods mrt --quiet")}) {
    const auto r = run(args, "/dev/full");
    EXPECT_EQ(r.code, 1) << args << "\n" << r.err;
    EXPECT_NE(r.err.find("cannot write to standard output"), std::string::npos) << args << "\n" << r.err;
  }
}

// A finished run directory is not overwritten by a new run without --force; --resume continues it.
TEST(Probe, FinishedRunsAreNotClobbered) {
  const fs::path d = tmpdir("clobber") / "run";
  ASSERT_EQ(run("beamform train --model deepsets --out " + d.string() + kTinyNn + " --set nn.epochs=1").code, 0);
  const std::string model = slurp(d / "model.pt"), test = slurp(d / "test.json");
  const auto again = run("beamform train --model deepsets --out " + d.string() + kTinyNn + " --set nn.epochs=2");
  EXPECT_EQ(again.code, 2) << again.err;
  EXPECT_NE(again.err.find("--force"), std::string::npos) << again.err;
  EXPECT_EQ(slurp(d / "model.pt"), model);
  EXPECT_EQ(slurp(d / "test.json"), test);
  const auto forced = run("beamform train --model deepsets --force --out " + d.string() + kTinyNn + " --set nn.epochs=2");
  EXPECT_EQ(forced.code, 0) << forced.err;

  const fs::path m = tmpdir("clobber_marl") / "run";
  const std::string marl = " --steps 512 --set env.oracle=zf --set marl.envs=2 --set marl.rollout=64 --set run.threads=1";
  ASSERT_EQ(run("train --algo vdn --out " + m.string() + marl).code, 0);
  const auto m2 = run("train --algo vdn --out " + m.string() + marl);
  EXPECT_EQ(m2.code, 2) << m2.err;
  EXPECT_EQ(run("train --algo vdn --force --out " + m.string() + marl).code, 0);
}

// kill -9 in the middle of `beamform train`, then --resume: the documented result, the same model
// as an uninterrupted run, and no temporary left behind.
TEST(Probe, KilledBeamformerTrainingResumesToTheSameModel) {
  const fs::path d = tmpdir("kill_nn");
  const std::string args = " --model gnn" + kTinyNn + " --set nn.train_samples=400 --set nn.epochs=40";
  ASSERT_EQ(run("beamform train --out " + (d / "straight").string() + args).code, 0);

  const fs::path killed = d / "killed";
  fs::create_directories(killed);
  const pid_t pid = spawn("beamform train --out " + killed.string() + args, d);
  ASSERT_TRUE(eventually([&] { return fs::exists(killed / "last.pt"); }, 120)) << slurp(d / "err");
  std::this_thread::sleep_for(std::chrono::milliseconds(300));
  ::kill(pid, SIGKILL);
  const int status = wait_for(pid, 30);
  ASSERT_TRUE(status != -1 && WIFSIGNALED(status)) << "the run finished before it could be killed; status " << status;
  spit(killed / "model.pt.tmp.999999", "debris of a process that is gone");  // as a kill mid-write leaves
  const auto r = run("beamform train --resume --out " + killed.string() + args);
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.err.find("resuming"), std::string::npos) << r.err;
  // The best model, the final checkpoint and the metrics equal the uninterrupted run's.
  for (const char* f : {"test.json"}) {
    auto strip = [](std::string s) {  // timings differ
      std::string out;
      std::istringstream in(s);
      for (std::string line; std::getline(in, line);)
        if (line.find("seconds") == std::string::npos && line.find("per_second") == std::string::npos) out += line + "\n";
      return out;
    };
    EXPECT_EQ(strip(slurp(killed / f)), strip(slurp(d / "straight" / f))) << f;
  }
  EXPECT_TRUE(temporaries_under(killed).empty());
}

// kill -9 in the middle of `train` (MARL), then --resume: it completes with a policy and the full
// step count, and no temporary is left behind.
TEST(Probe, KilledMarlTrainingResumes) {
  const fs::path d = tmpdir("kill_marl");
  const fs::path out = d / "run";
  const std::string args = " --algo mappo --steps 60000 --set env.oracle=zf --set marl.envs=2 --set marl.rollout=64"
                           " --set marl.checkpoint_every=2 --set run.threads=1 --out " + out.string();
  const pid_t pid = spawn("train" + args, d);
  ASSERT_TRUE(eventually([&] { return fs::exists(out / "last.pt"); }, 120)) << slurp(d / "err");
  std::this_thread::sleep_for(std::chrono::milliseconds(300));
  ::kill(pid, SIGKILL);
  const int status = wait_for(pid, 30);
  ASSERT_TRUE(status != -1 && WIFSIGNALED(status)) << "the run finished before it could be killed";
  EXPECT_FALSE(fs::exists(out / "policy.pt"));
  const auto r = run("train --resume" + args);
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_TRUE(fs::exists(out / "policy.pt"));
  const auto at = r.out.find(" environment steps");
  ASSERT_NE(at, std::string::npos) << r.out;
  const auto from = r.out.rfind(' ', at - 1);
  EXPECT_GE(std::stoll(r.out.substr(from + 1, at - from - 1)), 60000) << r.out;
  EXPECT_TRUE(temporaries_under(out).empty());
}

// `reproduce` with MARL child runs active: SIGINT or SIGTERM to its PID stops it at once, says
// "interrupted", and leaves no child running; SIGKILL to it stops the children too (they die with
// their parent). A rerun resumes and completes.
TEST(Probe, ReproduceStopsWithItsChildren) {
  const fs::path d = tmpdir("signals");
  fs::path out;
  for (int sig : {SIGINT, SIGTERM, SIGKILL}) {
    out = d / ("out" + std::to_string(sig));  // fresh each time: four MARL runs to interrupt
    fs::create_directories(d / std::to_string(sig));
    const pid_t pid = spawn("reproduce --profile tiny --no-plots --jobs 2 --threads 2 --only marl_training --out " + out.string(),
                            d / std::to_string(sig));
    // Wait until a child `skyloop train` of this output directory runs.
    const std::string needle = (out / "runs").string();
    const bool started = eventually([&] { return !processes_mentioning(needle).empty(); }, 180);
    if (!started) {  // a fresh output directory has four MARL runs to train as children
      ::kill(pid, SIGKILL);
      wait_for(pid, 10);
      FAIL() << "no MARL child process of reproduce was seen within 180 s: " << slurp(d / std::to_string(sig) / "err");
    }
    ::kill(pid, sig);
    const int status = wait_for(pid, 30);
    ASSERT_NE(status, -1) << "reproduce ignored signal " << sig;
    EXPECT_TRUE(WIFSIGNALED(status) && WTERMSIG(status) == sig) << "status " << status;
    if (sig != SIGKILL) {
      const std::string err = slurp(d / std::to_string(sig) / "err");
      EXPECT_NE(err.find("interrupted by SIG"), std::string::npos) << err;
    }
    EXPECT_TRUE(eventually([&] { return processes_mentioning(needle).empty(); }, 20))
        << "a child outlived reproduce after signal " << sig;
  }
  const auto r = run("reproduce --profile tiny --no-plots --jobs 2 --threads 2 --only marl_training --out " + out.string());
  EXPECT_EQ(r.code, 0) << r.err;
  EXPECT_TRUE(temporaries_under(out).empty());
}

// What the help and the README say is what the commands do.
TEST(Probe, DocsMatchBehaviour) {
  // `snapshot` (text) prints the channel and beamforming vectors of every served user.
  const auto s = run("snapshot --method zf --scenario " + kSrc + "/configs/scenarios/two_uavs.toml");
  ASSERT_EQ(s.code, 0) << s.err;
  std::size_t h = 0, w = 0;
  for (std::size_t at = 0; (at = s.out.find("h = [", at)) != std::string::npos; ++at) ++h;
  for (std::size_t at = 0; (at = s.out.find("w = [", at)) != std::string::npos; ++at) ++w;
  EXPECT_EQ(h, 5u) << s.out;  // five of the six users are served
  EXPECT_EQ(w, 5u) << s.out;
  // `beamform list`: every description starts in the same column.
  const auto l = run("beamform list");
  ASSERT_EQ(l.code, 0);
  std::istringstream in(l.out);
  std::set<std::size_t> columns;
  for (std::string line; std::getline(in, line);) {
    const auto name_end = line.find(' ');
    columns.insert(line.find_first_not_of(' ', name_end));
  }
  EXPECT_EQ(columns.size(), 1u) << l.out;
  // `train --help` lists only files a run writes.
  const auto help = run("train --help");
  EXPECT_EQ(help.out.find("summary.csv"), std::string::npos) << help.out;
  for (const char* f : {"config.toml", "metrics.csv", "last.pt", "policy.pt"}) {
    EXPECT_NE(help.out.find(f), std::string::npos) << f;
    EXPECT_TRUE(fs::exists(tiny_policy() / f)) << f;
  }
}
