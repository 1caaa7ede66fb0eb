// Channel generation: snapshots -> association -> cluster channel matrices.
#include <benchmark/benchmark.h>

#include "skyloop/channel/rates.hpp"
#include "skyloop/channel/system_model.hpp"
#include "skyloop/core/rng.hpp"

using namespace skyloop;

// One network snapshot (N UAVs, K users): random positions, association and all cluster channels.
static void BM_SnapshotClusters(benchmark::State& state) {
  const Config cfg;
  const SystemModel model(cfg);
  const int n = static_cast<int>(state.range(0)), k = static_cast<int>(state.range(1));
  std::uint64_t i = 0;
  for (auto _ : state) {
    const Snapshot s = model.random_snapshot(n, k, derive_seed(1, i++));
    auto c = model.clusters(s);
    benchmark::DoNotOptimize(c.data());
  }
  state.SetItemsProcessed(state.iterations());
}
BENCHMARK(BM_SnapshotClusters)->ArgsProduct({{3}, {8, 12, 16, 24}})->ArgNames({"N", "K"});

// One cluster's channel matrix G for K_n users (L = 4).
static void BM_ClusterChannel(benchmark::State& state) {
  const Config cfg;
  const SystemModel model(cfg);
  const int k = static_cast<int>(state.range(0));
  const Snapshot s = model.random_snapshot(1, k, 3);
  std::vector<int> users(static_cast<std::size_t>(k));
  for (int i = 0; i < k; ++i) users[static_cast<std::size_t>(i)] = i;
  for (auto _ : state) {
    Cluster c = model.make_cluster(0, 100, 100, s.users, users);
    benchmark::DoNotOptimize(c.G.data());
  }
  state.SetComplexityN(k);
}
BENCHMARK(BM_ClusterChannel)->DenseRange(1, 8)->ArgName("Kn")->Complexity(benchmark::oN);

// Sum rate of a cluster under a given W.
static void BM_SumRate(benchmark::State& state) {
  const Config cfg;
  const SystemModel model(cfg);
  const int k = static_cast<int>(state.range(0));
  const Snapshot s = model.random_snapshot(1, k, 4);
  std::vector<int> users(static_cast<std::size_t>(k));
  for (int i = 0; i < k; ++i) users[static_cast<std::size_t>(i)] = i;
  const Cluster c = model.make_cluster(0, 100, 100, s.users, users);
  const MatrixXcd W = c.G.adjoint();
  for (auto _ : state) benchmark::DoNotOptimize(sum_rate(c, W));
}
BENCHMARK(BM_SumRate)->DenseRange(1, 8)->ArgName("Kn");

BENCHMARK_MAIN();
