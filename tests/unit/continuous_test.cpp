// The continuous mobility model (skyloop/env/mobility.hpp): the command map, the projection onto
// what a UAV can fly, arrival and reachability by the HOME simulation, the safety layer over
// velocity commands (skyloop/planning/safety.hpp), the energy bookkeeping, and the planners on it.
#include <gtest/gtest.h>

#include <cmath>
#include <numeric>

#include "skyloop/beamforming/linear.hpp"
#include "skyloop/core/config_io.hpp"
#include "skyloop/core/error.hpp"
#include "skyloop/env/energy.hpp"
#include "skyloop/env/continuous.hpp"
#include "skyloop/planning/planners.hpp"
#include "skyloop/planning/safety.hpp"

#include "test_util.hpp"

using namespace skyloop;
using skyloop::test::error_of;

namespace {

Config continuous(double v_max = 20, double a_max = 5) {
  Config c;
  c.trajectory.mobility = "continuous";
  c.trajectory.v_max_mps = v_max;
  c.trajectory.a_max_mps2 = a_max;
  validate(c);
  return c;
}

std::unique_ptr<UavEnv> make_env(const Config& cfg, std::uint64_t seed = 1) {
  auto oracle = std::make_shared<RateOracle>(cfg, std::make_shared<ZfBeamformer>(), make_users(cfg, cfg.scenario.users, seed));
  return std::make_unique<UavEnv>(cfg, oracle);
}

/// Commands uniform in [-1, 1]^2 for every UAV, as velocities.
Positions random_commands(const UavEnv& env, Rng& rng) {
  Positions v(env.uavs(), 2);
  for (int n = 0; n < env.uavs(); ++n)
    static_cast<const ContinuousDynamics&>(env.dynamics()).velocity(2 * rng.uniform() - 1, 2 * rng.uniform() - 1, v(n, 0), v(n, 1));
  return v;
}

}  // namespace

TEST(Continuous, CommandsMapOneToOneOntoTheDisc) {
  const Config c = continuous();
  const ContinuousDynamics m(c);
  ASSERT_TRUE(m.commands_velocities());
  EXPECT_EQ(m.actions().dims, 2);
  EXPECT_EQ(m.actions().names.back(), "HOVER");
  EXPECT_EQ(m.actions().names[static_cast<std::size_t>(m.home())], "HOME");
  EXPECT_EQ(m.count(), 18);  // 8 headings at v_max / 2 and v_max, HOME, HOVER
  double vx, vy;
  m.velocity(1, 0, vx, vy);  // the square's edge midpoints and corners land on the rim
  EXPECT_NEAR(vx, 20, 1e-12);
  EXPECT_NEAR(vy, 0, 1e-12);
  m.velocity(1, 1, vx, vy);
  EXPECT_NEAR(vx, 20 / std::sqrt(2.0), 1e-12);
  EXPECT_NEAR(vy, 20 / std::sqrt(2.0), 1e-12);
  m.velocity(0.5, -0.25, vx, vy);  // |u|_inf = 0.5: half the top speed
  EXPECT_NEAR(std::hypot(vx, vy), 10, 1e-12);
  EXPECT_NEAR(std::atan2(vy, vx), std::atan2(-0.25, 0.5), 1e-12);
  m.velocity(0, 0, vx, vy);
  EXPECT_EQ(vx, 0);
  EXPECT_EQ(vy, 0);
  Rng rng(3);
  for (int i = 0; i < 1000; ++i) {
    const double u0 = 2 * rng.uniform() - 1, u1 = 2 * rng.uniform() - 1;
    m.velocity(u0, u1, vx, vy);
    EXPECT_LE(std::hypot(vx, vy), 20 + 1e-9);
    double b0, b1;
    m.command(vx, vy, b0, b1);
    EXPECT_NEAR(b0, u0, 1e-9);
    EXPECT_NEAR(b1, u1, 1e-9);
  }
}

