#include "skyloop/env/rate_oracle.hpp"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <limits>
#include <stdexcept>

#include "skyloop/channel/network.hpp"
#include "skyloop/channel/rates.hpp"
#include "skyloop/core/error.hpp"
#include "skyloop/core/parallel.hpp"
#include "skyloop/core/rng.hpp"

namespace skyloop {

std::size_t RateOracle::KeyHash::operator()(const Key& k) const {
  std::uint64_t h = hash_bytes(&k.x, sizeof k.x);
  h = hash_bytes(&k.y, sizeof k.y, h);
  h = hash_bytes(&k.z, sizeof k.z, h);
  h = hash_bytes(k.small.data(), sizeof(std::uint64_t) * k.small.size(), h);
  return static_cast<std::size_t>(k.big.empty() ? h : hash_bytes(k.big.data(), sizeof(std::uint64_t) * k.big.size(), h));
}

namespace {
std::atomic<std::uint64_t> next_oracle_id{1};
}  // namespace

RateOracle::RateOracle(const Config& cfg, std::shared_ptr<const Beamformer> beamformer, Positions users)
    : model_(cfg),
      beamformer_(std::move(beamformer)),
      users_(std::move(users)),
      threads_(resolve_threads(cfg.run.threads)),
      id_(next_oracle_id.fetch_add(1)) {
  if (users_.rows() > kMaxUsers)
    throw InputError("users: " + std::to_string(users_.rows()) + " users given: allowed at most " + std::to_string(kMaxUsers) +
                     " (scenario.users' bound)");
}

void RateOracle::keys_of(const Positions& uavs, std::vector<Key>& keys, std::vector<std::vector<int>>& members) const {
  const auto n = static_cast<std::size_t>(uavs.rows());
  // The last association this thread made, kept (storage and all): the position sets a batch asks
  // about come in runs that differ from the one before in one UAV (a UAV's moves, its radio map),
  // and a set that moves one UAV is reassociated for that UAV's distances alone.
  struct Last {
    std::uint64_t oracle = 0;
    Positions uavs;
    Association a;
    std::vector<double> nearest;
  };
  thread_local Last last;
  int moved = -1, changed = 2;  // UAVs moved since the last association (2: two or more, or none made)
  if (last.oracle == id_ && last.uavs.rows() == uavs.rows()) {
    changed = 0;
    for (Eigen::Index u = 0; u < uavs.rows() && changed < 2; ++u)
      if (!(uavs(u, 0) == last.uavs(u, 0) && uavs(u, 1) == last.uavs(u, 1) &&
            model_.altitude_of(uavs, u) == model_.altitude_of(last.uavs, u)))
        ++changed, moved = static_cast<int>(u);
  }
  if (changed == 1) model_.reassociate(uavs, users_, moved, last.a, last.nearest);
  else if (changed > 1) model_.associate(uavs, users_, last.a, &last.nearest);
  last.oracle = id_;
  last.uavs = uavs;
  const Association& a = last.a;
  keys.resize(n);  // each key's mask storage is kept and cleared: no allocation per call
  const std::size_t words = (static_cast<std::size_t>(users_.rows()) + 63) / 64;
  for (std::size_t i = 0; i < n; ++i) {
    Key& key = keys[i];
    const auto row = static_cast<Eigen::Index>(i);
    key.x = uavs(row, 0), key.y = uavs(row, 1), key.z = model_.altitude_of(uavs, row);
    key.small.fill(0);
    if (words > key.small.size()) key.big.assign(words, 0);
    else key.big.clear();
    std::uint64_t* mask = words > key.small.size() ? key.big.data() : key.small.data();
    for (int k : a.users[i]) mask[static_cast<std::size_t>(k) / 64] |= std::uint64_t{1} << (k % 64);
  }
  members.resize(n);
  for (std::size_t i = 0; i < n; ++i) members[i].assign(a.users[i].begin(), a.users[i].end());
}

std::size_t RateOracle::JointHash::operator()(const std::vector<double>& k) const {
  return static_cast<std::size_t>(hash_bytes(k.data(), sizeof(double) * k.size()));
}

void RateOracle::joint_key(const Positions& uavs, std::vector<double>& key) const {
  key.resize(static_cast<std::size_t>(3 * uavs.rows()));
  for (Eigen::Index n = 0; n < uavs.rows(); ++n) {
    const auto i = static_cast<std::size_t>(3 * n);
    key[i] = uavs(n, 0), key[i + 1] = uavs(n, 1), key[i + 2] = model_.altitude_of(uavs, n);
  }
}

std::vector<double> RateOracle::joint_key(const Positions& uavs) const {
  std::vector<double> key;
  joint_key(uavs, key);
  return key;
}

namespace {
/// A memo entry's bytes besides its key's and value's heap arrays: the hash node, the key's
/// inline part, the value and the bucket (about; only the memo's bound reads it).
constexpr double kEntryBytes = 112.0;

double total_of(const std::vector<double>& per_uav) {
  double t = 0.0;
  for (double r : per_uav) t += r;  // fixed order: a hit sums the same doubles as the miss
  return t;
}
}  // namespace

/// One call of batch_sum_rates: every position set's clusters (or network) looked up in its
/// oracle's memo, the misses designed per beamformer in one batch each, the sums assembled.
class RateBatch {
 public:
  using Key = RateOracle::Key;
  RateBatch(const std::vector<RateOracle*>& oracles, const std::vector<const Positions*>& uavs) : oracles_(oracles), uavs_(uavs) {}
  std::vector<double> run();

