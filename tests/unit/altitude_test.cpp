// Altitude as a decision: the channel read at each UAV's altitude (skyloop/channel/channel_model.hpp),
// the climb's energy (skyloop/env/energy.hpp) and trajectory.mobility = "grid-3d"
// (src/env/dynamics/grid3d.cpp) under the DP, brute force, the planners and the shield.
#include <gtest/gtest.h>

#include <cmath>
#include <set>

#include "skyloop/beamforming/linear.hpp"
#include "skyloop/channel/channel_model.hpp"
#include "skyloop/channel/system_model.hpp"
#include "skyloop/core/config_io.hpp"
#include "skyloop/core/error.hpp"
#include "skyloop/env/dynamics.hpp"
#include "skyloop/env/energy.hpp"
#include "skyloop/core/rng.hpp"
#include "skyloop/planning/planners.hpp"
#include "skyloop/planning/registry.hpp"
#include "skyloop/planning/safety.hpp"

#include "test_util.hpp"

using namespace skyloop;
using skyloop::test::error_of;

namespace {

std::unique_ptr<UavEnv> make_env(const Config& cfg, std::uint64_t seed = 1) { return skyloop::test::zf_env(cfg, seed); }

/// grid-3d on the paper's defaults: levels 60, 80, ..., 140 m, missions at H = 100 m.
Config grid3d() {
  Config c;
  c.trajectory.mobility = "grid-3d";
  validate(c);
  return c;
}

/// A tiny grid-3d instance the brute force can enumerate: 2 UAVs on a 40 m square (3 x 3 points),
/// three levels (80, 100, 120 m), one move home each and T_max = 3 (two slots: a climb or a
/// descent there and back).
Config tiny(const std::string& pathloss) {
  Config c = grid3d();
  c.scenario.area_x_m = c.scenario.area_y_m = 40;
  c.scenario.users = 4;
  c.trajectory.starts = {{0, 0}, {40, 40}};
  c.trajectory.destinations = {{20, 0}, {20, 40}};
  c.trajectory.d_min_m = 15;
  c.trajectory.t_max = 3;
  c.trajectory.altitude_min_m = 80, c.trajectory.altitude_max_m = 120;
  c.channel.pathloss = pathloss;
  validate(c);
  return c;
}

}  // namespace

// ---- the channel at a UAV's altitude ----------------------------------------------------------
// Al-Hourani, Kandeepan and Lardner (IEEE WCL 2014), urban (a = 9.61, b = 0.16): P_LoS =
// 1 / (1 + a exp(-b (theta - a))) at elevation theta in degrees. A user 100 m from the UAV's
// ground point, evaluated by hand outside skyloop: at 100 m altitude theta = 45 deg, P_LoS =
// 0.967692; at 60 m theta = 30.963757 deg, P_LoS = 0.760204; at 140 m theta = 54.462322 deg,
// P_LoS = 0.992707. TR 36.777 UMa-AV (Table B-1) at d_2D = 300 m: h = 60 m gives d1 = 117.9496,
// p1 = 3846.05, P_LoS = 0.954465; h = 80 m gives 0.972530; above 100 m P_LoS = 1.
TEST(Altitude, TheChannelReadsEachUavsAltitude) {
  Config c;
  c.channel.pathloss = "al-hourani";
  c.channel.environment = "urban";
  const ChannelModel al(c);
  struct Point {
    double z, elevation, p_los;
  };
  for (const Point& p : {Point{100, 45.0, 0.9676919}, Point{60, 30.9637565, 0.7602037}, Point{140, 54.4623222, 0.9927073}}) {
    const LinkState s = al.link(0, 0, p.z, 100, 0);
    EXPECT_NEAR(s.geometry.elevation_deg, p.elevation, 1e-6) << p.z;
    EXPECT_NEAR(s.geometry.distance_m, std::hypot(100.0, p.z), 1e-9) << p.z;
    EXPECT_EQ(s.geometry.height_m, p.z);
    EXPECT_NEAR(s.p_los, p.p_los, 1e-6) << p.z;
  }
  c.channel.pathloss = "3gpp-uma-av";
  const ChannelModel uma(c);
  EXPECT_NEAR(uma.link(0, 0, 60, 300, 0).p_los, 0.9544646, 1e-6);
  EXPECT_NEAR(uma.link(0, 0, 80, 300, 0).p_los, 0.9725295, 1e-6);
  EXPECT_EQ(uma.link(0, 0, 120, 300, 0).p_los, 1.0);
  // At the scenario's altitude the altitude-free overloads are the same link, bit for bit.
  for (const ChannelModel* m : {&al, &uma}) {
    EXPECT_EQ(m->link(10, 20, 100, 90, 50).gain, m->link(10, 20, 90, 50).gain);
    EXPECT_EQ(m->channel_at(10, 20, 100, 90, 50), m->channel(10, 20, 90, 50));
  }
  // The paper's channel at altitude z: beta0 (d0 / d)^2 with d the 3-D distance, steered at (z - h_u) / d.
  const Config paper;
  const ChannelModel free_space(paper);
  const double d = std::hypot(30.0, 60.0);
  EXPECT_NEAR(std::norm(free_space.channel_at(0, 0, 60, 30, 0)[0]), db_to_linear(paper.channel.beta0_db) / (d * d), 1e-18);
  EXPECT_EQ(free_space.channel_at(0, 0, 60, 30, 0), std::sqrt(free_space.free_space_gain(d)) * free_space.steering(60 / d));
  // A system model reads the third column of the UAV positions: association and clusters by 3-D distance.
  const SystemModel model(paper);
  Positions uavs(2, 3), users(1, 2);
  uavs << 0, 0, 140, 60, 0, 60;
  users << 20, 0;  // 20 m from UAV 0's ground point at 140 m, 40 m from UAV 1's at 60 m
  EXPECT_EQ(model.associate(uavs, users).serving[0], 1);
  uavs(1, 2) = 140;
  EXPECT_EQ(model.associate(uavs, users).serving[0], 0);
  EXPECT_EQ(model.distance(uavs, 1, 20, 0), std::hypot(40.0, 140.0));
}

