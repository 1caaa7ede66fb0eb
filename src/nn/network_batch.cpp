#include "network_batch.hpp"

#include <algorithm>

namespace skyloop::nn {

NetSet make_net_set(const std::vector<Network>& nets, int64_t antennas) {
  const int64_t S = static_cast<int64_t>(nets.size());
  int64_t C = 1, K = 1;
  for (const auto& n : nets) {
    C = std::max<int64_t>(C, static_cast<int64_t>(n.clusters.size()));
    for (const auto& c : n.clusters) K = std::max<int64_t>(K, c.size());
  }
  const int64_t L = antennas;
  NetSet s;
  s.antennas = L;
  s.h = torch::zeros({S, C, C, K, 2 * L}, torch::kFloat64);
  s.umask = torch::zeros({S, C, K}, torch::kFloat64);
  s.cmask = torch::zeros({S, C}, torch::kFloat64);
  s.p_max = torch::zeros({S, C}, torch::kFloat64);
  s.noise = torch::ones({S}, torch::kFloat64);
  s.bandwidth = torch::ones({S}, torch::kFloat64);
  auto h = s.h.accessor<double, 5>();
  auto um = s.umask.accessor<double, 3>();
  auto cm = s.cmask.accessor<double, 2>();
  auto pm = s.p_max.accessor<double, 2>();
  auto nz = s.noise.accessor<double, 1>();
  auto bw = s.bandwidth.accessor<double, 1>();
  for (int64_t i = 0; i < S; ++i) {
    const Network& n = nets[static_cast<std::size_t>(i)];
    if (!n.interferes()) s.interferes = false;
    for (std::size_t tx = 0; tx < n.clusters.size(); ++tx) {
      const Cluster& c = n.clusters[tx];
      cm[i][static_cast<int64_t>(tx)] = 1.0;
      pm[i][static_cast<int64_t>(tx)] = c.p_max;
      nz[i] = c.noise;
      bw[i] = c.bandwidth;
      for (int k = 0; k < c.size(); ++k) um[i][static_cast<int64_t>(tx)][k] = 1.0;
      for (std::size_t rx = 0; rx < n.clusters.size(); ++rx) {
        for (int k = 0; k < n.clusters[rx].size(); ++k) {
          const auto row = static_cast<Eigen::Index>(n.offset[rx] + k);
          for (int64_t l = 0; l < L; ++l) {
            const cdouble g = n.cross[tx](row, static_cast<Eigen::Index>(l));  // h^H entry: h = conj(g)
            h[i][static_cast<int64_t>(tx)][static_cast<int64_t>(rx)][k][l] = g.real();
            h[i][static_cast<int64_t>(tx)][static_cast<int64_t>(rx)][k][L + l] = -g.imag();
          }
        }
      }
    }
  }
  return s;
}

double channel_rms(const NetSet& set) {
  const auto pair_mask = set.umask.unsqueeze(1) * set.cmask.unsqueeze(2).unsqueeze(3);  // [S, C_tx, C_rx, K]
  const auto power = (set.h * set.h).sum(4) * pair_mask;                                 // sum over 2L
  const double pairs = pair_mask.sum().item<double>();
  return pairs > 0 ? std::sqrt(power.sum().item<double>() / (pairs * static_cast<double>(set.antennas))) : 1.0;
}

NetBatch make_net_batch(const NetSet& set, const torch::Tensor& ids, double feature_scale, const torch::Device& device,
                        torch::ScalarType dtype) {
  NetBatch b;
  const auto h = set.h.index_select(0, ids);
  const auto inv_sigma = torch::rsqrt(set.noise.index_select(0, ids)).view({-1, 1, 1, 1, 1});
  b.x = (h * feature_scale).to(dtype).to(device);
  b.g = (h * inv_sigma).to(dtype).to(device);
  b.umask = set.umask.index_select(0, ids).to(dtype).to(device);
  b.cmask = set.cmask.index_select(0, ids).to(dtype).to(device);
  b.p_max = set.p_max.index_select(0, ids).to(dtype).to(device);
  b.bandwidth = set.bandwidth.index_select(0, ids).to(dtype).to(device);
  b.interferes = set.interferes;
  return b;
}

torch::Tensor scale_to_budget(const torch::Tensor& raw, const NetBatch& b, PowerScaling mode) {
  const auto w = raw * b.umask.unsqueeze(3);
  const auto power = (w * w).sum({2, 3});  // [B, C]
  // sqrt(P) * rsqrt(.), not sqrt(P / .): an empty slot (P = 0) must have a finite gradient.
  auto alpha = torch::sqrt(b.p_max) * torch::rsqrt(power + 1e-12);
  if (mode == PowerScaling::Cap) alpha = torch::clamp_max(alpha, 1.0);
  return w * alpha.unsqueeze(2).unsqueeze(3);
}

torch::Tensor network_sum_rates(const torch::Tensor& w, const NetBatch& b) {
  const auto L = w.size(3) / 2;
  const auto gr = b.g.narrow(4, 0, L), gi = b.g.narrow(4, L, L);  // [B, Ct, Cr, K, L]
  const auto wr = w.narrow(3, 0, L), wi = w.narrow(3, L, L);      // [B, Ct, J, L]
  // h^H w = (hr.wr + hi.wi) + j (hr.wi - hi.wr) for every (tx, rx, k) and beam j of tx.
  const auto mr = torch::einsum("btrkl,btjl->btrkj", {gr, wr}) + torch::einsum("btrkl,btjl->btrkj", {gi, wi});
  const auto mi = torch::einsum("btrkl,btjl->btrkj", {gr, wi}) - torch::einsum("btrkl,btjl->btrkj", {gi, wr});
  auto p = mr * mr + mi * mi;  // [B, Ct, Cr, K, J]
  const auto C = p.size(1), K = p.size(3);
  const auto eye_c = torch::eye(C, p.options()).view({1, C, C, 1, 1});
  const auto eye_k = torch::eye(K, p.options()).view({1, 1, 1, K, K});
  if (!b.interferes) p = p * eye_c;  // orthogonal bands: only the own UAV's beams arrive
  const auto signal = (p * eye_c * eye_k).sum({1, 4});              // [B, Cr, K]
  const auto interference = (p * (1 - eye_c * eye_k)).sum({1, 4});  // summed without the signal term
  const auto rate = torch::log2(1 + signal / (interference + 1)) * b.umask;
  return rate.sum({1, 2}) * b.bandwidth;
}

}  // namespace skyloop::nn
