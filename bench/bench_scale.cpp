// Every stage's cost as the scenario grows (N up to 64 UAVs, K up to 4096 users, 2 km x 2 km),
// one core, with complexity fits over K: snapshot and channels, association (spatial index),
// one full network decision (association + every cluster's beamformer), and the environment step
// warm and cold. The learned beamformer is the shipped paper GNN (fused path, one thread).
#include <benchmark/benchmark.h>

#include "skyloop/core/config_io.hpp"
#include "skyloop/env/uav_env.hpp"
#include "skyloop/experiments/builtin.hpp"
#include "skyloop/nn/learned.hpp"

using namespace skyloop;

namespace {

Config district(int uavs, int users) {
  return resolve_config(std::nullopt, {"run.threads=1", "scenario.uavs=" + std::to_string(uavs),
                                       "scenario.users=" + std::to_string(users), "scenario.area_x_m=2000",
                                       "scenario.area_y_m=2000", "trajectory.layout=generated", "trajectory.t_max=60"});
}

int uavs_of(const benchmark::State& s) { return static_cast<int>(s.range(0)); }
int users_of(const benchmark::State& s) { return static_cast<int>(s.range(1)); }

const std::vector<std::vector<int64_t>> kGrid = {{4, 16, 64}, {256, 1024, 4096}};

}  // namespace

// Random snapshot, association and every cluster's channel matrix.
static void BM_ScaleClusters(benchmark::State& state) {
  const Config cfg = district(uavs_of(state), users_of(state));
  const SystemModel model(cfg);
  std::uint64_t seed = 0;
  for (auto _ : state) benchmark::DoNotOptimize(model.clusters(model.random_snapshot(uavs_of(state), users_of(state), seed++)));
  state.SetComplexityN(users_of(state));
}
BENCHMARK(BM_ScaleClusters)->ArgsProduct(kGrid)->ArgNames({"N", "K"})->Unit(benchmark::kMicrosecond);

// Association alone: the spatial index above 8 UAVs.
static void BM_ScaleAssociation(benchmark::State& state) {
  const Config cfg = district(uavs_of(state), users_of(state));
  const SystemModel model(cfg);
  std::vector<Snapshot> snaps;
  for (std::uint64_t s = 0; s < 16; ++s) snaps.push_back(model.random_snapshot(uavs_of(state), users_of(state), s));
  std::size_t i = 0;
  for (auto _ : state) benchmark::DoNotOptimize(model.associate(snaps[i++ % snaps.size()]));
  state.SetComplexityN(users_of(state));
}
BENCHMARK(BM_ScaleAssociation)->ArgsProduct(kGrid)->ArgNames({"N", "K"})->Unit(benchmark::kMicrosecond);

// One full decision at N = 64 over 2 km: association + clusters + every cluster's beamformer.
static void decision(benchmark::State& state, const std::string& method) {
  set_torch_threads(1);
  const int N = 64, K = static_cast<int>(state.range(0));
  const Config cfg = district(N, K);
  const SystemModel model(cfg);
  const auto bf = builtin_beamformers().create(method, cfg);
  std::vector<Snapshot> snaps;
  for (std::uint64_t s = 0; s < 8; ++s) snaps.push_back(model.random_snapshot(N, K, s));
  std::size_t i = 0, served = 0, clusters = 0;
  for (auto _ : state) {
    const auto cs = model.clusters(snaps[i++ % snaps.size()]);
    benchmark::DoNotOptimize(bf->design_batch(cs, 1));
    clusters += cs.size();
    for (const auto& c : cs) served += static_cast<std::size_t>(c.size());
  }
  state.SetComplexityN(K);
  state.counters["users_per_cluster"] = static_cast<double>(served) / static_cast<double>(std::max<std::size_t>(1, clusters));
}
static void BM_ScaleDecisionZfSel(benchmark::State& s) { decision(s, "zfsel"); }
static void BM_ScaleDecisionGnn(benchmark::State& s) { decision(s, "gnn"); }
static void BM_ScaleDecisionWmmse(benchmark::State& s) { decision(s, "wmmse"); }
BENCHMARK(BM_ScaleDecisionZfSel)->Arg(256)->Arg(1024)->Arg(4096)->ArgName("K")->Unit(benchmark::kMillisecond)->Complexity(benchmark::oN);
BENCHMARK(BM_ScaleDecisionGnn)->Arg(256)->Arg(1024)->Arg(4096)->ArgName("K")->Unit(benchmark::kMillisecond)->Complexity(benchmark::oN);
BENCHMARK(BM_ScaleDecisionWmmse)->Arg(256)->Arg(1024)->ArgName("K")->Unit(benchmark::kMillisecond)->Complexity(benchmark::oN);

// The environment step (random feasible-or-not actions, GNN oracle) at scale: warm (one oracle
// for the whole run, its cache filling) and cold (new users every 24 steps).
static void env_steps(benchmark::State& state, bool cold) {
  set_torch_threads(1);
  const Config cfg = district(uavs_of(state), users_of(state));
  const std::shared_ptr<const Beamformer> bf = builtin_beamformers().create("gnn", cfg);
  Rng rng(1);
  std::uint64_t users_seed = 10;
  auto fresh = [&] { return std::make_unique<UavEnv>(cfg, std::make_shared<RateOracle>(cfg, bf, make_users(cfg, users_of(state), users_seed++))); };
  auto env = fresh();
  int t = 0;
  std::vector<int> a(static_cast<std::size_t>(uavs_of(state)));
  for (auto _ : state) {
    if (env->done() || (cold && t == 24)) {
      state.PauseTiming();
      if (cold) env = fresh();
      else env->reset();
      t = 0;
      state.ResumeTiming();
    }
    for (auto& x : a) x = static_cast<int>(rng.below(kGridActions));
    benchmark::DoNotOptimize(env->step(a));
    ++t;
  }
  state.SetComplexityN(users_of(state));
  state.SetItemsProcessed(state.iterations());
}
static void BM_ScaleEnvStepWarm(benchmark::State& s) { env_steps(s, false); }
static void BM_ScaleEnvStepCold(benchmark::State& s) { env_steps(s, true); }
BENCHMARK(BM_ScaleEnvStepWarm)->ArgsProduct({{16, 64}, {256, 1024, 4096}})->ArgNames({"N", "K"})->Unit(benchmark::kMicrosecond);
BENCHMARK(BM_ScaleEnvStepCold)->ArgsProduct({{16, 64}, {256, 1024, 4096}})->ArgNames({"N", "K"})->Unit(benchmark::kMicrosecond);

BENCHMARK_MAIN();
