#pragma once
// SINR and rates of one cluster alone (eq:sinr, eq:rate), in bits/s/Hz per user:
//   gamma_k = |h_k^H w_k|^2 / (sum_{j != k} |h_k^H w_j|^2 + sigma^2),  R_k = b log2(1 + gamma_k)
// with sigma^2 = c.noise and b = c.bandwidth the cluster's band (1 and sigma_0^2 in the paper's
// orthogonal model, 1/N and sigma_0^2/N under orthogonal-split). Under the shared spectrum a
// cluster's rates depend on the other clusters' beams: use channel/network.hpp.
#include <algorithm>
#include <vector>

#include "skyloop/channel/system_model.hpp"

namespace skyloop {

/// The most entries of a received-power block |A B|^2 that for_received_power_blocks holds at once
/// (1 MiB of complex products).
inline constexpr Eigen::Index kReceivedPowerBlockEntries = Eigen::Index{1} << 16;

/// Calls f(r0, P) for consecutive row blocks of A that together cover its rows, in order, with
/// P(i, j) = |(A B)(r0 + i, j)|^2: the received power of row r0 + i's user from beam j. A product
/// of at most kReceivedPowerBlockEntries entries is one block; a larger one (a cluster of thousands
/// of users: K^2 entries) comes in blocks of that size, so its memory stays bounded. Each entry is
/// the same L-term product either way.
template <class F>
void for_received_power_blocks(const MatrixXcd& A, const MatrixXcd& B, F&& f) {
  const Eigen::Index rows = A.rows(), cols = B.cols();
  if (rows * cols <= kReceivedPowerBlockEntries) {
    f(Eigen::Index{0}, (A * B).cwiseAbs2().eval());
    return;
  }
  const Eigen::Index step = std::max<Eigen::Index>(1, kReceivedPowerBlockEntries / std::max<Eigen::Index>(1, cols));
  for (Eigen::Index r0 = 0; r0 < rows; r0 += step)
    f(r0, (A.middleRows(r0, std::min(step, rows - r0)) * B).cwiseAbs2().eval());
}

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
