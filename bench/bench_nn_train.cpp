// Training throughput of the learned beamformers: one epoch over 256 paper-setting snapshots
// (about 720 clusters, 4 optimiser steps of 64 snapshots), forward + backward + Adam step.
// Counter clusters_per_s excludes data generation and validation. Then the trajectory learners'
// update step on the fast backend and the element-wise tanh it spends its non-GEMM time in (each
// on the kernel variant ATEN_CPU_CAPABILITY allows).
#include <benchmark/benchmark.h>

#include <cstdlib>
#include <filesystem>
#include <random>
#include <string>
#include <system_error>

#include <unistd.h>

#include "../src/marl/ppo.hpp"
#include "../src/nn/fast_gemm.hpp"
#include "bench_util.hpp"
#include "skyloop/nn/learned.hpp"

using namespace skyloop;

static void train(benchmark::State& state, const std::string& model, const std::string& readout) {
  const char* t = std::getenv("SKYLOOP_BENCH_THREADS");
  Config cfg;
  cfg.run.threads = t ? std::atoi(t) : 1;
  cfg.nn.model = model;
  cfg.nn.readout = parse_choice<Readout>("nn.readout", readout);
  cfg.nn.train_samples = 64 * 4;
  cfg.nn.val_samples = 8;
  cfg.nn.test_samples = 8;
  cfg.nn.epochs = 1;
  const auto dir = std::filesystem::temp_directory_path() /
                   ("skyloop_bench_train_" + model + readout + "_" + std::to_string(::getpid()));
  double rate = 0;
  for (auto _ : state) {
    TrainOptions opt;
    opt.out_dir = dir.string();
    opt.force = true;  // the same scratch directory every iteration
    rate = train_beamformer(cfg, opt).clusters_per_second;
  }
  state.counters["clusters_per_s"] = rate;
  std::error_code ignored;
  std::filesystem::remove_all(dir, ignored);  // the trained model is not the benchmark's output
}

static void BM_TrainGnn(benchmark::State& s) { train(s, "gnn", "direct"); }
static void BM_TrainGnnStructured(benchmark::State& s) { train(s, "gnn", "structured"); }
static void BM_TrainDeepSets(benchmark::State& s) { train(s, "deepsets", "direct"); }
static void BM_TrainMsPointNet(benchmark::State& s) { train(s, "mspointnet", "direct"); }
BENCHMARK(BM_TrainGnn)->Unit(benchmark::kMillisecond)->Iterations(bench::iterations(2));
BENCHMARK(BM_TrainGnnStructured)->Unit(benchmark::kMillisecond)->Iterations(bench::iterations(2));
BENCHMARK(BM_TrainDeepSets)->Unit(benchmark::kMillisecond)->Iterations(bench::iterations(2));
BENCHMARK(BM_TrainMsPointNet)->Unit(benchmark::kMillisecond)->Iterations(bench::iterations(2));

// One PPO step of marl.backend = "fast" (src/marl/ppo.hpp) on a minibatch of 1,536 agent samples
// (8 environments x 256 steps x 3 UAVs over 4 minibatches: the paper scenario's), the paper's
// 11-real observation and the 37-real agent state, actor and critic 2 x 64 tanh: forward, loss,
// backward, clipping, Adam. GFLOP/s counts the multiply-adds of the unpadded layers (forward, the
// weight gradients and the hidden layers' input gradients).
static void BM_PpoUpdateStep(benchmark::State& state) {
  constexpr int kRows = 1536, kObs = 11, kCritic = 37, kHidden = 64, kActions = 5;
  marl::Minibatch b;
  b.rows = kRows, b.obs_width = kObs, b.critic_width = kCritic, b.action_count = kActions;
  std::mt19937 g(7);
  std::uniform_real_distribution<float> u(-1, 1);
  for (int i = 0; i < kRows * kObs; ++i) b.observations.push_back(u(g));
  for (int i = 0; i < kRows * kCritic; ++i) b.critic_inputs.push_back(u(g));
  for (int i = 0; i < kRows; ++i) {
    for (int k = 0; k < kActions; ++k) b.allowed.push_back(1.0f);
    b.actions.push_back(static_cast<std::int64_t>(g() % kActions));
    b.logprobs.push_back(std::log(1.0f / kActions) + 0.3f * u(g));
    b.advantages.push_back(u(g));
    b.active.push_back(1.0f);
    b.values.push_back(u(g));
    b.returns.push_back(u(g));
  }
  const char* t = std::getenv("SKYLOOP_BENCH_THREADS");
  auto nets = marl::make_ppo_networks(PpoBackend::Fast, kObs, kCritic, kHidden, 3e-4, torch::kCPU, 1, t ? std::atoi(t) : 1, kActions);
  const marl::PpoSettings settings{0.2, 0.5, 0.03, 10.0};
  for (auto _ : state) benchmark::DoNotOptimize(nets->step(b, settings));
  auto macs = [&](int in, int out) {  // forward, weight gradient, and the input gradient past the first layer
    return static_cast<double>(in) * kHidden * 2 + kHidden * kHidden * 3.0 + static_cast<double>(kHidden) * out * 3;
  };
  const double flops = 2.0 * kRows * (macs(kObs, kActions) + macs(kCritic, 1));
  state.counters["samples_per_s"] = benchmark::Counter(static_cast<double>(kRows), benchmark::Counter::kIsIterationInvariantRate);
  state.counters["GFLOP/s"] = benchmark::Counter(flops * 1e-9, benchmark::Counter::kIsIterationInvariantRate);
  state.SetLabel(nn::fast::kernel_isa());
}
BENCHMARK(BM_PpoUpdateStep)->Unit(benchmark::kMicrosecond);

// tanh over 64 Ki floats in place, as the learners' hidden layers take it.
static void BM_FastTanh(benchmark::State& state) {
  std::vector<float> x(65536);
  std::mt19937 g(3);
  std::normal_distribution<float> n(0.0f, 1.5f);
  for (auto& v : x) v = n(g);
  const std::vector<float> start = x;
  for (auto _ : state) {
    state.PauseTiming();
    x = start;
    state.ResumeTiming();
    nn::fast::tanh_inplace(x.data(), static_cast<long>(x.size()));
    benchmark::ClobberMemory();
  }
  state.counters["floats_per_s"] = benchmark::Counter(static_cast<double>(x.size()), benchmark::Counter::kIsIterationInvariantRate);
  state.SetLabel(nn::fast::kernel_isa());
}
BENCHMARK(BM_FastTanh)->Unit(benchmark::kMicrosecond);

BENCHMARK_MAIN();
