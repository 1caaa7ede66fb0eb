#include "skyloop/beamforming/coordinated.hpp"

#include <algorithm>
#include <cmath>
#include <numeric>
#include <optional>
#include <stdexcept>

#include "skyloop/beamforming/linear.hpp"
#include "skyloop/channel/rates.hpp"
#include "skyloop/core/error.hpp"
#include "skyloop/core/text.hpp"

namespace skyloop {

NetworkWmmseTrace network_wmmse_run(const Network& net, const std::vector<MatrixXcd>& W0, const WmmseOptions& opt) {
  const std::size_t nc = net.clusters.size();
  if (W0.size() != nc) throw std::invalid_argument("network_wmmse_run: W0 has the wrong cluster count");
  NetworkWmmseTrace tr;
  for (std::size_t i = 0; i < nc; ++i) {
    const Cluster& c = net.clusters[i];
    if (W0[i].rows() != c.G.cols() || W0[i].cols() != c.G.rows())
      throw std::invalid_argument("network_wmmse_run: W0[" + std::to_string(i) + "] has the wrong shape");
    tr.W.push_back(scale_to_budget(W0[i], c.p_max, PowerScaling::Full));
  }
  double rate = network_sum_rate(net, tr.W);
  tr.sum_rates.push_back(rate);
  tr.sum_rate = rate;
  if (nc == 0) {
    tr.converged = true;
    return tr;
  }
  // Without interference the clusters decouple: per-cluster WMMSE is the same iteration.
  if (!net.interferes()) {
    std::vector<WmmseTrace> parts;
    int iterations = 0;
    for (std::size_t i = 0; i < nc; ++i) {
      parts.push_back(wmmse_run(net.clusters[i], tr.W[i], opt));
      iterations = std::max(iterations, parts.back().iterations);
      tr.W[i] = scale_to_budget(parts.back().W, net.clusters[i].p_max, PowerScaling::Full);  // full power is optimal here
    }
    tr.iterations = iterations;
    tr.sum_rate = network_sum_rate(net, tr.W);
    tr.sum_rates.push_back(tr.sum_rate);
    tr.converged = std::all_of(parts.begin(), parts.end(), [](const WmmseTrace& t) { return t.converged; });
    return tr;
  }
  const Eigen::Index ks = net.served_count();
  std::vector<MatrixXcd> W = tr.W, M(nc);
  VectorXd a(ks);   // omega_r |u_r|^2
  VectorXcd b(ks);  // omega_r u_r
  for (int it = 0; it < opt.max_iterations; ++it) {
    for (std::size_t i = 0; i < nc; ++i) M[i].noalias() = net.cross[i] * W[i];  // [K_s x K_i]
    for (std::size_t c = 0; c < nc; ++c) {
      for (Eigen::Index j = 0; j < net.clusters[c].size(); ++j) {
        const Eigen::Index r = net.offset[c] + j;
        const cdouble desired = M[c](r, j);
        // Interference plus noise summed term by term: T_r - |desired|^2 cancels at high SNR.
        double interference = net.clusters[c].noise;
        for (std::size_t i = 0; i < nc; ++i)
          for (Eigen::Index jj = 0; jj < M[i].cols(); ++jj)
            if (i != c || jj != j) interference += std::norm(M[i](r, jj));
        const double total = interference + std::norm(desired);
        const double omega = total / interference;
        const cdouble u = desired / total;
        a[r] = omega * std::norm(u);
        b[r] = omega * u;
      }
    }
    for (std::size_t i = 0; i < nc; ++i) {
      const Cluster& c = net.clusters[i];
      const MatrixXcd HH = net.cross[i].adjoint();  // [L x K_s], column r = h_{i,r}
      const MatrixXcd A = HH * a.asDiagonal() * net.cross[i];
      const MatrixXcd B = HH.middleCols(net.offset[i], c.size()) * b.segment(net.offset[i], c.size()).asDiagonal();
      W[i] = budgeted_solve(A, B, c.p_max, opt.bisection_tolerance);
    }
    const double next = network_sum_rate(net, W);
    tr.sum_rates.push_back(next);
    ++tr.iterations;
    const bool finite = std::isfinite(next) && std::all_of(W.begin(), W.end(), [](const MatrixXcd& x) { return x.allFinite(); });
    if (wmmse_step_done(tr.W, rate, tr.converged, W, next, finite, opt.tolerance)) break;
  }
  tr.sum_rate = rate;
  return tr;
}

const std::vector<std::string>& network_wmmse_starts() {
  static const std::vector<std::string> names{"wmmse", "crzf", "czf", "czfsel"};
  return names;
}

std::vector<std::string> parse_network_wmmse_starts(const std::string& spec) {
  const auto& names = network_wmmse_starts();
  if (spec.empty()) return names;
  const std::string allowed = join(names);
  const std::string what = "method 'nwmmse=" + spec + "' ";
  const std::string rule = ": allowed 'nwmmse' (every start) or 'nwmmse=' and starts joined by '+', each once, of " + allowed;
  std::vector<std::string> out;
  std::size_t at = 0;
  while (true) {
    const auto plus = spec.find('+', at);
    const std::string item = spec.substr(at, plus == std::string::npos ? std::string::npos : plus - at);
    if (item.empty()) throw InputError(what + "has an empty start" + rule);
    if (std::find(names.begin(), names.end(), item) == names.end()) throw InputError(what + "names no start '" + item + "'" + rule);
    if (std::find(out.begin(), out.end(), item) != out.end()) throw InputError(what + "names '" + item + "' twice" + rule);
    out.push_back(item);
    if (plus == std::string::npos) break;
    at = plus + 1;
  }
  std::vector<std::string> ordered;  // the run order is the list's, whatever order the spec named them in
  for (const auto& n : names)
    if (std::find(out.begin(), out.end(), n) != out.end()) ordered.push_back(n);
  return ordered;
}

NetworkWmmseBeamformer::NetworkWmmseBeamformer(WmmseOptions opt, std::shared_ptr<const Beamformer> start,
                                               std::vector<std::string> starts)
    : opt_(opt), start_(std::move(start)), starts_(std::move(starts)) {
  const auto& names = network_wmmse_starts();
  if (starts_.empty()) throw std::invalid_argument("NetworkWmmseBeamformer: no start");
  for (const auto& s : starts_)
    if (std::find(names.begin(), names.end(), s) == names.end())
      throw std::invalid_argument("NetworkWmmseBeamformer: unknown start '" + s + "'");
}

MatrixXcd NetworkWmmseBeamformer::design(const Cluster& c) const { return design_network(Network::of(c)).front(); }

std::vector<MatrixXcd> NetworkWmmseBeamformer::design_network(const Network& net, int threads) const {
  // No coupling: the per-cluster WMMSE solution is the answer, whatever the starts.
  if (!net.interferes()) return start_->design_batch(net.clusters, threads);
  // A non-convex problem: run from each start and keep the best local optimum (ties: the earlier).
  std::optional<NetworkWmmseTrace> best;
  for (const auto& name : starts_) {
    const std::vector<MatrixXcd> W0 = name == "wmmse"  ? start_->design_batch(net.clusters, threads)
                                      : name == "crzf" ? coordinated_rzf(net)
                                      : name == "czf"  ? coordinated_zf(net)
                                                       : coordinated_zf_select(net);
    NetworkWmmseTrace t = network_wmmse_run(net, W0, opt_);
    if (!best || t.sum_rate > best->sum_rate) best = std::move(t);
  }
  return best->W;
}

std::vector<MatrixXcd> coordinated_rzf(const Network& net) {
  std::vector<MatrixXcd> out;
  for (std::size_t i = 0; i < net.clusters.size(); ++i) {
    const Cluster& c = net.clusters[i];
    if (!net.interferes()) {
      out.push_back(rzf(c));
      continue;
    }
    const MatrixXcd& H = net.cross[i];
    MatrixXcd gram = H.adjoint() * H;  // [L x L]
    gram.diagonal().array() += static_cast<double>(c.size()) * c.noise / c.p_max;
    MatrixXcd W = gram.ldlt().solve(MatrixXcd(c.G.adjoint()));
    out.push_back(scale_to_budget(std::move(W), c.p_max, PowerScaling::Full));
  }
  return out;
}

std::vector<MatrixXcd> coordinated_zf(const Network& net) {
  std::vector<MatrixXcd> out;
  for (std::size_t i = 0; i < net.clusters.size(); ++i) {
    const Cluster& c = net.clusters[i];
    std::vector<int> own;
    MatrixXcd W = zf_select(c, &own);
    const auto L = c.G.cols();
    const auto room = L - static_cast<Eigen::Index>(own.size());
    if (!net.interferes() || own.empty() || room <= 0) {
      out.push_back(std::move(W));
      continue;
    }
    // The other clusters' users, strongest channel from this UAV first.
    const MatrixXcd& H = net.cross[i];
    std::vector<Eigen::Index> others;
    for (Eigen::Index r = 0; r < H.rows(); ++r)
      if (r < net.offset[i] || r >= net.offset[i + 1]) others.push_back(r);
    std::stable_sort(others.begin(), others.end(),
                     [&](Eigen::Index x, Eigen::Index y) { return H.row(x).squaredNorm() > H.row(y).squaredNorm(); });
    others.resize(std::min<std::size_t>(others.size(), static_cast<std::size_t>(room)));
    const auto ko = static_cast<Eigen::Index>(own.size());
    MatrixXcd S(ko + static_cast<Eigen::Index>(others.size()), L);
    for (Eigen::Index k = 0; k < ko; ++k) S.row(k) = c.G.row(own[static_cast<std::size_t>(k)]);
    for (std::size_t o = 0; o < others.size(); ++o) S.row(ko + static_cast<Eigen::Index>(o)) = H.row(others[o]);
    Eigen::CompleteOrthogonalDecomposition<MatrixXcd> cod(S);
    cod.setThreshold(1e-10);
    if (cod.rank() < S.rows()) {  // a null would also cancel an own user: keep ZF-SEL
      out.push_back(std::move(W));
      continue;
    }
    const MatrixXcd V = cod.pseudoInverse().leftCols(ko);  // [L x ko]
    const VectorXd norms2 = V.colwise().squaredNorm().transpose();
    const VectorXd p = waterfill(c.noise * norms2, c.p_max);
    W.setZero();
    for (Eigen::Index k = 0; k < ko; ++k)
      W.col(own[static_cast<std::size_t>(k)]) = V.col(k) * std::sqrt(p[k] / norms2[k]);
    out.push_back(std::move(W));
  }
  return out;
}

std::vector<MatrixXcd> coordinated_zf_select(const Network& net) {
  const std::size_t nc = net.clusters.size();
  std::vector<MatrixXcd> out;
  if (!net.interferes()) {
    for (const Cluster& c : net.clusters) out.push_back(zf_select(c));
    return out;
  }
  // The ZF design on an active set S of (cluster, user) pairs, and its network sum rate: every
  // active beam nulls every other active user (V = pinv of the UAV's channels to S, so
  // h_s^H v_t = [s == t]), so user s's SINR is p_s / (sigma^2 ||v_s||^2) and an inactive user's
  // rate is 0. Returns -1 when a UAV with an active user cannot null every other one (its
  // channels to S rank-deficient). W is written when given.
  using Active = std::vector<std::pair<std::size_t, Eigen::Index>>;
  auto design = [&](const Active& S, std::vector<MatrixXcd>* W) {
    if (W) {
      W->clear();
      for (std::size_t i = 0; i < nc; ++i) W->push_back(MatrixXcd::Zero(net.clusters[i].G.cols(), net.clusters[i].size()));
    }
    const auto n = static_cast<Eigen::Index>(S.size());
    double rate = 0.0;
    for (std::size_t i = 0; i < nc; ++i) {
      std::vector<Eigen::Index> own;  // positions in S of cluster i's active users
      for (Eigen::Index s = 0; s < n; ++s)
        if (S[static_cast<std::size_t>(s)].first == i) own.push_back(s);
      if (own.empty()) continue;  // a UAV with no active user is silent: nothing to null
      const Cluster& c = net.clusters[i];
      if (n > c.G.cols()) return -1.0;
      MatrixXcd H(n, c.G.cols());
      for (Eigen::Index s = 0; s < n; ++s) {
        const auto& [cl, u] = S[static_cast<std::size_t>(s)];
        H.row(s) = net.cross[i].row(net.offset[cl] + u);
      }
      Eigen::CompleteOrthogonalDecomposition<MatrixXcd> cod(H);
      cod.setThreshold(1e-10);
      if (cod.rank() < n) return -1.0;
      const MatrixXcd V = cod.pseudoInverse();  // [L x n]
      VectorXd norms2(static_cast<Eigen::Index>(own.size()));
      for (std::size_t k = 0; k < own.size(); ++k) norms2[static_cast<Eigen::Index>(k)] = V.col(own[k]).squaredNorm();
      const VectorXd floor = c.noise * norms2;
      const VectorXd p = waterfill(floor, c.p_max);
      for (std::size_t k = 0; k < own.size(); ++k) {
        const auto kk = static_cast<Eigen::Index>(k);
        rate += c.bandwidth * std::log2(1.0 + p[kk] / floor[kk]);
        if (W) (*W)[i].col(S[static_cast<std::size_t>(own[k])].second) = V.col(own[k]) * std::sqrt(p[kk] / norms2[kk]);
      }
    }
    return rate;
  };
  // Greedy, as ZF-SEL: the user raising the network sum rate most joins, while one does (ties:
  // the first in network order).
  Active S;
  double best = 0.0;
  while (true) {
    Active pick;
    double pick_rate = best;
    for (std::size_t i = 0; i < nc; ++i)
      for (Eigen::Index j = 0; j < net.clusters[i].size(); ++j) {
        if (std::find(S.begin(), S.end(), std::make_pair(i, j)) != S.end()) continue;
        Active T = S;
        T.emplace_back(i, j);
        const double r = design(T, nullptr);
        if (r > pick_rate) pick_rate = r, pick = std::move(T);
      }
    if (pick.empty()) break;
    S = std::move(pick);
    best = pick_rate;
  }
  std::vector<MatrixXcd> W;
  design(S, &W);
  return W;
}

}  // namespace skyloop