TEST(Continuous, PolarCommandsAreASpeedAndATurnTheUavCanMake) {
  Config c = continuous();  // v_max 20 m/s, a_max 5 m/s^2 x 2 s: dv_max 10 m/s
  ASSERT_EQ(ContinuousDynamics(c).command(), Command::Velocity);
  c.trajectory.command = Command::Polar;
  const ContinuousDynamics polar(c);
  ASSERT_EQ(polar.command(), Command::Polar);
  double vx, vy;
  // Flying north-east at 10 m/s. u = 0 cruises straight on at v_max / 2; u1 turns by u1 times the
  // widest turn a_max allows at the speed asked for: at 10 m/s on 10 m/s, 60 degrees
  // (|dV| = 2 x 10 sin 30 = dv_max), so a constant u1 flies a circle.
  const double p = 10 / std::sqrt(2.0);
  polar.commanded_velocity(0, 0, p, p, 100, -50, vx, vy);
  EXPECT_NEAR(vx, p, 1e-12);
  EXPECT_NEAR(vy, p, 1e-12);
  polar.commanded_velocity(0, 1, p, p, 100, -50, vx, vy);
  EXPECT_NEAR(std::hypot(vx, vy), 10, 1e-12);
  EXPECT_NEAR(std::atan2(vy, vx), M_PI / 4 + M_PI / 3, 1e-12);
  EXPECT_NEAR(std::hypot(vx - p, vy - p), 10, 1e-9);
  polar.commanded_velocity(0, -0.5, p, p, 100, -50, vx, vy);
  EXPECT_NEAR(std::atan2(vy, vx), M_PI / 4 - M_PI / 6, 1e-12);
  // Speeding up from 10 to 20 m/s takes the whole dv_max: no turn left.
  polar.commanded_velocity(1, 0.5, p, p, 100, -50, vx, vy);
  EXPECT_NEAR(vx, 20 / std::sqrt(2.0), 1e-12);
  EXPECT_NEAR(vy, 20 / std::sqrt(2.0), 1e-12);
  polar.commanded_velocity(-1, 0.3, p, p, 100, -50, vx, vy);  // speed 0
  EXPECT_NEAR(std::hypot(vx, vy), 0, 1e-12);
  // From a standstill the heading is the bearing to the destination (here south), or east on it.
  polar.commanded_velocity(-0.5, -1.0 / 3, 0, 0, 0, -30, vx, vy);
  EXPECT_NEAR(std::hypot(vx, vy), 5, 1e-12);
  EXPECT_NEAR(std::atan2(vy, vx), -M_PI / 2 - M_PI / 3, 1e-12);
  polar.commanded_velocity(-0.5, 0, 0, 0, 0, 0, vx, vy);
  EXPECT_NEAR(vx, 5, 1e-12);
  EXPECT_NEAR(vy, 0, 1e-12);
  // Any speed within reach of the last one comes with a turn the UAV can make (the projection
  // leaves it as asked); the velocity command ignores what the UAV flew before.
  Rng rng(5);
  for (int i = 0; i < 1000; ++i) {
    const double speed = 20 * rng.uniform(), heading = 6.283185307179586 * rng.uniform();
    const double px = speed * std::cos(heading), py = speed * std::sin(heading);
    const double u0 = 2 * rng.uniform() - 1, u1 = 2 * rng.uniform() - 1;
    polar.commanded_velocity(u0, u1, px, py, 40, 40, vx, vy);
    EXPECT_NEAR(std::hypot(vx, vy), 10 * (u0 + 1), 1e-9);
    if (std::abs(10 * (u0 + 1) - speed) <= 10) {
      EXPECT_LE(std::hypot(vx - px, vy - py), 10 + 1e-9);
      double fx, fy;
      polar.project(vx, vy, px, py, fx, fy);
      EXPECT_NEAR(fx, vx, 1e-9);
      EXPECT_NEAR(fy, vy, 1e-9);
    }
    double wx, wy, ux, uy;
    ContinuousDynamics(continuous()).commanded_velocity(u0, u1, px, py, 40, 40, wx, wy);
    polar.velocity(u0, u1, ux, uy);
    EXPECT_EQ(wx, ux);
    EXPECT_EQ(wy, uy);
  }
  // The environment asks the model with each UAV's own last velocity and destination.
  auto env = make_env(c);
  env->command_velocity(0, 0, 0, vx, vy);
  const double tx = c.trajectory.destinations[0].x - c.trajectory.starts[0].x;
  const double ty = c.trajectory.destinations[0].y - c.trajectory.starts[0].y;
  EXPECT_NEAR(vx, 10 * tx / std::hypot(tx, ty), 1e-9);
  EXPECT_NEAR(vy, 10 * ty / std::hypot(tx, ty), 1e-9);
  const std::string bad = error_of([&] { apply_override(c, "trajectory.command=jerk"); });
  EXPECT_NE(bad.find("trajectory.command"), std::string::npos) << bad;
  EXPECT_NE(bad.find("polar"), std::string::npos) << bad;
}

