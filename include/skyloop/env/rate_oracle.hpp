#pragma once
// R[t] for UAV positions over fixed users: association, then each cluster's sum rate from a
// beamformer. With fixed users and the deterministic LoS channel, the result is a pure function
// of the positions, memoised exactly: a hit returns the identical doubles the beamformer produced
// on the miss.
//   orthogonal spectra: a cluster's sum rate depends only on its UAV's position and its user set,
//     so it is cached per cluster on that key (shared across joint positions);
//   shared spectrum: every cluster's rate depends on every UAV (interference, coordinated
//     beamformers), so the per-UAV rates are cached on the joint key (all N positions), and
//     misses go to the beamformer as whole networks (design_networks).
#include <array>
#include <cstdint>
#include <memory>
#include <optional>
#include <unordered_map>
#include <vector>

#include "skyloop/beamforming/beamformer.hpp"
#include "skyloop/channel/system_model.hpp"

namespace skyloop {

struct OracleStats {
  std::uint64_t hits = 0, misses = 0;
  double hit_rate() const { return hits + misses ? static_cast<double>(hits) / static_cast<double>(hits + misses) : 0.0; }
};

class RateOracle {
 public:
  /// `users` [K x 2] (any K). The beamformer is shared, not copied. A batch's misses go to the
  /// beamformer on cfg.run.threads threads (one when called from inside a parallel_for); each
  /// cluster's design is independent of the others, so the rates do not depend on the count.
  RateOracle(const Config& cfg, std::shared_ptr<const Beamformer> beamformer, Positions users);

  /// Network sum rate R for UAV positions [N x 2].
  double sum_rate(const Positions& uavs);
  /// R from the memo alone: the doubles sum_rate() returns when every rate it needs is memoised
  /// (counted as hits); std::nullopt, with nothing counted or computed, when one is missing. Then,
  /// when `miss_cost` is given, it receives the work the misses will take: per cluster missing,
  /// its users plus one (the learned beamformers' passes go over user rows and a row per cluster);
  /// per position set missing, under a joint oracle, its users plus its UAVs.
  std::optional<double> cached_sum_rate(const Positions& uavs, double* miss_cost = nullptr);
  /// R for many position sets; all cache misses go to the beamformer in one batched call.
  std::vector<double> sum_rates(const std::vector<Positions>& uavs);
  /// Per-UAV cluster sum rates for one position set (UAVs with no users get 0).
  std::vector<double> cluster_rates(const Positions& uavs);

  const Positions& users() const { return users_; }
  const Beamformer& beamformer() const { return *beamformer_; }
  std::shared_ptr<const Beamformer> beamformer_ptr() const { return beamformer_; }
  const SystemModel& model() const { return model_; }
  const OracleStats& stats() const { return stats_; }
  std::size_t cache_size() const { return cache_.size() + joint_cache_.size(); }
  /// The memo's bound: once what it holds passes this many bytes (estimated per entry), the next
  /// batch starts it afresh. A value is the same doubles computed again (every cluster's design is
  /// its own), so the bound costs time, never a different rate; it keeps a long run whose positions
  /// never repeat (continuous mobility over fixed users) from growing without end. Default 1 GiB.
  void set_memo_limit(double bytes) { memo_limit_ = bytes; }
  double memo_bytes() const { return memo_bytes_; }
  /// The threads a batch of this oracle's misses may use (cfg.run.threads, resolved).
  int threads() const { return threads_; }
  /// Under one band (channel.spectrum = shared) the rates come from whole networks
  /// (design_networks). A learned network model serves a call's networks in padded batches, so
  /// a network's beams may differ in their last bits with the other networks of its call: a
  /// caller that wants the same numbers on any thread count keeps each batch's company fixed.
  bool joint() const { return model_.spectrum() == Spectrum::Shared; }

 private:
  friend class RateBatch;  // batch_sum_rates' work (rate_oracle.cpp)
  /// A cluster: its UAV's position (with its altitude) and its user set as a bit mask (inline up
  /// to 256 users).
  struct Key {
    double x = 0, y = 0, z = 0;
    std::array<std::uint64_t, 4> small{};
    std::vector<std::uint64_t> big;  // the mask when K > 256 (small stays zero)
    bool operator==(const Key& o) const { return x == o.x && y == o.y && z == o.z && small == o.small && big == o.big; }
  };
  struct KeyHash {
    std::size_t operator()(const Key& k) const;
  };
  struct JointHash {
    std::size_t operator()(const std::vector<double>& k) const;
  };
  /// The joint memo's key: every UAV's (x, y, z).
  std::vector<double> joint_key(const Positions& uavs) const;
  void joint_key(const Positions& uavs, std::vector<double>& key) const;
  /// Association of `uavs`: for each UAV its key; fills `members`.
  void keys_of(const Positions& uavs, std::vector<Key>& keys, std::vector<std::vector<int>>& members) const;

  SystemModel model_;
  std::shared_ptr<const Beamformer> beamformer_;
  Positions users_;
  std::unordered_map<Key, double, KeyHash> cache_;
  std::unordered_map<std::vector<double>, std::vector<double>, JointHash> joint_cache_;  // per-UAV rates
  OracleStats stats_;
  double memo_bytes_ = 0, memo_limit_ = 1073741824.0;  // what the memo holds (estimated), its bound
  int threads_ = 1;  // cfg.run.threads, resolved
  std::uint64_t id_;  // this model and these users (copies keep it): keys_of's last association is theirs
};

/// R for (oracle i, positions i) pairs, e.g. the M environments of a vector environment (each with
/// its own users): the cache misses of all of them go to the beamformer in one batched call
/// (grouped by beamformer when the oracles use different ones).
std::vector<double> batch_sum_rates(const std::vector<RateOracle*>& oracles, const std::vector<const Positions*>& uavs);

}  // namespace skyloop