// ---- climbing costs m g dz --------------------------------------------------------------------
// energy.mass_kg = 2.04 kg (Zeng, Xu and Zhang, Table I: W = 20 N), g = 9.80665 m/s^2: a climb of
// 20 m costs 2.04 x 9.80665 x 20 = 400.11132 J on top of the level flight (P(10) = 126.0337 W for
// 2 s at D_fly / delta_t = 10 m/s); a descent costs the level flight only.
TEST(Altitude, AClimbCostsItsPotentialEnergy) {
  const Config c = grid3d();
  const PropulsionModel p(c.energy);
  EXPECT_NEAR(p.climb_energy(20), 400.11132, 1e-5);
  EXPECT_EQ(p.climb_energy(-20), 0.0);
  EXPECT_EQ(p.climb_energy(0), 0.0);
  auto env = make_env(c);
  const ActionSpec& a = env->dynamics().actions();
  ASSERT_EQ(env->actions(), 15);
  EXPECT_EQ(env->hover(), kStay);
  EXPECT_STREQ(a.name(kUp), "UP");
  EXPECT_STREQ(a.name(kGridActions + kUp), "UP+CLIMB");
  EXPECT_STREQ(a.name(2 * kGridActions + kStay), "STAY+DESCEND");
  // UAV 0 at (20, 20, 100) climbs while flying up; UAV 1 descends in place; UAV 2 holds.
  const StepInfo info = env->step({kGridActions + kUp, 2 * kGridActions + kStay, kStay});
  EXPECT_EQ(env->positions()(0, 1), 40.0);
  EXPECT_EQ(env->altitude(0), 120.0);
  EXPECT_EQ(env->altitude(1), 80.0);
  EXPECT_EQ(env->altitude(2), 100.0);
  const double level = p.slot_energy(10, 0, 2), hover = p.slot_energy(0, 0, 2);
  EXPECT_NEAR(env->energy_j(0), level + 400.11132, 1e-6);
  EXPECT_NEAR(env->energy_j(1), hover, 1e-9);
  EXPECT_NEAR(info.energy_j, level + 400.11132 + 2 * hover, 1e-6);
  // The altitude band is a boundary: a climb above altitude_max_m is cancelled and counted.
  env->step({kGridActions + kStay, kStay, kStay});
  EXPECT_EQ(env->altitude(0), 140.0);
  const StepInfo out = env->step({kGridActions + kStay, kStay, kStay});
  EXPECT_EQ(env->altitude(0), 140.0);
  EXPECT_EQ(out.boundary, 1);
  EXPECT_FALSE(env->feasible(0, kGridActions + kStay));
}

// ---- the exact optimum over the altitude levels -----------------------------------------------

TEST(Altitude, OptimumEqualsBruteForceOnTinyInstances) {
  for (const char* pathloss : {"free-space", "al-hourani", "3gpp-uma-av"})
    for (const char* objective : {"sum-rate", "energy-efficiency"})
      for (std::uint64_t seed : {1u, 2u}) {
        Config c = tiny(pathloss);
        c.env.objective = parse_choice<Objective>("env.objective", objective);
        auto env = make_env(c, seed);
        const OptimalPlan plan = solve_optimal(*env);
        const double brute = brute_force_optimum(*env);
        const double tol = 1e-9 * std::max(1.0, std::abs(brute));
        EXPECT_NEAR(plan.objective, brute, tol) << pathloss << " " << objective << " seed " << seed;
        OptimalPlanner optimal;
        const auto r = run_episode(*env, optimal);
        EXPECT_NEAR(r.objective, plan.objective, tol);
        EXPECT_TRUE(r.success);
        EXPECT_EQ(r.collisions + r.boundary, 0);
        // Holding the altitude is one of the choices: never below the fixed-altitude optimum.
        Config flat = c;
        flat.trajectory.mobility = "grid";
        validate(flat);
        auto fixed = make_env(flat, seed);
        EXPECT_GE(plan.objective, solve_optimal(*fixed).objective * (1 - 1e-12)) << pathloss << " " << objective;
      }
}

