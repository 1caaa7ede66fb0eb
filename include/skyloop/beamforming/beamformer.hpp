#pragma once
// The one beamformer interface. A beamformer maps a cluster (its [K_n x L] channel matrix G,
// P_max and sigma_0^2) to W: [L x K_n] complex, column k = w_k, with ||W||_F^2 <= P_max
// (eq:power_constraint). design() is const and must be safe to call from several threads;
// stochastic beamformers are pure functions of (their seed, the cluster), so a result never
// depends on call order or thread count.
//
// Two levels, one interface. design() sees one cluster; design_network() sees a whole network
// (every cluster of a snapshot, the cross channels and the spectrum model, channel/network.hpp).
// A per-cluster beamformer needs only design(): its network call designs each cluster alone
// (interference-unaware, as in the paper). A coordinated beamformer overrides design_network()
// and answers design() as the network of that one cluster. Every tool calls design_network(), so
// it takes either kind.
#include <memory>
#include <string>
#include <vector>

#include "skyloop/channel/network.hpp"

namespace skyloop {

class Beamformer {
 public:
  virtual ~Beamformer() = default;
  /// Short name used in CSV rows and tables ("wmmse", "ga:sga", ...).
  virtual std::string name() const = 0;
  /// W for one cluster: [L x K_n] complex with ||W||_F^2 <= c.p_max.
  virtual MatrixXcd design(const Cluster& c) const = 0;
  /// out[i] = design(clusters[i]); the default splits the clusters over `threads` threads.
  /// Learned beamformers override it with one batched forward pass.
  virtual std::vector<MatrixXcd> design_batch(const std::vector<Cluster>& clusters, int threads = 1) const;
  /// W for every cluster of a network: out[i] for net.clusters[i], each within its UAV's budget.
  /// The default is design_batch(net.clusters): each UAV alone.
  virtual std::vector<MatrixXcd> design_network(const Network& net, int threads = 1) const;
  /// out[s] = design_network(nets[s]). The default puts every cluster of every network through one
  /// design_batch() call when the beamformer is per-cluster, else splits the networks over threads.
  virtual std::vector<std::vector<MatrixXcd>> design_networks(const std::vector<Network>& nets, int threads = 1) const;
  /// True when design_network() looks beyond each cluster (coordinated beamforming).
  virtual bool coordinated() const { return false; }
};

/// check_beamformer_output() on every cluster of a network (count, shapes, finiteness, each UAV's budget).
void check_network_output(const Beamformer& bf, const Network& net, const std::vector<MatrixXcd>& W);

/// Scales W onto the budget: Full -> ||W||^2 = P exactly; Cap -> min(1, sqrt(P/||W||^2)) (the
/// paper's alpha). A zero W stays zero.
MatrixXcd scale_to_budget(MatrixXcd W, double p_max, PowerScaling mode);

/// Throws std::runtime_error naming the beamformer if W has the wrong shape, is not finite, or
/// exceeds the budget by more than a relative 1e-9. Evaluations call it on every decision.
void check_beamformer_output(const Beamformer& bf, const Cluster& c, const MatrixXcd& W);

/// Hash of a cluster's numbers (G, p_max, noise), the per-cluster stream of stochastic beamformers.
std::uint64_t cluster_hash(const Cluster& c);

}  // namespace skyloop
