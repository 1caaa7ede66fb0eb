#include <gtest/gtest.h>

#include "skyloop/channel/system_model.hpp"

using namespace skyloop;

TEST(Channel, DistanceIs3D) {
  const SystemModel m{Config{}};
  EXPECT_DOUBLE_EQ(m.distance(100, 100, 100, 100), 100.0);         // straight below, H = 100
  EXPECT_DOUBLE_EQ(m.distance(0, 0, 30, 40), std::sqrt(2500.0 + 10000.0));
}

TEST(Channel, PathLossHandValues) {
  const SystemModel m{Config{}};
  // beta0 = -20 dB = 0.01 at d0 = 1 m; beta = 0.01 (1/d)^2.
  EXPECT_NEAR(m.path_loss(1.0), 0.01, 1e-15);
  EXPECT_NEAR(m.path_loss(100.0), 1e-6, 1e-18);              // -60 dB
  EXPECT_NEAR(m.path_loss(100.0 * std::sqrt(2.0)), 0.5e-6, 1e-18);
  EXPECT_NEAR(10 * std::log10(m.path_loss(150.0)), -20 - 20 * std::log10(150.0), 1e-9);
  // Path loss falls with distance (the printed exponent -2 would make it grow).
  EXPECT_GT(m.path_loss(100.0), m.path_loss(120.0));
}

TEST(Channel, SteeringVectorHandValues) {
  const SystemModel m{Config{}};  // d_a / lambda = 0.5, L = 4
  // cos(theta) = 1 (user straight below): phase step pi -> [1, -1, 1, -1].
  VectorXcd a = m.steering(1.0);
  ASSERT_EQ(a.size(), 4);
  for (int l = 0; l < 4; ++l) {
    EXPECT_NEAR(a[l].real(), l % 2 ? -1.0 : 1.0, 1e-12);
    EXPECT_NEAR(a[l].imag(), 0.0, 1e-12);
  }
  // cos(theta) = 0.5: phase step pi/2 -> [1, j, -1, -j].
  a = m.steering(0.5);
  const cdouble expect[4] = {{1, 0}, {0, 1}, {-1, 0}, {0, -1}};
  for (int l = 0; l < 4; ++l) EXPECT_NEAR(std::abs(a[l] - expect[l]), 0.0, 1e-12);
}

TEST(Channel, ChannelIsScaledSteeringVector) {
  const SystemModel m{Config{}};
  const double d = m.distance(50, 60, 120, 90);
  const VectorXcd h = m.channel(50, 60, 120, 90);
  EXPECT_NEAR(h.squaredNorm(), 4 * m.path_loss(d), 1e-18);  // ||h||^2 = L beta
  const VectorXcd a = m.steering(100.0 / d);
  EXPECT_NEAR((h - std::sqrt(m.path_loss(d)) * a).norm(), 0.0, 1e-15);
}

TEST(Channel, ClusterRowsAreConjugateChannels) {
  const SystemModel m{Config{}};
  Positions users(2, 2);
  users << 90, 100, 130, 70;
  const Cluster c = m.make_cluster(0, 100, 100, users, {0, 1});
  ASSERT_EQ(c.size(), 2);
  ASSERT_EQ(c.antennas(), 4);
  EXPECT_NEAR((c.G.row(1).transpose() - m.channel(100, 100, 130, 70).conjugate()).norm(), 0.0, 1e-18);
  EXPECT_DOUBLE_EQ(c.p_max, 1.0);
  EXPECT_DOUBLE_EQ(c.noise, 1e-12);
}

TEST(Channel, RandomSnapshotsAreSeededAndInArea) {
  const SystemModel m{Config{}};
  const Snapshot a = m.random_snapshot(3, 12, 99), b = m.random_snapshot(3, 12, 99), c = m.random_snapshot(3, 12, 100);
  EXPECT_EQ(a.users, b.users);
  EXPECT_EQ(a.uavs, b.uavs);
  EXPECT_NE(a.users, c.users);
  EXPECT_TRUE((a.users.array() >= 0).all() && (a.users.array() <= 200).all());
  EXPECT_TRUE((a.uavs.array() >= 0).all() && (a.uavs.array() <= 200).all());
}

TEST(Channel, BatchSnapshotsMatchSingleOnes) {
  const SystemModel m{Config{}};
  const auto snaps = random_snapshots(m, 3, 12, 5, 10);
  std::vector<int> owner;
  const auto clusters = clusters_of(m, snaps, &owner);
  ASSERT_EQ(owner.size(), clusters.size());
  std::size_t idx = 0;
  for (std::size_t i = 0; i < snaps.size(); ++i)
    for (const auto& c : m.clusters(snaps[i])) {
      ASSERT_LT(idx, clusters.size());
      EXPECT_EQ(owner[idx], static_cast<int>(i));
      EXPECT_EQ(clusters[idx].G, c.G);
      ++idx;
    }
  EXPECT_EQ(idx, clusters.size());
}