TEST(Continuous, ProjectionIsTheNearestVelocityTheUavCanFly) {
  // The nearest point of {|V| <= v_max} n {|V - V_prev| <= a_max delta_t} (v_max = 20, a_max
  // delta_t = 10 m/s), against a search over a fine grid of the feasible set.
  const Config c = continuous();
  const ContinuousDynamics m(c);
  Rng rng(5);
  for (int i = 0; i < 300; ++i) {
    const double r = 20 * std::sqrt(rng.uniform()), th = 6.283185307179586 * rng.uniform();
    const double px = r * std::cos(th), py = r * std::sin(th);
    const double qx = 80 * rng.uniform() - 40, qy = 80 * rng.uniform() - 40;
    double ox, oy;
    m.project(qx, qy, px, py, ox, oy);
    EXPECT_LE(std::hypot(ox, oy), 20 + 1e-7);
    EXPECT_LE(std::hypot(ox - px, oy - py), 10 + 1e-7);
    double best = 1e300;
    for (double gx = -20; gx <= 20; gx += 0.05)
      for (double gy = -20; gy <= 20; gy += 0.05)
        if (std::hypot(gx, gy) <= 20 && std::hypot(gx - px, gy - py) <= 10) best = std::min(best, std::hypot(gx - qx, gy - qy));
    EXPECT_LE(std::hypot(ox - qx, oy - qy), best + 1e-9) << "case " << i;
    EXPECT_GE(std::hypot(ox - qx, oy - qy), best - 0.08) << "case " << i;  // the grid's spacing
    double ax, ay;  // a feasible velocity projects to itself
    m.project(ox, oy, px, py, ax, ay);
    EXPECT_NEAR(ax, ox, 1e-9);
    EXPECT_NEAR(ay, oy, 1e-9);
  }
}

TEST(Continuous, HomeFliesInTheSlotsReachabilityCounts) {
  // From rest, the HOME primitive alone brings each UAV home in exactly min_moves slots, and the
  // count falls by one each slot (the simulation is the dynamics').
  const Config c = continuous();
  auto env = make_env(c);
  const int N = env->uavs();
  std::vector<int> need(static_cast<std::size_t>(N));
  for (int n = 0; n < N; ++n) {
    need[static_cast<std::size_t>(n)] = env->min_moves(n, env->current(n));
    // At least the straight-line distance at v_max (the paper scenario's 160 m at 40 m a slot: 4).
    const double d = std::hypot(env->destinations()(n, 0) - env->starts()(n, 0), env->destinations()(n, 1) - env->starts()(n, 1));
    EXPECT_GE(need[static_cast<std::size_t>(n)], static_cast<int>(std::ceil(d / 40.0 - 1e-9)));
    EXPECT_LT(need[static_cast<std::size_t>(n)], c.trajectory.t_max);
  }
  const std::vector<int> home(static_cast<std::size_t>(N), static_cast<const ContinuousDynamics&>(env->dynamics()).home());
  while (!env->done()) {
    for (int n = 0; n < N; ++n) {
      if (!env->arrived(n)) {
        EXPECT_EQ(env->min_moves(n, env->current(n)), need[static_cast<std::size_t>(n)] - (env->t() - 1));
      }
    }
    env->step(home);
  }
  for (int n = 0; n < N; ++n) EXPECT_TRUE(env->arrived(n));
  EXPECT_EQ(env->t(), 1 + *std::max_element(need.begin(), need.end()));
}

