#pragma once
// The paper's system model (Section III): its channel (eq:channel_model, eq:steering_vector; the
// default of the channel-model seam, channel/channel_model.hpp, which also gives the 3GPP and
// Al-Hourani air-to-ground models and Rician fading), nearest-UAV association within R_c
// (eq:cluster_association), and the clusters that the beamformers see.
//
// Conventions
//   UAV n at (x_n, y_n, z_n), user k at (x_k, y_k, 0); d_{n,k} the 3-D distance. z_n = H (the
//   paper) unless the UAV positions carry a third column (the altitude, types.hpp's Positions).
//   beta_{n,k}  = beta0 * (d0 / d_{n,k})^2          (the printed exponent -2 is a typo: path loss
//                                                      must fall with distance)
//   cos(theta)  = z_n / d_{n,k}
//   a_l         = exp(j 2 pi (d_a/lambda) l cos(theta)),  l = 0..L-1
//   h_{n,k}     = sqrt(beta_{n,k}) a                   [L] complex
//   A cluster's channel matrix G is [K_n x L] complex with row k = h_k^H, so the received
//   signal of the cluster is y = G W s + z and (G W)(k, j) = h_k^H w_j.
#include <cstdint>
#include <memory>
#include <vector>

#include "skyloop/channel/channel_model.hpp"
#include "skyloop/core/config.hpp"
#include "skyloop/core/rng.hpp"
#include "skyloop/core/types.hpp"

namespace skyloop {

struct Network;  // channel/network.hpp

/// Positions of one network snapshot.
struct Snapshot {
  Positions uavs;   // [N x 2], or [N x 3] with each UAV's altitude
  Positions users;  // [K x 2]
};

/// One UAV's cluster: the beamformer's input. Beamformers read G, p_max and noise only.
struct Cluster {
  int uav = -1;             // serving UAV index n
  std::vector<int> users;   // user indices, ascending; row i of G is user users[i]
  MatrixXcd G;              // [K_n x L] complex, row i = h_{n,users[i]}^H
  double p_max = 1.0;       // power budget (W)
  double noise = 1e-12;     // noise power in the cluster's band (W): sigma_0^2, or sigma_0^2 / N under orthogonal-split
  double bandwidth = 1.0;   // the band's share of the bandwidth: rates are scaled by it (1/N under orthogonal-split)
  int size() const { return static_cast<int>(G.rows()); }
  int antennas() const { return static_cast<int>(G.cols()); }
};

/// K user positions [K x 2] drawn from `rng` under scenario.user_layout: uniform in the area (the
/// paper; two draws per user, x then y), or hotspot: `hotspots` centres uniform in the area, then
/// each user with probability hotspot_fraction at a centre chosen uniformly plus a Gaussian offset
/// of std hotspot_radius_m per axis (clipped to the area), else uniform.
Positions draw_users(const ScenarioConfig& s, int users, Rng& rng);

/// User association of one snapshot (eq:cluster_association).
struct Association {
  std::vector<int> serving;             // [K]: serving UAV of user k, or -1 if no UAV covers it
  std::vector<std::vector<int>> users;  // [N]: users of UAV n, ascending (may be empty)
};

class SystemModel {
 public:
  explicit SystemModel(const Config& cfg);

  int antennas() const { return antennas_; }
  double altitude() const { return altitude_; }
  double p_max() const { return p_max_; }
  double noise() const { return noise_; }
  double area_x() const { return area_x_; }
  double area_y() const { return area_y_; }
  double coverage() const { return coverage_; }
  Spectrum spectrum() const { return spectrum_; }

  /// 3-D distance between a UAV at altitude H above (ux, uy) and a user at (x, y, h_u).
  double distance(double ux, double uy, double x, double y) const;
  /// 3-D distance between UAV n of `uavs` (at its altitude) and a user at (x, y, h_u).
  double distance(const Positions& uavs, Eigen::Index n, double x, double y) const {
    return channel_->distance(uavs(n, 0), uavs(n, 1), skyloop::altitude_of(uavs, n, altitude_), x, y);
  }
  /// UAV n's altitude in `uavs` (H where they have two columns).
  double altitude_of(const Positions& uavs, Eigen::Index n) const { return skyloop::altitude_of(uavs, n, altitude_); }
  /// beta0 * (d0 / d)^2 (the paper's model; other models: channel_model().link()).
  double path_loss(double d) const;
  /// Steering vector for cos(theta) = (H - h_u) / d: [L] complex.
  VectorXcd steering(double cos_theta) const;
  /// h_{n,k} in fast slot `slot` (the paper: sqrt(beta) a(theta)): [L] complex.
  VectorXcd channel(double ux, double uy, double x, double y, int slot = 0) const;
  /// The channel model every link is asked of.
  const ChannelModel& channel_model() const { return *channel_; }
  /// Small-scale realisations per trajectory slot (1 without fading).
  int fast_slots() const { return channel_->fast_slots(); }

