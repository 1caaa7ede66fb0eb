// Mobility models (skyloop/env/mobility.hpp), propulsion energy (skyloop/env/energy.hpp), the
// objectives, and the planners and DP over them.
#include <gtest/gtest.h>

#include <cmath>
#include <numeric>

#include "skyloop/beamforming/linear.hpp"
#include "skyloop/core/config_io.hpp"
#include "skyloop/core/error.hpp"
#include "skyloop/env/energy.hpp"
#include "skyloop/env/dynamics.hpp"
#include "skyloop/planning/planners.hpp"
#include "skyloop/planning/safety.hpp"

#include "test_util.hpp"

using namespace skyloop;
using skyloop::test::error_of;

namespace {

std::unique_ptr<UavEnv> make_env(const Config& cfg, std::uint64_t seed = 1) { return skyloop::test::zf_env(cfg, seed); }

Config headings(std::vector<double> speeds = {0, 10, 20}) {
  Config c;
  c.trajectory.mobility = "headings";
  c.trajectory.speeds_mps = std::move(speeds);
  validate(c);
  return c;
}


}  // namespace

// ---- propulsion power: Zeng, Xu and Zhang, IEEE TWC 2019, eq. (12), Table I ----------------------
// Reference values computed by hand from eq. (12) with Table I's parameters (P0 = 79.86 W, Pi =
// 88.63 W, U_tip = 120 m/s, v0 = 4.03 m/s, d0 = 0.6, rho = 1.225 kg/m^3, s = 0.05, A = 0.503 m^2),
// evaluated in double precision outside skyloop: P(0) = P0 + Pi = 168.49 W; P(10) = 126.0337 W;
// P(20) = 178.3003 W; argmin P = 10.2125 m/s (P = 126.0073 W); argmin P / V = 18.2953 m/s
// (P / V = 8.8290 J/m). Zeng et al. report V_me ~ 10.2 and V_mr ~ 18.3 m/s for these values.
TEST(Energy, RotaryWingPowerMatchesZengTableI) {
  const Config c;
  const PropulsionModel p(c.energy);
  EXPECT_NEAR(p.hover_power(), 168.49, 0.01);
  EXPECT_NEAR(p.power(10.0), 126.0337, 0.01);
  EXPECT_NEAR(p.power(20.0), 178.3003, 0.01);
  EXPECT_NEAR(p.max_endurance_speed(), 10.2125, 0.01);
  EXPECT_NEAR(p.power(p.max_endurance_speed()), 126.0073, 0.01);
  EXPECT_NEAR(p.max_range_speed(), 18.2953, 0.01);
  EXPECT_NEAR(p.power(p.max_range_speed()) / p.max_range_speed(), 8.8290, 0.001);
  // The characteristic speeds are minima: nothing nearby does better.
  for (double dv : {-0.5, 0.5}) {
    EXPECT_GT(p.power(p.max_endurance_speed() + dv), p.power(p.max_endurance_speed()));
    const double v = p.max_range_speed() + dv;
    EXPECT_GT(p.power(v) / v, p.power(p.max_range_speed()) / p.max_range_speed());
  }
}

TEST(Energy, SlotEnergyAndTheKineticTerm) {
  Config c;
  const PropulsionModel steady(c.energy);
  EXPECT_DOUBLE_EQ(steady.slot_energy(10, 0, 2), 2 * steady.power(10));
  c.energy.acceleration = Acceleration::Kinetic;
  const PropulsionModel kinetic(c.energy);
  // Speeding up 0 -> 20 m/s adds m v^2 / 2 = 2.04 * 400 / 2 = 408 J; slowing down adds nothing.
  EXPECT_NEAR(kinetic.slot_energy(20, 0, 2) - steady.slot_energy(20, 0, 2), 408.0, 1e-9);
  EXPECT_DOUBLE_EQ(kinetic.slot_energy(0, 20, 2), steady.slot_energy(0, 20, 2));
  c.energy.model = Propulsion::None;
  EXPECT_EQ(PropulsionModel(c.energy).slot_energy(20, 0, 2), 0.0);
}

