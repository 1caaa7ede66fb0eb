// The planners beyond the paper's baselines: the sequential greedy's collision-free search, the
// best-known planner against the exact optimum, and the planner registry.
#include <gtest/gtest.h>

#include <iostream>

#include "skyloop/core/config_io.hpp"
#include "skyloop/core/error.hpp"
#include "skyloop/experiments/builtin.hpp"
#include "skyloop/planning/planners.hpp"
#include "skyloop/planning/registry.hpp"

using namespace skyloop;

namespace {

Config scene(const std::vector<std::string>& sets) {
  std::vector<std::string> all = {"env.oracle=mrt"};
  all.insert(all.end(), sets.begin(), sets.end());
  return resolve_config(std::nullopt, all);
}

std::shared_ptr<RateOracle> oracle_of(const Config& cfg, std::uint64_t users_seed) {
  return std::make_shared<RateOracle>(cfg, builtin_beamformers().create(cfg.env.oracle, cfg),
                                      make_users(cfg, cfg.scenario.users, users_seed));
}

/// Whether some joint move of feasible actions leaves no two UAVs within D_min (all 5^N).
bool collision_free_move_exists(const UavEnv& env) {
  const int n = env.uavs();
  int total = 1;
  for (int i = 0; i < n; ++i) total *= kGridActions;
  for (int j = 0; j < total; ++j) {
    std::vector<int> a(static_cast<std::size_t>(n));
    bool ok = true;
    for (int i = 0, r = j; i < n && ok; ++i, r /= kGridActions) {
      a[static_cast<std::size_t>(i)] = r % kGridActions;
      ok = env.feasible(i, a[static_cast<std::size_t>(i)]);
    }
    if (ok && env.collisions(env.next_positions(a)) == 0) return true;
  }
  return false;
}

}  // namespace

// Crowded small scenes (4 to 6 UAVs on a 7 x 7 lattice, D_min above D_fly), walked by the random
// planner into every kind of crowding: wherever a collision-free joint move of feasible actions
// exists (checked over all 5^N), the sequential greedy's move is collision-free and feasible.
TEST(Planners, SequentialGreedyAvoidsCollisionsWheneverItCan) {
  int checked = 0, crowded = 0;
  for (int uavs : {4, 5, 6})
    for (std::uint64_t layout = 1; layout <= 12; ++layout) {
      Config cfg = scene({"scenario.uavs=" + std::to_string(uavs), "scenario.users=8", "scenario.area_x_m=120",
                          "scenario.area_y_m=120", "trajectory.layout=generated", "trajectory.layout_seed=" + std::to_string(layout),
                          "trajectory.t_max=16", "trajectory.d_min_m=25"});
      UavEnv env(cfg, oracle_of(cfg, layout));
      RandomPlanner walk(layout);
      SequentialGreedyPlanner seq;
      env.reset();
      walk.reset(env);
      seq.reset(env);
      while (!env.done()) {
        const auto a = seq.act(env);
        for (int i = 0; i < env.uavs(); ++i) ASSERT_TRUE(env.feasible(i, a[static_cast<std::size_t>(i)]));
        crowded += env.collisions(env.next_positions(walk.act(env))) > 0;
        if (collision_free_move_exists(env)) {
          ++checked;
          EXPECT_EQ(env.collisions(env.next_positions(a)), 0) << uavs << " UAVs, layout " << layout << ", slot " << env.t();
        }
        env.step(walk.act(env));
      }
    }
  EXPECT_GT(checked, 100);
  EXPECT_GT(crowded, 10) << "the scenes should be crowded enough for random moves to collide";
}

// With the learners' safety settings (a slack margin of 2, the mask counting around the other
// UAVs' destinations; the fleet recipe's), the sequential greedy flies only moves the margin-0
// mask allows, brings every UAV home, and collides less than with the plain mask.
TEST(Planners, SequentialGreedyFliesTheMarginAndClearance) {
  int collided[2] = {0, 0}, missed[2] = {0, 0};
  for (int uavs : {5, 6})
    for (std::uint64_t layout = 1; layout <= 12; ++layout) {
      Config cfg = scene({"scenario.uavs=" + std::to_string(uavs), "scenario.users=8", "scenario.area_x_m=120",
                          "scenario.area_y_m=120", "trajectory.layout=generated", "trajectory.layout_seed=" + std::to_string(layout),
                          "trajectory.t_max=16", "trajectory.d_min_m=25"});
      UavEnv env(cfg, oracle_of(cfg, layout));
      for (const bool safe : {false, true}) {
        const SafetyOptions safety{true, false, safe ? 2 : 0, safe ? Clearance::Destinations : Clearance::None};
        SequentialGreedyPlanner seq(safety);
        env.reset();
        seq.reset(env);
        while (!env.done()) {
          const auto a = seq.act(env);
          for (int i = 0; i < env.uavs(); ++i) {
            ASSERT_TRUE(reachable_moves(env, i, 0, safety.clearance) >> a[static_cast<std::size_t>(i)] & 1u);
          }
          collided[safe ? 1 : 0] += env.collisions(env.next_positions(a));
          env.step(a);
        }
        for (int i = 0; i < env.uavs(); ++i) missed[safe ? 1 : 0] += env.arrived(i) ? 0 : 1;
      }
    }
  EXPECT_EQ(missed[0] + missed[1], 0);
  EXPECT_GT(collided[0], 0) << "the scenes should hold collisions for the plain mask";
  EXPECT_LT(collided[1], collided[0]) << "plain " << collided[0] << ", margin and clearance " << collided[1];
}

