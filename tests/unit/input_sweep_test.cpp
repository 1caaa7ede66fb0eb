// The class of "an accepted value crashes, hangs or exhausts memory": every numeric configuration
// field set to its minimum, its maximum and just inside each, one at a time, then a tiny snapshot
// (every classical beamformer, network rates), an exact and a greedy plan and environment steps
// with every array written. Each case runs in a child process with a time bound (and, outside
// AddressSanitizer, a memory bound): it must succeed or refuse with one line (InputError).
#include <gtest/gtest.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <csignal>
#include <string>
#include <thread>

#include "skyloop/planning/registry.hpp"
#include "skyloop/beamforming/registry.hpp"
#include "skyloop/channel/network.hpp"
#include "skyloop/channel/system_model.hpp"
#include "skyloop/core/config.hpp"
#include "skyloop/core/config_io.hpp"
#include "skyloop/core/error.hpp"
#include "skyloop/env/uav_env.hpp"
#include "skyloop/planning/planners.hpp"

#if defined(__SANITIZE_ADDRESS__)
#define SKYLOOP_ASAN 1
#elif defined(__has_feature)
#if __has_feature(address_sanitizer)
#define SKYLOOP_ASAN 1
#endif
#endif

using namespace skyloop;

namespace {

// A tiny world: 2 UAVs on a 100 m square (6 x 6 lattice), 6 users; snapshots of 9 UAVs so that the
// association's spatial index is used.
const std::vector<std::string> kBase = {
    "scenario.area_x_m=100", "scenario.area_y_m=100", "scenario.users=6", "scenario.uavs=9",
    "trajectory.starts=[[20, 20], [80, 80]]", "trajectory.destinations=[[80, 20], [20, 80]]", "trajectory.t_max=10",
    "env.oracle=\"zf\"", "run.threads=1"};

/// What one case does: config, snapshot, plans, steps. Throws InputError for a refusal.
void exercise(const std::string& assignment) {
  std::vector<std::string> sets = kBase;
  sets.push_back(assignment);
  const Config cfg = resolve_config(std::nullopt, sets);
  BeamformerRegistry reg;
  register_classical_beamformers(reg);
  SystemModel model(cfg);
  const Snapshot s = model.random_snapshot(cfg.scenario.uavs, cfg.scenario.users, 5);
  const Network net = model.network(s);
  for (const char* name : {"mrt", "zf", "zfsel", "zfgain", "rzf", "wmmse", "nwmmse", "nwmmse=czfsel", "czf", "crzf", "czfsel"}) {
    const auto bf = reg.create(name, cfg);
    const auto W = bf->design_network(net, 1);
    (void)network_sum_rate(net, W);
  }
  auto oracle = std::make_shared<RateOracle>(cfg, std::shared_ptr<const Beamformer>(reg.create("zf", cfg)),
                                             make_users(cfg, cfg.scenario.users, 3));
  for (const char* planner : {"optimal", "greedy", "seqgreedy", "random"}) {
    // The DP evaluates every joint state (1296 here) and a state costs O(K^2 L) under ZF once
    // K > L: at K = 4096 that is minutes of honest work, not a hang; its bounds are the state and
    // table limits, tested on the paper grid below.
    if (std::string(planner) == "optimal" && cfg.scenario.users > 256) continue;
    UavEnv env(cfg, oracle);
    PlannerArgs args;
    args.seed = 1;
    const auto p = builtin_planners().create(planner, args);
    (void)run_episode(env, *p);
  }
  UavEnv env(cfg, oracle);
  std::vector<float> row(static_cast<std::size_t>(env.spec().agent_state.size + env.spec().obs.size + env.spec().state.size));
  for (int t = 0; t < 3 && !env.done(); ++t) {
    for (int n = 0; n < env.uavs(); ++n) env.write_obs(n, row.data()), env.write_agent_state(n, row.data());
    env.write_state(row.data());
    env.step(std::vector<int>(static_cast<std::size_t>(env.uavs()), kRight));
  }
}

struct Outcome {
  enum Kind { Ok, Refused, Failed } kind;
  std::string text;
};

/// Runs exercise(assignment) in a child; refusals come back over a pipe. The child may spend
/// `cpu_seconds` of processor time (RLIMIT_CPU, all its threads together: what the case costs,
/// whatever else the machine runs) and five times that in wall time (a hang that waits without
/// computing).
Outcome run_case(const std::string& assignment, double cpu_seconds) {
  const double seconds = 5 * cpu_seconds;
  int fd[2];
  if (pipe(fd) != 0) return {Outcome::Failed, "pipe"};
  const pid_t pid = fork();
  if (pid == 0) {
    close(fd[0]);
#ifndef SKYLOOP_ASAN
    rlimit mem{6ULL << 30, 6ULL << 30};  // 6 GiB of address space: "exhausts memory" fails here
    setrlimit(RLIMIT_AS, &mem);
#endif
    const auto cpu = static_cast<rlim_t>(std::ceil(cpu_seconds));
    rlimit time{cpu, cpu + 5};  // SIGXCPU at the soft limit, SIGKILL at the hard one
    setrlimit(RLIMIT_CPU, &time);
    int code = 0;
    std::string text;
    try {
      exercise(assignment);
    } catch (const InputError& e) {
      code = 2, text = e.what();
    } catch (const std::exception& e) {
      code = 3, text = std::string("not an InputError: ") + e.what();
    }
    if (!text.empty()) (void)!write(fd[1], text.data(), text.size());
    close(fd[1]);
    _exit(code);
  }
  close(fd[1]);
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::duration<double>(seconds);
  int status = 0;
  while (waitpid(pid, &status, WNOHANG) == 0) {
    if (std::chrono::steady_clock::now() > deadline) {
      kill(pid, SIGKILL);
      waitpid(pid, &status, 0);
      close(fd[0]);
      return {Outcome::Failed, "did not finish within " + std::to_string(seconds) + " s"};
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }
  std::string text;
  char buf[4096];
  for (ssize_t got; (got = read(fd[0], buf, sizeof buf)) > 0;) text.append(buf, static_cast<std::size_t>(got));
  close(fd[0]);
  if (WIFSIGNALED(status) && (WTERMSIG(status) == SIGXCPU || WTERMSIG(status) == SIGKILL))
    return {Outcome::Failed, "used more than " + std::to_string(cpu_seconds) + " s of processor time"};
  if (WIFSIGNALED(status)) return {Outcome::Failed, "killed by signal " + std::to_string(WTERMSIG(status))};
  const int code = WEXITSTATUS(status);
  if (code == 0) return {Outcome::Ok, ""};
  if (code == 2) return {Outcome::Refused, text};
  return {Outcome::Failed, "exit " + std::to_string(code) + ": " + text};
}

std::string number(double v, bool integer) {
  if (integer) return std::to_string(static_cast<long long>(v));
  char b[64];
  std::snprintf(b, sizeof b, "%.17g", v);
  std::string s = b;
  if (s.find_first_of(".eEn") == std::string::npos) s += ".0";  // a TOML float
  return s;
}

}  // namespace

TEST(InputSweep, EveryNumericFieldAtItsBoundsRunsOrIsRefusedInOneLine) {
  // Processor seconds per case (all threads): every case together took 30 s of processor time
  // (2-core VM, 2026-11-25, beside a training run that made the old 30 s wall-clock bound fail
  // scenario.users = 4095); the sanitizers run about 10x slower.
#ifdef SKYLOOP_ASAN
  const double bound = 240;
#else
  const double bound = 60;
#endif
  int cases = 0, ok = 0;
  for (const Field& f : config_fields()) {
    if (f.type != Field::Type::Integer && f.type != Field::Type::Real) continue;
    const bool integer = f.type == Field::Type::Integer;
    const double step = integer ? 1.0 : std::max(1e-9, (f.hi - f.lo) * 1e-6);
    for (const double v : {f.lo, f.lo + step, f.hi - step, f.hi}) {
      if (v < f.lo || v > f.hi) continue;
      const std::string assignment = f.key + "=" + number(v, integer);
#ifdef SKYLOOP_ASAN
      // Under the sanitizers (about 10x slower) thousands of users take minutes of honest work;
      // the optimised build runs those values, this one looks for memory errors at the rest.
      if (f.key == "scenario.users" && v > 1024) continue;
#endif
      const Outcome o = run_case(assignment, bound);
      ++cases;
      ok += o.kind == Outcome::Ok;
      EXPECT_NE(o.kind, Outcome::Failed) << assignment << ": " << o.text;
      if (o.kind == Outcome::Refused) {
        EXPECT_FALSE(o.text.empty()) << assignment;
        EXPECT_EQ(o.text.find('\n'), std::string::npos) << assignment << ": more than one line: " << o.text;
      }
    }
  }
  EXPECT_GT(cases, 200);
  EXPECT_GT(ok, cases / 2) << "most bound values must run, not only be refused";
}

// The defects found by probing, each reproduced (crash, hang, memory) before its fix.
TEST(InputSweep, KnownHangsAndCrashesAreFixed) {
  // WMMSE's bisection at its documented lowest tolerance (below double precision) used to loop for ever.
  EXPECT_EQ(run_case("wmmse.bisection_tolerance=1e-16", 60).kind, Outcome::Ok);
  // R_c just above H: the spatial index's cells used to be the (tiny) horizontal reach wide.
  EXPECT_EQ(run_case("channel.coverage_radius_m=100.0000001", 60).kind, Outcome::Ok);
}

TEST(InputSweep, TheExactPlannerRefusesAHorizonItsTableCannotHold) {
  // The paper's grid (121 cells, 3 UAVs) at T_max = 500: 8.9e8 table entries used to be allocated.
  const Config cfg = resolve_config(std::nullopt, {"trajectory.t_max=500", "env.oracle=\"zf\""});
  BeamformerRegistry reg;
  register_classical_beamformers(reg);
  auto oracle = std::make_shared<RateOracle>(cfg, std::shared_ptr<const Beamformer>(reg.create("zf", cfg)),
                                             make_users(cfg, cfg.scenario.users, 3));
  UavEnv env(cfg, oracle);
  try {
    solve_optimal(env, nullptr);
    FAIL() << "the DP accepted T_max = 500 on the paper grid";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("trajectory.t_max <= 75"), std::string::npos) << e.what();
  }
}

TEST(InputSweep, TrajectoriesNoMoveCanCompleteAreRefused) {
  // A destination equal to its start, or off the D_fly lattice of its start, passed validation.
  EXPECT_THROW(resolve_config(std::nullopt, {"trajectory.destinations=[[20, 20], [180, 20], [20, 100]]"}), InputError);
  EXPECT_THROW(resolve_config(std::nullopt, {"trajectory.destinations=[[185, 100], [180, 20], [20, 100]]"}), InputError);
  EXPECT_NO_THROW(resolve_config(std::nullopt, {"trajectory.destinations=[[40, 20], [180, 20], [20, 100]]"}));
  EXPECT_THROW(resolve_config(std::nullopt, {"env.users_max=100000"}), InputError);
  // "--set key=50 # comment" used to set 50 silently; an empty value fell back to the default.
  EXPECT_THROW(resolve_config(std::nullopt, {"channel.p_max_dbm=50 #=40"}), InputError);
  EXPECT_THROW(resolve_config(std::nullopt, {"channel.p_max_dbm="}), InputError);
}