// ---- mobility models ---------------------------------------------------------------------------

TEST(Mobility, GridIsThePapersFiveMoves) {
  const Config c;
  const auto model = make_dynamics(c);
  const LatticeDynamics& m = *model->lattice();
  ASSERT_EQ(m.count(), 5);
  EXPECT_EQ(m.actions().names, (std::vector<std::string>{"UP", "DOWN", "LEFT", "RIGHT", "STAY"}));
  EXPECT_EQ(m.hover(), kStay);
  EXPECT_EQ(m.step(kUp).dy, 1);
  EXPECT_EQ(m.step(kLeft).dx, -1);
  EXPECT_DOUBLE_EQ(m.speed(kRight), c.trajectory.d_fly_m / c.trajectory.slot_s);  // V = D_fly / delta_t
  EXPECT_EQ(m.speed(kStay), 0.0);
}

TEST(Mobility, HeadingsAreEightPerSpeedAndHover) {
  const Config c = headings({0, 10, 20});
  const auto model = make_dynamics(c);
  const LatticeDynamics& m = *model->lattice();
  ASSERT_EQ(m.count(), 17);
  EXPECT_EQ(m.actions().names.front(), "E@10");
  EXPECT_EQ(m.actions().names[9], "NE@20");
  EXPECT_EQ(m.actions().names.back(), "HOVER");
  EXPECT_EQ(m.hover(), 16);
  // 10 m/s x 2 s = 20 m = one lattice step; 20 m/s two; diagonals fly sqrt(2) faster.
  EXPECT_EQ(m.step(0).dx, 1);
  EXPECT_EQ(m.step(0).dy, 0);
  EXPECT_EQ(m.step(9).dx, 2);
  EXPECT_EQ(m.step(9).dy, 2);
  EXPECT_DOUBLE_EQ(m.speed(0), 10.0);
  EXPECT_DOUBLE_EQ(m.speed(9), 20.0 * std::sqrt(2.0));
  EXPECT_EQ(m.speed(16), 0.0);
  // Every move has its opposite (the breadth-first search relies on it).
  for (int a = 0; a < m.count(); ++a) {
    bool found = false;
    for (int b = 0; b < m.count(); ++b) found = found || (m.step(b).dx == -m.step(a).dx && m.step(b).dy == -m.step(a).dy);
    EXPECT_TRUE(found) << m.actions().name(a);
  }
}

TEST(Mobility, SlotsToDestinationAreExact) {
  // Grid: Manhattan distance; headings with one speed of one step: Chebyshev distance (king moves).
  const auto grid_model = make_dynamics(Config{}), king_model = make_dynamics(headings({10}));
  const LatticeDynamics &grid = *grid_model->lattice(), &king = *king_model->lattice();
  const int nx = 7, ny = 5, to = 2 * nx + 3;
  const auto g = grid.slots_to(nx, ny, to), k = king.slots_to(nx, ny, to);
  for (int c = 0; c < nx * ny; ++c) {
    const int dx = std::abs(c % nx - 3), dy = std::abs(c / nx - 2);
    EXPECT_EQ(g[static_cast<std::size_t>(c)], dx + dy);
    EXPECT_EQ(k[static_cast<std::size_t>(c)], std::max(dx, dy));
  }
  // Two steps per slot only: cells of odd offset along an axis need a detour; the search knows.
  const auto two_model = make_dynamics(headings({20}));
  const LatticeDynamics& two = *two_model->lattice();
  const auto t = two.slots_to(5, 1, 0);
  EXPECT_EQ(t, (std::vector<int>{0, -1, 1, -1, 2}));  // a 5 x 1 strip: odd cells unreachable
}