  /// Nearest UAV by 3-D distance (lowest index on ties), served only if that distance <= R_c.
  Association associate(const Snapshot& s) const;
  /// The same for UAV positions [N x 2] or [N x 3] and user positions [K x 2]. Above kAssociationGridFrom
  /// UAVs a spatial index (a grid of cells one horizontal coverage radius wide) visits only the
  /// UAVs around each user: O(K + N) for spread-out UAVs instead of O(K N), same result.
  Association associate(const Positions& uavs, const Positions& users) const;
  /// The same into `out`, reusing its storage (the rate oracle's hot path); `nearest`, when given,
  /// receives each user's distance to its serving UAV (+inf where unserved), for reassociate.
  void associate(const Positions& uavs, const Positions& users, Association& out, std::vector<double>* nearest = nullptr) const;
  /// `a` and `nearest`, associate's result for positions that differ from `uavs` in row `moved`
  /// alone, made associate's result for `uavs`: the moved UAV's distance to every user, and a
  /// search of all UAVs for the users it served, instead of every user's search. The same result
  /// bit for bit (the same distance() calls and ties; Scale.ReassociatingOneMovedUavIsAssociating).
  void reassociate(const Positions& uavs, const Positions& users, int moved, Association& a, std::vector<double>& nearest) const;
  static constexpr int kAssociationGridFrom = 8;
  /// The non-empty clusters of a snapshot, ascending UAV index (noise and bandwidth share of the
  /// spectrum model; a per-cluster beamformer sees nothing else).
  std::vector<Cluster> clusters(const Snapshot& s) const;
  std::vector<Cluster> clusters(const Snapshot& s, const Association& a) const;
  /// Cluster of UAV n at (ux, uy, uz) serving the given users (of `users_xy`), in a network of
  /// `uavs` UAVs (the orthogonal-split band is 1/uavs).
  Cluster make_cluster(int uav, double ux, double uy, double uz, const Positions& users_xy, const std::vector<int>& users,
                       int uavs = 1, int slot = 0) const;
  /// The same at the scenario's altitude H.
  Cluster make_cluster(int uav, double ux, double uy, const Positions& users_xy, const std::vector<int>& users,
                       int uavs = 1, int slot = 0) const {
    return make_cluster(uav, ux, uy, altitude_, users_xy, users, uavs, slot);
  }
  /// The whole network of a snapshot: clusters, cross channels and spectrum (channel/network.hpp).
  Network network(const Snapshot& s) const;
  Network network(const Snapshot& s, const Association& a) const;
  /// The network of UAVs at `uavs` over users `users_xy` with the given association, in fast slot `slot`.
  Network network(const Positions& uavs, const Positions& users_xy, const std::vector<std::vector<int>>& members,
                  int slot = 0) const;

  /// N UAVs and K users uniform in the area; a pure function of `seed`.
  Snapshot random_snapshot(int uavs, int users, std::uint64_t seed) const;

 private:
  int antennas_;
  double altitude_, coverage_, p_max_, noise_, area_x_, area_y_;
  Spectrum spectrum_;
  std::shared_ptr<const ChannelModel> channel_;
  ScenarioConfig scenario_;  // area and user layout of random snapshots
};

/// Snapshots i = 0..count-1 of a run seeded `seed`: snapshot i uses derive_seed(seed, i).
std::vector<Snapshot> random_snapshots(const SystemModel& model, int uavs, int users, std::uint64_t seed,
                                       std::size_t count);

/// The clusters of many snapshots, concatenated; `owner[i]` is the snapshot of cluster i.
std::vector<Cluster> clusters_of(const SystemModel& model, const std::vector<Snapshot>& snapshots,
                                 std::vector<int>* owner = nullptr);

}  // namespace skyloop
