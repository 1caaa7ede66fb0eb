#include "skyloop/channel/rates.hpp"

#include <cmath>
#include <stdexcept>

namespace skyloop {

VectorXd sinr(const Cluster& c, const MatrixXcd& W) {
  if (W.rows() != c.G.cols() || W.cols() != c.G.rows())
    throw std::invalid_argument("beamformer shape " + std::to_string(W.rows()) + "x" + std::to_string(W.cols()) +
                                " does not match the cluster: expected " + std::to_string(c.G.cols()) + "x" +
                                std::to_string(c.G.rows()));
  VectorXd out(c.G.rows());
  // P(i, j) = |h_k^H w_j|^2 for user k = r0 + i.
  for_received_power_blocks(c.G, W, [&](Eigen::Index r0, const Eigen::MatrixXd& P) {
    for (Eigen::Index i = 0; i < P.rows(); ++i) {
      const Eigen::Index k = r0 + i;
      const double signal = P(i, k);
      double interference = 0.0;  // summed explicitly: no cancellation when interference << signal
      for (Eigen::Index j = 0; j < P.cols(); ++j)
        if (j != k) interference += P(i, j);
      out[k] = signal / (interference + c.noise);
    }
  });
  return out;
}

VectorXd rates(const Cluster& c, const MatrixXcd& W) {
  const double share = c.bandwidth;
  return sinr(c, W).unaryExpr([share](double g) { return share * std::log2(1.0 + g); });
}

double sum_rate(const Cluster& c, const MatrixXcd& W) { return c.G.rows() == 0 ? 0.0 : rates(c, W).sum(); }

double transmit_power(const MatrixXcd& W) { return W.squaredNorm(); }

std::vector<double> sum_rates(const std::vector<Cluster>& clusters, const std::vector<MatrixXcd>& W) {
  if (clusters.size() != W.size()) throw std::invalid_argument("sum_rates: clusters and beamformers differ in count");
  std::vector<double> out(clusters.size());
  for (std::size_t i = 0; i < clusters.size(); ++i) out[i] = sum_rate(clusters[i], W[i]);
  return out;
}

}  // namespace skyloop
