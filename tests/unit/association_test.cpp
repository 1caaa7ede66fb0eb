#include <gtest/gtest.h>

#include <set>

#include "skyloop/channel/system_model.hpp"

using namespace skyloop;

TEST(Association, PartitionOfCoveredUsersWithinRc) {
  const Config cfg;
  const SystemModel m(cfg);
  for (std::uint64_t seed = 0; seed < 200; ++seed) {
    const Snapshot s = m.random_snapshot(3, 12, seed);
    const Association a = m.associate(s);
    std::set<int> seen;
    for (int n = 0; n < 3; ++n)
      for (int k : a.users[n]) {
        EXPECT_TRUE(seen.insert(k).second) << "user " << k << " in two clusters";
        EXPECT_EQ(a.serving[k], n);
        const double d = m.distance(s.uavs(n, 0), s.uavs(n, 1), s.users(k, 0), s.users(k, 1));
        EXPECT_LE(d, cfg.channel.coverage_radius_m);
        for (int j = 0; j < 3; ++j)  // nearest UAV
          EXPECT_LE(d, m.distance(s.uavs(j, 0), s.uavs(j, 1), s.users(k, 0), s.users(k, 1)));
      }
    for (int k = 0; k < 12; ++k) {
      if (a.serving[k] >= 0) {
        EXPECT_TRUE(seen.count(k));
        continue;
      }
      EXPECT_FALSE(seen.count(k));
      for (int n = 0; n < 3; ++n)  // unserved: no UAV within R_c
        EXPECT_GT(m.distance(s.uavs(n, 0), s.uavs(n, 1), s.users(k, 0), s.users(k, 1)), cfg.channel.coverage_radius_m);
    }
  }
}

TEST(Association, HandMadeCases) {
  const SystemModel m{Config{}};
  Snapshot s;
  s.uavs.resize(2, 2);
  s.uavs << 0, 0, 200, 0;
  s.users.resize(4, 2);
  s.users << 10, 0,    // near UAV 0
      190, 0,          // near UAV 1
      100, 0,          // equidistant (d = sqrt(100^2 + 100^2) = 141.4 <= 150): lowest index wins
      100, 200;        // d = sqrt(100^2 + 200^2 + 100^2) > 150 from both: unserved
  const Association a = m.associate(s);
  EXPECT_EQ(a.serving, (std::vector<int>{0, 1, 0, -1}));
  EXPECT_EQ(a.users[0], (std::vector<int>{0, 2}));
  EXPECT_EQ(a.users[1], (std::vector<int>{1}));
  const auto clusters = m.clusters(s);
  ASSERT_EQ(clusters.size(), 2u);
  EXPECT_EQ(clusters[0].size(), 2);
  EXPECT_EQ(clusters[1].uav, 1);
}

TEST(Association, RcIsOnThe3DDistance) {
  Config cfg;
  cfg.channel.coverage_radius_m = 120;  // horizontal reach sqrt(120^2 - 100^2) = 66.3 m
  const SystemModel m(cfg);
  Snapshot s;
  s.uavs.resize(1, 2);
  s.uavs << 100, 100;
  s.users.resize(2, 2);
  s.users << 166, 100, 167, 100;
  EXPECT_EQ(m.associate(s).serving, (std::vector<int>{0, -1}));
}

TEST(Association, EmptyClustersAreSkipped) {
  const SystemModel m{Config{}};
  Snapshot s;
  s.uavs.resize(2, 2);
  s.uavs << 0, 0, 200, 200;
  s.users.resize(1, 2);
  s.users << 10, 10;
  const auto clusters = m.clusters(s);
  ASSERT_EQ(clusters.size(), 1u);
  EXPECT_EQ(clusters[0].uav, 0);
}
