#include <gtest/gtest.h>

#include "skyloop/channel/rates.hpp"
#include "skyloop/experiments/builtin.hpp"
#include "test_util.hpp"

using namespace skyloop;

// Every registered beamformer meets eq:power_constraint on random clusters of every size,
// including K_n > L, and with full scaling spends exactly the budget. This binary is LibTorch-free
// (the classical and GA beamformers); the learned ones are checked the same way in
// Learned.ShippedModelsMeetTheBudgetOnRandomClusters.
TEST(PowerBudget, EveryBeamformerOnRandomClusters) {
  std::vector<std::string> names;
  for (const auto& [name, desc] : builtin_beamformers().list()) names.push_back(name);
  test::expect_budget_on_random_clusters(builtin_beamformers(), names);
}

TEST(PowerBudget, OtherAntennaCountsAndBudgets) {
  for (int L : {1, 2, 8}) {
    Config cfg;
    cfg.channel.antennas = L;
    cfg.channel.p_max_dbm = 45;
    cfg.ga.generations = 5;
    cfg.ga.population = 10;
    for (const auto& [name, desc] : builtin_beamformers().list()) {
      if (name == "gnn" || name == "deepsets" || name == "mspointnet" || name == "ignn") continue;  // shipped for L = 4 only
      const auto bf = builtin_beamformers().create(name, cfg);
      for (const auto& c : test::clusters_of_size(cfg, 3, 3, 7 + L)) {
        const MatrixXcd W = bf->design(c);
        EXPECT_LE(W.squaredNorm(), c.p_max * (1 + 1e-9)) << name << " L=" << L;
        EXPECT_TRUE(W.allFinite()) << name;
      }
    }
  }
}

TEST(PowerBudget, ScaleToBudget) {
  MatrixXcd W = MatrixXcd::Constant(2, 2, cdouble(1, 1));  // power 8
  EXPECT_NEAR(scale_to_budget(W, 2.0, PowerScaling::Full).squaredNorm(), 2.0, 1e-12);
  EXPECT_NEAR(scale_to_budget(W, 2.0, PowerScaling::Cap).squaredNorm(), 2.0, 1e-12);
  EXPECT_NEAR(scale_to_budget(W, 20.0, PowerScaling::Full).squaredNorm(), 20.0, 1e-12);
  EXPECT_NEAR(scale_to_budget(W, 20.0, PowerScaling::Cap).squaredNorm(), 8.0, 1e-12);  // never scales up
  EXPECT_EQ(scale_to_budget(MatrixXcd::Zero(2, 2), 1.0, PowerScaling::Full).squaredNorm(), 0.0);
}

TEST(PowerBudget, CheckerRejectsViolations) {
  const auto bf = builtin_beamformers().create("mrt", Config{});
  Cluster c;
  c.G = MatrixXcd::Ones(2, 4);
  c.p_max = 1.0;
  EXPECT_THROW(check_beamformer_output(*bf, c, MatrixXcd::Ones(4, 2)), std::runtime_error);  // power 8
  EXPECT_THROW(check_beamformer_output(*bf, c, MatrixXcd::Zero(4, 3)), std::runtime_error);  // shape
  EXPECT_NO_THROW(check_beamformer_output(*bf, c, MatrixXcd::Constant(4, 2, 0.25)));
}

TEST(Batch, DesignBatchEqualsOneByOneForAnyThreadCount) {
  Config cfg;
  cfg.wmmse.init = WmmseInit::Random;
  const auto bf = builtin_beamformers().create("wmmse", cfg);
  const auto clusters = test::clusters_of_size(cfg, 4, 16, 3);
  const auto one = bf->design_batch(clusters, 1);
  const auto two = bf->design_batch(clusters, 2);
  for (std::size_t i = 0; i < clusters.size(); ++i) {
    EXPECT_EQ(one[i], bf->design(clusters[i]));
    EXPECT_EQ(two[i], one[i]);
  }
}

// The corners of the allowed ranges: budget and noise 60 dB apart either way, and the extremes
// (-30 dBm budget under 30 dBm noise; 80 dBm over -200 dBm). Every classical beamformer stays on
// the budget to rounding (1e-9 relative, of P_max itself, whatever its scale) and returns finite
// values (a probe found ZF-SEL 1% over a 1 uW budget under 30 dBm noise: cancellation in the
// water level).
TEST(PowerBudget, ExtremeBudgetsAndNoise) {
  for (const auto& [p_dbm, noise_dbm] : std::vector<std::pair<double, double>>{{-30, 30}, {-30, -200}, {80, -200}, {80, 30}}) {
    Config cfg;
    cfg.channel.p_max_dbm = p_dbm;
    cfg.channel.noise_dbm = noise_dbm;
    for (const char* name : {"mrt", "zf", "zfsel", "zfgain", "rzf", "wmmse"}) {
      const auto bf = builtin_beamformers().create(name, cfg);
      for (int k = 1; k <= 6; ++k)
        for (const auto& c : test::clusters_of_size(cfg, k, 3, 200 + k)) {
          const MatrixXcd W = bf->design(c);
          EXPECT_NO_THROW(check_beamformer_output(*bf, c, W)) << name << " P " << p_dbm << " noise " << noise_dbm;
          EXPECT_NEAR(W.squaredNorm(), c.p_max, 1e-9 * c.p_max) << name << " P " << p_dbm << " noise " << noise_dbm;
        }
    }
  }
}
