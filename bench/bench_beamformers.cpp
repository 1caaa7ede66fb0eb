// Decision latency of each beamformer per cluster versus cluster size K_n (L = 4, paper channel
// settings). Each iteration designs one cluster, cycling through 64 seeded clusters of that size,
// so a figure is the mean over realistic clusters. Single-threaded.
#include <benchmark/benchmark.h>

#include "bench_util.hpp"
#include "skyloop/beamforming/wmmse.hpp"
#include "skyloop/experiments/builtin.hpp"

using namespace skyloop;

namespace {
void run(benchmark::State& state, const std::string& method, const Config& cfg, int pool = 64) {
  const int k = static_cast<int>(state.range(0));
  const auto clusters = bench::clusters(k, pool);
  const auto bf = builtin_beamformers().create(method, cfg);
  std::size_t i = 0;
  for (auto _ : state) {
    MatrixXcd W = bf->design(clusters[i++ % clusters.size()]);
    benchmark::DoNotOptimize(W.data());
  }
  state.SetComplexityN(k);
}
}  // namespace

static void BM_Mrt(benchmark::State& s) { run(s, "mrt", Config{}); }
static void BM_Zf(benchmark::State& s) { run(s, "zf", Config{}); }
static void BM_ZfSel(benchmark::State& s) { run(s, "zfsel", Config{}); }
static void BM_Rzf(benchmark::State& s) { run(s, "rzf", Config{}); }
// skyloop's WMMSE as configured by default (start: ZF with user selection, tol 1e-6, cap 1000).
static void BM_Wmmse(benchmark::State& s) { run(s, "wmmse", Config{}); }
// Textbook WMMSE (start: RZF, tol 1e-6, cap 1000): slow in this highly correlated LoS channel.
static void BM_WmmseRzfStart(benchmark::State& s) {
  Config cfg;
  cfg.wmmse.init = WmmseInit::Rzf;
  run(s, "wmmse", cfg);
}
// The paper's GA: pagmo sga, population 100, 2000 generations.
static void BM_Ga2000(benchmark::State& s) { run(s, "ga", Config{}, 4); }

BENCHMARK(BM_Mrt)->DenseRange(1, 8)->ArgName("Kn")->Unit(benchmark::kMicrosecond)->Complexity();
BENCHMARK(BM_Zf)->DenseRange(1, 8)->ArgName("Kn")->Unit(benchmark::kMicrosecond)->Complexity();
BENCHMARK(BM_ZfSel)->DenseRange(1, 8)->ArgName("Kn")->Unit(benchmark::kMicrosecond)->Complexity();
BENCHMARK(BM_Rzf)->DenseRange(1, 8)->ArgName("Kn")->Unit(benchmark::kMicrosecond)->Complexity();
BENCHMARK(BM_Wmmse)->DenseRange(1, 8)->ArgName("Kn")->Unit(benchmark::kMicrosecond)->Complexity();
BENCHMARK(BM_WmmseRzfStart)->DenseRange(1, 8)->ArgName("Kn")->Unit(benchmark::kMicrosecond);
BENCHMARK(BM_Ga2000)->DenseRange(1, 8)->ArgName("Kn")->Unit(benchmark::kMillisecond)->Iterations(bench::iterations(4));

// Coordinated beamformers under the shared spectrum: one decision = one network of N UAVs, K = 12.
static void network_run(benchmark::State& state, const std::string& method) {
  Config cfg;
  cfg.channel.spectrum = Spectrum::Shared;
  const auto bf = builtin_beamformers().create(method, cfg);
  const SystemModel model(cfg);
  std::vector<Network> nets;
  for (std::uint64_t s = 0; s < 32; ++s) nets.push_back(model.network(model.random_snapshot(static_cast<int>(state.range(0)), 12, s)));
  std::size_t i = 0;
  for (auto _ : state) {
    auto W = bf->design_network(nets[i++ % nets.size()]);
    benchmark::DoNotOptimize(W.data());
  }
}
static void BM_NetworkWmmse(benchmark::State& s) { network_run(s, "nwmmse"); }
static void BM_CoordinatedRzf(benchmark::State& s) { network_run(s, "crzf"); }
static void BM_CoordinatedZf(benchmark::State& s) { network_run(s, "czf"); }
static void BM_NetworkZfSelect(benchmark::State& s) { network_run(s, "czfsel"); }
static void BM_NetworkWmmseFromZfSelect(benchmark::State& s) { network_run(s, "nwmmse=czfsel"); }
BENCHMARK(BM_NetworkWmmse)->DenseRange(2, 6)->ArgName("N")->Unit(benchmark::kMicrosecond);
BENCHMARK(BM_CoordinatedRzf)->DenseRange(2, 6)->ArgName("N")->Unit(benchmark::kMicrosecond);
BENCHMARK(BM_CoordinatedZf)->DenseRange(2, 6)->ArgName("N")->Unit(benchmark::kMicrosecond);
BENCHMARK(BM_NetworkZfSelect)->DenseRange(2, 6)->ArgName("N")->Unit(benchmark::kMicrosecond);
BENCHMARK(BM_NetworkWmmseFromZfSelect)->DenseRange(2, 6)->ArgName("N")->Unit(benchmark::kMicrosecond);

BENCHMARK_MAIN();
