#include "skyloop/beamforming/wmmse.hpp"

#include <cmath>
#include <stdexcept>

#include "skyloop/beamforming/linear.hpp"
#include "skyloop/channel/rates.hpp"
#include "skyloop/core/rng.hpp"

namespace skyloop {
namespace {

/// Sum rate from M = G W without allocating per user (times the cluster's band share).
double sum_rate_of(const MatrixXcd& M, double noise, double share) {
  double total = 0.0;
  for (Eigen::Index k = 0; k < M.rows(); ++k) {
    double interference = noise;
    for (Eigen::Index j = 0; j < M.cols(); ++j)
      if (j != k) interference += std::norm(M(k, j));
    total += std::log2(1.0 + std::norm(M(k, k)) / interference);
  }
  return share * total;
}

}  // namespace

MatrixXcd budgeted_solve(const MatrixXcd& A, const MatrixXcd& B, double p_max, double bisection_tolerance) {
  const Eigen::Index L = A.rows();
  Eigen::SelfAdjointEigenSolver<MatrixXcd> eig(A);
  const VectorXd& lambda = eig.eigenvalues();
  const MatrixXcd C = eig.eigenvectors().adjoint() * B;  // [L x K]
  const VectorXd cpow = C.rowwise().squaredNorm();
  // Components with lambda ~ 0 lie outside the span of the channels, where C is ~0 too:
  // they are dropped (pseudo-inverse at mu = 0).
  const double lambda_floor = 1e-12 * std::max(lambda.maxCoeff(), 0.0);
  auto power = [&](double mu) {
    double p = 0.0;
    for (Eigen::Index i = 0; i < L; ++i) {
      const double den = lambda[i] + mu;
      if (lambda[i] > lambda_floor || mu > 0) p += cpow[i] / (den * den);
    }
    return p;
  };
  double mu = 0.0;
  if (!(power(0.0) <= p_max)) {
    double lo = 0.0, hi = std::sqrt(cpow.sum() / p_max);
    for (int k = 0; k < 2100 && power(hi) > p_max; ++k) hi *= 2.0;  // guards rounding; normally already feasible
    // Bisection to the relative tolerance, or until lo and hi are adjacent doubles (a tolerance
    // below the double precision, e.g. 1e-16, then stops there instead of looping for ever).
    while (hi - lo > bisection_tolerance * hi) {
      const double mid = 0.5 * (lo + hi);
      if (!(mid > lo && mid < hi)) break;
      (power(mid) > p_max ? lo : hi) = mid;
    }
    mu = hi;  // feasible side
  }
  VectorXd inv(L);
  for (Eigen::Index i = 0; i < L; ++i) inv[i] = (lambda[i] > lambda_floor || mu > 0) ? 1.0 / (lambda[i] + mu) : 0.0;
  return eig.eigenvectors() * (inv.asDiagonal() * C);
}

MatrixXcd random_beamformer(Eigen::Index L, Eigen::Index K, double p_max, std::uint64_t seed) {
  Rng rng(seed);
  MatrixXcd W(L, K);
  for (Eigen::Index j = 0; j < K; ++j)
    for (Eigen::Index i = 0; i < L; ++i) W(i, j) = cdouble(rng.normal(), rng.normal());
  return scale_to_budget(std::move(W), p_max, PowerScaling::Full);
}

WmmseTrace wmmse_run(const Cluster& c, const MatrixXcd& W0, const WmmseOptions& opt) {
  const Eigen::Index K = c.G.rows(), L = c.G.cols();
  if (W0.rows() != L || W0.cols() != K) throw std::invalid_argument("wmmse_run: W0 has the wrong shape");
  WmmseTrace tr;
  tr.W = scale_to_budget(W0, c.p_max, PowerScaling::Full);
  if (K == 0) {
    tr.sum_rates.push_back(0.0);
    tr.sum_rate = 0.0;
    tr.converged = true;
    return tr;
  }
  const MatrixXcd GH = c.G.adjoint();  // [L x K], column k = g_k^H
  MatrixXcd M = c.G * tr.W;
  double rate = sum_rate_of(M, c.noise, c.bandwidth);
  tr.sum_rates.push_back(rate);

  VectorXcd u(K);
  VectorXd a(K);  // omega_k |u_k|^2
  VectorXcd b(K); // omega_k u_k
  MatrixXcd W(L, K);
  for (int it = 0; it < opt.max_iterations; ++it) {
    for (Eigen::Index k = 0; k < K; ++k) {
      const double desired = std::norm(M(k, k));
      const double interference = M.row(k).squaredNorm() - desired + c.noise;
      const double total = desired + interference;
      // 1 + SINR, from the interference itself: total - desired cancels catastrophically at high SNR.
      const double omega = total / std::max(interference, c.noise);
      u[k] = M(k, k) / total;
      a[k] = omega * std::norm(u[k]);
      b[k] = omega * u[k];
    }
    W = budgeted_solve(GH * a.asDiagonal() * c.G, GH * b.asDiagonal(), c.p_max, opt.bisection_tolerance);
    M.noalias() = c.G * W;
    const double next = sum_rate_of(M, c.noise, c.bandwidth);
    tr.sum_rates.push_back(next);
    ++tr.iterations;
    // In exact arithmetic every iteration raises the sum rate. At extreme SNR (noise far below the
    // received power) the W-step's matrix spans many orders of magnitude and rounding can break
    // that: a non-finite or lower iterate ends the run, and the best iterate (at worst the start
    // point) is returned, so WMMSE never ends below where it started.
    if (wmmse_step_done(tr.W, rate, tr.converged, W, next, std::isfinite(next) && W.allFinite(), opt.tolerance)) break;
  }
  tr.sum_rate = rate;
  return tr;
}

WmmseBeamformer::WmmseBeamformer(WmmseOptions opt, WmmseInit init, int restarts, std::uint64_t seed,
                                 PowerScaling scaling)
    : opt_(opt), init_(init), restarts_(restarts), seed_(seed), scaling_(scaling) {}

MatrixXcd WmmseBeamformer::design(const Cluster& c) const {
  const Eigen::Index K = c.G.rows(), L = c.G.cols();
  if (K == 0) return MatrixXcd(L, 0);
  const std::uint64_t stream = derive_seed(seed_, cluster_hash(c));
  MatrixXcd W0 = init_ == WmmseInit::ZfSel ? zf_select(c)
                 : init_ == WmmseInit::Rzf ? rzf(c)
                 : init_ == WmmseInit::Mrt ? mrt(c)
                                           : random_beamformer(L, K, c.p_max, stream);
  WmmseTrace best = wmmse_run(c, W0, opt_);
  for (int r = 1; r <= restarts_; ++r) {
    WmmseTrace t = wmmse_run(c, random_beamformer(L, K, c.p_max, derive_seed(stream, r)), opt_);
    if (t.sum_rate > best.sum_rate) best = std::move(t);
  }
  return scale_to_budget(std::move(best.W), c.p_max, scaling_);
}

}  // namespace skyloop