// Where the joint DP runs, the best-known planner is the exact optimum; its best responses alone
// are exact for one UAV, and for 2 and 3 UAVs lie between the sequential greedy and the optimum.
TEST(Planners, BestKnownAgainstTheExactOptimum) {
  for (int uavs : {1, 2, 3})
    for (std::uint64_t layout = 1; layout <= 3; ++layout) {
      Config cfg = scene({"scenario.uavs=" + std::to_string(uavs), "scenario.users=10", "scenario.area_x_m=120",
                          "scenario.area_y_m=120", "trajectory.layout=generated", "trajectory.layout_seed=" + std::to_string(layout),
                          "trajectory.t_max=14", "env.oracle=zf"});
      UavEnv env(cfg, oracle_of(cfg, 10 + layout));
      const double optimum = solve_optimal(env).objective;
      const auto exact = solve_best_known(env);
      EXPECT_TRUE(exact.exact);
      EXPECT_DOUBLE_EQ(exact.objective, optimum);
      const auto iterated = solve_best_known(env, nullptr, 20, true);
      EXPECT_FALSE(iterated.exact);
      EXPECT_EQ(iterated.collisions, 0);
      EXPECT_LE(iterated.objective, optimum * (1 + 1e-12)) << uavs << " UAVs, layout " << layout;
      EXPECT_GE(iterated.objective, iterated.start_objective) << "best responses never lose";
      if (uavs == 1) {
        EXPECT_NEAR(iterated.objective, optimum, 1e-12 * optimum) << "one UAV: the best response is the optimum";
      }
      // Replayed in the environment, the plan scores what it says.
      BestKnownPlanner p(nullptr, 20, true);
      const auto rec = run_episode(env, p);
      EXPECT_TRUE(rec.success);
      EXPECT_EQ(rec.collisions, 0);
      EXPECT_EQ(rec.boundary, 0);
      EXPECT_NEAR(rec.objective, iterated.objective, 1e-9 * optimum);
    }
}

// optimum_key names what the exact optimum depends on, so that reproduce's stages and the layout
// evaluation's --cache share one solve: the learners' settings, the run's, the reward's and the
// drawing of layouts leave both the key and the DP's plan as they are; the scenario, the channel,
// the oracle, the objective and the horizon change the key.
TEST(Planners, OptimumKeyNamesWhatTheOptimumDependsOn) {
  const std::vector<std::string> small = {"scenario.uavs=2", "scenario.users=8", "scenario.area_x_m=120", "scenario.area_y_m=120",
                                          "trajectory.layout=generated", "trajectory.t_max=14", "env.oracle=zf"};
  auto with = [&](const std::vector<std::string>& more) {
    auto all = small;
    all.insert(all.end(), more.begin(), more.end());
    return scene(all);
  };
  const Config base = with({});
  UavEnv base_env(base, oracle_of(base, 5));
  const OptimalPlan plan = solve_optimal(base_env);
  for (const auto& same : std::vector<std::vector<std::string>>{{"marl.algo=ippo", "marl.envs=3"},
                                                                 {"run.seed=7", "run.threads=1"},
                                                                 {"env.w_arr=10", "env.w_rate=0.5", "env.w_col=9"},
                                                                 {"env.reward=objective", "env.state=compact"},
                                                                 {"env.resample_users=true", "env.users_min=4", "env.users_max=9", "env.state=compact"}}) {
    const Config cfg = with(same);
    EXPECT_EQ(optimum_key(cfg), optimum_key(base)) << same.front();
    UavEnv env(cfg, oracle_of(cfg, 5));
    const OptimalPlan other = solve_optimal(env);
    EXPECT_EQ(other.objective, plan.objective) << same.front();
    EXPECT_EQ(other.actions, plan.actions) << same.front();
  }
  for (const auto& differs : std::vector<std::string>{"scenario.altitude_m=120", "channel.pathloss=3gpp-uma-av", "channel.seed=2",
                                                       "env.oracle=mrt", "env.objective=energy-efficiency", "trajectory.t_max=15",
                                                       "trajectory.layout_seed=2"})
    EXPECT_NE(optimum_key(with({differs})), optimum_key(base)) << differs;
  // The key holds values only, and none of the learners' or the run's: a learner setting added
  // later, or a help text reworded, keeps every cached optimum (`eval --cache`, reproduce's).
  const std::string key = optimum_key(base);
  EXPECT_EQ(key.find("marl."), std::string::npos) << key;
  EXPECT_EQ(key.find("run."), std::string::npos) << key;
  EXPECT_EQ(key.find('#'), std::string::npos) << key;
  EXPECT_NE(key.find("scenario.uavs = 2\n"), std::string::npos) << key;
}

