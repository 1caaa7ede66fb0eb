// Learned beamformers: inference latency per decision (one snapshot, N = 3, K = 12, its clusters in
// one batched call) and per cluster in batches of 1, 64 and 1024; training throughput.
// Uses the shipped models (models/<name>/model.pt); one torch thread unless SKYLOOP_BENCH_THREADS.
#include <benchmark/benchmark.h>

#include <cstdlib>
#include <filesystem>

#include "bench_util.hpp"
#include "skyloop/nn/learned.hpp"

using namespace skyloop;

namespace {

const std::string kModels = SKYLOOP_MODELS_DIR;

/// The shipped model `name`, served by the fused kernels (torch = false, the default) or LibTorch.
std::unique_ptr<LearnedBeamformer> load(const std::string& name, bool torch) {
  const std::string path = kModels + "/" + name + "/model.pt";
  if (!std::filesystem::exists(path)) return nullptr;
  Config cfg;
  cfg.nn.inference = torch ? Inference::Torch : Inference::Fast;
  return LearnedBeamformer::load(path, cfg);
}

int bench_threads() {
  const char* t = std::getenv("SKYLOOP_BENCH_THREADS");
  return t ? std::atoi(t) : 1;
}

void per_decision(benchmark::State& state, const std::string& name) {
  set_torch_threads(bench_threads());
  const auto bf = load(name, state.range(0) != 0);
  if (!bf) return state.SkipWithError("no shipped model");
  const Config cfg;
  const SystemModel model(cfg);
  std::vector<std::vector<Cluster>> decisions;
  for (std::uint64_t s = 0; s < 64; ++s) decisions.push_back(model.clusters(model.random_snapshot(3, 12, s)));
  std::size_t i = 0;
  for (auto _ : state) {
    auto W = bf->design_batch(decisions[i++ % decisions.size()]);
    benchmark::DoNotOptimize(W.data());
  }
}

void per_cluster(benchmark::State& state, const std::string& name) {
  set_torch_threads(bench_threads());
  const auto bf = load(name, state.range(1) != 0);
  if (!bf) return state.SkipWithError("no shipped model");
  const Config cfg;
  const SystemModel model(cfg);
  const auto batch = static_cast<std::size_t>(state.range(0));
  std::vector<Cluster> pool;
  for (std::uint64_t s = 0; pool.size() < batch; ++s)
    for (auto& c : model.clusters(model.random_snapshot(3, 12, 1000 + s))) pool.push_back(std::move(c));
  pool.resize(batch);
  for (auto _ : state) {
    auto W = bf->design_batch(pool);
    benchmark::DoNotOptimize(W.data());
  }
  state.SetItemsProcessed(state.iterations() * static_cast<int64_t>(batch));  // clusters per second
}

/// Interference-aware GNN under the shared spectrum: one decision = one network (N = 3, K = 12),
/// or `batch` networks in one design_networks call (the rate oracle's and the DP's batched path);
/// torch = 1 serves it with LibTorch (the reference), 0 with the fused float32 path. rows = 0: every
/// network new (4,096 networks of random users in turn, 147,456 user and edge rows, far beyond the
/// fused path's row caches); rows = 1: the same 64 networks again and again, every user and edge
/// row from the caches, as in the DP, where a million joint states hold a few thousand rows.
void per_network(benchmark::State& state, const std::string& name) {
  set_torch_threads(bench_threads());
  Config cfg;
  cfg.channel.spectrum = Spectrum::Shared;
  cfg.nn.inference = state.range(1) != 0 ? Inference::Torch : Inference::Fast;
  const std::string path = kModels + "/" + name + "/model.pt";
  if (!std::filesystem::exists(path)) return state.SkipWithError("no shipped model");
  const auto bf = LearnedBeamformer::load(path, cfg);
  const SystemModel model(cfg);
  const auto batch = static_cast<std::size_t>(state.range(0));
  const bool recurring = state.range(2) != 0;
  std::vector<Network> nets;
  const std::size_t pool = recurring ? std::max<std::size_t>(batch, 64) : std::max<std::size_t>(batch, 4096);
  for (std::uint64_t s = 0; s < pool; ++s) nets.push_back(model.network(model.random_snapshot(3, 12, s)));
  std::size_t i = 0;
  for (auto _ : state) {
    if (batch == 1) {
      auto W = bf->design_network(nets[i++ % nets.size()]);
      benchmark::DoNotOptimize(W.data());
    } else {
      const std::size_t first = recurring ? 0 : (i * batch) % (nets.size() - batch + 1);
      ++i;
      auto W = bf->design_networks(std::vector<Network>(nets.begin() + static_cast<std::ptrdiff_t>(first),
                                                        nets.begin() + static_cast<std::ptrdiff_t>(first + batch)));
      benchmark::DoNotOptimize(W.data());
    }
  }
  state.SetItemsProcessed(state.iterations() * static_cast<int64_t>(batch));  // networks per second
}

}  // namespace

static void BM_IgnnNetwork(benchmark::State& s) { per_network(s, "ignn_structured"); }
BENCHMARK(BM_IgnnNetwork)
    ->ArgsProduct({{1, 64, 1024}, {0, 1}, {0, 1}})
    ->ArgNames({"batch", "torch", "rows"})
    ->Unit(benchmark::kMicrosecond);

static void BM_GnnDecision(benchmark::State& s) { per_decision(s, "gnn"); }
static void BM_DeepSetsDecision(benchmark::State& s) { per_decision(s, "deepsets"); }
static void BM_MsPointNetDecision(benchmark::State& s) { per_decision(s, "mspointnet"); }
static void BM_GnnClusters(benchmark::State& s) { per_cluster(s, "gnn"); }
static void BM_DeepSetsClusters(benchmark::State& s) { per_cluster(s, "deepsets"); }
static void BM_MsPointNetClusters(benchmark::State& s) { per_cluster(s, "mspointnet"); }

static void BM_GnnStructuredDecision(benchmark::State& s) { per_decision(s, "gnn_structured"); }

// torch:0 = the fused float32 path (the default for inference), torch:1 = LibTorch (the reference).
BENCHMARK(BM_GnnDecision)->Arg(0)->Arg(1)->ArgName("torch")->Unit(benchmark::kMicrosecond);
BENCHMARK(BM_GnnStructuredDecision)->Arg(0)->Arg(1)->ArgName("torch")->Unit(benchmark::kMicrosecond);
BENCHMARK(BM_DeepSetsDecision)->Arg(0)->Arg(1)->ArgName("torch")->Unit(benchmark::kMicrosecond);
BENCHMARK(BM_MsPointNetDecision)->Arg(0)->Arg(1)->ArgName("torch")->Unit(benchmark::kMicrosecond);
BENCHMARK(BM_GnnClusters)->ArgsProduct({{1, 8, 64, 1024}, {0, 1}})->ArgNames({"batch", "torch"})->Unit(benchmark::kMicrosecond);
BENCHMARK(BM_DeepSetsClusters)->ArgsProduct({{1, 64, 1024}, {0, 1}})->ArgNames({"batch", "torch"})->Unit(benchmark::kMicrosecond);
BENCHMARK(BM_MsPointNetClusters)->ArgsProduct({{1, 64, 1024}, {0, 1}})->ArgNames({"batch", "torch"})->Unit(benchmark::kMicrosecond);

BENCHMARK_MAIN();
