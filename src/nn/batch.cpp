#include "batch.hpp"

namespace skyloop::nn {

ClusterSet make_cluster_set(const std::vector<Cluster>& clusters, const std::vector<int>& owner, std::size_t samples) {
  ClusterSet s;
  const int64_t C = static_cast<int64_t>(clusters.size());
  s.antennas = C ? clusters[0].antennas() : 0;
  int64_t U = 0;
  for (const auto& c : clusters) U += c.size();
  s.gr = torch::empty({U, s.antennas}, torch::kFloat64);
  s.gi = torch::empty({U, s.antennas}, torch::kFloat64);
  s.offsets = torch::empty({C}, torch::kInt64);
  s.sizes = torch::empty({C}, torch::kInt64);
  s.p_max = torch::empty({C}, torch::kFloat64);
  s.noise = torch::empty({C}, torch::kFloat64);
  auto gr = s.gr.accessor<double, 2>();
  auto gi = s.gi.accessor<double, 2>();
  auto off = s.offsets.accessor<int64_t, 1>();
  auto siz = s.sizes.accessor<int64_t, 1>();
  auto pm = s.p_max.accessor<double, 1>();
  auto nz = s.noise.accessor<double, 1>();
  s.sample_clusters.assign(samples, {});
  int64_t row = 0;
  for (int64_t i = 0; i < C; ++i) {
    const Cluster& c = clusters[static_cast<std::size_t>(i)];
    off[i] = row;
    siz[i] = c.size();
    pm[i] = c.p_max;
    nz[i] = c.noise;
    for (int k = 0; k < c.size(); ++k, ++row)
      for (int l = 0; l < s.antennas; ++l) gr[row][l] = c.G(k, l).real(), gi[row][l] = c.G(k, l).imag();
    s.sample_clusters[static_cast<std::size_t>(owner[static_cast<std::size_t>(i)])].push_back(i);
  }
  return s;
}

double channel_rms(const ClusterSet& set) {
  const auto p = (set.gr * set.gr + set.gi * set.gi).mean().item<double>();
  return std::sqrt(p);
}

Batch make_batch(const ClusterSet& set, const torch::Tensor& ids, double feature_scale, const torch::Device& device,
                 torch::ScalarType dtype) {
  const auto sizes = set.sizes.index_select(0, ids);                  // [C]
  const auto C = ids.size(0);
  const auto seg = torch::repeat_interleave(torch::arange(C, torch::kInt64), sizes);  // [U]
  const auto starts = torch::cumsum(sizes, 0) - sizes;                 // first batch row of each cluster
  const auto pos = torch::arange(seg.size(0), torch::kInt64) - starts.index_select(0, seg);
  const auto rows = set.offsets.index_select(0, ids).index_select(0, seg) + pos;
  const auto gr = set.gr.index_select(0, rows), gi = set.gi.index_select(0, rows);  // [U, L] rows g = h^H
  const auto inv_sigma = torch::rsqrt(set.noise.index_select(0, ids)).index_select(0, seg).unsqueeze(1);

  Batch b;
  // h = conj(g): Re h = Re g, Im h = -Im g.
  b.x = (torch::cat({gr, -gi}, 1) * feature_scale).to(dtype).to(device);
  b.graph.seg = seg.to(device);
  b.graph.pos = pos.to(device);
  b.graph.count = sizes.to(dtype).unsqueeze(1).to(device);
  b.graph.clusters = C;
  b.graph.kmax = C ? sizes.max().item<int64_t>() : 0;
  const auto to_pad = [&](const torch::Tensor& v) {
    return torch::zeros({C, b.graph.kmax, v.size(1)}, v.options()).index_put({seg, pos}, v);
  };
  b.gr = to_pad(gr * inv_sigma).to(dtype).to(device);
  b.gi = to_pad(gi * inv_sigma).to(dtype).to(device);
  b.mask = torch::zeros({C, b.graph.kmax}, dtype).index_put({seg, pos}, torch::ones({seg.size(0)}, dtype)).to(device);
  b.p_max = set.p_max.index_select(0, ids).to(dtype).to(device);
  return b;
}

torch::Tensor scale_to_budget(const torch::Tensor& raw, const Batch& b, PowerScaling mode) {
  const auto& g = b.graph;
  const auto power = torch::zeros({g.clusters}, raw.options()).index_add(0, g.seg, (raw * raw).sum(1));
  auto alpha = torch::sqrt(b.p_max / (power + 1e-12));
  if (mode == PowerScaling::Cap) alpha = torch::clamp_max(alpha, 1.0);
  return raw * alpha.index_select(0, g.seg).unsqueeze(1);
}

torch::Tensor cluster_sum_rates(const torch::Tensor& w, const Batch& b) {
  const auto L = b.gr.size(2);
  const auto wr = to_padded(w.narrow(1, 0, L), b.graph, 0.0);  // [C, K, L], column j = w_j
  const auto wi = to_padded(w.narrow(1, L, L), b.graph, 0.0);
  // M(k, j) = g_k w_j with g_k = row k of G (complex, no conjugation).
  const auto mr = torch::bmm(b.gr, wr.transpose(1, 2)) - torch::bmm(b.gi, wi.transpose(1, 2));
  const auto mi = torch::bmm(b.gr, wi.transpose(1, 2)) + torch::bmm(b.gi, wr.transpose(1, 2));
  const auto p = mr * mr + mi * mi;                                // [C, K, K]
  const auto eye = torch::eye(p.size(1), p.options());
  const auto signal = torch::diagonal(p, 0, 1, 2);                // [C, K]
  const auto interference = (p * (1 - eye)).sum(2);               // summed without the signal term
  const auto rate = torch::log2(1 + signal / (interference + 1)) * b.mask;  // noise power 1
  return rate.sum(1);
}

}  // namespace skyloop::nn
