#pragma once
// SINR and rates of one cluster alone (eq:sinr, eq:rate), in bits/s/Hz per user:
//   gamma_k = |h_k^H w_k|^2 / (sum_{j != k} |h_k^H w_j|^2 + sigma^2),  R_k = b log2(1 + gamma_k)
// with sigma^2 = c.noise and b = c.bandwidth the cluster's band (1 and sigma_0^2 in the paper's
// orthogonal model, 1/N and sigma_0^2/N under orthogonal-split). Under the shared spectrum a
// cluster's rates depend on the other clusters' beams: use channel/network.hpp.
#include <vector>

#include "skyloop/channel/system_model.hpp"

namespace skyloop {

/// Per-user SINR of a cluster under beamformer W: [K_n] real.  W is [L x K_n], column k = w_k.
VectorXd sinr(const Cluster& c, const MatrixXcd& W);
/// Per-user rate b log2(1 + SINR): [K_n] real.
VectorXd rates(const Cluster& c, const MatrixXcd& W);
/// Cluster sum rate (eq:cluster sum rate). An empty cluster has sum rate 0.
double sum_rate(const Cluster& c, const MatrixXcd& W);
/// Total transmit power ||W||_F^2.
double transmit_power(const MatrixXcd& W);

/// Sum rates of many clusters: out[i] = sum_rate(clusters[i], W[i]).
std::vector<double> sum_rates(const std::vector<Cluster>& clusters, const std::vector<MatrixXcd>& W);

}  // namespace skyloop
