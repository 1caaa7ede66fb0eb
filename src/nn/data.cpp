#include "data.hpp"

#include <numeric>

#include "skyloop/core/rng.hpp"

namespace skyloop::nn {

ClusterSet make_split(const Config& cfg, Split split, std::size_t samples) {
  const SystemModel model(cfg);
  const auto seed = derive_seed(cfg.nn.data_seed, static_cast<std::uint64_t>(split));
  const auto snaps = random_snapshots(model, cfg.scenario.uavs, cfg.scenario.users, seed, samples);
  std::vector<int> owner;
  const auto clusters = clusters_of(model, snaps, &owner);
  ClusterSet set = make_cluster_set(clusters, owner, samples);
  set.antennas = cfg.channel.antennas;
  return set;
}

torch::Tensor cluster_ids(const ClusterSet& set, const std::vector<std::size_t>& order, std::size_t first,
                          std::size_t last) {
  std::vector<int64_t> ids;
  for (std::size_t i = first; i < last; ++i) {
    const auto& c = set.sample_clusters[order[i]];
    ids.insert(ids.end(), c.begin(), c.end());
  }
  return torch::tensor(ids, torch::kInt64);
}

double evaluate_sum_rate(BeamNetImpl& model, const ClusterSet& set, double feature_scale, PowerScaling mode,
                         const torch::Device& device, std::size_t chunk) {
  torch::NoGradGuard no_grad;
  const std::size_t samples = set.sample_clusters.size();
  std::vector<std::size_t> order(samples);
  std::iota(order.begin(), order.end(), 0);
  double total = 0.0;
  for (std::size_t first = 0; first < samples; first += chunk) {
    const auto ids = cluster_ids(set, order, first, std::min(samples, first + chunk));
    if (ids.size(0) == 0) continue;
    const Batch b = make_batch(set, ids, feature_scale, device);
    const auto w = scale_to_budget(model.forward(b.x, b.graph), b, mode);
    total += cluster_sum_rates(w, b).sum().item<double>();
  }
  return samples ? total / static_cast<double>(samples) : 0.0;
}

}  // namespace skyloop::nn
