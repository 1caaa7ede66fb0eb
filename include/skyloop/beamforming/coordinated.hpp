#pragma once
// Coordinated beamformers: they design every cluster of a network together and see the cross
// channels (channel/network.hpp). Under the orthogonal spectra there is nothing to coordinate and
// each reduces to its per-cluster counterpart; design(cluster) is the network of that one cluster.
//
// Network WMMSE (nwmmse): WMMSE for the interfering broadcast channel (Shi, Razaviyayn, Luo, He,
//   IEEE TSP 2011, all weights 1), one power budget and one multiplier per UAV. With user r in
//   cluster a (beam w_{a,r}), T_r = sum_b ||h_{b,r}^H W_b||^2 + sigma^2 its received power:
//     u_r     = h_{a,r}^H w_{a,r} / T_r,   omega_r = T_r / (T_r - |h_{a,r}^H w_{a,r}|^2)
//     W_b     = (sum_{every served r} omega_r |u_r|^2 h_{b,r} h_{b,r}^H + mu_b I)^{-1}
//               [omega_r u_r h_{b,r}]_{r in cluster b},  mu_b >= 0 the least meeting ||W_b||^2 <= P_b
//   The network sum rate never decreases between iterations (block-coordinate ascent); the best
//   iterate is kept. It starts from per-cluster WMMSE ([wmmse] settings), so it never ends below
//   the interference-unaware solution; without interference it returns that solution. Unlike the per-cluster methods it may leave a UAV below
//   its budget (mu_b = 0): its power is other clusters' interference.
// Coordinated RZF (crzf): W_b = c (H_b^H H_b + (K_b sigma^2 / P_b) I)^{-1} G_b^H, H_b the channels
//   from UAV b to every served user of the network (its own and the others'), c onto the budget:
//   regularised zero forcing that also regularises toward other clusters' users.
// Coordinated ZF (czf): ZF-SEL's users of each cluster, plus zero-forcing nulls toward the
//   strongest other-cluster users (largest ||h_{b,r}||) while antennas remain (|S_b| + nulls <= L),
//   water-filled over the own users' noise floors.
#include <cstdint>
#include <vector>

#include "skyloop/beamforming/beamformer.hpp"
#include "skyloop/beamforming/wmmse.hpp"

namespace skyloop {

struct NetworkWmmseTrace {
  std::vector<MatrixXcd> W;       // best iterate, per cluster
  double sum_rate = 0;            // its network sum rate (>= the start's)
  std::vector<double> sum_rates;  // the start, then after each iteration
  int iterations = 0;
  bool converged = false;
};

/// One network WMMSE run from W0 (per cluster; each first scaled onto its budget).
NetworkWmmseTrace network_wmmse_run(const Network& net, const std::vector<MatrixXcd>& W0, const WmmseOptions& opt);

class NetworkWmmseBeamformer final : public Beamformer {
 public:
  /// `start`: the per-cluster beamformer of the starting point (per-cluster WMMSE in the registry).
  NetworkWmmseBeamformer(WmmseOptions opt, std::shared_ptr<const Beamformer> start);
  std::string name() const override { return "nwmmse"; }
  MatrixXcd design(const Cluster& c) const override;
  std::vector<MatrixXcd> design_network(const Network& net, int threads = 1) const override;
  bool coordinated() const override { return true; }

 private:
  WmmseOptions opt_;
  std::shared_ptr<const Beamformer> start_;
};

/// Coordinated RZF / ZF of one network.
std::vector<MatrixXcd> coordinated_rzf(const Network& net);
std::vector<MatrixXcd> coordinated_zf(const Network& net);

class CoordinatedRzfBeamformer final : public Beamformer {
 public:
  std::string name() const override { return "crzf"; }
  MatrixXcd design(const Cluster& c) const override { return coordinated_rzf(Network::of(c)).front(); }
  std::vector<MatrixXcd> design_network(const Network& net, int) const override { return coordinated_rzf(net); }
  bool coordinated() const override { return true; }
};

class CoordinatedZfBeamformer final : public Beamformer {
 public:
  std::string name() const override { return "czf"; }
  MatrixXcd design(const Cluster& c) const override { return coordinated_zf(Network::of(c)).front(); }
  std::vector<MatrixXcd> design_network(const Network& net, int) const override { return coordinated_zf(net); }
  bool coordinated() const override { return true; }
};

}  // namespace skyloop