TEST(Mobility, BadSettingsAreRefusedInOneLine) {
  auto refused = [](const std::vector<std::string>& sets) {
    return error_of([&] {
      Config c;
      for (const auto& s : sets) apply_override(c, s);
      validate(c);
    });
  };
  EXPECT_NE(refused({"trajectory.mobility=headings", "trajectory.speeds_mps=[0, 15]"}).find("multiple of trajectory.d_fly_m"),
            std::string::npos);
  EXPECT_NE(refused({"trajectory.mobility=headings", "trajectory.speeds_mps=[0]"}).find("no positive speed"), std::string::npos);
  EXPECT_NE(refused({"trajectory.mobility=headings", "trajectory.speeds_mps=[10, 10]"}).find("distinct"), std::string::npos);
  EXPECT_NE(refused({"trajectory.mobility=headings", "trajectory.speeds_mps=[10, 20, 30, 40, 50, 60, 70, 80]"}).find("at most 7"),
            std::string::npos);
  EXPECT_NE(refused({"trajectory.mobility=headings", "trajectory.speeds_mps=[100]"}).find("tip speed"), std::string::npos);
  EXPECT_NE(refused({"trajectory.speeds_mps=[]"}).find("trajectory.speeds_mps"), std::string::npos);
  EXPECT_NE(refused({"trajectory.mobility=walk"}).find("allowed one of grid, headings, continuous"), std::string::npos);
  EXPECT_NE(refused({"env.objective=joules"}).find("env.objective"), std::string::npos);
  // Only two-step moves: the paper's destination (160 m along x, 80 m along y from its start) is out of reach.
  const std::string parity = error_of([] {
    Config c = headings({0, 20});
    c.trajectory.destinations[0] = {180, 80};
    make_env(c);
  });
  EXPECT_NE(parity.find("trajectory.destinations[0] cannot be reached"), std::string::npos) << parity;
  for (const auto& e : {refused({"trajectory.mobility=headings", "trajectory.speeds_mps=[0, 15]"}), refused({"trajectory.speeds_mps=[]"}),
                        parity})
    EXPECT_EQ(e.find('\n'), std::string::npos) << e;
}

// ---- the environment under headings ------------------------------------------------------------

TEST(Mobility, HeadingsMaskBringsEveryUavHomeAndTheShieldAvoidsCollisions) {
  // Flown with the reachability mask (Random) every mission completes by T_max; with the shield
  // (shielded_argmax on random scores) no two UAVs meet where a joint move avoids it.
  Config c = headings();
  int missions = 0, shielded_collisions = 0;
  for (std::uint64_t seed = 1; seed <= 8; ++seed) {
    auto env = make_env(c, seed);
    RandomPlanner random(seed);
    const auto r = run_episode(*env, random);
    EXPECT_TRUE(r.success) << "seed " << seed;
    EXPECT_EQ(r.boundary, 0);
    ++missions;
    env->reset();
    Rng rng(seed);
    while (!env->done()) {
      std::vector<std::vector<float>> scores(3, std::vector<float>(static_cast<std::size_t>(env->actions())));
      for (auto& s : scores)
        for (auto& x : s) x = static_cast<float>(rng.uniform());
      const auto a = shielded_argmax(*env, SafetyOptions{}, scores);
      for (int n = 0; n < 3; ++n) {
        EXPECT_TRUE(allowed_moves(*env, n, SafetyOptions{}) >> a[static_cast<std::size_t>(n)] & 1u);
      }
      const int hit = env->collisions(env->next_positions(a));
      if (hit) {  // only where no joint move of allowed moves avoids it
        const int A = env->actions();
        bool avoidable = false;
        std::vector<ActionSet> allowed;
        for (int n = 0; n < 3; ++n) allowed.push_back(allowed_moves(*env, n, SafetyOptions{}));
        for (int j = 0; j < A * A * A && !avoidable; ++j) {
          const std::vector<int> b{j % A, j / A % A, j / A / A};
          bool ok = true;
          for (int n = 0; n < 3; ++n) ok = ok && (allowed[static_cast<std::size_t>(n)] >> b[static_cast<std::size_t>(n)] & 1u);
          avoidable = ok && env->collisions(env->next_positions(b)) == 0;
        }
        shielded_collisions += avoidable;
      }
      env->step(a);
    }
    EXPECT_TRUE(env->arrived(0) && env->arrived(1) && env->arrived(2)) << "seed " << seed;
  }
  EXPECT_EQ(missions, 8);
  EXPECT_EQ(shielded_collisions, 0);
}

