#pragma once
// Helpers shared by the unit tests.
#include <functional>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "skyloop/beamforming/registry.hpp"
#include "skyloop/channel/rates.hpp"
#include "skyloop/channel/system_model.hpp"
#include "skyloop/core/error.hpp"
#include "skyloop/beamforming/linear.hpp"
#include "skyloop/core/rng.hpp"
#include "skyloop/env/uav_env.hpp"

namespace skyloop::test {

/// An environment of cfg with ZF behind R[t] and cfg.scenario.users users drawn from `seed`.
inline std::unique_ptr<UavEnv> zf_env(const Config& cfg, std::uint64_t seed = 1) {
  auto oracle = std::make_shared<RateOracle>(cfg, std::make_shared<ZfBeamformer>(), make_users(cfg, cfg.scenario.users, seed));
  return std::make_unique<UavEnv>(cfg, oracle);
}

/// The message of the InputError `f` throws ("" if it throws none).
inline std::string error_of(const std::function<void()>& f) {
  try {
    f();
  } catch (const InputError& e) {
    return e.what();
  }
  return "";
}

/// Clusters of K users (from random snapshots) served by one UAV at the area's centre, so every
/// user in range is in the cluster; only clusters of exactly `k` users are kept.
inline std::vector<Cluster> clusters_of_size(const Config& cfg, int k, int count, std::uint64_t seed) {
  SystemModel model(cfg);
  std::vector<Cluster> out;
  Rng rng(seed);
  while (static_cast<int>(out.size()) < count) {
    Positions users(k, 2);
    for (int i = 0; i < k; ++i) {
      // Uniform in the disc of horizontal radius sqrt(R_c^2 - H^2) around the centre.
      const double r_max = std::sqrt(cfg.channel.coverage_radius_m * cfg.channel.coverage_radius_m -
                                     cfg.scenario.altitude_m * cfg.scenario.altitude_m);
      const double r = r_max * std::sqrt(rng.uniform()), phi = 2 * M_PI * rng.uniform();
      users(i, 0) = 100 + r * std::cos(phi);
      users(i, 1) = 100 + r * std::sin(phi);
    }
    std::vector<int> idx(k);
    for (int i = 0; i < k; ++i) idx[i] = i;
    out.push_back(model.make_cluster(0, 100, 100, users, idx));
  }
  return out;
}

/// eq:power_constraint for each of `names` in `registry` on random clusters of every size 1..8,
/// including K_n > L, under both scalings: the output has the cluster's shape, stays within the
/// budget, gives a positive sum rate, and with full scaling spends exactly the budget.
inline void expect_budget_on_random_clusters(const BeamformerRegistry& registry, const std::vector<std::string>& names) {
  for (const char* scaling : {"full", "cap"}) {
    Config cfg;
    cfg.ga.generations = 20;
    cfg.ga.population = 16;
    cfg.wmmse.restarts = 1;
    cfg.beamforming.power_scaling = std::string(scaling) == "cap" ? PowerScaling::Cap : PowerScaling::Full;
    for (const std::string& name : names) {
      const auto bf = registry.create(name, cfg);
      for (int k = 1; k <= 8; ++k)
        for (const auto& c : clusters_of_size(cfg, k, 3, 100 + k)) {
          const MatrixXcd W = bf->design(c);
          ASSERT_EQ(W.rows(), 4);
          ASSERT_EQ(W.cols(), k);
          EXPECT_NO_THROW(check_beamformer_output(*bf, c, W)) << name;
          EXPECT_LE(W.squaredNorm(), c.p_max * (1 + 1e-9)) << name << " K_n=" << k;
          EXPECT_GT(sum_rate(c, W), 0.0) << name;
          if (std::string(scaling) == "full") {
            EXPECT_NEAR(W.squaredNorm(), c.p_max, 1e-9 * c.p_max) << name;
          }
        }
    }
  }
}

/// A tiny learned-beamformer training config (d = 16, 2 layers, 40 snapshots, one epoch, one
/// thread): "gnn", "deepsets", "mspointnet", "ignn" (under the shared spectrum), or
/// "<model>+structured" for the structured readout.
inline Config tiny_nn_config(const std::string& model) {
  // "model[+readout][+log]", e.g. "gnn+structured+log".
  Config cfg;
  std::size_t plus = model.find('+');
  cfg.nn.model = model.substr(0, plus);
  while (plus != std::string::npos) {
    const std::size_t next = model.find('+', plus + 1);
    const std::string part = model.substr(plus + 1, next == std::string::npos ? std::string::npos : next - plus - 1);
    if (part == "log") cfg.nn.features = Features::Log;
    else cfg.nn.readout = parse_choice<Readout>("nn.readout", part);
    plus = next;
  }
  if (cfg.nn.model == "ignn") cfg.channel.spectrum = Spectrum::Shared;  // the network model learns interference
  cfg.nn.hidden = 16;
  cfg.nn.layers = 2;
  cfg.nn.epochs = 1;
  cfg.nn.train_samples = 40;
  cfg.nn.val_samples = 10;
  cfg.nn.test_samples = 10;
  cfg.nn.batch_samples = 8;
  cfg.run.threads = 1;
  return cfg;
}

}  // namespace skyloop::test
