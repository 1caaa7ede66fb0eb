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
//   iterate is kept. The problem is non-convex and the iteration local: it runs from each of its
//   starts (network_wmmse_starts(); by default all four, 'nwmmse=czfsel' names one) and keeps the
//   best. From per-cluster WMMSE it never ends below the interference-unaware solution; without
//   interference it returns that solution. Toward interference nulls at high SNR it climbs slowly
//   (from the per-cluster starts half the runs of a 60 dB network stop at the 1000-iteration cap,
//   well below the nulls), which the czfsel start reaches at once. Unlike the per-cluster methods
//   it may leave a UAV below its budget (mu_b = 0): its power is other clusters' interference.
// Coordinated RZF (crzf): W_b = c (H_b^H H_b + (K_b sigma^2 / P_b) I)^{-1} G_b^H, H_b the channels
//   from UAV b to every served user of the network (its own and the others'), c onto the budget:
//   regularised zero forcing that also regularises toward other clusters' users.
// Coordinated ZF (czf): ZF-SEL's users of each cluster, plus zero-forcing nulls toward the
//   strongest other-cluster users (largest ||h_{b,r}||) while antennas remain (|S_b| + nulls <= L),
//   water-filled over the own users' noise floors.
// Network ZF with user selection (czfsel): one active set S of users over the whole network, grown
//   greedily (the user raising the network sum rate most joins, while one does and |S| <= L); every
//   UAV's beam to an active user of its own is zero-forcing toward every other active user of the
//   network, so the active users hear no interference at all, water-filled per UAV over its own
//   active users. ZF-SEL (linear.hpp) with the network as one cluster of distributed antennas,
//   each UAV's power its own. The interference-free design that is optimal in degrees of freedom
//   at high SNR; at low SNR the starts that keep every user on do better.

#include <cstdint>
#include <string>
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

/// The starts network WMMSE may run from, in the order it runs them (ties keep the earlier): the
/// per-cluster beamformer it is given (per-cluster WMMSE), crzf, czf, czfsel. One list, read by the
/// registry's parser, its description and its errors.
const std::vector<std::string>& network_wmmse_starts();

/// The starts named by 'a+b+...' (each once, from network_wmmse_starts()); an empty spec is all of
/// them. A bad spec is refused in one line naming 'nwmmse=SPEC' and what is allowed.
std::vector<std::string> parse_network_wmmse_starts(const std::string& spec);

class NetworkWmmseBeamformer final : public Beamformer {
 public:
  /// `start`: the per-cluster beamformer of the 'wmmse' start and of a network without interference
  /// (per-cluster WMMSE in the registry); `starts`: from network_wmmse_starts(), each once.
  NetworkWmmseBeamformer(WmmseOptions opt, std::shared_ptr<const Beamformer> start,
                         std::vector<std::string> starts = network_wmmse_starts());
  std::string name() const override { return "nwmmse"; }
  MatrixXcd design(const Cluster& c) const override;
  std::vector<MatrixXcd> design_network(const Network& net, int threads = 1) const override;
  bool coordinated() const override { return true; }

 private:
  WmmseOptions opt_;
  std::shared_ptr<const Beamformer> start_;
  std::vector<std::string> starts_;
};

/// Coordinated RZF / ZF / network ZF-SEL of one network (without interference each is its
/// per-cluster counterpart: rzf, zfsel, zfsel).
std::vector<MatrixXcd> coordinated_rzf(const Network& net);
std::vector<MatrixXcd> coordinated_zf(const Network& net);
std::vector<MatrixXcd> coordinated_zf_select(const Network& net);

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

class CoordinatedZfSelectBeamformer final : public Beamformer {
 public:
  std::string name() const override { return "czfsel"; }
  MatrixXcd design(const Cluster& c) const override { return coordinated_zf_select(Network::of(c)).front(); }
  std::vector<MatrixXcd> design_network(const Network& net, int) const override { return coordinated_zf_select(net); }
  bool coordinated() const override { return true; }
};

}  // namespace skyloop
