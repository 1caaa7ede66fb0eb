#pragma once
#include "batch.hpp"
#include "network_batch.hpp"

namespace skyloop::nn {

/// Data set streams under nn.data_seed: disjoint by construction.
enum class Split : std::uint64_t { Train = 1, Validation = 2, Test = 3 };

/// The snapshots of a split, as flat clusters (N = scenario.uavs, K = scenario.users).
ClusterSet make_split(const Config& cfg, Split split, std::size_t samples);

/// Mean network sum rate per snapshot of `model` on `set` (no grad, chunks of `chunk` snapshots).
double evaluate_sum_rate(BeamNetImpl& model, const ClusterSet& set, double feature_scale, PowerScaling mode,
                         const torch::Device& device, std::size_t chunk = 256);

/// Cluster ids of the snapshots [first, last) of `order` (snapshot indices) as an int64 tensor.
torch::Tensor cluster_ids(const ClusterSet& set, const std::vector<std::size_t>& order, std::size_t first,
                          std::size_t last);

/// A data split for either kind of model: clusters (the per-cluster models, trained on the cluster
/// sum rate, eq:loss_function) or whole networks (network models, trained on the network sum rate
/// under channel.spectrum).
struct TrainData {
  bool network = false;
  ClusterSet clusters;
  NetSet nets;
  std::size_t samples() const;       // snapshots
  double channel_rms() const;
};
TrainData make_data(const Config& cfg, Split split, std::size_t samples, bool network);

/// The loss of the snapshots order[first, last): minus the mean cluster sum rate (per-cluster
/// models) or minus the mean network sum rate (network models). `units` receives the number of
/// graph instances in the batch (clusters or networks); 0 when there is nothing to learn from.
torch::Tensor batch_loss(BeamNetImpl& model, const TrainData& d, const std::vector<std::size_t>& order, std::size_t first,
                         std::size_t last, double feature_scale, PowerScaling mode, const torch::Device& device,
                         int64_t* units);

/// Mean training objective per snapshot (network sum rate for network models, the sum of the
/// interference-unaware cluster sum rates otherwise), no grad.
double evaluate_sum_rate(BeamNetImpl& model, const TrainData& d, double feature_scale, PowerScaling mode,
                         const torch::Device& device, std::size_t chunk = 256);

}  // namespace skyloop::nn