 private:
  // Misses per beamformer. Per-cluster (orthogonal): (oracle, key) and its cluster. Joint
  // (shared): (oracle, joint key) and its network.
  // A miss holds its fast slots' clusters (or networks) at [first, first + slots); its rate is
  // their mean (channel.fast_slots; one slot without small-scale fading).
  struct Miss {
    RateOracle* oracle;
    Key key;
    std::size_t first = 0;
    int slots = 1;
  };
  struct JointMiss {
    RateOracle* oracle;
    std::vector<double> key;
    std::size_t first = 0;
    int slots = 1;
  };
  /// A memo past its bound starts afresh before the batch looks anything up (the batch reads back
  /// what it inserts, so never in the middle of one).
  void clear_full_memos();
  std::size_t group_of(const Beamformer* bf);
  /// Position set s under one band: its network, a hit or a miss.
  void add_network(std::size_t s, RateOracle& o);
  /// Position set s per cluster: each cluster's rate, a hit (also by the set before's same key) or a miss.
  void add_clusters(std::size_t s, RateOracle& o);
  /// Every group's misses designed in one batch, into the memos.
  void design();
  std::vector<double> assemble() const;
  static std::vector<Key>& scratch_keys(int which) {
    thread_local std::vector<Key> keys[2];  // reused storage: one association at a time
    return keys[which];
  }
  static std::vector<std::vector<int>>& scratch_members() {
    thread_local std::vector<std::vector<int>> members;
    return members;
  }

