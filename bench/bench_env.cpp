// Environment throughput on the paper scenario (3 UAVs, K = 12, T_max = 24) with the shipped GNN
// as the rate oracle, and the exact optimum's solve time. One torch thread.
#include <benchmark/benchmark.h>

#include <filesystem>

#include "skyloop/env/vec_env.hpp"
#include "skyloop/experiments/builtin.hpp"
#include "skyloop/nn/learned.hpp"
#include "skyloop/planning/planners.hpp"

using namespace skyloop;

namespace {
std::shared_ptr<const Beamformer> oracle_beamformer(const std::string& name) {
  set_torch_threads(1);
  return builtin_beamformers().create(name, Config{});
}

/// Steps with uniformly random actions (boundary moves included), resetting finished episodes.
void steps(benchmark::State& state, UavEnv& env, const std::vector<std::vector<int>>& actions) {
  std::size_t i = 0;
  std::int64_t n = 0;
  for (auto _ : state) {
    if (env.done()) env.reset();
    benchmark::DoNotOptimize(env.step(actions[i++ % actions.size()]));
    ++n;
  }
  state.SetItemsProcessed(n);  // environment steps per second
}

std::vector<std::vector<int>> random_actions() {
  Rng rng(1);
  std::vector<std::vector<int>> a(4096, std::vector<int>(3));
  for (auto& x : a)
    for (auto& y : x) y = static_cast<int>(rng.below(kGridActions));
  return a;
}
}  // namespace

// Warm cache: the oracle has seen the whole 11 x 11 grid for these users. It is warmed once per
// process (the DP visits every joint position the random walk can reach, about 8 s): Google
// Benchmark calls this function again for each trial iteration count.
static void BM_EnvStepWarm(benchmark::State& state) {
  const Config cfg;
  static const std::shared_ptr<RateOracle> oracle = [&] {
    auto o = std::make_shared<RateOracle>(cfg, oracle_beamformer("gnn"), make_users(cfg, 12, 3));
    UavEnv warm(cfg, o);
    solve_optimal(warm);
    return o;
  }();
  UavEnv env(cfg, oracle);
  steps(state, env, random_actions());
  state.SetLabel("hit_rate=" + std::to_string(oracle->stats().hit_rate()));
}
BENCHMARK(BM_EnvStepWarm)->Unit(benchmark::kMicrosecond);

// Cold cache: a new oracle (new users) every 24 steps, so most cluster rates are GNN calls.
static void BM_EnvStepCold(benchmark::State& state) {
  const Config cfg;
  const auto bf = oracle_beamformer("gnn");
  const auto actions = random_actions();
  std::uint64_t users_seed = 100;
  std::unique_ptr<UavEnv> env;
  std::size_t i = 0;
  std::int64_t n = 0;
  for (auto _ : state) {
    if (!env || env->done()) {
      state.PauseTiming();
      env = std::make_unique<UavEnv>(cfg, std::make_shared<RateOracle>(cfg, bf, make_users(cfg, 12, users_seed++)));
      state.ResumeTiming();
    }
    benchmark::DoNotOptimize(env->step(actions[i++ % actions.size()]));
    ++n;
  }
  state.SetItemsProcessed(n);
}
BENCHMARK(BM_EnvStepCold)->Unit(benchmark::kMicrosecond);

// Vector environment: M environments per batched step (cache misses of all in one GNN call).
static void BM_VecEnvStep(benchmark::State& state) {
  const Config cfg;
  const int m = static_cast<int>(state.range(0));
  VecEnv vec(cfg, oracle_beamformer("gnn"), m, 5);
  const auto actions = random_actions();
  std::size_t i = 0;
  for (auto _ : state) {
    std::vector<std::vector<int>> a(static_cast<std::size_t>(m));
    for (auto& x : a) x = actions[i++ % actions.size()];
    benchmark::DoNotOptimize(vec.step(a));
  }
  state.SetItemsProcessed(state.iterations() * m);
}
BENCHMARK(BM_VecEnvStep)->Arg(16)->Arg(64)->ArgName("envs")->Unit(benchmark::kMicrosecond);