// Beyond the DP (10 UAVs, 300 m, 150 users): every UAV home without a collision, at least the
// sequential greedy's objective.
TEST(Planners, BestKnownScalesBeyondTheDp) {
  Config cfg = scene({"scenario.uavs=10", "scenario.users=150", "scenario.area_x_m=300", "scenario.area_y_m=300",
                      "trajectory.layout=generated", "trajectory.t_max=24", "env.oracle=zfsel"});
  UavEnv env(cfg, oracle_of(cfg, 4));
  EXPECT_FALSE(fits_optimal(env));
  BestKnownPlanner best;
  const auto rec = run_episode(env, best);
  EXPECT_FALSE(best.plan().exact);
  EXPECT_TRUE(rec.success);
  EXPECT_EQ(rec.collisions, 0);
  EXPECT_EQ(rec.boundary, 0);
  SequentialGreedyPlanner seq;
  EXPECT_GE(rec.objective, run_episode(env, seq).objective);
  EXPECT_GE(best.plan().rounds, 1);
}

TEST(Planners, RegistryNamesEveryPlannerAndRefusesOthersInOneLine) {
  const auto names = builtin_planners().names();
  EXPECT_EQ(names, (std::vector<std::string>{"random", "greedy", "seqgreedy", "rollout", "bestknown", "optimal"}));
  for (const auto& n : names) EXPECT_EQ(builtin_planners().create(n)->name(), n);
  try {
    builtin_planners().create("astar");
    FAIL() << "an unknown planner was built";
  } catch (const InputError& e) {
    EXPECT_STREQ(e.what(), "planner 'astar' is unknown: allowed random, greedy, seqgreedy, rollout, bestknown, optimal");
  }
  // A user's planner joins the list every consumer reads.
  PlannerRegistry mine = builtin_planners();
  mine.add("stay", "everyone stays", [](const PlannerArgs&) {
    struct Stay final : Planner {
      std::string name() const override { return "stay"; }
      std::vector<int> act(UavEnv& env) override { return std::vector<int>(static_cast<std::size_t>(env.uavs()), kStay); }
    };
    return std::make_unique<Stay>();
  });
  EXPECT_EQ(mine.names().back(), "stay");
  EXPECT_EQ(mine.create("stay")->name(), "stay");
}

namespace {
/// Failures of a mission in the rollout's order: UAVs not home, colliding UAVs, boundary events.
int failures(const EpisodeRecord& r) {
  const int uavs = static_cast<int>(r.positions.front().rows());
  const int home = r.steps.empty() ? 0 : r.steps.back().home;
  return (uavs - home) + r.collisions + r.boundary + r.over_budget;
}
}  // namespace

