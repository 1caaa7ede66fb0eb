#include "skyloop/beamforming/linear.hpp"

#include <algorithm>
#include <cmath>
#include <numeric>

namespace skyloop {

MatrixXcd mrt(const Cluster& c) {
  const auto K = c.G.rows();
  MatrixXcd W = c.G.adjoint();  // column k = h_k
  if (K == 0) return W;
  const double per_user = c.p_max / static_cast<double>(K);
  for (Eigen::Index k = 0; k < K; ++k) {
    const double n = W.col(k).norm();
    W.col(k) *= n > 0 ? std::sqrt(per_user) / n : 0.0;
  }
  return W;
}

VectorXd waterfill(const VectorXd& floor, double budget) {
  const auto n = floor.size();
  std::vector<Eigen::Index> order(static_cast<std::size_t>(n));
  std::iota(order.begin(), order.end(), 0);
  std::sort(order.begin(), order.end(), [&](auto a, auto b) { return floor[a] < floor[b]; });
  // Find the largest m such that the water level over the m best channels is above floor[m-1].
  double sum = 0.0, mu = 0.0;
  for (Eigen::Index m = 1; m <= n; ++m) {
    const double f = floor[order[static_cast<std::size_t>(m - 1)]];
    if (!std::isfinite(f)) break;
    const double level = (budget + sum + f) / static_cast<double>(m);
    if (level <= f) break;
    sum += f;
    mu = level;
  }
  VectorXd p(n);
  for (Eigen::Index k = 0; k < n; ++k) p[k] = std::max(0.0, mu - floor[k]);
  return p;
}

MatrixXcd zf(const Cluster& c, bool waterfilling) {
  const auto K = c.G.rows();
  if (K == 0) return MatrixXcd(c.G.cols(), 0);
  Eigen::CompleteOrthogonalDecomposition<MatrixXcd> cod(c.G);
  cod.setThreshold(1e-10);
  const bool nulls_interference = cod.rank() == K;
  MatrixXcd V = cod.pseudoInverse();  // [L x K]
  VectorXd norms2 = V.colwise().squaredNorm().transpose();
  VectorXd power(K);
  if (nulls_interference && waterfilling) {
    power = waterfill(c.noise * norms2, c.p_max);
  } else {
    const auto active = (norms2.array() > 0).count();
    for (Eigen::Index k = 0; k < K; ++k) power[k] = norms2[k] > 0 ? c.p_max / static_cast<double>(active) : 0.0;
  }
  for (Eigen::Index k = 0; k < K; ++k)
    V.col(k) *= norms2[k] > 0 ? std::sqrt(power[k] / norms2[k]) : 0.0;
  return V;
}

MatrixXcd rzf(const Cluster& c) {
  const auto K = c.G.rows();
  if (K == 0) return MatrixXcd(c.G.cols(), 0);
  MatrixXcd gram = c.G * c.G.adjoint();
  gram.diagonal().array() += static_cast<double>(K) * c.noise / c.p_max;
  MatrixXcd W = c.G.adjoint() * gram.ldlt().solve(MatrixXcd::Identity(K, K));
  return scale_to_budget(std::move(W), c.p_max, PowerScaling::Full);
}

}  // namespace skyloop
