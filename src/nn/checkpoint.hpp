#pragma once
// Checkpoints: one torch archive holding a JSON header ("skyloop_meta": format, version, model,
// sizes, input normalisation, training state, resolved config), the model parameters, and for
// resumable checkpoints the optimiser state. Written atomically (temporary file, then rename).
#include <memory>
#include <string>

#include "models.hpp"
#include "skyloop/nn/learned.hpp"

namespace skyloop::nn {

constexpr int kCheckpointVersion = 1;
constexpr const char* kCheckpointFormat = "skyloop-beamformer";

struct TrainingState {
  int epoch = 0;            // epochs completed
  std::int64_t step = 0;    // optimiser steps taken
  int best_epoch = 0;
  double best_val = -1;     // best validation sum rate so far
};

void save_checkpoint(const std::string& path, const ModelInfo& info, const TrainingState& state, BeamNetImpl& model,
                     torch::optim::Optimizer* optimizer);

/// A loaded checkpoint. Throws InputError naming the path for a missing, corrupt or foreign file.
struct LoadedCheckpoint {
  ModelInfo info;
  TrainingState state;
  std::shared_ptr<BeamNetImpl> model;
  bool has_optimizer = false;
};
LoadedCheckpoint load_checkpoint(const std::string& path, const torch::Device& device,
                                 torch::optim::Optimizer* optimizer_to_fill = nullptr);

/// Fills optimizer state from a checkpoint whose model is `model` (for resuming).
void load_optimizer(const std::string& path, torch::optim::Optimizer& optimizer);

std::int64_t count_parameters(const torch::nn::Module& m);

}  // namespace skyloop::nn
