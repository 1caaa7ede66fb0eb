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

std::size_t TrainData::samples() const {
  return network ? static_cast<std::size_t>(nets.size()) : clusters.sample_clusters.size();
}

double TrainData::channel_rms() const { return network ? nn::channel_rms(nets) : nn::channel_rms(clusters); }

TrainData make_data(const Config& cfg, Split split, std::size_t samples, bool network) {
  TrainData d;
  d.network = network;
  if (!network) {
    d.clusters = make_split(cfg, split, samples);
    return d;
  }
  const SystemModel model(cfg);
  const auto seed = derive_seed(cfg.nn.data_seed, static_cast<std::uint64_t>(split));
  const auto snaps = random_snapshots(model, cfg.scenario.uavs, cfg.scenario.users, seed, samples);
  std::vector<Network> nets;
  nets.reserve(snaps.size());
  for (const auto& s : snaps) nets.push_back(model.network(s));
  d.nets = make_net_set(nets, cfg.channel.antennas);
  return d;
}

namespace {
torch::Tensor ids_of(const std::vector<std::size_t>& order, std::size_t first, std::size_t last) {
  std::vector<int64_t> ids(order.begin() + static_cast<std::ptrdiff_t>(first), order.begin() + static_cast<std::ptrdiff_t>(last));
  return torch::tensor(ids, torch::kInt64);
}
}  // namespace

torch::Tensor batch_loss(BeamNetImpl& model, const TrainData& d, const std::vector<std::size_t>& order, std::size_t first,
                         std::size_t last, double feature_scale, PowerScaling mode, const torch::Device& device,
                         int64_t* units) {
  if (d.network) {
    const auto ids = ids_of(order, first, last);
    *units = ids.size(0);
    const NetBatch b = make_net_batch(d.nets, ids, feature_scale, device);
    const auto w = scale_to_budget(model.forward_network(b), b, mode);
    return -network_sum_rates(w, b).mean();
  }
  const auto ids = cluster_ids(d.clusters, order, first, last);
  *units = ids.size(0);
  if (ids.size(0) == 0) return torch::zeros({});
  const Batch b = make_batch(d.clusters, ids, feature_scale, device);
  const auto w = scale_to_budget(model.forward(b.x, b.graph), b, mode);
  return -cluster_sum_rates(w, b).mean();  // eq:loss_function
}

double evaluate_sum_rate(BeamNetImpl& model, const TrainData& d, double feature_scale, PowerScaling mode,
                         const torch::Device& device, std::size_t chunk) {
  if (!d.network) return evaluate_sum_rate(model, d.clusters, feature_scale, mode, device, chunk);
  torch::NoGradGuard no_grad;
  const std::size_t samples = d.samples();
  std::vector<std::size_t> order(samples);
  std::iota(order.begin(), order.end(), 0);
  double total = 0.0;
  for (std::size_t first = 0; first < samples; first += chunk) {
    const NetBatch b = make_net_batch(d.nets, ids_of(order, first, std::min(samples, first + chunk)), feature_scale, device);
    total += network_sum_rates(scale_to_budget(model.forward_network(b), b, mode), b).sum().item<double>();
  }
  return samples ? total / static_cast<double>(samples) : 0.0;
}

}  // namespace skyloop::nn
