#pragma once
#include <cstdlib>
#include <vector>

#include "skyloop/channel/system_model.hpp"
#include "skyloop/core/rng.hpp"

namespace skyloop::bench {

/// Iterations of a benchmark that fixes its own count: `n`, or 1 under the ctest smoke run
/// (SKYLOOP_BENCH_SMOKE set: each benchmark once, to show it still runs, not to time it).
inline int iterations(int n) { return std::getenv("SKYLOOP_BENCH_SMOKE") ? 1 : n; }

/// `count` clusters of exactly `k` users, cut from seeded random paper-setting snapshots with
/// the UAV at the centre, so their geometry is the one the beamformers meet in practice.
inline std::vector<Cluster> clusters(int k, int count = 64, std::uint64_t seed = 1) {
  const Config cfg;
  const SystemModel model(cfg);
  std::vector<Cluster> out;
  for (std::uint64_t s = 0; static_cast<int>(out.size()) < count; ++s) {
    Snapshot snap = model.random_snapshot(1, 4 * k, derive_seed(seed, s));
    snap.uavs << 100, 100;
    const Association a = model.associate(snap);
    if (static_cast<int>(a.users[0].size()) < k) continue;
    std::vector<int> users(a.users[0].begin(), a.users[0].begin() + k);
    out.push_back(model.make_cluster(0, 100, 100, snap.users, users));
  }
  return out;
}

}  // namespace skyloop::bench
