#include <gtest/gtest.h>

#include "skyloop/beamforming/ga.hpp"
#include "skyloop/beamforming/linear.hpp"
#include "skyloop/channel/rates.hpp"
#include "skyloop/core/error.hpp"
#include "../unit/test_util.hpp"

using namespace skyloop;

TEST(Ga, SameSeedSameResultOtherSeedOtherResult) {
  const auto clusters = test::clusters_of_size(Config{}, 4, 3, 1);
  GaBeamformer a(GaOptions{GaAlgorithm::Sga, 20, 50, 7}), b(GaOptions{GaAlgorithm::Sga, 20, 50, 7}), c(GaOptions{GaAlgorithm::Sga, 20, 50, 8});
  for (const auto& cl : clusters) {
    const MatrixXcd wa = a.design(cl);
    EXPECT_EQ(wa, b.design(cl));
    EXPECT_NE(wa, c.design(cl));
  }
}

TEST(Ga, ResultDoesNotDependOnCallOrder) {
  const auto clusters = test::clusters_of_size(Config{}, 3, 3, 2);
  GaBeamformer ga(GaOptions{GaAlgorithm::Sga, 16, 20, 3});
  const MatrixXcd last_first = ga.design(clusters[2]);
  ga.design(clusters[0]);
  EXPECT_EQ(ga.design(clusters[2]), last_first);
  const auto batch = ga.design_batch(clusters, 2);
  EXPECT_EQ(batch[2], last_first);
}

TEST(Ga, SearchImprovesWithGenerations) {
  const auto clusters = test::clusters_of_size(Config{}, 3, 8, 4);
  GaBeamformer short_run(GaOptions{GaAlgorithm::Sga, 50, 2, 1}), long_run(GaOptions{GaAlgorithm::Sga, 50, 300, 1});
  double s = 0, l = 0, m = 0;
  for (const auto& c : clusters) {
    s += sum_rate(c, short_run.design(c));
    l += sum_rate(c, long_run.design(c));
    m += sum_rate(c, mrt(c));
  }
  EXPECT_GT(l, s);
  EXPECT_GT(l, m);
}

TEST(Ga, EveryPagmoAlgorithmRunsAndMeetsTheBudget) {
  const auto clusters = test::clusters_of_size(Config{}, 3, 2, 5);
  for (const auto& a : choices<GaAlgorithm>()) {
    GaBeamformer ga(GaOptions{a.value, 20, 10, 1});
    for (const auto& c : clusters) {
      const MatrixXcd W = ga.design(c);
      EXPECT_NEAR(W.squaredNorm(), c.p_max, 1e-9) << a.name;
      EXPECT_GT(sum_rate(c, W), 0.0) << a.name;
    }
  }
}

TEST(Ga, CapScalingNeverExceedsBudget) {
  const auto clusters = test::clusters_of_size(Config{}, 4, 3, 6);
  GaBeamformer ga(GaOptions{GaAlgorithm::Sga, 16, 10, 1, PowerScaling::Cap});
  for (const auto& c : clusters) EXPECT_LE(ga.design(c).squaredNorm(), c.p_max * (1 + 1e-12));
}

TEST(Ga, BadOptionsAreRejected) {
  BeamformerRegistry reg;
  register_ga_beamformers(reg);
  EXPECT_THROW(reg.create("ga=nsga2", Config{}), InputError);  // an optimiser pagmo's table lacks
  EXPECT_THROW(GaBeamformer(GaOptions{GaAlgorithm::Sga, 2, 10, 1}), InputError);
}
