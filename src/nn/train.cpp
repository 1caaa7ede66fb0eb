// Unsupervised training of the learned beamformers (Algorithm alg:gnn-training).
#include <chrono>
#include <cmath>
#include <filesystem>
#include <fmt/format.h>
#include <nlohmann/json.hpp>
#include <numeric>
#include <ostream>

#include "checkpoint.hpp"
#include "models.hpp"
#include "data.hpp"
#include "skyloop/channel/rates.hpp"
#include "skyloop/core/config_io.hpp"
#include "skyloop/core/error.hpp"
#include "skyloop/core/io.hpp"
#include "skyloop/core/memory.hpp"
#include "skyloop/core/parallel.hpp"
#include "skyloop/core/progress.hpp"
#include "skyloop/core/rng.hpp"
#include "skyloop/beamforming/registry.hpp"

#include <dlfcn.h>

namespace skyloop {

void set_torch_threads(int threads) {
  if (threads > 0) {
    torch::set_num_threads(threads);
    // The BLAS under LibTorch keeps threads of its own: OpenBLAS splits a GEMM over every core it
    // sees whatever torch's count, so "one thread" trained another model on a machine with more
    // cores visible (a process bound to one core, as mpirun binds its ranks, got other bits).
    // Found at run time: Debian's libblas.so.3 may be OpenBLAS or the reference BLAS.
    using SetThreads = void (*)(int);
    static const auto openblas = reinterpret_cast<SetThreads>(::dlsym(RTLD_DEFAULT, "openblas_set_num_threads"));
    if (openblas) openblas(threads);
  }
  flush_denormals();  // as the process's main thread (a thread started before it was set)
}

namespace nn {
torch::Device resolve_device(const std::string& name) {
  if (name == "cuda") {
    if (!torch::cuda::is_available())
      throw InputError("nn.device = \"cuda\" is not available (this LibTorch has no CUDA, or no GPU is visible): allowed cpu");
    return torch::Device(torch::kCUDA);
  }
  return torch::Device(torch::kCPU);
}
}  // namespace nn

namespace {

using Clock = std::chrono::steady_clock;

/// The test snapshots as networks (channel.spectrum).
std::vector<Network> test_networks(const Config& cfg) {
  const SystemModel model(cfg);
  const auto seed = derive_seed(cfg.nn.data_seed, static_cast<std::uint64_t>(nn::Split::Test));
  const auto snaps = random_snapshots(model, cfg.scenario.uavs, cfg.scenario.users, seed,
                                      static_cast<std::size_t>(cfg.nn.test_samples));
  std::vector<Network> nets;
  for (const auto& s : snaps) nets.push_back(model.network(s));
  return nets;
}

/// Mean network sum rate of a beamformer on networks (the same path as every evaluation).
double mean_network_rate(const Beamformer& bf, const std::vector<Network>& nets, int threads) {
  const auto W = bf.design_networks(nets, threads);
  double total = 0;
  for (std::size_t i = 0; i < nets.size(); ++i) total += network_sum_rate(nets[i], W[i]);
  return nets.empty() ? 0.0 : total / static_cast<double>(nets.size());
}

/// Sum rates of the classical references on the test snapshots, for the test report.
nlohmann::json reference_rates(const Config& cfg, const std::vector<Network>& nets) {
  nlohmann::json out;
  BeamformerRegistry classical;
  register_classical_beamformers(classical);
  std::vector<const char*> names{"mrt", "zf", "zfsel", "wmmse"};
  if (parse_spectrum(cfg.channel.spectrum) == Spectrum::Shared) names.insert(names.end(), {"crzf", "nwmmse"});
  for (const char* name : names) out[name] = mean_network_rate(*classical.create(name, cfg), nets, cfg.run.threads);
  return out;
}

}  // namespace

TrainResult train_beamformer(const Config& cfg, const TrainOptions& opt) {
  namespace fs = std::filesystem;
  if (opt.out_dir.empty()) throw InputError("--out is empty: allowed a directory for the model and its logs");
  const torch::Device device = nn::resolve_device(cfg.nn.device);
  set_torch_threads(cfg.run.threads);
  const fs::path dir(opt.out_dir);
  const std::string last_path = (dir / "last.pt").string(), best_path = (dir / "model.pt").string();
  check_resume_or_force(opt.resume, opt.force);
  if (opt.resume && !fs::exists(last_path))
    throw InputError("--resume: '" + last_path + "' does not exist: allowed a directory of an earlier training run");
  const bool network = nn::make_model(cfg.nn.model, cfg.channel.antennas, 4, 1)->network();
  {
    // What the data sets hold (measured: about 2.2 KB a snapshot at N = 3, K = 12, L = 4): each
    // user's channel row twice (the snapshot's clusters and the set's tensors), N of them for a
    // network, and a few hundred bytes a cluster; the test set as networks.
    const double N = cfg.scenario.uavs, K = cfg.scenario.users, L = cfg.channel.antennas;
    auto per_snapshot = [&](bool whole) { return (whole ? N : 1.0) * K * L * 32.0 + 200.0 * N + 64.0; };
    const double learn = static_cast<double>(cfg.nn.train_samples) + static_cast<double>(cfg.nn.val_samples);
    const double bytes = learn * per_snapshot(network) + static_cast<double>(cfg.nn.test_samples) * per_snapshot(true);
    require_memory(bytes,
                   fmt::format("nn.train_samples = {} + nn.val_samples = {} + nn.test_samples = {} snapshots of {} UAVs x {} "
                               "users x {} antennas", cfg.nn.train_samples, cfg.nn.val_samples, cfg.nn.test_samples,
                               cfg.scenario.uavs, cfg.scenario.users, cfg.channel.antennas),
                   fmt::format("allowed nn.train_samples + nn.val_samples <= {:.0f} for this scenario and nn.test_samples",
                               std::max(0.0, std::floor((memory_limit_bytes() - static_cast<double>(cfg.nn.test_samples) *
                                                                                    per_snapshot(true)) /
                                                        per_snapshot(network)))));
  }
  const RunDirLock lock = check_fresh_run_dir(opt.out_dir, {"model.pt", "last.pt", "test.json", "metrics.csv"}, opt.resume, opt.force);
  remove_stale_temporaries(opt.out_dir);

  // Data: snapshots of N UAVs and K users; their clusters are the graph instances.
  const auto t_data = Clock::now();
  const nn::TrainData train = nn::make_data(cfg, nn::Split::Train, static_cast<std::size_t>(cfg.nn.train_samples), network);
  const nn::TrainData val = nn::make_data(cfg, nn::Split::Validation, static_cast<std::size_t>(cfg.nn.val_samples), network);
  const double data_s = std::chrono::duration<double>(Clock::now() - t_data).count();

  ModelInfo info;
  info.model = cfg.nn.model;
  info.antennas = cfg.channel.antennas;
  info.hidden = cfg.nn.hidden;
  info.layers = cfg.nn.layers;
  info.readout = cfg.nn.readout;
  info.features = cfg.nn.features;
  info.feature_scale = 1.0 / train.channel_rms();
  info.config_toml = to_toml(cfg);

  torch::manual_seed(cfg.run.seed);
  auto model = nn::make_model(info.model, info.antennas, info.hidden, info.layers, nn::parse_readout(info.readout));
  model->set_features(nn::parse_features(info.features));
  model->to(device);
  info.parameters = nn::count_parameters(*model);
  torch::optim::Adam adam(model->parameters(),
                          torch::optim::AdamOptions(cfg.nn.learning_rate).weight_decay(cfg.nn.weight_decay));

  nn::TrainingState state;
  std::string metrics = "seed,epoch,step,train_loss,val_sum_rate,best_val_sum_rate,epoch_seconds,clusters_per_s\n";
  if (opt.resume) {
    auto ck = nn::load_checkpoint(last_path, device);
    if (ck.info.model != info.model || ck.info.hidden != info.hidden || ck.info.layers != info.layers ||
        ck.info.antennas != info.antennas || ck.info.readout != info.readout || ck.info.features != info.features)
      throw InputError("--resume: '" + last_path + "' holds a " + ck.info.model + " (hidden " +
                       std::to_string(ck.info.hidden) + ", layers " + std::to_string(ck.info.layers) + ", L " +
                       std::to_string(ck.info.antennas) + ", readout " + ck.info.readout + ", features " +
                       ck.info.features + "): allowed the same model, sizes, readout and features as the config");
    torch::NoGradGuard no_grad;
    auto dst = model->parameters();
    auto src = ck.model->parameters();
    for (std::size_t i = 0; i < dst.size(); ++i) dst[i].copy_(src[i]);
    nn::load_optimizer(last_path, adam);
    state = ck.state;
    if (fs::exists(dir / "metrics.csv")) metrics = read_file((dir / "metrics.csv").string());
    if (opt.progress) *opt.progress << "resuming " << info.model << " from epoch " << state.epoch << "\n";
  }
  write_file_atomic((dir / "config.toml").string(), info.config_toml);

  const std::size_t samples = train.samples();
  const std::size_t batch = static_cast<std::size_t>(cfg.nn.batch_samples);
  const std::size_t steps_per_epoch = (samples + batch - 1) / batch;
  const bool cosine = cfg.nn.lr_schedule == "cosine";
  const std::int64_t total_steps = std::max<std::int64_t>(1, static_cast<std::int64_t>(steps_per_epoch) * cfg.nn.epochs);
  const auto t_start = Clock::now();
  std::int64_t clusters_seen = 0;
  double train_seconds = 0;
  bool stop = false;
  if (opt.progress)
    *opt.progress << fmt::format("training {} ({} parameters) on {} snapshots ({}), {} epochs; data {:.1f}s\n",
                                 info.model, info.parameters, samples,
                                 network ? "whole networks, " + cfg.channel.spectrum + " spectrum"
                                         : std::to_string(train.clusters.clusters()) + " clusters",
                                 cfg.nn.epochs, data_s);

  const int start_epoch = state.epoch;
  for (int epoch = state.epoch; epoch < cfg.nn.epochs && !stop; ++epoch) {
    const auto t_epoch = Clock::now();
    std::vector<std::size_t> order(samples);
    std::iota(order.begin(), order.end(), 0);
    Rng rng(derive_seed(cfg.run.seed, 0x5348554646ULL, static_cast<std::uint64_t>(epoch)));  // shuffle stream
    for (std::size_t i = samples; i > 1; --i) std::swap(order[i - 1], order[rng.below(i)]);

    std::unique_ptr<Progress> bar;
    if (opt.progress) bar = std::make_unique<Progress>(fmt::format("epoch {}/{}", epoch + 1, cfg.nn.epochs), steps_per_epoch, *opt.progress, 5.0, 5.0);
    double loss_sum = 0;
    std::int64_t epoch_clusters = 0, epoch_steps = 0;
    for (std::size_t first = 0; first < samples; first += batch) {
      int64_t units = 0;
      const auto loss = nn::batch_loss(*model, train, order, first, std::min(samples, first + batch), info.feature_scale,
                                       cfg.beamforming.power_scaling, device, &units);
      if (units == 0) continue;
      const double value = loss.item<double>();
      if (!std::isfinite(value))
        throw std::runtime_error(fmt::format("training diverged: the loss is {} at epoch {}, step {}; "
                                             "lower nn.learning_rate (now {}) or set nn.grad_clip",
                                             value, epoch + 1, state.step + 1, cfg.nn.learning_rate));
      if (cosine) {
        // Cosine decay per step from the configured rate to 1% of it at the last step of the
        // last epoch (a function of the step alone, so --resume continues the same curve).
        const double progress = static_cast<double>(state.step) / static_cast<double>(total_steps);
        const double lr = cfg.nn.learning_rate * (0.01 + 0.99 * 0.5 * (1.0 + std::cos(3.14159265358979323846 * std::min(1.0, progress))));
        for (auto& group : adam.param_groups()) static_cast<torch::optim::AdamOptions&>(group.options()).lr(lr);
      }
      adam.zero_grad();
      loss.backward();
      if (cfg.nn.grad_clip > 0) torch::nn::utils::clip_grad_norm_(model->parameters(), cfg.nn.grad_clip);
      adam.step();
      loss_sum += value;
      epoch_clusters += units;
      ++epoch_steps;
      ++state.step;
      if (bar) bar->advance();
      if (opt.max_steps >= 0 && state.step >= opt.max_steps) {
        stop = true;
        break;
      }
    }
    if (bar) bar->finish();
    const double epoch_train_s = std::chrono::duration<double>(Clock::now() - t_epoch).count();
    train_seconds += epoch_train_s;
    clusters_seen += epoch_clusters;
    model->eval();
    const double val_rate = nn::evaluate_sum_rate(*model, val, info.feature_scale, cfg.beamforming.power_scaling, device);
    model->train();
    state.epoch = epoch + 1;
    if (val_rate > state.best_val) {
      state.best_val = val_rate;
      state.best_epoch = state.epoch;
      info.epoch = state.epoch;
      info.best_val_sum_rate = val_rate;
      nn::save_checkpoint(best_path, info, state, *model, nullptr);
    }
    nn::save_checkpoint(last_path, info, state, *model, &adam);
    const double epoch_s = std::chrono::duration<double>(Clock::now() - t_epoch).count();
    const double rate = epoch_clusters / std::max(epoch_train_s, 1e-9);
    metrics += fmt::format("{},{},{},{},{},{},{},{}\n", cfg.run.seed, state.epoch, state.step,
                           format_double(epoch_steps ? loss_sum / epoch_steps : 0.0), format_double(val_rate),
                           format_double(state.best_val), format_double(epoch_s), format_double(rate));
    write_file_atomic((dir / "metrics.csv").string(), metrics);
    if (opt.progress) {
      const double elapsed = std::chrono::duration<double>(Clock::now() - t_start).count();
      const int done = state.epoch, remaining = cfg.nn.epochs - state.epoch;
      *opt.progress << fmt::format("epoch {}/{}  loss {:.4f}  val sum rate {:.3f} (best {:.3f} @ {})  {:.0f} clusters/s  "
                                   "{:.1f}s  ETA {:.0f}s\n",
                                   done, cfg.nn.epochs, epoch_steps ? loss_sum / epoch_steps : 0.0, val_rate,
                                   state.best_val, state.best_epoch, rate, epoch_s,
                                   remaining * elapsed / std::max(1, done - start_epoch))
                     << std::flush;
    }
  }

  // Test-set figures of the best model, beside the classical references on the same snapshots.
  TrainResult result;
  const auto best = nn::load_checkpoint(best_path, device);
  best.model->eval();
  // Held-out test networks, evaluated as every tool evaluates: the served model through
  // design_network and the network sum rate under channel.spectrum (for a per-cluster model under
  // the shared spectrum, interference-unaware designs scored with the interference).
  const auto nets = test_networks(cfg);
  result.info = best.info;
  result.test_sum_rate = mean_network_rate(*LearnedBeamformer::load(best_path, cfg), nets, cfg.run.threads);
  result.wall_seconds = std::chrono::duration<double>(Clock::now() - t_start).count();
  result.steps = state.step;
  result.clusters_per_second = clusters_seen / std::max(train_seconds, 1e-9);
  nlohmann::json report = {{"model", info.model},
                           {"seed", cfg.run.seed},
                           {"data_seed", cfg.nn.data_seed},
                           {"test_samples", cfg.nn.test_samples},
                           {"uavs", cfg.scenario.uavs},
                           {"users", cfg.scenario.users},
                           {"p_max_dbm", cfg.channel.p_max_dbm},
                           {"noise_dbm", cfg.channel.noise_dbm},
                           {"best_epoch", best.state.best_epoch},
                           {"val_sum_rate", best.state.best_val},
                           {"test_sum_rate", result.test_sum_rate},
                           {"parameters", info.parameters},
                           {"readout", info.readout},
                           {"features", info.features},
                           {"train_seconds", train_seconds},
                           {"clusters_per_second", result.clusters_per_second},
                           {"spectrum", cfg.channel.spectrum},
                           {"references_test_sum_rate", reference_rates(cfg, nets)}};
  write_file_atomic((dir / "test.json").string(), report.dump(2) + "\n");
  return result;
}

}  // namespace skyloop
