#pragma once
#include "batch.hpp"

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

}  // namespace skyloop::nn
