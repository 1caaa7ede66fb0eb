#include "skyloop/channel/network.hpp"

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
  // Received power of every served user from every UAV's beams: P_b(r, j) = |h_{b,r}^H w_{b,j}|^2.
  // Under orthogonal bands only a cluster's own rows are needed.
  std::vector<Eigen::MatrixXd> P(nc);
  for (std::size_t b = 0; b < nc; ++b)
    P[b] = net.interferes() ? (net.cross[b] * W[b]).cwiseAbs2().eval() : (net.clusters[b].G * W[b]).cwiseAbs2().eval();
  for (std::size_t a = 0; a < nc; ++a) {
    const Cluster& c = net.clusters[a];
    out[a].resize(static_cast<std::size_t>(c.size()));
    for (Eigen::Index j = 0; j < c.size(); ++j) {
      UserPowers& u = out[a][static_cast<std::size_t>(j)];
      const Eigen::Index r = net.interferes() ? net.offset[a] + j : j;  // row in P[a]
      u.signal = P[a](r, j);
      for (Eigen::Index jj = 0; jj < P[a].cols(); ++jj)  // summed explicitly: no cancellation
        if (jj != j) u.intra += P[a](r, jj);
      if (net.interferes())
        for (std::size_t b = 0; b < nc; ++b)
          if (b != a) u.inter += P[b].row(net.offset[a] + j).sum();
      u.noise = c.noise;
    }
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
