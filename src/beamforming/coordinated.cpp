#include "skyloop/beamforming/coordinated.hpp"

#include <algorithm>
#include <cmath>
#include <numeric>
#include <stdexcept>

#include "skyloop/beamforming/linear.hpp"
#include "skyloop/channel/rates.hpp"

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

NetworkWmmseBeamformer::NetworkWmmseBeamformer(WmmseOptions opt, std::shared_ptr<const Beamformer> start)
    : opt_(opt), start_(std::move(start)) {}

MatrixXcd NetworkWmmseBeamformer::design(const Cluster& c) const { return design_network(Network::of(c)).front(); }

std::vector<MatrixXcd> NetworkWmmseBeamformer::design_network(const Network& net, int threads) const {
  auto W0 = start_->design_batch(net.clusters, threads);
  if (!net.interferes()) return W0;  // no coupling: the per-cluster WMMSE solution is the answer
  // A non-convex problem: run from several structured starts and keep the best local optimum.
  NetworkWmmseTrace best = network_wmmse_run(net, W0, opt_);
  for (const auto& start : {coordinated_rzf(net), coordinated_zf(net)}) {
    NetworkWmmseTrace t = network_wmmse_run(net, start, opt_);
    if (t.sum_rate > best.sum_rate) best = std::move(t);
  }
  return best.W;
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

}  // namespace skyloop