TEST(Mobility, EnergyBookkeepingAddsUp) {
  // The per-slot powers x delta_t sum to each UAV's energy and to the total; arrived UAVs hover.
  for (const char* mobility : {"grid", "headings"}) {
    Config c = headings();
    c.trajectory.mobility = mobility;
    auto env = make_env(c, 2);
    RandomPlanner random(5);
    const auto r = run_episode(*env, random);
    ASSERT_EQ(r.powers.size(), static_cast<std::size_t>(r.T - 1));
    double total = 0;
    for (int n = 0; n < 3; ++n) {
      double e = 0;
      for (std::size_t t = 0; t < r.powers.size(); ++t) {
        e += r.powers[t][static_cast<std::size_t>(n)] * c.trajectory.slot_s;
        const PropulsionModel p(c.energy);
        EXPECT_NEAR(r.powers[t][static_cast<std::size_t>(n)], p.power(r.speeds[t][static_cast<std::size_t>(n)]), 1e-9);
        if (r.positions[t](n, 0) == r.positions.back()(n, 0) && r.positions[t](n, 1) == r.positions.back()(n, 1) &&
            r.positions[t + 1](n, 0) == r.positions[t](n, 0) && r.positions[t + 1](n, 1) == r.positions[t](n, 1)) {
          EXPECT_EQ(r.speeds[t][static_cast<std::size_t>(n)], 0.0);
        }
      }
      EXPECT_NEAR(e, r.uav_energy_j[static_cast<std::size_t>(n)], 1e-6);
      total += e;
    }
    EXPECT_NEAR(total, r.energy_j, 1e-6) << mobility;
    EXPECT_NEAR(r.steps.back().episode_energy_j, r.energy_j, 1e-9);
    // Bits per joule: B delta_t sum R / E.
    const double bits = c.channel.bandwidth_hz * c.trajectory.slot_s * std::accumulate(r.rates.begin(), r.rates.end(), 0.0);
    EXPECT_NEAR(r.bits_per_joule, bits / r.energy_j, 1e-9 * r.bits_per_joule);
  }
}

TEST(Mobility, EnergyBudgetFailsAMissionThatPassesIt) {
  Config c;
  c.energy.budget_j = 1000;  // less than 24 slots of hover (24 x 2 s x 168 W)
  auto env = make_env(c);
  RandomPlanner random(1);
  const auto r = run_episode(*env, random);
  EXPECT_EQ(r.arrivals, 3);
  EXPECT_EQ(r.over_budget, 3);
  EXPECT_FALSE(r.success);
}

TEST(Mobility, ObjectiveRewardSumsToTheObjective) {
  // env.reward = objective: an episode's rewards sum to J (J[1] = 0 for energy-efficiency and energy).
  for (const char* objective : {"energy-efficiency", "weighted", "energy"}) {
    Config c = headings();
    c.env.reward = Reward::Objective;
    c.env.w_bud = c.env.w_col = 0;  // the penalties aside
    c.env.objective = parse_choice<Objective>("env.objective", objective);
    c.energy.weight = 0.05;
    auto env = make_env(c, 3);
    RandomPlanner random(2);
    const auto r = run_episode(*env, random);
    const double j1 = std::string(objective) == "weighted" ? r.rates.front() : 0.0;
    EXPECT_NEAR(r.reward + j1, r.objective, 1e-9 * std::max(1.0, std::abs(r.objective))) << objective;
  }
}

// ---- the exact optimum over headings and every objective ---------------------------------------