// Multiagent rollout's cost improvement (planners.hpp, RolloutPlanner): over a deterministic,
// memoryless base (Greedy, the sequential greedy) its mission is never worse than the base's,
// failures first, then the objective, on the paper's scenario, on crowded scenes where the bases
// collide, and under the headings model with the energy-efficiency objective; it never passes
// the exact optimum, and it improves on its base somewhere (or the test proves nothing).
TEST(Planners, RolloutIsNeverWorseThanItsBase) {
  int improved = 0, fewer_failures = 0, compared = 0;
  auto check = [&](const Config& cfg, std::uint64_t users_seed, bool with_optimum) {
    UavEnv env(cfg, oracle_of(cfg, users_seed));
    std::vector<std::unique_ptr<Planner>> bases;
    bases.push_back(std::make_unique<SequentialGreedyPlanner>());
    if (cfg.scenario.uavs <= 4 && cfg.trajectory.mobility == "grid") bases.push_back(std::make_unique<GreedyPlanner>());
    const double optimum = with_optimum ? solve_optimal(env).objective : 0.0;
    for (auto& b : bases) {
      const std::string name = b->name();
      const auto base = run_episode(env, *b);
      RolloutPlanner rollout(std::move(b));
      EXPECT_EQ(rollout.name(), name + "+rollout");
      const auto r = run_episode(env, rollout);
      EXPECT_GT(rollout.simulated_steps(), 0);
      const std::string where = cfg.trajectory.mobility + " " + name + " users seed " + std::to_string(users_seed);
      EXPECT_LE(failures(r), failures(base)) << where;
      if (failures(r) == failures(base)) {
        EXPECT_GE(r.objective, base.objective) << where;
      }
      if (with_optimum && failures(r) == 0) {
        EXPECT_LE(r.objective, optimum * (1 + 1e-12)) << where;
      }
      ++compared;
      improved += failures(r) == failures(base) && r.objective > base.objective * (1 + 1e-9);
      fewer_failures += failures(r) < failures(base);
    }
  };
  for (std::uint64_t s = 1; s <= 4; ++s) check(scene({"env.oracle=zf", "scenario.users=12"}), s, false);
  for (std::uint64_t s = 1; s <= 3; ++s)
    check(scene({"env.oracle=zf", "scenario.users=6", "scenario.area_x_m=120", "scenario.area_y_m=120",
                 "trajectory.starts=[[0.0, 0.0], [120.0, 120.0]]", "trajectory.destinations=[[120.0, 40.0], [0.0, 80.0]]",
                 "trajectory.t_max=12"}),
          s, true);
  for (int uavs : {4, 5})
    for (std::uint64_t layout = 1; layout <= 4; ++layout)
      check(scene({"scenario.uavs=" + std::to_string(uavs), "scenario.users=8", "scenario.area_x_m=120", "scenario.area_y_m=120",
                   "trajectory.layout=generated", "trajectory.layout_seed=" + std::to_string(layout), "trajectory.t_max=16",
                   "trajectory.d_min_m=25"}),
            layout, false);
  check(scene({"env.oracle=zf", "scenario.users=10", "trajectory.mobility=headings", "env.objective=energy-efficiency"}), 2, false);
  EXPECT_GE(compared, 20);
  EXPECT_GE(improved, 3) << "the rollout never improved on its base: the test proves nothing";
  std::cout << "rollout: " << improved << " of " << compared << " missions improved, " << fewer_failures << " with fewer failures\n";
}

// The continuous model: over a base that commands velocities (here each UAV's HOME command, or
// hovering while it has slack to spare: deterministic and memoryless) the rollout keeps a command
// unless a feasible primitive scores strictly better; over seqgreedy it rolls out the primitives.
// Never worse than either base, and better than the plain flight home.
TEST(Planners, RolloutFliesTheContinuousModel) {
  struct HomeLate final : Planner {
    std::string name() const override { return "homelate"; }
    std::vector<int> act(UavEnv& env) override { return std::vector<int>(static_cast<std::size_t>(env.uavs()), env.hover()); }
    bool commands_velocities() const override { return true; }
    Positions act_velocities(UavEnv& env) override {
      Positions v = Positions::Zero(env.uavs(), 2);
      const auto& names = env.dynamics().actions().names;
      const int home = static_cast<int>(std::find(names.begin(), names.end(), "HOME") - names.begin());
      for (int n = 0; n < env.uavs(); ++n) {
        const auto now = env.current(n);
        if (env.min_moves(n, now) + 2 >= env.t_max() - env.t()) env.primitive_velocity(n, home, v(n, 0), v(n, 1));
      }
      return v;
    }
  };
  Config cfg = scene({"env.oracle=zf", "scenario.users=10", "trajectory.mobility=continuous", "env.objective=energy-efficiency"});
  int improved = 0;
  for (std::uint64_t seed = 1; seed <= 1; ++seed) {
    UavEnv env(cfg, oracle_of(cfg, seed));
    std::vector<std::unique_ptr<Planner>> bases;
    bases.push_back(std::make_unique<HomeLate>());
    bases.push_back(std::make_unique<SequentialGreedyPlanner>());
    for (auto& b : bases) {
      const bool velocities = b->commands_velocities();
      const auto base = run_episode(env, *b);
      RolloutPlanner rollout(std::move(b));
      EXPECT_EQ(rollout.commands_velocities(), velocities);
      const auto r = run_episode(env, rollout);
      EXPECT_LE(failures(r), failures(base)) << rollout.name() << " seed " << seed;
      if (failures(r) == failures(base)) {
        EXPECT_GE(r.objective, base.objective) << rollout.name() << " seed " << seed;
      }
      improved += failures(r) < failures(base) || r.objective > base.objective * (1 + 1e-9);
      std::cout << rollout.name() << ": failures " << failures(base) << " -> " << failures(r) << ", objective " << base.objective
                << " -> " << r.objective << "\n";
    }
  }
  EXPECT_EQ(improved, 2) << "the rollout did not improve on each base: the test proves nothing";
}