// Vector environment with a cold cache: new users at every reset (env.resample_users), so every
// episode starts with an empty oracle; the misses of all M environments go to the GNN in one
// batched call per step (user drawing and oracle construction at reset are timed too).
static void BM_VecEnvStepCold(benchmark::State& state) {
  Config cfg;
  cfg.env.resample_users = true;
  const int m = static_cast<int>(state.range(0));
  VecEnv vec(cfg, oracle_beamformer("gnn"), m, 5);
  const auto actions = random_actions();
  std::size_t i = 0;
  std::uint64_t hits = 0, misses = 0;
  for (auto _ : state) {
    std::vector<std::vector<int>> a(static_cast<std::size_t>(m));
    for (auto& x : a) x = actions[i++ % actions.size()];
    benchmark::DoNotOptimize(vec.step(a));
  }
  for (int e = 0; e < m; ++e) hits += vec.env(e).oracle().stats().hits, misses += vec.env(e).oracle().stats().misses;
  state.SetItemsProcessed(state.iterations() * m);
  state.SetLabel("hit_rate(current episodes)=" + std::to_string(static_cast<double>(hits) / static_cast<double>(hits + misses)));
}
BENCHMARK(BM_VecEnvStepCold)->Arg(1)->Arg(8)->Arg(16)->Arg(64)->ArgName("envs")->Unit(benchmark::kMicrosecond);

// The paper's three starts and destinations on a square of `side` m (200: the paper's own).
static void square_area(Config& cfg, double side) {
  cfg.scenario.area_x_m = cfg.scenario.area_y_m = side;
  cfg.trajectory.starts = {{20, 20}, {20, side - 20}, {side - 20, side - 20}};
  cfg.trajectory.destinations = {{side - 20, side / 2}, {side - 20, 20}, {20, side / 2}};
}

// The exact optimum on the paper scenario (users seed 3), oracle cold at the start. Args: oracle
// (0 gnn, 1 wmmse), area side in m (200: the paper's), users K (12: the paper's).
static void BM_OptimalPaper(benchmark::State& state) {
  Config cfg;
  square_area(cfg, static_cast<double>(state.range(1)));
  const int users = static_cast<int>(state.range(2));
  const auto bf = oracle_beamformer(state.range(0) == 0 ? "gnn" : "wmmse");
  double objective = 0, mem = 0;
  for (auto _ : state) {
    auto oracle = std::make_shared<RateOracle>(cfg, bf, make_users(cfg, users, 3));
    UavEnv env(cfg, oracle);
    const auto plan = solve_optimal(env);
    objective = plan.objective;
    mem = static_cast<double>(plan.memory_bytes);
  }
  // A label, not counters: Google Benchmark's CSV needs every counter in every run of a binary.
  state.SetLabel("objective=" + std::to_string(objective) + " tables_MiB=" + std::to_string(mem / (1024.0 * 1024.0)));
}
BENCHMARK(BM_OptimalPaper)->Args({0, 200, 12})->Args({1, 200, 12})->ArgNames({"wmmse", "side", "users"})
    ->Unit(benchmark::kSecond)->Iterations(1);

// The exact optimum under the headings mobility model (8 headings x 10, 20 m/s, hover: 17
// actions) on the paper scenario, GNN oracle cold, per objective. Args: objective (0 sum-rate,
// 1 energy-efficiency, 2 weighted w = 0.1), area side in m (200: 11 x 11 cells, the paper; 240:
// 13 x 13, 4.8e6 joint states, the largest square lattice the DP takes for three UAVs), users K
// (12: the paper's).
static void BM_OptimalHeadings(benchmark::State& state) {
  Config cfg;
  cfg.trajectory.mobility = "headings";
  const Objective objectives[] = {Objective::SumRate, Objective::EnergyEfficiency, Objective::Weighted};
  cfg.env.objective = objectives[state.range(0)];
  cfg.energy.weight = 0.1;
  square_area(cfg, static_cast<double>(state.range(1)));
  const auto bf = oracle_beamformer("gnn");
  const int users = static_cast<int>(state.range(2));
  double objective = 0, iterations = 0;
  for (auto _ : state) {
    UavEnv env(cfg, std::make_shared<RateOracle>(cfg, bf, make_users(cfg, users, 3)));
    const auto plan = solve_optimal(env);
    objective = plan.objective, iterations = plan.iterations;
  }
  state.SetLabel("objective=" + std::to_string(objective) + " dinkelbach_iterations=" + std::to_string(iterations));
}
BENCHMARK(BM_OptimalHeadings)->Args({0, 200, 12})->Args({1, 200, 12})->ArgNames({"objective", "side", "users"})
    ->Unit(benchmark::kSecond)->Iterations(1);
