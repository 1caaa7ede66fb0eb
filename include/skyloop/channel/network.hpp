#pragma once
// The spectrum model: the one place that decides what a user's SINR counts. Beamformers, rates,
// the environment's oracle, evaluations and reports all ask it.
//
// A network is every non-empty cluster of one snapshot plus the cross channels from each
// transmitting UAV to every served user. With r a served user in cluster a (local index j),
// H_b the [K_s x L] cross channels of UAV b (row r = h_{b,r}^H) and W_b its [L x K_b] beams:
//
//   orthogonal (the paper, eq:sinr; each UAV its own band of the full bandwidth B):
//     gamma_r = |h_{a,r}^H w_{a,j}|^2 / (sum_{j' != j} |h_{a,r}^H w_{a,j'}|^2 + sigma^2)
//     R_r     = log2(1 + gamma_r)
//   orthogonal-split (equal total bandwidth: N bands of B/N each; the noise scales with the band):
//     gamma_r = |h_{a,r}^H w_{a,j}|^2 / (sum_{j' != j} |h_{a,r}^H w_{a,j'}|^2 + sigma^2 / N)
//     R_r     = (1/N) log2(1 + gamma_r)
//   shared (every UAV on the whole band B: inter-cluster interference):
//     gamma_r = |h_{a,r}^H w_{a,j}|^2 / (sum_{j' != j} |h_{a,r}^H w_{a,j'}|^2
//                                        + sum_{b != a} ||h_{b,r}^H W_b||^2 + sigma^2)
//     R_r     = log2(1 + gamma_r)
// Rates are in bit/s/Hz of B; N counts every UAV of the snapshot (a UAV with no users keeps its
// band under orthogonal-split and transmits nothing under shared). Unserved users add 0.
#include <string>
#include <vector>

#include "skyloop/channel/system_model.hpp"

namespace skyloop {

/// The clusters of one snapshot with their cross channels and the spectrum model.
struct Network {
  Spectrum spectrum = Spectrum::Orthogonal;
  int uavs = 0;                   // N, every UAV of the snapshot
  std::vector<Cluster> clusters;  // the non-empty clusters, ascending UAV index
  std::vector<int> served;        // the served users, cluster by cluster
  std::vector<int> offset;        // [clusters + 1]: cluster i's users are rows offset[i]..offset[i+1)-1
  /// cross[i]: [K_s x L] complex, row r = h_{uav of cluster i, served[r]}^H; its rows
  /// offset[i].. are cluster i's G.
  std::vector<MatrixXcd> cross;

  int served_count() const { return static_cast<int>(served.size()); }
  /// True when one cluster's beams reach another cluster's users (the shared spectrum).
  bool interferes() const { return spectrum == Spectrum::Shared; }
  /// A network of one cluster and no other UAV: what a per-cluster call sees.
  static Network of(const Cluster& c);
};

/// Received powers of one served user (W).
struct UserPowers {
  double signal = 0;  // |h_{a,r}^H w_{a,j}|^2
  double intra = 0;   // the other beams of its own UAV
  double inter = 0;   // every beam of every other UAV (0 unless the spectrum is shared)
  double noise = 0;   // in its band
  double sinr() const { return signal / (intra + inter + noise); }
};

/// Per cluster, per user: out[i][j] for user j of cluster i. W[i] is cluster i's [L x K_i].
std::vector<std::vector<UserPowers>> user_powers(const Network& net, const std::vector<MatrixXcd>& W);
/// Per-cluster sum rates under the network's spectrum (bandwidth share included).
std::vector<double> network_cluster_rates(const Network& net, const std::vector<MatrixXcd>& W);
/// The network sum rate: the sum of network_cluster_rates in cluster order.
double network_sum_rate(const Network& net, const std::vector<MatrixXcd>& W);

}  // namespace skyloop
