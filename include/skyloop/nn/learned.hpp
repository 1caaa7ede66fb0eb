#pragma once
// Learned beamformers (the paper's Section IV GNN and its DeepSets and MS-PointNet baselines):
// training, checkpoints and serving behind the common Beamformer interface. This header is
// torch-free; everything that includes LibTorch lives in src/nn (target skyloop_nn).
#include <cstdint>
#include <iosfwd>
#include <memory>
#include <string>
#include <vector>

#include "skyloop/beamforming/beamformer.hpp"
#include "skyloop/beamforming/registry.hpp"
#include "skyloop/core/config.hpp"

namespace skyloop {

/// nn.features = "log": the encoders see x * log(1 + r / eps) / (r log(1 + 1 / eps)), r = ||x||,
/// with this eps (src/nn/models.hpp, encode_features; the fast path the same).
inline constexpr double kLogFeatureFloor = 1e-3;

/// What a checkpoint says about itself.
struct ModelInfo {
  std::string model;            // gnn | deepsets | mspointnet (per cluster) | ignn (network, interference-aware)
  int antennas = 0;             // L the model was trained for
  int hidden = 0, layers = 0;
  Readout readout = Readout::Direct;    // nn.readout: direct (the paper) | structured (see src/nn/models.hpp)
  Features features = Features::Linear;  // nn.features: what the encoders see (see src/nn/models.hpp)
  double feature_scale = 1.0;   // input normalisation: x = [Re h, Im h] * feature_scale
  int epoch = 0;                // epochs completed
  double best_val_sum_rate = 0; // mean network sum rate on the validation set (bit/s/Hz)
  std::int64_t parameters = 0;  // trainable parameter count
  std::string config_toml;      // the resolved training configuration
};

/// A trained model served through the Beamformer interface. design_batch() runs one batched,
/// no-grad forward pass over all clusters; design() is design_batch() of one. Both are safe to
/// call from several threads. The network's raw output is scaled onto the budget with
/// beamforming.power_scaling (full by default; "cap" is the paper's alpha).
class LearnedBeamformer final : public Beamformer {
 public:
  /// Loads `path` (a model.pt written by train_beamformer). A missing, corrupt or foreign file,
  /// or one trained for another antenna count than cfg.channel.antennas, throws InputError.
  static std::unique_ptr<LearnedBeamformer> load(const std::string& path, const Config& cfg);
  ~LearnedBeamformer() override;

  std::string name() const override;
  MatrixXcd design(const Cluster& c) const override;
  std::vector<MatrixXcd> design_batch(const std::vector<Cluster>& clusters, int threads = 1) const override;
  /// A network model (ignn) designs every cluster of each network in one batched forward pass; a
  /// per-cluster model designs each cluster alone.
  std::vector<MatrixXcd> design_network(const Network& net, int threads = 1) const override;
  std::vector<std::vector<MatrixXcd>> design_networks(const std::vector<Network>& nets, int threads = 1) const override;
  bool coordinated() const override;
  const ModelInfo& info() const;
  /// True when the fused float32 path serves this model (nn.inference = "fast", the default, at
  /// float32 on the CPU); false when LibTorch does.
  bool fast() const;

  struct Impl;

 private:
  explicit LearnedBeamformer(std::unique_ptr<Impl> impl);
  std::vector<MatrixXcd> design_fast(const std::vector<const Cluster*>& nonempty, const std::vector<std::size_t>& where,
                                     std::vector<MatrixXcd> out, int threads) const;
  std::vector<std::vector<MatrixXcd>> design_networks_fast(const std::vector<Network>& nets, int threads) const;
  std::unique_ptr<Impl> impl_;
};

struct TrainOptions {
  std::string out_dir;   // model.pt (best validation), last.pt (resume), metrics.csv, config.toml, test.json
  bool resume = false;   // continue from out_dir/last.pt
  bool force = false;    // replace a run already in out_dir (refused otherwise)
  std::ostream* progress = nullptr;
  int max_steps = -1;    // stop after this many optimiser steps in total (tests); -1 = all epochs
};

struct TrainResult {
  ModelInfo info;
  double test_sum_rate = 0;         // best model, mean network sum rate on the test set
  double wall_seconds = 0;
  std::int64_t steps = 0;
  double clusters_per_second = 0;   // training throughput (forward + backward + step)
};

/// Trains cfg.nn.model on cfg.nn settings (unsupervised: loss = minus the mean cluster sum rate,
/// eq:loss_function). Seeded by run.seed (initialisation, shuffling); data from nn.data_seed.
TrainResult train_beamformer(const Config& cfg, const TrainOptions& opt);

/// Registers "gnn", "deepsets", "mspointnet", "ignn": "gnn=PATH" loads PATH (a model.pt or a directory
/// holding one); "gnn" alone loads models/gnn/model.pt under `models_dir` (empty: data_dir()/models,
/// read when the model is created).
void register_learned_beamformers(BeamformerRegistry& reg, const std::string& models_dir);

/// Number of intra-op threads torch uses (0 = library default).
void set_torch_threads(int threads);

}  // namespace skyloop
