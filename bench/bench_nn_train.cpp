// Training throughput of the learned beamformers: one epoch over 256 paper-setting snapshots
// (about 720 clusters, 4 optimiser steps of 64 snapshots), forward + backward + Adam step.
// Counter clusters_per_s excludes data generation and validation.
#include <benchmark/benchmark.h>

#include <cstdlib>
#include <filesystem>

#include "skyloop/nn/learned.hpp"

using namespace skyloop;

static void train(benchmark::State& state, const std::string& model, const std::string& readout) {
  const char* t = std::getenv("SKYLOOP_BENCH_THREADS");
  Config cfg;
  cfg.run.threads = t ? std::atoi(t) : 1;
  cfg.nn.model = model;
  cfg.nn.readout = readout;
  cfg.nn.train_samples = 64 * 4;
  cfg.nn.val_samples = 8;
  cfg.nn.test_samples = 8;
  cfg.nn.epochs = 1;
  const auto dir = std::filesystem::temp_directory_path() / ("skyloop_bench_train_" + model + readout);
  double rate = 0;
  for (auto _ : state) {
    TrainOptions opt;
    opt.out_dir = dir.string();
    opt.force = true;  // the same scratch directory every iteration
    rate = train_beamformer(cfg, opt).clusters_per_second;
  }
  state.counters["clusters_per_s"] = rate;
}

static void BM_TrainGnn(benchmark::State& s) { train(s, "gnn", "direct"); }
static void BM_TrainGnnStructured(benchmark::State& s) { train(s, "gnn", "structured"); }
static void BM_TrainDeepSets(benchmark::State& s) { train(s, "deepsets", "direct"); }
static void BM_TrainMsPointNet(benchmark::State& s) { train(s, "mspointnet", "direct"); }
BENCHMARK(BM_TrainGnn)->Unit(benchmark::kMillisecond)->Iterations(2);
BENCHMARK(BM_TrainGnnStructured)->Unit(benchmark::kMillisecond)->Iterations(2);
BENCHMARK(BM_TrainDeepSets)->Unit(benchmark::kMillisecond)->Iterations(2);
BENCHMARK(BM_TrainMsPointNet)->Unit(benchmark::kMillisecond)->Iterations(2);

BENCHMARK_MAIN();
