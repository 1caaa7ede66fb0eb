// Scenarios beyond the paper's size: the spatial-index association, generated layouts, hotspot
// users, the sequential greedy's masks, the compact state, and one-line refusals of bad sizes.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>

#include "skyloop/core/config_io.hpp"
#include "skyloop/core/error.hpp"
#include "skyloop/experiments/builtin.hpp"
#include "skyloop/planning/planners.hpp"

using namespace skyloop;

namespace {

/// The reference association: every UAV for every user, nearest (lowest index on ties) within R_c.
Association brute_force(const SystemModel& m, const Positions& uavs, const Positions& users) {
  Association a;
  a.serving.assign(static_cast<std::size_t>(users.rows()), -1);
  a.users.assign(static_cast<std::size_t>(uavs.rows()), {});
  for (Eigen::Index k = 0; k < users.rows(); ++k) {
    int best = -1;
    double best_d = std::numeric_limits<double>::infinity();
    for (Eigen::Index n = 0; n < uavs.rows(); ++n) {
      const double d = m.distance(uavs(n, 0), uavs(n, 1), users(k, 0), users(k, 1));
      if (d < best_d) best_d = d, best = static_cast<int>(n);
    }
    if (best >= 0 && best_d <= m.coverage()) {
      a.serving[static_cast<std::size_t>(k)] = best;
      a.users[static_cast<std::size_t>(best)].push_back(static_cast<int>(k));
    }
  }
  return a;
}

Config city(int uavs, int users, double side) {
  return resolve_config(std::nullopt, {"scenario.uavs=" + std::to_string(uavs), "scenario.users=" + std::to_string(users),
                                       "scenario.area_x_m=" + std::to_string(side), "scenario.area_y_m=" + std::to_string(side),
                                       "trajectory.layout=generated", "trajectory.t_max=" + std::to_string(int(side / 20) + 10)});
}

}  // namespace

TEST(Scale, SpatialIndexAssociationEqualsBruteForce) {
  for (const auto& [uavs, users, side] : {std::tuple{64, 4096, 2000.0}, std::tuple{16, 500, 300.0}, std::tuple{9, 300, 1000.0}}) {
    const Config cfg = city(uavs, users, side);
    const SystemModel model(cfg);
    for (std::uint64_t seed = 0; seed < 5; ++seed) {
      const Snapshot s = model.random_snapshot(uavs, users, seed);
      EXPECT_EQ(model.associate(s).users, brute_force(model, s.uavs, s.users).users) << uavs << " UAVs, seed " << seed;
    }
  }
  // Ties: UAVs on a lattice, users exactly between two of them; the lower index serves.
  Config cfg = city(16, 1, 400);
  const SystemModel model(cfg);
  Positions uavs(16, 2), users(40, 2);
  for (int i = 0; i < 16; ++i) uavs(i, 0) = 50.0 + 100.0 * (i % 4), uavs(i, 1) = 50.0 + 100.0 * (i / 4);
  for (int k = 0; k < 40; ++k) users(k, 0) = 100.0 + 100.0 * (k % 3), users(k, 1) = 50.0 + 7.5 * (k / 3);
  EXPECT_EQ(model.associate(uavs, users).serving, brute_force(model, uavs, users).serving);
}

// The rate oracle's runs of position sets that move one UAV (its moves, its radio map) update the
// association for that UAV alone (SystemModel::reassociate): the same association as a fresh one,
// over the grid path and the plain scan, with ties (UAVs and users on a lattice, a UAV moved onto
// another's place) and users left unserved.
TEST(Scale, ReassociatingOneMovedUavIsAssociating) {
  for (const auto& [uavs, users, side] : {std::tuple{16, 400, 1000.0}, std::tuple{64, 1600, 2000.0}, std::tuple{3, 40, 200.0}}) {
    const Config cfg = city(uavs, users, side);
    const SystemModel model(cfg);
    Rng rng(static_cast<std::uint64_t>(uavs));
    Snapshot s = model.random_snapshot(uavs, users, 7);
    for (Eigen::Index k = 0; k < s.users.rows() / 4; ++k)  // a quarter of the users on the 20 m lattice: ties
      s.users(k, 0) = 20.0 * std::round(s.users(k, 0) / 20.0), s.users(k, 1) = 20.0 * std::round(s.users(k, 1) / 20.0);
    Association a;
    std::vector<double> nearest;
    model.associate(s.uavs, s.users, a, &nearest);
    int unserved = 0;
    for (int step = 0; step < 300; ++step) {
      const int n = static_cast<int>(rng.below(static_cast<std::uint64_t>(uavs)));
      switch (rng.below(3)) {
        case 0:  // one lattice move
          s.uavs(n, rng.below(2)) += rng.below(2) ? 20.0 : -20.0;
          break;
        case 1:  // onto another UAV's place
          s.uavs.row(n) = s.uavs.row(static_cast<Eigen::Index>(rng.below(static_cast<std::uint64_t>(uavs))));
          break;
        default:  // anywhere on the lattice
          s.uavs(n, 0) = 20.0 * static_cast<double>(rng.below(static_cast<std::uint64_t>(side / 20) + 1));
          s.uavs(n, 1) = 20.0 * static_cast<double>(rng.below(static_cast<std::uint64_t>(side / 20) + 1));
      }
      model.reassociate(s.uavs, s.users, n, a, nearest);
      Association fresh;
      std::vector<double> fresh_nearest;
      model.associate(s.uavs, s.users, fresh, &fresh_nearest);
      ASSERT_EQ(a.serving, fresh.serving) << uavs << " UAVs, step " << step;
      ASSERT_EQ(a.users, fresh.users) << uavs << " UAVs, step " << step;
      ASSERT_EQ(nearest, fresh_nearest) << uavs << " UAVs, step " << step;
      ASSERT_EQ(a.users, brute_force(model, s.uavs, s.users).users);
      unserved += static_cast<int>(std::count(a.serving.begin(), a.serving.end(), -1));
    }
    if (uavs != 3) {
      EXPECT_GT(unserved, 0) << uavs << " UAVs";  // R_c leaves some users out
    }
  }
  const SystemModel model(city(3, 4, 200));
  Association a;
  std::vector<double> nearest;
  EXPECT_THROW(model.reassociate(Positions::Zero(3, 2), Positions::Zero(4, 2), 0, a, nearest), std::invalid_argument);
}

