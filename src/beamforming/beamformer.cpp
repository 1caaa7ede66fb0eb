#include "skyloop/beamforming/beamformer.hpp"

#include <cmath>
#include <stdexcept>

#include "skyloop/core/parallel.hpp"
#include "skyloop/core/rng.hpp"

namespace skyloop {

std::vector<MatrixXcd> Beamformer::design_batch(const std::vector<Cluster>& clusters, int threads) const {
  std::vector<MatrixXcd> out(clusters.size());
  parallel_for(clusters.size(), threads, [&](std::size_t i) { out[i] = design(clusters[i]); });
  return out;
}

std::vector<MatrixXcd> Beamformer::design_network(const Network& net, int threads) const {
  return design_batch(net.clusters, threads);
}

std::vector<std::vector<MatrixXcd>> Beamformer::design_networks(const std::vector<Network>& nets, int threads) const {
  std::vector<std::vector<MatrixXcd>> out(nets.size());
  if (coordinated()) {
    parallel_for(nets.size(), threads, [&](std::size_t i) { out[i] = design_network(nets[i]); });
    return out;
  }
  std::vector<Cluster> all;
  for (const auto& n : nets) all.insert(all.end(), n.clusters.begin(), n.clusters.end());
  auto W = design_batch(all, threads);
  std::size_t next = 0;
  for (std::size_t i = 0; i < nets.size(); ++i)
    for (std::size_t c = 0; c < nets[i].clusters.size(); ++c) out[i].push_back(std::move(W[next++]));
  return out;
}

void check_network_output(const Beamformer& bf, const Network& net, const std::vector<MatrixXcd>& W) {
  if (W.size() != net.clusters.size())
    throw std::runtime_error("beamformer '" + bf.name() + "' returned " + std::to_string(W.size()) +
                             " matrices for a network of " + std::to_string(net.clusters.size()) + " clusters");
  for (std::size_t i = 0; i < W.size(); ++i) check_beamformer_output(bf, net.clusters[i], W[i]);
}

MatrixXcd scale_to_budget(MatrixXcd W, double p_max, PowerScaling mode) {
  const double power = W.squaredNorm();
  if (power <= 0.0 || !std::isfinite(power)) return MatrixXcd::Zero(W.rows(), W.cols());
  double alpha = std::sqrt(p_max / power);
  if (mode == PowerScaling::Cap) alpha = std::min(1.0, alpha);
  W *= alpha;
  return W;
}

void check_beamformer_output(const Beamformer& bf, const Cluster& c, const MatrixXcd& W) {
  if (W.rows() != c.G.cols() || W.cols() != c.G.rows())
    throw std::runtime_error("beamformer '" + bf.name() + "' returned a " + std::to_string(W.rows()) + "x" +
                             std::to_string(W.cols()) + " matrix for a cluster of " + std::to_string(c.G.rows()) +
                             " users and " + std::to_string(c.G.cols()) + " antennas");
  const double p = W.squaredNorm();
  if (!std::isfinite(p)) throw std::runtime_error("beamformer '" + bf.name() + "' returned non-finite values");
  if (p > c.p_max * (1.0 + 1e-9))
    throw std::runtime_error("beamformer '" + bf.name() + "' exceeds the power budget: ||W||^2 = " +
                             std::to_string(p) + " W > P_max = " + std::to_string(c.p_max) + " W");
}

std::uint64_t cluster_hash(const Cluster& c) {
  std::uint64_t h = hash_bytes(c.G.data(), sizeof(cdouble) * static_cast<std::size_t>(c.G.size()));
  h = hash_bytes(&c.p_max, sizeof c.p_max, h);
  return hash_bytes(&c.noise, sizeof c.noise, h);
}

}  // namespace skyloop
