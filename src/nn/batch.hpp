#pragma once
// Cluster-level batching: clusters of different sizes share one batch as flat user rows plus a
// segment index; rates are computed on a padded [C, Kmax, L] view. No per-cluster loop runs in the
// forward or backward pass.
#include <vector>

#include "models.hpp"
#include "skyloop/channel/system_model.hpp"
#include "skyloop/core/config.hpp"

namespace skyloop::nn {

/// Clusters stored flat (CPU, double): the data set a batch is cut from.
struct ClusterSet {
  torch::Tensor gr, gi;       // [U_all, L] Re / Im of G's rows (h_k^H), physical units
  torch::Tensor offsets;      // [C_all] int64, first row of each cluster
  torch::Tensor sizes;        // [C_all] int64, K_n of each cluster
  torch::Tensor p_max, noise; // [C_all] double (W)
  std::vector<std::vector<int64_t>> sample_clusters;  // clusters of each snapshot
  int64_t antennas = 0;
  int64_t clusters() const { return sizes.size(0); }
};

/// `owner[i]` = snapshot of cluster i (as from clusters_of); `samples` the snapshot count.
ClusterSet make_cluster_set(const std::vector<Cluster>& clusters, const std::vector<int>& owner, std::size_t samples);

/// RMS of the channel entries |h_kl| over the set; feature_scale = 1 / rms.
double channel_rms(const ClusterSet& set);

struct Batch {
  torch::Tensor x;          // [U, 2L] features [Re h, Im h] * feature_scale
  Graph graph;              // seg, pos, count
  torch::Tensor gr, gi;     // [C, Kmax, L] float, G / sqrt(noise) (so the noise power is 1)
  torch::Tensor mask;       // [C, Kmax] float, 1 for real users
  torch::Tensor p_max;      // [C] float (W)
};

/// Batch of the clusters `ids` (int64 [C]) of `set`, built with tensor ops, on `device`, its
/// floating tensors in `dtype` (float32 for training and serving; float64 for reference checks).
Batch make_batch(const ClusterSet& set, const torch::Tensor& ids, double feature_scale, const torch::Device& device,
                 torch::ScalarType dtype = torch::kFloat32);

/// Raw network output [U, 2L] -> beamformers on the budget [U, 2L] (Re, Im), per cluster:
/// full: alpha = sqrt(P / (||W~||^2 + eps)); cap: min(1, .) (the paper's alpha_n, eps = 1e-12).
torch::Tensor scale_to_budget(const torch::Tensor& raw, const Batch& b, PowerScaling mode);

/// Cluster sum rates (eq:sinr, eq:rate) [C] for beamformers w [U, 2L] on the budget.
torch::Tensor cluster_sum_rates(const torch::Tensor& w, const Batch& b);

}  // namespace skyloop::nn
