#include <gtest/gtest.h>

#include "skyloop/beamforming/linear.hpp"
#include "skyloop/channel/rates.hpp"
#include "test_util.hpp"

using namespace skyloop;

TEST(Zf, NullsInterUserInterferenceWhenKnAtMostL) {
  const Config cfg;
  for (int k = 1; k <= 4; ++k)
    for (const auto& c : test::clusters_of_size(cfg, k, 30, 10 + k)) {
      for (bool wf : {true, false}) {
        const MatrixXcd W = zf(c, wf);
        const MatrixXcd M = c.G * W;  // M(k, j) = h_k^H w_j
        const double scale = M.cwiseAbs().maxCoeff();
        for (int i = 0; i < k; ++i)
          for (int j = 0; j < k; ++j)
            if (i != j) {
              EXPECT_LT(std::abs(M(i, j)), 1e-6 * scale) << "K_n=" << k;
            }
      }
    }
}

TEST(Zf, WaterfillingIsAtLeastEqualPower) {
  const Config cfg;
  for (const auto& c : test::clusters_of_size(cfg, 3, 50, 3))
    EXPECT_GE(sum_rate(c, zf(c, true)), sum_rate(c, zf(c, false)) - 1e-9);
}

TEST(Zf, MoreUsersThanAntennasStillMeetsBudget) {
  const Config cfg;
  for (const auto& c : test::clusters_of_size(cfg, 7, 20, 4)) {
    const MatrixXcd W = zf(c);
    EXPECT_NEAR(W.squaredNorm(), c.p_max, 1e-9 * c.p_max);
    EXPECT_TRUE(W.allFinite());
    EXPECT_GT(sum_rate(c, W), 0.0);
  }
}

TEST(Waterfill, MeetsBudgetAndKkt) {
  VectorXd floor(4);
  floor << 0.1, 0.5, 2.0, 10.0;
  const VectorXd p = waterfill(floor, 1.0);
  EXPECT_NEAR(p.sum(), 1.0, 1e-12);
  // Active channels share one water level; inactive ones have floor above it.
  const double level = p[0] + floor[0];
  for (int k = 0; k < 4; ++k) {
    if (p[k] > 0) EXPECT_NEAR(p[k] + floor[k], level, 1e-12);
    else EXPECT_GE(floor[k], level - 1e-12);
  }
  EXPECT_EQ(p[3], 0.0);
}

TEST(Mrt, SingleUserIsOptimal) {
  const Config cfg;
  for (const auto& c : test::clusters_of_size(cfg, 1, 10, 5)) {
    const double snr = c.p_max * c.G.row(0).squaredNorm() / c.noise;
    EXPECT_NEAR(sum_rate(c, mrt(c)), std::log2(1 + snr), 1e-9);
    EXPECT_NEAR(sum_rate(c, zf(c)), std::log2(1 + snr), 1e-9);
    EXPECT_NEAR(sum_rate(c, rzf(c)), std::log2(1 + snr), 1e-6);
  }
}

TEST(ZfSelect, SelectsAtMostLUsersAndBeatsPlainZfOnAverage) {
  const Config cfg;
  double sel = 0, plain = 0;
  for (const auto& c : test::clusters_of_size(cfg, 6, 40, 6)) {
    std::vector<int> chosen;
    const MatrixXcd W = zf_select(c, &chosen);
    EXPECT_GE(chosen.size(), 1u);
    EXPECT_LE(chosen.size(), 4u);
    for (int k = 0; k < 6; ++k)
      if (std::find(chosen.begin(), chosen.end(), k) == chosen.end()) {
        EXPECT_EQ(W.col(k).norm(), 0.0);
      }
    EXPECT_NEAR(W.squaredNorm(), c.p_max, 1e-9);
    sel += sum_rate(c, W);
    plain += sum_rate(c, zf(c));
  }
  EXPECT_GT(sel, plain);
}