TEST(Continuous, MaskBringsEveryUavHomeUnderAnyCommands) {
  // Random commands through safe_velocities: every mission complete by T_max, no boundary event,
  // every flown velocity within v_max and within a_max delta_t of the last one; with the shield,
  // no collision that a joint choice of allowed primitives would have avoided.
  for (const bool shield : {false, true}) {
    int collisions = 0;
    for (std::uint64_t seed = 1; seed <= 12; ++seed) {
      Config c = continuous(seed % 3 == 0 ? 25 : 20, seed % 2 == 0 ? 2 : 5);
      c.trajectory.t_max = seed % 4 == 0 ? 14 : 24;  // little slack: the mask must act
      auto env = make_env(c, seed);
      Rng rng(seed);
      const SafetyOptions safety{true, shield, 0};
      while (!env->done()) {
        Positions last(env->uavs(), 2);
        for (int n = 0; n < env->uavs(); ++n) last(n, 0) = env->velocity_x(n), last(n, 1) = env->velocity_y(n);
        std::vector<bool> was(static_cast<std::size_t>(env->uavs()));
        for (int n = 0; n < env->uavs(); ++n) was[static_cast<std::size_t>(n)] = env->arrived(n);
        const Positions v = safe_velocities(*env, safety, random_commands(*env, rng));
        // A collision counts against the shield only if a joint choice of allowed primitives avoids it.
        Positions next(env->uavs(), 2);
        for (int n = 0; n < env->uavs(); ++n) {
          const auto l = env->arrived(n) ? env->landing(n, env->hover()) : env->landing_velocity(n, v(n, 0), v(n, 1));
          next(n, 0) = l.x, next(n, 1) = l.y;
        }
        if (env->collisions(next) > 0) {
          const int A = env->actions();
          bool avoidable = false;
          for (int j = 0; j < A * A * A && !avoidable; ++j) {
            const std::vector<int> b{j % A, j / A % A, j / A / A};
            bool ok = true;
            for (int n = 0; n < 3; ++n) ok = ok && (allowed_moves(*env, n, safety) >> b[static_cast<std::size_t>(n)] & 1u);
            avoidable = ok && env->collisions(env->next_positions(b)) == 0;
          }
          collisions += avoidable;
        }
        const auto info = env->step_velocities(v);
        EXPECT_EQ(info.boundary, 0);
        for (int n = 0; n < env->uavs(); ++n) {
          if (was[static_cast<std::size_t>(n)]) continue;
          const double vx = env->velocity_x(n), vy = env->velocity_y(n);
          EXPECT_LE(std::hypot(vx, vy), c.trajectory.v_max_mps + 1e-7);
          EXPECT_LE(std::hypot(vx - last(n, 0), vy - last(n, 1)), c.trajectory.a_max_mps2 * c.trajectory.slot_s + 1e-7);
        }
      }
      EXPECT_TRUE(env->arrived(0) && env->arrived(1) && env->arrived(2)) << "seed " << seed << ", shield " << shield;
    }
    if (shield) {
      EXPECT_EQ(collisions, 0);
    }
  }
}

TEST(Continuous, ACommandThatWouldLeaveTheAreaSlidesAlongTheBoundary) {
  // UAV 0 from (20, 20) west at 5 m/s to (10, 20), then asked for 10 m/s west: flown, it would land
  // at x = -10. The safety layer turns the command by 15, 30, 45, 60, ... degrees, each side:
  // turned by 15, 30 and 45 degrees it still lands west of x = 0 (10 - 20 cos 45 < 0). Turned by
  // +60 degrees, (-5, -5 sqrt 3), it lands inside at (0, 20 - 10 sqrt 3) but heading south-west
  // into the corner, from where the HOME command meets the boundary: out of reach. Turned by
  // -60 degrees, (-5, 5 sqrt 3), within a_max delta_t = 10 m/s of (-5, 0) (|dV| = 5 sqrt 3), it
  // lands at (0, 20 + 10 sqrt 3): inside, reachable, at the commanded 10 m/s (126 W) instead of a
  // stop at hover power (168 W).
  for (const bool shield : {false, true}) {
    const Config c = continuous();
    auto env = make_env(c);
    Positions v = Positions::Zero(3, 2);
    v(0, 0) = -5;
    env->step_velocities(v);
    ASSERT_NEAR(env->positions()(0, 0), 10, 1e-12);
    ASSERT_NEAR(env->positions()(0, 1), 20, 1e-12);
    v(0, 0) = -10;
    ASSERT_FALSE(env->landing_velocity(0, -10, 0).inside);
    const auto corner = env->landing_velocity(0, -5, -5 * std::sqrt(3.0));
    ASSERT_TRUE(corner.inside);
    ASSERT_GT(env->min_moves(0, corner), c.trajectory.t_max);
    const Positions flown = safe_velocities(*env, SafetyOptions{true, shield, 0}, v);
    EXPECT_NEAR(flown(0, 0), -5, 1e-9) << "shield " << shield;
    EXPECT_NEAR(flown(0, 1), 5 * std::sqrt(3.0), 1e-9) << "shield " << shield;
    const auto l = env->landing_velocity(0, flown(0, 0), flown(0, 1));
    EXPECT_TRUE(l.inside);
    EXPECT_NEAR(l.speed, 10, 1e-9);
    EXPECT_NEAR(l.x, 0, 1e-9);
    EXPECT_NEAR(l.y, 20 + 10 * std::sqrt(3.0), 1e-9);
    EXPECT_LE(env->min_moves(0, l), c.trajectory.t_max - 2);
    // Without the mask the command is flown as asked (and cancelled at the boundary).
    const Positions raw = safe_velocities(*env, SafetyOptions{false, shield, 0}, v);
    EXPECT_EQ(raw(0, 0), -10);
    EXPECT_EQ(raw(0, 1), 0);
  }
}

