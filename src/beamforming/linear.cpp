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

namespace {
// Water-filling over n floors into p (n entries), ordering through `order` (n entries of scratch):
// the one implementation behind waterfill() and the selections' set rates, which call it per
// candidate set without allocating.
void waterfill_into(const double* floor, Eigen::Index n, double budget, double* p, Eigen::Index* order) {
  std::iota(order, order + n, Eigen::Index{0});
  std::sort(order, order + n, [&](auto a, auto b) { return floor[a] < floor[b]; });
  // The m best channels are active while the water level (budget + sum_{j<=m} f_j) / m stays above
  // f_m, i.e. while budget > sum_{j<m} (f_m - f_j). Everything is written with differences of
  // floors: when the floors dwarf the budget (noise far above the received power) the level itself
  // rounds to a floor and the budget would vanish (no user served) or overshoot.
  Eigen::Index m = 0;
  for (Eigen::Index cand = 1; cand <= n; ++cand) {
    const double f = floor[order[cand - 1]];
    if (!std::isfinite(f)) break;
    double spread = 0.0;
    for (Eigen::Index j = 0; j + 1 < cand; ++j) spread += f - floor[order[j]];
    if (!(budget > spread)) break;
    m = cand;
  }
  std::fill(p, p + n, 0.0);
  if (m == 0) return;
  for (Eigen::Index i = 0; i < m; ++i) {
    const auto k = order[i];
    double spread = 0.0;
    for (Eigen::Index j = 0; j < m; ++j) spread += floor[order[j]] - floor[k];
    p[k] = std::max(0.0, (budget + spread) / static_cast<double>(m));
  }
  double total = 0.0;
  for (Eigen::Index k = 0; k < n; ++k) total += p[k];
  if (total > 0)  // exactly on the budget, whatever rounding did
    for (Eigen::Index k = 0; k < n; ++k) p[k] *= budget / total;
}
}  // namespace

