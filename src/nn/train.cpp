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
torch::Device resolve_device(ComputeDevice device) {
  if (device == ComputeDevice::Cuda) {
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
  if (cfg.channel.spectrum == Spectrum::Shared) names.insert(names.end(), {"crzf", "czfsel", "nwmmse"});
  for (const char* name : names) out[name] = mean_network_rate(*classical.create(name, cfg), nets, cfg.run.threads);
  return out;
}

}  // namespace

namespace {

/// What the data sets hold (measured: about 2.2 KB a snapshot at N = 3, K = 12, L = 4): each
/// user's channel row twice (the snapshot's clusters and the set's tensors), N of them for a
/// network, and a few hundred bytes a cluster; the test set as networks. Refused in one line.
void require_data_memory(const Config& cfg, bool network) {
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

/// One training run (Algorithm alg:gnn-training): the data, the model and its optimiser, the
/// epochs with their checkpoints and metrics, then the test report.
class BeamformerTraining {
 public:
  BeamformerTraining(const Config& cfg, const TrainOptions& opt);
  TrainResult run();

 private:
  /// The model, its sizes and its optimiser; from last.pt under --resume.
  void make_model();
  void resume();
  /// One epoch's steps in a shuffled order; false once opt.max_steps is reached.
  bool train_epoch(int epoch, double& loss_sum, std::int64_t& clusters, std::int64_t& steps);
  /// Validation, the checkpoints, metrics.csv and the progress line after an epoch.
  void end_epoch(int epoch_done, Clock::time_point t_epoch, double epoch_train_s, double loss_sum, std::int64_t clusters,
                 std::int64_t steps);
  /// Test-set figures of the best model, beside the classical references on the same snapshots.
  TrainResult test_report();

  const Config& cfg_;
  const TrainOptions& opt_;
  torch::Device device_;
  std::filesystem::path dir_;
  std::string last_path_, best_path_;
  bool network_ = false;
  RunDirLock lock_;
  nn::TrainData train_, val_;
  double data_s_ = 0;
  ModelInfo info_;
  std::shared_ptr<nn::BeamNetImpl> model_;
  std::unique_ptr<torch::optim::Adam> adam_;
  nn::TrainingState state_;
  std::string metrics_ = "seed,epoch,step,train_loss,val_sum_rate,best_val_sum_rate,epoch_seconds,clusters_per_s\n";
  std::size_t samples_ = 0, batch_ = 0, steps_per_epoch_ = 0;
  std::int64_t total_steps_ = 1, clusters_seen_ = 0;
  double train_seconds_ = 0;
  Clock::time_point t_start_;
  int start_epoch_ = 0;
};

BeamformerTraining::BeamformerTraining(const Config& cfg, const TrainOptions& opt)
    : cfg_(cfg), opt_(opt), device_(nn::resolve_device(cfg.nn.device)) {
  namespace fs = std::filesystem;
  if (opt.out_dir.empty()) throw InputError("--out is empty: allowed a directory for the model and its logs");
  set_torch_threads(cfg.run.threads);
  dir_ = fs::path(opt.out_dir);
  last_path_ = (dir_ / "last.pt").string(), best_path_ = (dir_ / "model.pt").string();
  check_resume_or_force(opt.resume, opt.force);
  if (opt.resume && !fs::exists(last_path_))
    throw InputError("--resume: '" + last_path_ + "' does not exist: allowed a directory of an earlier training run");
  network_ = nn::make_model(cfg.nn.model, cfg.channel.antennas, 4, 1)->network();
  require_data_memory(cfg, network_);
  lock_ = check_fresh_run_dir(opt.out_dir, {"model.pt", "last.pt", "test.json", "metrics.csv"}, opt.resume, opt.force);
  remove_stale_temporaries(opt.out_dir);

  // Data: snapshots of N UAVs and K users; their clusters are the graph instances.
  const auto t_data = Clock::now();
  train_ = nn::make_data(cfg, nn::Split::Train, static_cast<std::size_t>(cfg.nn.train_samples), network_);
  val_ = nn::make_data(cfg, nn::Split::Validation, static_cast<std::size_t>(cfg.nn.val_samples), network_);
  data_s_ = std::chrono::duration<double>(Clock::now() - t_data).count();
  make_model();
  if (opt.resume) resume();
  write_file_atomic((dir_ / "config.toml").string(), info_.config_toml);
}

void BeamformerTraining::make_model() {
  info_.model = cfg_.nn.model;
  info_.antennas = cfg_.channel.antennas;
  info_.hidden = cfg_.nn.hidden;
  info_.layers = cfg_.nn.layers;
  info_.readout = cfg_.nn.readout;
  info_.features = cfg_.nn.features;
  info_.feature_scale = 1.0 / train_.channel_rms();
  info_.config_toml = to_toml(cfg_);
  torch::manual_seed(cfg_.run.seed);
  model_ = nn::make_model(info_.model, info_.antennas, info_.hidden, info_.layers, info_.readout);
  model_->set_features(info_.features);
  model_->to(device_);
  info_.parameters = nn::count_parameters(*model_);
  adam_ = std::make_unique<torch::optim::Adam>(model_->parameters(),
                                               torch::optim::AdamOptions(cfg_.nn.learning_rate).weight_decay(cfg_.nn.weight_decay));
}

void BeamformerTraining::resume() {
  auto ck = nn::load_checkpoint(last_path_, device_);
  if (ck.info.model != info_.model || ck.info.hidden != info_.hidden || ck.info.layers != info_.layers ||
      ck.info.antennas != info_.antennas || ck.info.readout != info_.readout || ck.info.features != info_.features)
    throw InputError("--resume: '" + last_path_ + "' holds a " + ck.info.model + " (hidden " + std::to_string(ck.info.hidden) +
                     ", layers " + std::to_string(ck.info.layers) + ", L " + std::to_string(ck.info.antennas) + ", readout " +
                     name_of(ck.info.readout) + ", features " + name_of(ck.info.features) +
                     "): allowed the same model, sizes, readout and features as the config");
  torch::NoGradGuard no_grad;
  auto dst = model_->parameters();
  auto src = ck.model->parameters();
  for (std::size_t i = 0; i < dst.size(); ++i) dst[i].copy_(src[i]);
  nn::load_optimizer(last_path_, *adam_);
  state_ = ck.state;
  if (std::filesystem::exists(dir_ / "metrics.csv")) metrics_ = read_file((dir_ / "metrics.csv").string());
  if (opt_.progress) *opt_.progress << "resuming " << info_.model << " from epoch " << state_.epoch << "\n";
}

bool BeamformerTraining::train_epoch(int epoch, double& loss_sum, std::int64_t& clusters, std::int64_t& steps) {
  std::vector<std::size_t> order(samples_);
  std::iota(order.begin(), order.end(), 0);
  Rng rng(derive_seed(cfg_.run.seed, 0x5348554646ULL, static_cast<std::uint64_t>(epoch)));  // shuffle stream
  for (std::size_t i = samples_; i > 1; --i) std::swap(order[i - 1], order[rng.below(i)]);
  std::unique_ptr<Progress> bar;
  if (opt_.progress)
    bar = std::make_unique<Progress>(fmt::format("epoch {}/{}", epoch + 1, cfg_.nn.epochs), steps_per_epoch_, *opt_.progress, 5.0, 5.0);
  const bool cosine = cfg_.nn.lr_schedule == LrSchedule::Cosine;
  bool go_on = true;
  for (std::size_t first = 0; first < samples_; first += batch_) {
    int64_t units = 0;
    const auto loss = nn::batch_loss(*model_, train_, order, first, std::min(samples_, first + batch_), info_.feature_scale,
                                     cfg_.beamforming.power_scaling, device_, &units);
    if (units == 0) continue;
    const double value = loss.item<double>();
    if (!std::isfinite(value))
      throw std::runtime_error(fmt::format("training diverged: the loss is {} at epoch {}, step {}; "
                                           "lower nn.learning_rate (now {}) or set nn.grad_clip",
                                           value, epoch + 1, state_.step + 1, cfg_.nn.learning_rate));
    if (cosine) {
      // Cosine decay per step from the configured rate to 1% of it at the last step of the
      // last epoch (a function of the step alone, so --resume continues the same curve).
      const double progress = static_cast<double>(state_.step) / static_cast<double>(total_steps_);
      const double lr = cfg_.nn.learning_rate * (0.01 + 0.99 * 0.5 * (1.0 + std::cos(3.14159265358979323846 * std::min(1.0, progress))));
      for (auto& group : adam_->param_groups()) static_cast<torch::optim::AdamOptions&>(group.options()).lr(lr);
    }
    adam_->zero_grad();
    loss.backward();
    if (cfg_.nn.grad_clip > 0) torch::nn::utils::clip_grad_norm_(model_->parameters(), cfg_.nn.grad_clip);
    adam_->step();
    loss_sum += value;
    clusters += units;
    ++steps;
    ++state_.step;
    if (bar) bar->advance();
    if (opt_.max_steps >= 0 && state_.step >= opt_.max_steps) {
      go_on = false;
      break;
    }
  }
  if (bar) bar->finish();
  return go_on;
}

void BeamformerTraining::end_epoch(int epoch_done, Clock::time_point t_epoch, double epoch_train_s, double loss_sum,
                                   std::int64_t clusters, std::int64_t steps) {
  model_->eval();
  const double val_rate = nn::evaluate_sum_rate(*model_, val_, info_.feature_scale, cfg_.beamforming.power_scaling, device_);
  model_->train();
  state_.epoch = epoch_done;
  if (val_rate > state_.best_val) {
    state_.best_val = val_rate;
    state_.best_epoch = state_.epoch;
    info_.epoch = state_.epoch;
    info_.best_val_sum_rate = val_rate;
    nn::save_checkpoint(best_path_, info_, state_, *model_, nullptr);
  }
  nn::save_checkpoint(last_path_, info_, state_, *model_, adam_.get());
  const double epoch_s = std::chrono::duration<double>(Clock::now() - t_epoch).count();
  const double rate = clusters / std::max(epoch_train_s, 1e-9);
  metrics_ += fmt::format("{},{},{},{},{},{},{},{}\n", cfg_.run.seed, state_.epoch, state_.step,
                          format_double(steps ? loss_sum / steps : 0.0), format_double(val_rate), format_double(state_.best_val),
                          format_double(epoch_s), format_double(rate));
  write_file_atomic((dir_ / "metrics.csv").string(), metrics_);
  if (opt_.progress) {
    const double elapsed = std::chrono::duration<double>(Clock::now() - t_start_).count();
    const int done = state_.epoch, remaining = cfg_.nn.epochs - state_.epoch;
    *opt_.progress << fmt::format("epoch {}/{}  loss {:.4f}  val sum rate {:.3f} (best {:.3f} @ {})  {:.0f} clusters/s  "
                                  "{:.1f}s  ETA {:.0f}s\n",
                                  done, cfg_.nn.epochs, steps ? loss_sum / steps : 0.0, val_rate, state_.best_val,
                                  state_.best_epoch, rate, epoch_s, remaining * elapsed / std::max(1, done - start_epoch_))
                   << std::flush;
  }
}

TrainResult BeamformerTraining::test_report() {
  TrainResult result;
  const auto best = nn::load_checkpoint(best_path_, device_);
  best.model->eval();
  // Held-out test networks, evaluated as every tool evaluates: the served model through
  // design_network and the network sum rate under channel.spectrum (for a per-cluster model under
  // the shared spectrum, interference-unaware designs scored with the interference).
  const auto nets = test_networks(cfg_);
  result.info = best.info;
  result.test_sum_rate = mean_network_rate(*LearnedBeamformer::load(best_path_, cfg_), nets, cfg_.run.threads);
  result.wall_seconds = std::chrono::duration<double>(Clock::now() - t_start_).count();
  result.steps = state_.step;
  result.clusters_per_second = clusters_seen_ / std::max(train_seconds_, 1e-9);
  nlohmann::json report = {{"model", info_.model},
                           {"seed", cfg_.run.seed},
                           {"data_seed", cfg_.nn.data_seed},
                           {"test_samples", cfg_.nn.test_samples},
                           {"uavs", cfg_.scenario.uavs},
                           {"users", cfg_.scenario.users},
                           {"p_max_dbm", cfg_.channel.p_max_dbm},
                           {"noise_dbm", cfg_.channel.noise_dbm},
                           {"best_epoch", best.state.best_epoch},
                           {"val_sum_rate", best.state.best_val},
                           {"test_sum_rate", result.test_sum_rate},
                           {"parameters", info_.parameters},
                           {"readout", name_of(info_.readout)},
                           {"features", name_of(info_.features)},
                           {"train_seconds", train_seconds_},
                           {"clusters_per_second", result.clusters_per_second},
                           {"spectrum", name_of(cfg_.channel.spectrum)},
                           {"references_test_sum_rate", reference_rates(cfg_, nets)}};
  write_file_atomic((dir_ / "test.json").string(), report.dump(2) + "\n");
  return result;
}

TrainResult BeamformerTraining::run() {
  samples_ = train_.samples();
  batch_ = static_cast<std::size_t>(cfg_.nn.batch_samples);
  steps_per_epoch_ = (samples_ + batch_ - 1) / batch_;
  total_steps_ = std::max<std::int64_t>(1, static_cast<std::int64_t>(steps_per_epoch_) * cfg_.nn.epochs);
  t_start_ = Clock::now();
  if (opt_.progress)
    *opt_.progress << fmt::format("training {} ({} parameters) on {} snapshots ({}), {} epochs; data {:.1f}s\n", info_.model,
                                  info_.parameters, samples_,
                                  network_ ? "whole networks, " + std::string(name_of(cfg_.channel.spectrum)) + " spectrum"
                                           : std::to_string(train_.clusters.clusters()) + " clusters",
                                  cfg_.nn.epochs, data_s_);
  start_epoch_ = state_.epoch;
  bool go_on = true;
  for (int epoch = state_.epoch; epoch < cfg_.nn.epochs && go_on; ++epoch) {
    const auto t_epoch = Clock::now();
    double loss_sum = 0;
    std::int64_t clusters = 0, steps = 0;
    go_on = train_epoch(epoch, loss_sum, clusters, steps);
    const double epoch_train_s = std::chrono::duration<double>(Clock::now() - t_epoch).count();
    train_seconds_ += epoch_train_s;
    clusters_seen_ += clusters;
    end_epoch(epoch + 1, t_epoch, epoch_train_s, loss_sum, clusters, steps);
  }
  return test_report();
}

}  // namespace

TrainResult train_beamformer(const Config& cfg, const TrainOptions& opt) { return BeamformerTraining(cfg, opt).run(); }

}  // namespace skyloop