TEST(Mobility, OptimumEqualsBruteForceOnTinyHeadingsInstances) {
  // weighted with w = 2 has a negative optimum (Dinkelbach must not stop at lambda = 0).
  for (const char* objective : {"sum-rate", "energy-efficiency", "weighted", "weighted-heavy", "energy"})
    for (std::uint64_t seed : {1u, 2u}) {
      Config c = headings({0, 10});
      c.scenario.area_x_m = 40;
      c.scenario.area_y_m = 40;
      c.scenario.users = 4;
      c.trajectory.starts = {{0, 0}, {40, 40}};
      c.trajectory.destinations = {{40, 20}, {0, 20}};
      c.trajectory.d_min_m = 15;
      c.trajectory.t_max = 4;
      const bool heavy = std::string(objective) == "weighted-heavy";
      c.env.objective = parse_choice<Objective>("env.objective", heavy ? "weighted" : objective);
      c.energy.weight = heavy ? 2.0 : 0.1;
      auto env = make_env(c, seed);
      const OptimalPlan plan = solve_optimal(*env);
      if (heavy) {
        EXPECT_LT(plan.objective, 0.0);
      }
      const double brute = brute_force_optimum(*env);
      const double tol = 1e-9 * std::max(1.0, std::abs(brute));
      EXPECT_NEAR(plan.objective, brute, tol) << objective << " seed " << seed;
      OptimalPlanner optimal;
      const auto r = run_episode(*env, optimal);
      EXPECT_NEAR(r.objective, plan.objective, tol) << objective;
      EXPECT_NEAR(r.energy_j, plan.energy_j, 1e-6) << objective;
      EXPECT_TRUE(r.success);
      EXPECT_EQ(r.collisions, 0);
    }
}

TEST(Mobility, LeastEnergyCruiseIsTheMaximumRangeSpeed) {
  // The rate term off (env.objective = energy), one UAV 396 m from its destination with plenty of
  // time: the optimum cruises at the offered speed whose energy per metre P(V) / V is least, the one
  // nearest Zeng's maximum-range speed (18.3 m/s), never hovering on the way.
  Config c = headings();
  c.scenario.area_x_m = 400;
  c.scenario.area_y_m = 2;
  c.trajectory.starts = {{0, 1}};
  c.trajectory.destinations = {{396, 1}};
  c.trajectory.d_fly_m = 1;
  c.trajectory.slot_s = 1;
  c.trajectory.speeds_mps = {0, 14, 16, 18, 20, 22};
  c.trajectory.t_max = 40;
  c.env.objective = Objective::Energy;
  validate(c);
  auto env = make_env(c);
  const OptimalPlan plan = solve_optimal(*env);
  const PropulsionModel p(c.energy);
  double best_v = 0;
  for (double v : {14.0, 16.0, 18.0, 20.0, 22.0})
    if (best_v == 0 || p.power(v) / v < p.power(best_v) / best_v) best_v = v;
  EXPECT_EQ(best_v, 18.0);
  EXPECT_LT(std::abs(best_v - p.max_range_speed()), 1.0);
  const LatticeDynamics& m = *env->dynamics().lattice();
  for (const auto& a : plan.actions) EXPECT_DOUBLE_EQ(m.speed(a[0]), best_v) << m.actions().name(a[0]);
  EXPECT_NEAR(plan.energy_j, 396.0 / best_v * p.power(best_v), 1e-6);
}

TEST(Mobility, GreedyFollowsTheObjectiveAndRefusesHugeJointSpaces) {
  Config c = headings();
  c.env.objective = Objective::Energy;
  auto env = make_env(c, 4);
  GreedyPlanner greedy;
  RandomPlanner random(4);
  const auto g = run_episode(*env, greedy), r = run_episode(*env, random);
  EXPECT_TRUE(g.success);
  EXPECT_GT(g.objective, r.objective);  // fewer joules than a random flight
  Config big = headings();
  big.trajectory.starts = {{20, 20}, {20, 180}, {180, 180}, {180, 20}, {100, 100}};
  big.trajectory.destinations = {{180, 100}, {180, 40}, {20, 100}, {20, 40}, {100, 60}};
  auto env5 = make_env(big);
  EXPECT_NE(error_of([&] { run_episode(*env5, greedy); }).find("seqgreedy"), std::string::npos);
}
