#include "skyloop/channel/network.hpp"

#include "skyloop/channel/rates.hpp"

#include <cmath>
#include <stdexcept>

namespace skyloop {

Network Network::of(const Cluster& c) {
  Network net;
  net.uavs = 1;
  net.clusters.push_back(c);
  net.offset = {0, c.size()};
  net.served = c.users.size() == static_cast<std::size_t>(c.size()) ? c.users : std::vector<int>(static_cast<std::size_t>(c.size()), -1);
  net.cross.push_back(c.G);
  return net;
}

std::vector<std::vector<UserPowers>> user_powers(const Network& net, const std::vector<MatrixXcd>& W) {
  const std::size_t nc = net.clusters.size();
  if (W.size() != nc)
    throw std::invalid_argument("network beamformers: " + std::to_string(W.size()) + " matrices for " +
                                std::to_string(nc) + " clusters");
  for (std::size_t i = 0; i < nc; ++i) {
    const Cluster& c = net.clusters[i];
    if (W[i].rows() != c.G.cols() || W[i].cols() != c.G.rows())
      throw std::invalid_argument("beamformer shape " + std::to_string(W[i].rows()) + "x" + std::to_string(W[i].cols()) +
                                  " does not match cluster " + std::to_string(i) + ": expected " +
                                  std::to_string(c.G.cols()) + "x" + std::to_string(c.G.rows()));
  }
  std::vector<std::vector<UserPowers>> out(nc);
  for (std::size_t a = 0; a < nc; ++a) {
    out[a].resize(static_cast<std::size_t>(net.clusters[a].size()));
    for (UserPowers& u : out[a]) u.noise = net.clusters[a].noise;
  }
  // Received power of every served user from UAV b's beams: P_b(r, j) = |h_{b,r}^H w_{b,j}|^2, row
  // r = offset[a] + j for user j of cluster a. Under orthogonal bands only cluster b's own rows are
  // needed. A user's interference from the other UAVs accumulates in the order of b.
  for (std::size_t b = 0; b < nc; ++b) {
    const MatrixXcd& rows = net.interferes() ? net.cross[b] : net.clusters[b].G;
    std::size_t a = net.interferes() ? 0 : b;  // the cluster of the block's first row
    for_received_power_blocks(rows, W[b], [&](Eigen::Index r0, const Eigen::MatrixXd& P) {
      for (Eigen::Index i = 0; i < P.rows(); ++i) {
        const Eigen::Index r = r0 + i;
        if (net.interferes())
          while (r >= net.offset[a + 1]) ++a;
        const Eigen::Index j = net.interferes() ? r - net.offset[a] : r;
        UserPowers& u = out[a][static_cast<std::size_t>(j)];
        if (a == b) {
          u.signal = P(i, j);
          for (Eigen::Index jj = 0; jj < P.cols(); ++jj)  // summed explicitly: no cancellation
            if (jj != j) u.intra += P(i, jj);
        } else {
          u.inter += P.row(i).sum();
        }
      }
    });
  }
  return out;
}

std::vector<double> network_cluster_rates(const Network& net, const std::vector<MatrixXcd>& W) {
  const auto powers = user_powers(net, W);
  std::vector<double> out(powers.size(), 0.0);
  for (std::size_t i = 0; i < powers.size(); ++i) {
    double total = 0.0;
    for (const UserPowers& u : powers[i]) total += std::log2(1.0 + u.sinr());
    out[i] = net.clusters[i].bandwidth * total;
  }
  return out;
}

double network_sum_rate(const Network& net, const std::vector<MatrixXcd>& W) {
  double total = 0.0;
  for (double r : network_cluster_rates(net, W)) total += r;
  return total;
}

}  // namespace skyloop
