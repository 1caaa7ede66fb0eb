#include "skyloop/beamforming/linear.hpp"

#include <algorithm>
#include <cmath>
#include <numeric>
#include <stdexcept>
#include <string>

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
  // The m best channels are active while the water level (budget + sum_{j<=m} f_j) / m stays above
  // f_m, i.e. while budget > sum_{j<m} (f_m - f_j). Everything is written with differences of
  // floors: when the floors dwarf the budget (noise far above the received power) the level itself
  // rounds to a floor and the budget would vanish (no user served) or overshoot.
  Eigen::Index m = 0;
  for (Eigen::Index cand = 1; cand <= n; ++cand) {
    const double f = floor[order[static_cast<std::size_t>(cand - 1)]];
    if (!std::isfinite(f)) break;
    double spread = 0.0;
    for (Eigen::Index j = 0; j + 1 < cand; ++j) spread += f - floor[order[static_cast<std::size_t>(j)]];
    if (!(budget > spread)) break;
    m = cand;
  }
  VectorXd p = VectorXd::Zero(n);
  if (m == 0) return p;
  for (Eigen::Index i = 0; i < m; ++i) {
    const auto k = order[static_cast<std::size_t>(i)];
    double spread = 0.0;
    for (Eigen::Index j = 0; j < m; ++j) spread += floor[order[static_cast<std::size_t>(j)]] - floor[k];
    p[k] = std::max(0.0, (budget + spread) / static_cast<double>(m));
  }
  const double total = p.sum();
  if (total > 0) p *= budget / total;  // exactly on the budget, whatever rounding did
  return p;
}

namespace {
// ZF of a cluster with more users than this (and than antennas) takes its pseudo-inverse through
// the adjoint. Below it the direct decomposition is kept (at most a few milliseconds), so every
// figure of the paper's and the scale study's scenes keeps its bits.
constexpr Eigen::Index kLargeTallCluster = 256;
}  // namespace