// Under free space the nearest link is the best: with every level open the optimum of the sum rate
// leaves H for the lowest level, and comes back to H to land.
TEST(Altitude, TheFreeSpaceOptimumFliesLow) {
  Config c = tiny("free-space");
  c.trajectory.t_max = 6;
  auto env = make_env(c, 1);
  OptimalPlanner optimal;
  const auto r = run_episode(*env, optimal);
  ASSERT_TRUE(r.success);
  std::set<double> seen;
  for (const Positions& p : r.positions)
    for (int n = 0; n < 2; ++n) seen.insert(p(n, 2));
  EXPECT_TRUE(seen.count(80.0)) << "the optimum never flew below H";
  EXPECT_EQ(r.positions.back()(0, 2), 100.0);
  EXPECT_EQ(r.positions.back()(1, 2), 100.0);
}

// ---- every planner and the shield on grid-3d ---------------------------------------------------

TEST(Altitude, PlannersAndTheShieldFlyGrid3d) {
  Config c = grid3d();
  c.env.oracle = "zf";
  auto env = make_env(c, 3);
  for (const std::string name : {"random", "greedy", "seqgreedy", "bestknown"}) {
    auto planner = builtin_planners().create(name);
    const auto r = run_episode(*env, *planner);
    EXPECT_TRUE(r.success) << name;
    EXPECT_EQ(r.collisions, 0) << name;
    for (const Positions& p : r.positions)
      for (int n = 0; n < env->uavs(); ++n) {
        EXPECT_GE(p(n, 2), 60.0) << name;
        EXPECT_LE(p(n, 2), 140.0) << name;
      }
    EXPECT_TRUE(r.positions.back().isApprox(env->destinations())) << name;
  }
  // The shield over a random wish: every move allowed, every UAV home at H, no collision.
  SafetyOptions safety;
  Rng rng(5);
  env->reset();
  int collisions = 0;
  while (!env->done()) {
    const auto a = sequential_safe_actions(*env, safety, [&](int, ActionSet ok) {
      std::vector<int> moves;
      for (int k = 0; k < env->actions(); ++k)
        if (ok >> k & 1u) moves.push_back(k);
      return moves[rng.below(moves.size())];
    });
    collisions += env->step(a).collisions;
  }
  EXPECT_EQ(collisions, 0);
  EXPECT_TRUE(env->positions().isApprox(env->destinations()));
}

// Two UAVs at one ground point but different altitudes are D_min apart in 3-D: no collision.
TEST(Altitude, SeparationIsThreeDimensional) {
  Positions p(2, 3);
  p << 50, 50, 80, 50, 50, 120;
  EXPECT_EQ(UavEnv::separation(p, 0, 1), 40.0);
  p(1, 2) = 80;
  EXPECT_EQ(UavEnv::separation(p, 0, 1), 0.0);
  p << 0, 0, 100, 3, 4, 100;
  EXPECT_EQ(UavEnv::separation(p, 0, 1), 5.0);
}

// ---- settings refused in one line ---------------------------------------------------------------

TEST(Altitude, BadBandsAreRefusedInOneLine) {
  auto refused = [](Config c) { return error_of([&] { validate(c); make_dynamics(c); }); };
  Config c = grid3d();
  c.trajectory.altitude_min_m = 150;
  EXPECT_NE(refused(c).find("trajectory.altitude_min_m = 150 is not below trajectory.altitude_max_m = 140"), std::string::npos);
  c = grid3d();
  c.trajectory.climb_m = 30;
  EXPECT_NE(refused(c).find("not a whole number of trajectory.climb_m = 30"), std::string::npos) << refused(c);
  c = grid3d();
  c.scenario.altitude_m = 90;
  EXPECT_NE(refused(c).find("scenario.altitude_m = 90 (where missions start and end) is not one of the altitude levels"),
            std::string::npos);
  c = grid3d();
  c.channel.pathloss = "3gpp-uma-av";
  c.trajectory.altitude_min_m = 20;
  EXPECT_NE(refused(c).find("leaves channel.pathloss = \"3gpp-uma-av\"'s range: allowed 22.5 < altitude <= 300 m"), std::string::npos)
      << refused(c);
}