  const std::vector<RateOracle*>& oracles_;
  const std::vector<const Positions*>& uavs_;
  // One association at a time (reused storage); what R needs of it is kept flat: per position set
  // its clusters' rates in UAV order, a hit's value at once, a miss's looked up once computed.
  std::vector<Key>& keys_ = scratch_keys(0);
  std::vector<Key>& prev_keys_ = scratch_keys(1);
  std::vector<std::vector<int>>& members_ = scratch_members();
  // A set asked right after another of the same oracle (a UAV's moves, its radio map) mostly keeps
  // its clusters: a cluster whose key is the one before's takes that part's rate (or, while that
  // one is a miss, its value once computed: `aliases_`) without a memo lookup.
  const RateOracle* prev_oracle_ = nullptr;
  std::vector<std::ptrdiff_t> part_of_, prev_part_of_;  // per UAV of the set (and of the set before): its part, -1 none
  std::vector<std::pair<std::size_t, std::size_t>> aliases_;  // (part, the earlier part whose rate it takes)
  std::vector<std::size_t> parts_begin_;
  std::vector<double> part_rate_;        // the cluster's rate, or NaN until its miss is computed
  std::vector<std::size_t> part_later_;  // parts whose rate is a miss of this batch (with its key and oracle below)
  std::vector<Key> later_keys_;
  std::vector<RateOracle*> later_oracle_;
  std::vector<const Beamformer*> groups_;
  std::vector<std::vector<Miss>> misses_;
  std::vector<std::vector<Cluster>> clusters_;
  std::vector<std::vector<JointMiss>> joint_misses_;
  std::vector<std::vector<Network>> networks_;
  std::unordered_map<const RateOracle*, std::unordered_map<Key, char, RateOracle::KeyHash>> pending_;
  std::unordered_map<const RateOracle*, std::unordered_map<std::vector<double>, char, RateOracle::JointHash>> joint_pending_;
  std::vector<std::vector<double>> jkeys_;
};

void RateBatch::clear_full_memos() {
  for (RateOracle* o : oracles_)
    if (o->memo_bytes_ > o->memo_limit_) {
      o->cache_ = {};
      o->joint_cache_ = {};
      o->memo_bytes_ = 0;
    }
}

std::size_t RateBatch::group_of(const Beamformer* bf) {
  std::size_t g = 0;
  while (g < groups_.size() && groups_[g] != bf) ++g;
  if (g == groups_.size()) {
    groups_.push_back(bf);
    misses_.emplace_back(), clusters_.emplace_back(), joint_misses_.emplace_back(), networks_.emplace_back();
  }
  return g;
}

void RateBatch::add_network(std::size_t s, RateOracle& o) {
  prev_oracle_ = nullptr;
  jkeys_[s] = o.joint_key(*uavs_[s]);
  auto& mine = joint_pending_[&o];
  if (o.joint_cache_.count(jkeys_[s]) || mine.count(jkeys_[s])) {
    ++o.stats_.hits;
    return;
  }
  ++o.stats_.misses;
  mine.emplace(jkeys_[s], 1);
  const std::size_t g = group_of(o.beamformer_.get());
  const int slots = o.model_.fast_slots();
  joint_misses_[g].push_back({&o, jkeys_[s], networks_[g].size(), slots});
  for (int slot = 0; slot < slots; ++slot) networks_[g].push_back(o.model_.network(*uavs_[s], o.users_, members_, slot));
}

void RateBatch::add_clusters(std::size_t s, RateOracle& o) {
  std::unordered_map<Key, char, RateOracle::KeyHash>* mine = nullptr;
  const bool chained = prev_oracle_ == &o && prev_keys_.size() == keys_.size();
  part_of_.assign(keys_.size(), -1);
  for (std::size_t i = 0; i < keys_.size(); ++i) {
    if (members_[i].empty()) continue;
    const Key& key = keys_[i];
    const std::size_t part = part_rate_.size();
    part_of_[i] = static_cast<std::ptrdiff_t>(part);
    if (chained && prev_part_of_[i] >= 0 && key == prev_keys_[i]) {
      const auto q = static_cast<std::size_t>(prev_part_of_[i]);
      const double known = part_rate_[q];
      part_rate_.push_back(known);
      if (std::isnan(known)) aliases_.emplace_back(part, q);
      ++o.stats_.hits;  // a memo hit, or a miss this batch computes: a hit as below
      continue;
    }
    part_rate_.push_back(std::numeric_limits<double>::quiet_NaN());
    if (const auto it = o.cache_.find(key); it != o.cache_.end()) {
      ++o.stats_.hits;
      part_rate_.back() = it->second;
      continue;
    }
    part_later_.push_back(part);
    later_keys_.push_back(key);
    later_oracle_.push_back(&o);
    if (!mine) mine = &pending_[&o];
    if (mine->count(key)) {
      ++o.stats_.hits;
      continue;
    }
    ++o.stats_.misses;
    mine->emplace(key, 1);
    const std::size_t g = group_of(o.beamformer_.get());
    const int slots = o.model_.fast_slots();
    misses_[g].push_back({&o, key, clusters_[g].size(), slots});
    for (int slot = 0; slot < slots; ++slot)
      clusters_[g].push_back(o.model_.make_cluster(static_cast<int>(i), key.x, key.y, key.z, o.users_, members_[i],
                                                   static_cast<int>(uavs_[s]->rows()), slot));
  }
  prev_oracle_ = &o;
  std::swap(keys_, prev_keys_);
  std::swap(part_of_, prev_part_of_);
}

void RateBatch::design() {
  int threads = 1;
  if (!in_parallel_for())
    for (const RateOracle* o : oracles_) threads = std::max(threads, o->threads_);
  for (std::size_t g = 0; g < groups_.size(); ++g) {
    if (!clusters_[g].empty()) {
      const auto W = groups_[g]->design_batch(clusters_[g], threads);
      for (const Miss& miss : misses_[g]) {
        double rate = 0;
        for (int slot = 0; slot < miss.slots; ++slot) {
          const std::size_t c = miss.first + static_cast<std::size_t>(slot);
          check_beamformer_output(*groups_[g], clusters_[g][c], W[c]);
          rate += sum_rate(clusters_[g][c], W[c]);
        }
        miss.oracle->cache_.emplace(miss.key, miss.slots == 1 ? rate : rate / miss.slots);
        miss.oracle->memo_bytes_ += kEntryBytes + 8.0 * static_cast<double>(miss.key.big.size());
      }
    }
    if (!networks_[g].empty()) {
      const auto W = groups_[g]->design_networks(networks_[g], threads);
      for (const JointMiss& miss : joint_misses_[g]) {
        std::vector<double> per_uav;
        for (int slot = 0; slot < miss.slots; ++slot) {
          const std::size_t n = miss.first + static_cast<std::size_t>(slot);
          const Network& net = networks_[g][n];
          check_network_output(*groups_[g], net, W[n]);
          const auto rates = network_cluster_rates(net, W[n]);
          per_uav.resize(static_cast<std::size_t>(net.uavs), 0.0);
          for (std::size_t c = 0; c < net.clusters.size(); ++c) per_uav[static_cast<std::size_t>(net.clusters[c].uav)] += rates[c];
        }
        if (miss.slots > 1)
          for (double& r : per_uav) r /= miss.slots;
        miss.oracle->memo_bytes_ += kEntryBytes + 8.0 * static_cast<double>(miss.key.size() + per_uav.size());
        miss.oracle->joint_cache_.emplace(miss.key, std::move(per_uav));
      }
    }
  }
}

std::vector<double> RateBatch::assemble() const {
  std::vector<double> out(oracles_.size(), 0.0);
  for (std::size_t s = 0; s < oracles_.size(); ++s) {
    if (oracles_[s]->joint()) {
      out[s] = total_of(oracles_[s]->joint_cache_.at(jkeys_[s]));
      continue;
    }
    for (std::size_t p = parts_begin_[s]; p < parts_begin_[s + 1]; ++p) out[s] += part_rate_[p];  // in UAV order, as total_of
  }
  return out;
}

std::vector<double> RateBatch::run() {
  const std::size_t m = oracles_.size();
  parts_begin_.assign(m + 1, 0);
  jkeys_.resize(m);
  clear_full_memos();
  for (std::size_t s = 0; s < m; ++s) {
    RateOracle& o = *oracles_[s];
    o.keys_of(*uavs_[s], keys_, members_);
    parts_begin_[s] = part_rate_.size();
    if (o.joint()) add_network(s, o);
    else add_clusters(s, o);
  }
  parts_begin_[m] = part_rate_.size();
  design();
  for (std::size_t j = 0; j < part_later_.size(); ++j) part_rate_[part_later_[j]] = later_oracle_[j]->cache_.at(later_keys_[j]);
  for (const auto& [part, q] : aliases_) part_rate_[part] = part_rate_[q];  // in order: q is filled before
  return assemble();
}

std::vector<double> batch_sum_rates(const std::vector<RateOracle*>& oracles, const std::vector<const Positions*>& uavs) {
  return RateBatch(oracles, uavs).run();
}

std::vector<double> RateOracle::sum_rates(const std::vector<Positions>& all) {
  // In chunks whose channels (users x antennas x fast slots per position set, at most: a user is
  // in one cluster) stay within 2^24 complex entries (256 MiB): a planner's batch over every cell
  // and slot with thousands of users would otherwise hold them all at once. The rates are the
  // same: a chunk's misses are in the memo for the next.
  const double per_set = static_cast<double>(std::max<Eigen::Index>(users_.rows(), 1)) * model_.antennas() * model_.fast_slots();
  const std::size_t chunk = static_cast<std::size_t>(std::max(1.0, std::floor(16777216.0 / per_set)));
  std::vector<double> out;
  out.reserve(all.size());
  for (std::size_t first = 0; first < all.size(); first += chunk) {
    const std::size_t last = std::min(all.size(), first + chunk);
    std::vector<RateOracle*> self(last - first, this);
    std::vector<const Positions*> ptrs;
    for (std::size_t i = first; i < last; ++i) ptrs.push_back(&all[i]);
    const auto r = batch_sum_rates(self, ptrs);
    out.insert(out.end(), r.begin(), r.end());
  }
  return out;
}

std::optional<double> RateOracle::cached_sum_rate(const Positions& uavs, double* miss_cost) {
  // No allocation of the batch machinery: the common case once the memo is warm.
  if (joint()) {
    thread_local std::vector<double> key;
    joint_key(uavs, key);
    const auto it = joint_cache_.find(key);
    if (it == joint_cache_.end()) {
      if (miss_cost) *miss_cost = static_cast<double>(users_.rows() + uavs.rows());
      return std::nullopt;
    }
    ++stats_.hits;
    return total_of(it->second);
  }
  thread_local std::vector<Key> keys;
  thread_local std::vector<std::vector<int>> members;
  keys_of(uavs, keys, members);
  double total = 0.0;  // in UAV order, as batch_sum_rates sums a position set's clusters
  double cost = 0.0;
  for (std::size_t i = 0; i < keys.size(); ++i) {
    if (members[i].empty()) continue;
    const auto it = cache_.find(keys[i]);
    if (it == cache_.end()) {
      if (!miss_cost) return std::nullopt;
      cost += static_cast<double>(members[i].size() + 1);
      continue;
    }
    total += it->second;
  }
  if (cost > 0) {
    *miss_cost = cost;
    return std::nullopt;
  }
  for (std::size_t i = 0; i < keys.size(); ++i) stats_.hits += !members[i].empty();
  return total;
}

double RateOracle::sum_rate(const Positions& uavs) {
  if (const auto known = cached_sum_rate(uavs)) return *known;
  return sum_rates({uavs}).front();
}

std::vector<double> RateOracle::cluster_rates(const Positions& uavs) {
  sum_rates({uavs});  // fills the cache
  if (joint()) return joint_cache_.at(joint_key(uavs));
  std::vector<Key> keys;
  std::vector<std::vector<int>> members;
  keys_of(uavs, keys, members);
  std::vector<double> out(keys.size(), 0.0);
  for (std::size_t i = 0; i < keys.size(); ++i)
    if (!members[i].empty()) out[i] = cache_.at(keys[i]);
  return out;
}

}  // namespace skyloop
