#include "skyloop/channel/rates.hpp"

#include <cmath>
#include <stdexcept>

namespace skyloop {

VectorXd sinr(const Cluster& c, const MatrixXcd& W) {
  if (W.rows() != c.G.cols() || W.cols() != c.G.rows())
    throw std::invalid_argument("beamformer shape " + std::to_string(W.rows()) + "x" + std::to_string(W.cols()) +
                                " does not match the cluster: expected " + std::to_string(c.G.cols()) + "x" +
                                std::to_string(c.G.rows()));
  const MatrixXcd M = c.G * W;  // M(k, j) = h_k^H w_j
  const Eigen::MatrixXd P = M.cwiseAbs2();
  VectorXd out(M.rows());
  for (Eigen::Index k = 0; k < M.rows(); ++k) {
    const double signal = P(k, k);
    double interference = 0.0;  // summed explicitly: no cancellation when interference << signal
    for (Eigen::Index j = 0; j < M.cols(); ++j)
      if (j != k) interference += P(k, j);
    out[k] = signal / (interference + c.noise);
  }
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