MatrixXcd zf(const Cluster& c, bool waterfilling) {
  const auto K = c.G.rows();
  if (K == 0) return MatrixXcd(c.G.cols(), 0);
  bool nulls_interference = false;
  MatrixXcd V;  // [L x K]: G^+
  if (K > kLargeTallCluster && K > c.G.cols()) {
    // More users than antennas (rank <= L < K: no nulling). pinv(G) = pinv(G^H)^H: the L x K
    // adjoint's decomposition solves against an L x L identity, O(K L^2) time and O(K L) memory,
    // where G's own builds and solves a K x K one (4096 users: 256 MiB).
    Eigen::CompleteOrthogonalDecomposition<MatrixXcd> cod(c.G.adjoint());
    cod.setThreshold(1e-10);
    V = cod.pseudoInverse().adjoint();
  } else {
    Eigen::CompleteOrthogonalDecomposition<MatrixXcd> cod(c.G);
    cod.setThreshold(1e-10);
    nulls_interference = cod.rank() == K;
    V = cod.pseudoInverse();
  }
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

namespace {
// The water-filled ZF sum rate of serving `set` alone, from the diagonal of its inverse Gram
// matrix: ||v_k||^2 = [(G_S G_S^H)^{-1}]_kk. Only the set's rows are touched (|S| <= L), so it
// costs O(L^3), never the K x K Gram matrix of a cluster of hundreds of users. -1: the set's
// channels are linearly dependent (no ZF).
double zf_set_rate(const Cluster& c, const std::vector<int>& set) {
  const auto n = static_cast<Eigen::Index>(set.size());
  MatrixXcd rows(n, c.G.cols());
  for (Eigen::Index i = 0; i < n; ++i) rows.row(i) = c.G.row(set[static_cast<std::size_t>(i)]);
  const MatrixXcd sub = rows * rows.adjoint();
  Eigen::LLT<MatrixXcd> llt(sub);
  if (llt.info() != Eigen::Success) return -1.0;
  const MatrixXcd inv = llt.solve(MatrixXcd::Identity(n, n));
  VectorXd floor(n);
  for (Eigen::Index i = 0; i < n; ++i) {
    floor[i] = c.noise * inv(i, i).real();
    if (!(floor[i] > 0) || !std::isfinite(floor[i])) return -1.0;
  }
  const VectorXd p = waterfill(floor, c.p_max);
  double rate = 0.0;
  for (Eigen::Index i = 0; i < n; ++i) rate += std::log2(1.0 + p[i] / floor[i]);
  return rate;
}

// Water-filled ZF over the users in `set`; every other user gets w_k = 0.
MatrixXcd zf_on_set(const Cluster& c, std::vector<int> set) {
  std::sort(set.begin(), set.end());
  MatrixXcd W = MatrixXcd::Zero(c.G.cols(), c.G.rows());
  if (set.empty()) return W;
  Cluster sub;
  sub.p_max = c.p_max;
  sub.noise = c.noise;
  sub.G.resize(static_cast<Eigen::Index>(set.size()), c.G.cols());
  for (std::size_t i = 0; i < set.size(); ++i) sub.G.row(static_cast<Eigen::Index>(i)) = c.G.row(set[i]);
  const MatrixXcd Ws = zf(sub, true);
  for (std::size_t i = 0; i < set.size(); ++i) W.col(set[i]) = Ws.col(static_cast<Eigen::Index>(i));
  return W;
}
}  // namespace

MatrixXcd zf_select(const Cluster& c, std::vector<int>* selected) {
  const auto K = c.G.rows(), L = c.G.cols();
  if (K == 0) {
    if (selected) selected->clear();
    return MatrixXcd(L, 0);
  }
  // Greedy: O(K L^4) per cluster (zf_set_rate is O(L^3) for each of K candidates, L rounds).
  std::vector<int> set;
  double best = 0.0;
  while (static_cast<Eigen::Index>(set.size()) < std::min(K, L)) {
    int pick = -1;
    double pick_rate = best;
    for (int k = 0; k < static_cast<int>(K); ++k) {
      if (std::find(set.begin(), set.end(), k) != set.end()) continue;
      std::vector<int> trial = set;
      trial.push_back(k);
      const double r = zf_set_rate(c, trial);
      if (r > pick_rate) pick_rate = r, pick = k;
    }
    if (pick < 0) break;
    set.push_back(pick);
    best = pick_rate;
  }
  std::sort(set.begin(), set.end());
  if (selected) *selected = set;
  return zf_on_set(c, set);
}

MatrixXcd zf_ranked(const Cluster& c, const std::vector<int>& ranking, std::vector<int>* selected) {
  const auto K = c.G.rows(), L = c.G.cols();
  std::vector<int> set, best_set;
  std::vector<bool> seen(static_cast<std::size_t>(K), false);
  double best = 0.0;
  for (const int k : ranking) {
    if (static_cast<Eigen::Index>(set.size()) >= std::min(K, L)) break;
    if (k < 0 || k >= K || seen[static_cast<std::size_t>(k)])
      throw std::invalid_argument("zf_ranked: user " + std::to_string(k) + " is not in the cluster or ranked twice");
    seen[static_cast<std::size_t>(k)] = true;
    set.push_back(k);
    const double r = zf_set_rate(c, set);
    if (r > best) best = r, best_set = set; else set.pop_back();
  }
  std::sort(best_set.begin(), best_set.end());
  if (selected) *selected = best_set;
  return zf_on_set(c, best_set);
}

MatrixXcd ZfGainBeamformer::design(const Cluster& c) const {
  std::vector<int> order(static_cast<std::size_t>(c.G.rows()));
  std::iota(order.begin(), order.end(), 0);
  const VectorXd gain = c.G.rowwise().squaredNorm();
  std::stable_sort(order.begin(), order.end(), [&](int a, int b) { return gain[a] > gain[b]; });
  return zf_ranked(c, order);
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