TEST(Scale, GeneratedLayoutIsSeededSeparatedAndReachable) {
  const Config a = city(64, 100, 2000), b = city(64, 100, 2000);
  ASSERT_EQ(a.trajectory.starts.size(), 64u);
  EXPECT_EQ(a.trajectory.starts, b.trajectory.starts);
  EXPECT_EQ(a.trajectory.destinations, b.trajectory.destinations);
  Config c = a;
  c.trajectory.layout_seed = 2;
  finalise(c);
  EXPECT_NE(c.trajectory.starts, a.trajectory.starts);
  const auto& t = a.trajectory;
  for (std::size_t i = 0; i < t.starts.size(); ++i) {
    const double moves = (std::abs(t.starts[i].x - t.destinations[i].x) + std::abs(t.starts[i].y - t.destinations[i].y)) / t.d_fly_m;
    EXPECT_GE(moves, 1);
    EXPECT_LE(moves, t.t_max - 1);
    for (std::size_t j = 0; j < i; ++j) {
      EXPECT_GE(std::hypot(t.starts[i].x - t.starts[j].x, t.starts[i].y - t.starts[j].y), t.d_min_m);
      EXPECT_GE(std::hypot(t.destinations[i].x - t.destinations[j].x, t.destinations[i].y - t.destinations[j].y), t.d_min_m);
    }
  }
}

TEST(Scale, HotspotUsersGatherAroundFewCentres) {
  Config cfg = city(3, 2000, 1000);
  const SystemModel uniform(cfg);
  cfg.scenario.user_layout = UserLayout::Hotspot;
  cfg.scenario.hotspots = 3;
  cfg.scenario.hotspot_radius_m = 30;
  const SystemModel hot(cfg);
  // Share of the 100 x 100 cells of a 10 x 10 grid that hold any user: all of them when uniform,
  // a few when 80% of the users are within ~3 std of 3 centres.
  auto occupied = [](const Positions& p) {
    std::vector<int> cell(100, 0);
    for (Eigen::Index k = 0; k < p.rows(); ++k) cell[std::min(9, int(p(k, 0) / 100)) * 10 + std::min(9, int(p(k, 1) / 100))] = 1;
    int n = 0;
    for (int c : cell) n += c;
    return n;
  };
  EXPECT_EQ(occupied(uniform.random_snapshot(3, 2000, 1).users), 100);
  const Positions h = hot.random_snapshot(3, 2000, 1).users;
  for (Eigen::Index k = 0; k < h.rows(); ++k) {
    EXPECT_GE(h(k, 0), 0);
    EXPECT_LE(h(k, 0), 1000);
  }
  // 20% uniform users (400) reach most cells, so count dense cells instead: >= 40 users.
  std::vector<int> count(100, 0);
  for (Eigen::Index k = 0; k < h.rows(); ++k) ++count[std::min(9, int(h(k, 0) / 100)) * 10 + std::min(9, int(h(k, 1) / 100))];
  int dense = 0;
  for (int c : count) dense += c >= 40;
  EXPECT_LE(dense, 12);
  EXPECT_GE(dense, 1);
}