static void BM_OptimalHeadingsLarge(benchmark::State& state) { BM_OptimalHeadings(state); }
BENCHMARK(BM_OptimalHeadingsLarge)->Args({2, 200, 12})->Args({0, 240, 12})->Args({1, 240, 12})
    ->ArgNames({"objective", "side", "users"})->Unit(benchmark::kSecond)->Iterations(1);

// The DP benchmarks above take from 6 s to a minute each and are measured by hand
// (--benchmark_filter=BM_Optimal); the smoke test (bench/CMakeLists.txt) leaves them out and runs
// the same functions on small instances instead (a 120 m square: 7 x 7 cells, 1.2e5 joint states
// against the paper's 1.8e6; 6 users), so that it exercises every DP benchmark in seconds.
static void BM_OptimalPaperSmall(benchmark::State& state) { BM_OptimalPaper(state); }
BENCHMARK(BM_OptimalPaperSmall)->Args({0, 120, 6})->Args({1, 120, 6})->ArgNames({"wmmse", "side", "users"})
    ->Unit(benchmark::kSecond)->Iterations(1);
static void BM_OptimalHeadingsSmall(benchmark::State& state) { BM_OptimalHeadings(state); }
BENCHMARK(BM_OptimalHeadingsSmall)->Args({0, 120, 6})->Args({1, 120, 6})->Args({2, 120, 6})
    ->ArgNames({"objective", "side", "users"})->Unit(benchmark::kSecond)->Iterations(1);

// The rate oracle's cost per new position (a cache miss: every cluster's channel drawn, the
// beamformer run on it in each fast slot, the sum rate): the paper's channel, and 3GPP UMa-AV with
// Rician fading at M = 1 and M = 8 fast slots. Args: oracle (0 gnn, 1 zfsel), channel (0 paper,
// 1 3gpp-uma-av + rician), fast slots.
static void BM_OracleNewPosition(benchmark::State& state) {
  Config cfg;
  const std::string name = state.range(0) == 0 ? "gnn" : "zfsel";
  if (state.range(1) == 1) {
    cfg.channel.pathloss = "3gpp-uma-av";
    cfg.channel.fading = "rician";
    cfg.channel.fast_slots = static_cast<int>(state.range(2));
  }
  set_torch_threads(1);
  RateOracle oracle(cfg, builtin_beamformers().create(name, cfg), make_users(cfg, 12, 3));
  Rng rng(7);
  Positions uavs(3, 2);
  for (auto _ : state) {
    for (Eigen::Index n = 0; n < 3; ++n) uavs(n, 0) = rng.uniform(0, 200), uavs(n, 1) = rng.uniform(0, 200);
    benchmark::DoNotOptimize(oracle.sum_rate(uavs));  // never seen: a miss for every UAV
  }
  state.SetLabel(name + (state.range(1) ? " 3gpp-uma-av+rician M=" + std::to_string(state.range(2)) : " paper"));
}
BENCHMARK(BM_OracleNewPosition)
    ->Args({0, 0, 1})->Args({0, 1, 1})->Args({0, 1, 8})->Args({1, 0, 1})->Args({1, 1, 1})->Args({1, 1, 8})
    ->ArgNames({"oracle", "channel", "slots"})->Unit(benchmark::kMicrosecond);

BENCHMARK_MAIN();