VectorXd waterfill(const VectorXd& floor, double budget) {
  const auto n = floor.size();
  std::vector<Eigen::Index> order(static_cast<std::size_t>(n));
  VectorXd p(n);
  waterfill_into(floor.data(), n, budget, p.data(), order.data());
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
// The water-filled ZF sum rate of a set of users S (|S| <= L) from the diagonal of its inverse
// Gram matrix, ||v_k||^2 = [(G_S G_S^H)^{-1}]_kk, for sets that grow one user at a time (the
// greedy searches below). With the Gram matrix's Cholesky factor built row by row (L L^H = A),
// adding a user appends one row to L and one to M = L^{-1}:
//   L(n,j) = (A(n,j) - sum_{m<j} L(n,m) conj(L(j,m))) / L(j,j),  L(n,n) = sqrt(A(n,n) - sum_{m<n} |L(n,m)|^2),
//   M(n,n) = 1 / L(n,n),  M(n,j) = -(sum_{j<=m<n} L(n,m) M(m,j)) / L(n,n),
// and [A^{-1}]_jj = sum_{i>=j} |M(i,j)|^2 gains the new row's |M(n,j)|^2. A candidate costs
// O(n L + n^2) and no allocation, where a fresh factorisation and inverse cost O(n^3) and a dozen
// small heap matrices; the set's Cholesky factor is the same one (rows < n unchanged).
class GrowingZfSet {
 public:
  explicit GrowingZfSet(const Cluster& c)
      : c_(c), cap_(std::min(c.G.rows(), c.G.cols())) {
    const auto sq = static_cast<std::size_t>(cap_ * cap_), n = static_cast<std::size_t>(cap_);
    l_.assign(sq, cdouble(0.0, 0.0));
    m_.assign(sq, cdouble(0.0, 0.0));
    diag_.assign(n, 0.0);
    row_l_.assign(n, cdouble(0.0, 0.0));
    row_m_.assign(n, cdouble(0.0, 0.0));
    floor_.assign(n, 0.0);
    power_.assign(n, 0.0);
    order_.assign(n, 0);
  }

  Eigen::Index size() const { return static_cast<Eigen::Index>(users_.size()); }
  Eigen::Index capacity() const { return cap_; }
  const std::vector<int>& users() const { return users_; }

  /// The water-filled ZF sum rate of the set plus user k; -1 where k's channel is (numerically)
  /// in the span of the set's (no ZF), or the set is full.
  double rate_with(int k) {
    const Eigen::Index n = size();
    if (n >= cap_ || !extend(k)) return -1.0;
    for (Eigen::Index j = 0; j <= n; ++j) {
      const double d = j < n ? diag_[static_cast<std::size_t>(j)] + std::norm(row_m_[static_cast<std::size_t>(j)])
                             : std::norm(row_m_[static_cast<std::size_t>(n)]);
      const double f = c_.noise * d;
      if (!(f > 0) || !std::isfinite(f)) return -1.0;
      floor_[static_cast<std::size_t>(j)] = f;
    }
    waterfill_into(floor_.data(), n + 1, c_.p_max, power_.data(), order_.data());
    double rate = 0.0;
    for (Eigen::Index j = 0; j <= n; ++j)
      rate += std::log2(1.0 + power_[static_cast<std::size_t>(j)] / floor_[static_cast<std::size_t>(j)]);
    return rate;
  }

  /// Adds user k (whose rate_with was not -1).
  void add(int k) {
    const Eigen::Index n = size();
    if (n >= cap_ || !extend(k)) throw std::logic_error("GrowingZfSet::add: user " + std::to_string(k) + " cannot extend the set");
    for (Eigen::Index j = 0; j <= n; ++j) {
      at(l_, n, j) = row_l_[static_cast<std::size_t>(j)];
      at(m_, n, j) = row_m_[static_cast<std::size_t>(j)];
      diag_[static_cast<std::size_t>(j)] += std::norm(row_m_[static_cast<std::size_t>(j)]);
    }
    users_.push_back(k);
  }

 private:
  cdouble& at(std::vector<cdouble>& v, Eigen::Index i, Eigen::Index j) const {
    return v[static_cast<std::size_t>(i * cap_ + j)];
  }
  // Row n of L and M for user k in row_l_ / row_m_; false where the new pivot is not positive.
  bool extend(int k) {
    const Eigen::Index n = size(), antennas = c_.G.cols();
    for (Eigen::Index j = 0; j < n; ++j) {
      const int u = users_[static_cast<std::size_t>(j)];
      cdouble a(0.0, 0.0);  // A(n, j) = g_k . conj(g_u)
      for (Eigen::Index l = 0; l < antennas; ++l) a += c_.G(k, l) * std::conj(c_.G(u, l));
      for (Eigen::Index m = 0; m < j; ++m) a -= row_l_[static_cast<std::size_t>(m)] * std::conj(at(l_, j, m));
      row_l_[static_cast<std::size_t>(j)] = a / at(l_, j, j).real();
    }
    double pivot = c_.G.row(k).squaredNorm();
    for (Eigen::Index m = 0; m < n; ++m) pivot -= std::norm(row_l_[static_cast<std::size_t>(m)]);
    if (!(pivot > 0) || !std::isfinite(pivot)) return false;
    const double lnn = std::sqrt(pivot);
    row_l_[static_cast<std::size_t>(n)] = cdouble(lnn, 0.0);
    for (Eigen::Index j = 0; j < n; ++j) {
      cdouble s(0.0, 0.0);
      for (Eigen::Index m = j; m < n; ++m) s += row_l_[static_cast<std::size_t>(m)] * at(m_, m, j);
      row_m_[static_cast<std::size_t>(j)] = -s / lnn;
    }
    row_m_[static_cast<std::size_t>(n)] = cdouble(1.0 / lnn, 0.0);
    return true;
  }

  const Cluster& c_;
  Eigen::Index cap_;
  std::vector<int> users_;
  std::vector<cdouble> l_, m_, row_l_, row_m_;  // L and M = L^{-1}, row-major cap x cap; the candidate's rows
  std::vector<double> diag_, floor_, power_;     // [A^{-1}]_jj of the set; the candidate's floors and powers
  std::vector<Eigen::Index> order_;
};

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
  // Greedy: O(K L^3) per cluster (each of K candidates costs O(L^2) on top of its L Gram
  // entries, L rounds).
  GrowingZfSet grow(c);
  double best = 0.0;
  while (grow.size() < grow.capacity()) {
    int pick = -1;
    double pick_rate = best;
    for (int k = 0; k < static_cast<int>(K); ++k) {
      if (std::find(grow.users().begin(), grow.users().end(), k) != grow.users().end()) continue;
      const double r = grow.rate_with(k);
      if (r > pick_rate) pick_rate = r, pick = k;
    }
    if (pick < 0) break;
    grow.add(pick);
    best = pick_rate;
  }
  std::vector<int> set = grow.users();
  std::sort(set.begin(), set.end());
  if (selected) *selected = set;
  return zf_on_set(c, set);
}

MatrixXcd zf_ranked(const Cluster& c, const std::vector<int>& ranking, std::vector<int>* selected) {
  const auto K = c.G.rows(), L = c.G.cols();
  GrowingZfSet grow(c);
  std::vector<bool> seen(static_cast<std::size_t>(K), false);
  double best = 0.0;
  for (const int k : ranking) {
    if (grow.size() >= std::min(K, L)) break;
    if (k < 0 || k >= K || seen[static_cast<std::size_t>(k)])
      throw std::invalid_argument("zf_ranked: user " + std::to_string(k) + " is not in the cluster or ranked twice");
    seen[static_cast<std::size_t>(k)] = true;
    const double r = grow.rate_with(k);
    if (r > best) best = r, grow.add(k);
  }
  std::vector<int> set = grow.users();
  std::sort(set.begin(), set.end());
  if (selected) *selected = set;
  return zf_on_set(c, set);
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