TEST(Continuous, EnergyBookkeepingAddsUp) {
  const Config c = continuous();
  auto env = make_env(c, 2);
  RandomPlanner random(5);
  const auto r = run_episode(*env, random);
  ASSERT_EQ(r.powers.size(), static_cast<std::size_t>(r.T - 1));
  const PropulsionModel p(c.energy);
  double total = 0;
  for (int n = 0; n < 3; ++n) {
    double e = 0;
    for (std::size_t t = 0; t < r.powers.size(); ++t) {
      const auto i = static_cast<std::size_t>(n);
      e += r.powers[t][i] * c.trajectory.slot_s;
      EXPECT_NEAR(r.powers[t][i], p.power(r.speeds[t][i]), 1e-9);
      // The speed charged is the distance flown over the slot (arrival may place a UAV up to
      // arrival_m nearer).
      const double flown = std::hypot(r.positions[t + 1](n, 0) - r.positions[t](n, 0), r.positions[t + 1](n, 1) - r.positions[t](n, 1));
      EXPECT_NEAR(r.speeds[t][i] * c.trajectory.slot_s, flown, c.trajectory.arrival_m + 1e-9);
    }
    EXPECT_NEAR(e, r.uav_energy_j[static_cast<std::size_t>(n)], 1e-6);
    total += e;
  }
  EXPECT_NEAR(total, r.energy_j, 1e-6);
}

TEST(Continuous, PlannersFlyItAndLatticeSearchesRefuseIt) {
  const Config c = continuous();
  auto env = make_env(c, 3);
  RandomPlanner random(1);
  GreedyPlanner greedy;
  SequentialGreedyPlanner seq;
  for (Planner* p : std::initializer_list<Planner*>{&random, &greedy, &seq}) {
    const auto r = run_episode(*env, *p);
    EXPECT_TRUE(r.success) << p->name();
  }
  EXPECT_NE(error_of([&] { solve_optimal(*env); }).find("trajectory.mobility = \"continuous\""), std::string::npos);
  EXPECT_NE(error_of([&] { brute_force_optimum(*env); }).find("allowed trajectory.mobility = " + lattice_dynamics_names()), std::string::npos);
  // Bad settings: one line naming the field, the value and what is allowed.
  Config bad = continuous();
  bad.trajectory.v_max_mps = 130;
  EXPECT_NE(error_of([&] { validate(bad); }).find("trajectory.v_max_mps = 130"), std::string::npos);
  Config none;
  const std::string a_max = error_of([&] { apply_override(none, "trajectory.a_max_mps2=0"); });
  EXPECT_NE(a_max.find("trajectory.a_max_mps2"), std::string::npos) << a_max;
  EXPECT_EQ(a_max.find('\n'), std::string::npos) << a_max;
  EXPECT_NE(error_of([&] { apply_override(none, "trajectory.mobility=smooth"); }).find("continuous"), std::string::npos);
}
