#pragma once
// `skyloop snapshot`: explicit positions in, every per-user quantity out. The inspection tool.
#include <optional>
#include <string>
#include <vector>

#include "skyloop/beamforming/beamformer.hpp"
#include "skyloop/channel/channel_model.hpp"
#include "skyloop/channel/network.hpp"

namespace skyloop {

/// Reads a scenario file (TOML): `uavs = [[x, y], ...]` and `users = [[x, y], ...]` in metres,
/// both non-empty and inside the configured area. Any other key, or a malformed file, throws
/// InputError naming the file and the key.
Snapshot load_scenario_file(const std::string& path, const Config& cfg);

struct UserReport {
  int index = 0;
  double x = 0, y = 0;
  int serving_uav = -1;          // -1: no UAV within R_c
  double distance_m = 0;         // to the serving UAV (or the nearest if unserved)
  double path_loss_db = 0;       // mean path loss of the link to that UAV (dB, positive; -10 log10 beta without shadowing)
  std::vector<LinkState> links;  // the large-scale state of the link from every UAV m = 0..N-1
  VectorXcd channel;             // h_{n,k} [L], empty if unserved
  VectorXcd beamformer;          // w_k [L], empty if unserved
  double sinr = 0, rate = 0;     // 0 if unserved
  UserPowers powers;             // received signal, intra- and inter-cluster interference, noise (W); 0 if unserved
  std::vector<VectorXcd> cross;  // h_{m,k} [L] from every UAV m = 0..N-1 (the serving one included)
};

struct ClusterReport {
  int uav = 0;
  double x = 0, y = 0;
  std::vector<int> users;
  double power_w = 0, sum_rate = 0;
};

struct SnapshotReport {
  std::string method;
  std::string spectrum;
  std::vector<UserReport> users;
  std::vector<ClusterReport> uavs;  // one per UAV, empty clusters included
  double total_sum_rate = 0;
};

SnapshotReport evaluate_snapshot(const Config& cfg, const Snapshot& s, const Beamformer& bf);
std::string snapshot_json(const SnapshotReport& r, const Config& cfg);
std::string snapshot_text(const SnapshotReport& r);

}  // namespace skyloop
