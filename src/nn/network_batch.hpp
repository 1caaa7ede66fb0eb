#pragma once
// Network-level batching for the interference-aware GNN: B networks (snapshots) as dense padded
// tensors. Slot c of a network is its c-th non-empty cluster (ascending UAV); slot (c, k) its k-th
// user. Every channel from every transmitting UAV to every served user is kept, so the graph has
// serving edges (tx == rx slot) and interference edges (tx != rx).
//
// Shapes: B networks, C cluster slots, K user slots per cluster, L antennas.
//   h     [B, C_tx, C_rx, K, 2L]  [Re h, Im h] of h_{tx -> user (rx, k)} (h, not h^H)
//   umask [B, C, K]  1 for a real user;  cmask [B, C]  1 for a real cluster
#include <vector>

#include "torch_fwd.hpp"
#include "skyloop/channel/network.hpp"
#include "skyloop/core/config.hpp"

namespace skyloop::nn {

/// Networks stored padded (CPU, double, physical units): the data set a batch is cut from.
struct NetSet {
  torch::Tensor h;            // [S, C, C, K, 2L]
  torch::Tensor umask;        // [S, C, K]
  torch::Tensor cmask;        // [S, C]
  torch::Tensor p_max;        // [S, C] (W); 0 in empty slots
  torch::Tensor noise;        // [S] (W), one noise power per network (in its band)
  torch::Tensor bandwidth;    // [S] band share of every cluster of the network
  bool interferes = true;     // shared spectrum: beams reach other clusters' users
  int64_t antennas = 0;
  int64_t size() const { return h.size(0); }
};

/// Pads `nets` to C = the most clusters, K = the largest cluster among them.
NetSet make_net_set(const std::vector<Network>& nets, int64_t antennas);
/// RMS of |h_l| over the real (tx, user) pairs; feature_scale = 1 / rms.
double channel_rms(const NetSet& set);

struct NetBatch {
  torch::Tensor x;       // [B, C, C, K, 2L] features h * feature_scale (zero in padding)
  torch::Tensor g;       // [B, C, C, K, 2L] h / sqrt(noise) (noise power 1)
  torch::Tensor umask;   // [B, C, K]
  torch::Tensor cmask;   // [B, C]
  torch::Tensor p_max;   // [B, C]
  torch::Tensor bandwidth;  // [B]
  bool interferes = true;
};

NetBatch make_net_batch(const NetSet& set, const torch::Tensor& ids, double feature_scale, const torch::Device& device,
                        torch::ScalarType dtype = torch::kFloat32);

/// Raw beams [B, C, K, 2L] -> each cluster scaled onto its budget (full or cap), padding zero.
torch::Tensor scale_to_budget(const torch::Tensor& raw, const NetBatch& b, PowerScaling mode);

/// Network sum rates [B] (channel/network.hpp's SINR, the batch's spectrum) for beams on the budget.
torch::Tensor network_sum_rates(const torch::Tensor& w, const NetBatch& b);

}  // namespace skyloop::nn