// The sequential greedy never takes a masked action: every chosen move keeps its UAV in the area
// and its destination reachable (so every UAV is home by T_max and no boundary event occurs), and
// it never chooses a move within D_min of a UAV already placed when another move avoids it.
TEST(Scale, SequentialGreedyRespectsItsMasks) {
  for (std::uint64_t layout = 1; layout <= 3; ++layout) {
    Config cfg = city(16, 300, 400);
    cfg.trajectory.layout_seed = layout;
    cfg.trajectory.t_max = 24;
    finalise(cfg);
    cfg.env.oracle = "zfsel";
    auto oracle = std::make_shared<RateOracle>(cfg, builtin_beamformers().create("zfsel", cfg), make_users(cfg, 300, layout));
    UavEnv env(cfg, oracle);
    SequentialGreedyPlanner planner;
    env.reset();
    planner.reset(env);
    while (!env.done()) {
      const auto a = planner.act(env);
      for (int n = 0; n < env.uavs(); ++n) ASSERT_TRUE(env.feasible(n, a[static_cast<std::size_t>(n)])) << "UAV " << n;
      env.step(a);
    }
    for (int n = 0; n < env.uavs(); ++n) EXPECT_TRUE(env.arrived(n)) << "layout " << layout << " UAV " << n;
    const auto rec = run_episode(env, planner);
    EXPECT_TRUE(rec.success);
    EXPECT_EQ(rec.boundary, 0);
  }
  // Two UAVs side by side, both heading right, D_min larger than D_fly: the second to choose
  // must not move into the first's new cell when staying or another move avoids it.
  Config cfg = resolve_config(std::nullopt, {"trajectory.starts=[[20.0, 100.0], [60.0, 100.0]]",
                                             "trajectory.destinations=[[100.0, 100.0], [140.0, 100.0]]",
                                             "trajectory.d_min_m=25", "env.oracle=mrt"});
  auto oracle = std::make_shared<RateOracle>(cfg, builtin_beamformers().create("mrt", cfg), make_users(cfg, 12, 3));
  UavEnv env(cfg, oracle);
  SequentialGreedyPlanner planner;
  const auto rec = run_episode(env, planner);
  EXPECT_TRUE(rec.success);
  EXPECT_EQ(rec.collisions, 0);
}

TEST(Scale, JointGreedyRefusesLargeFleetsInOneLine) {
  Config cfg = city(16, 50, 600);
  auto oracle = std::make_shared<RateOracle>(cfg, builtin_beamformers().create("mrt", cfg), make_users(cfg, 50, 1));
  UavEnv env(cfg, oracle);
  GreedyPlanner greedy;
  try {
    run_episode(env, greedy);
    FAIL() << "greedy accepted 16 UAVs";
  } catch (const InputError& e) {
    const std::string what = e.what();
    EXPECT_EQ(what.find('\n'), std::string::npos);
    EXPECT_NE(what.find("seqgreedy"), std::string::npos) << what;
    EXPECT_NE(what.find("16"), std::string::npos) << what;
  }
}

TEST(Scale, BadSizesAreRefusedInOneLine) {
  for (const std::vector<std::string>& sets :
       {std::vector<std::string>{"scenario.uavs=65"}, {"scenario.users=4097"}, {"scenario.uavs=0"},
        {"scenario.hotspots=0"}, {"scenario.user_layout=grid"}, {"env.state=tiny"},
        {"trajectory.layout=generated", "scenario.uavs=64"},  // 200 m: 81 lattice points
        {"trajectory.layout=generated", "scenario.uavs=40", "scenario.area_x_m=2000", "scenario.area_y_m=2000",
         "trajectory.t_max=1"}}) {
    try {
      resolve_config(std::nullopt, sets);
      FAIL() << "accepted " << sets.front();
    } catch (const InputError& e) {
      const std::string what = e.what();
      EXPECT_EQ(what.find('\n'), std::string::npos) << what;
      EXPECT_NE(what.find("allowed"), std::string::npos) << what;
    }
  }
}

TEST(Scale, CompactStateIsSizedIndependentlyOfNAndK) {
  for (const auto& [uavs, users] : {std::pair{3, 12}, std::pair{16, 400}, std::pair{64, 4096}}) {
    Config cfg = city(uavs, users, 2000);
    cfg.env.state = StateKind::Compact;
    auto oracle = std::make_shared<RateOracle>(cfg, builtin_beamformers().create("mrt", cfg), make_users(cfg, users, 1));
    UavEnv env(cfg, oracle);
    EXPECT_EQ(env.state_size(), 3 * kStateGrid * kStateGrid + 2);
    EXPECT_EQ(env.agent_context_size(), 2 * kNeighbours);
    const auto s = env.state();
    const int G2 = kStateGrid * kStateGrid;
    double user_share = 0, uav_share = 0, dest_share = 0;
    for (int i = 0; i < G2; ++i) user_share += s[i], uav_share += s[G2 + i], dest_share += s[2 * G2 + i];
    EXPECT_NEAR(user_share, 1.0, 1e-4);
    EXPECT_NEAR(uav_share, 1.0, 1e-4);
    EXPECT_NEAR(dest_share, 1.0, 1e-4);  // nobody home at the start
    EXPECT_EQ(static_cast<int>(env.agent_state(0).size()), env.agent_state_size());
  }
}
