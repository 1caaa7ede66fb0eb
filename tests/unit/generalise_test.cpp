// Layouts that a policy never saw, the safety masks, and the set observation.
#include <gtest/gtest.h>

#include <cmath>
#include <functional>
#include <set>
#include <stdexcept>

#include "skyloop/beamforming/linear.hpp"
#include "skyloop/core/error.hpp"
#include "skyloop/core/parallel.hpp"
#include "skyloop/core/rng.hpp"
#include "skyloop/env/layouts.hpp"
#include "skyloop/env/vec_env.hpp"
#include "skyloop/planning/planners.hpp"
#include "skyloop/planning/safety.hpp"
#include "skyloop/planning/ways_home.hpp"

using namespace skyloop;

namespace {

std::shared_ptr<const Beamformer> zf_bf() { return std::make_shared<ZfBeamformer>(); }

UavEnv make_env(const Config& cfg, const Positions& users) {
  return UavEnv(cfg, std::make_shared<RateOracle>(cfg, zf_bf(), users));
}

/// N UAVs crowded on a 100 x 100 m area: many states where some moves collide.
Config crowded(int uavs) {
  Config cfg;
  cfg.scenario.area_x_m = cfg.scenario.area_y_m = 100;
  cfg.scenario.uavs = uavs;
  cfg.scenario.users = 6;
  cfg.trajectory.layout = LayoutSource::Generated;
  cfg.trajectory.t_max = 12;
  cfg.trajectory.layout_seed = 7;
  finalise(cfg);
  return cfg;
}

}  // namespace

TEST(Layouts, SplitsAreDisjointRangesOfSeeds) {
  constexpr std::uint64_t span = std::uint64_t{1} << 62;
  EXPECT_EQ(layout_seed(LayoutSplit::Train, 5), 5u);
  EXPECT_EQ(layout_seed(LayoutSplit::Validation, 0), span);
  EXPECT_EQ(layout_seed(LayoutSplit::Test, 3), 2 * span + 3);
  for (auto s : {LayoutSplit::Train, LayoutSplit::Validation, LayoutSplit::Test})
    for (std::uint64_t i : {std::uint64_t{0}, std::uint64_t{1}, span - 1}) EXPECT_EQ(layout_split(layout_seed(s, i)), s);
  EXPECT_THROW(layout_seed(LayoutSplit::Train, span), InputError);
  EXPECT_THROW(layout_split(3 * span), InputError);
  // Whatever the run seed, environment and episode, training draws from the training range.
  for (std::uint64_t seed = 0; seed < 50; ++seed)
    for (std::uint64_t env = 0; env < 8; ++env)
      for (std::uint64_t ep = 0; ep < 50; ++ep) ASSERT_EQ(layout_split(training_layout_seed(seed, env, ep)), LayoutSplit::Train);
  EXPECT_EQ(parse_layout_split("validation", "--split"), LayoutSplit::Validation);
  EXPECT_THROW(parse_layout_split("holdout", "--split"), InputError);
}

TEST(Layouts, TrainingEnvironmentsNeverMeetATestLayout) {
  Config cfg;
  cfg.scenario.users = 4;
  cfg.env.resample_users = true;
  std::set<std::vector<double>> test;
  for (std::uint64_t i = 0; i < 200; ++i) {
    const auto u = layout_users(cfg, layout_seed(LayoutSplit::Test, i));
    test.insert(std::vector<double>(u.data(), u.data() + u.size()));
  }
  VecEnv vec(cfg, zf_bf(), 4, 11);
  std::set<std::vector<double>> seen;
  for (int step = 0; step < 23 * 60; ++step) {
    for (int e = 0; e < vec.size(); ++e) {
      const auto& u = vec.env(e).oracle().users();
      const std::vector<double> key(u.data(), u.data() + u.size());
      ASSERT_EQ(test.count(key), 0u) << "environment " << e << " drew a test layout";
      seen.insert(key);
    }
    vec.step(std::vector<std::vector<int>>(4, std::vector<int>(3, kStay)));
  }
  EXPECT_GE(seen.size(), 4u * 50) << "the environments did not resample their users";
}

TEST(Layouts, UserCountIsSeededAndInItsRange) {
  Config cfg;
  cfg.scenario.users = 12;
  // Fixed K: the users of `skyloop plan --seed`.
  EXPECT_EQ(layout_user_count(cfg, 9), 12);
  EXPECT_TRUE(layout_users(cfg, 9).isApprox(make_users(cfg, 12, 9)));
  cfg.env.users_min = 8;
  cfg.env.users_max = 16;
  std::set<int> ks;
  for (std::uint64_t i = 0; i < 300; ++i) {
    const auto s = layout_seed(LayoutSplit::Test, i);
    const int k = layout_user_count(cfg, s);
    ASSERT_GE(k, 8);
    ASSERT_LE(k, 16);
    ASSERT_EQ(layout_users(cfg, s).rows(), k);
    ASSERT_EQ(layout_user_count(cfg, s), k);
    ks.insert(k);
  }
  EXPECT_EQ(ks.size(), 9u);
  EXPECT_EQ(max_layout_users(cfg), 16);
  // A K range with the paper's state (4N + 2K reals) is refused.
  EXPECT_THROW(validate(cfg), InputError);
  cfg.env.state = StateKind::Compact;
  EXPECT_NO_THROW(validate(cfg));
  cfg.env.users_min = 20;
  EXPECT_THROW(validate(cfg), InputError);
}

TEST(Safety, TheMaskNeverChoosesAnUnreachableMoveAndBringsEveryUavHome) {
  Config cfg;
  Rng rng(3);
  for (std::uint64_t layout = 0; layout < 10; ++layout) {
    UavEnv env = make_env(cfg, layout_users(cfg, layout_seed(LayoutSplit::Test, layout)));
    env.reset();
    while (!env.done()) {
      // Scores that want to fly anywhere, the boundary and away from the destination included.
      std::vector<std::vector<float>> scores(3, std::vector<float>(kGridActions));
      for (auto& s : scores)
        for (auto& x : s) x = static_cast<float>(rng.normal());
      const auto a = shielded_argmax(env, SafetyOptions{true, false}, scores);
      for (int n = 0; n < env.uavs(); ++n) {
        ASSERT_TRUE(env.feasible(n, a[static_cast<std::size_t>(n)])) << "UAV " << n << " at t = " << env.t();
        ASSERT_TRUE(reachable_moves(env, n) >> a[static_cast<std::size_t>(n)] & 1u);
      }
      env.step(a);
    }
    EXPECT_TRUE(env.positions().isApprox(env.destinations())) << "layout " << layout;
    EXPECT_EQ(env.total_boundary(), 0);
  }
}

TEST(Safety, TheShieldNeverCollidesWhenAJointMoveAvoidsIt) {
  for (int uavs : {3, 4, 5}) {
    const Config cfg = crowded(uavs);
    UavEnv env = make_env(cfg, layout_users(cfg, 1));
    Rng rng(static_cast<std::uint64_t>(uavs));
    int avoidable = 0, unavoidable = 0, saved = 0;
    for (int episode = 0; episode < 30; ++episode) {
      env.reset();
      while (!env.done()) {
        std::vector<std::vector<float>> scores(static_cast<std::size_t>(uavs), std::vector<float>(kGridActions));
        for (auto& s : scores)
          for (auto& x : s) x = static_cast<float>(rng.normal());
        const auto a = shielded_argmax(env, SafetyOptions{true, true}, scores);
        // Brute force over the joint actions of the masked moves.
        bool exists = false;
        int total = 1;
        for (int n = 0; n < uavs; ++n) total *= kGridActions;
        for (int j = 0; j < total && !exists; ++j) {
          std::vector<int> b(static_cast<std::size_t>(uavs));
          bool ok = true;
          for (int n = 0, r = j; n < uavs; ++n, r /= kGridActions) {
            b[static_cast<std::size_t>(n)] = r % kGridActions;
            ok = ok && (allowed_moves(env, n, SafetyOptions{}) >> (r % kGridActions) & 1u);
          }
          exists = ok && env.collisions(env.next_positions(b)) == 0;
        }
        const int chosen = env.collisions(env.next_positions(a));
        saved += chosen == 0 && env.collisions(env.next_positions(shielded_argmax(env, SafetyOptions{true, false}, scores))) > 0;
        if (exists) {
          ++avoidable;
          ASSERT_EQ(chosen, 0) << uavs << " UAVs, t = " << env.t();
        } else {
          ++unavoidable;
        }
        for (int n = 0; n < uavs; ++n) ASSERT_TRUE(allowed_moves(env, n, SafetyOptions{}) >> a[static_cast<std::size_t>(n)] & 1u);
        env.step(a);
      }
    }
    EXPECT_GT(avoidable, 100) << uavs << " UAVs";
    EXPECT_GT(saved, 10) << uavs << " UAVs: the shield never had to act; the test proves nothing";
  }
}

TEST(Safety, SequentialChoiceStaysInsideTheAllowedMoves) {
  const Config cfg = crowded(4);
  UavEnv env = make_env(cfg, layout_users(cfg, 2));
  Rng rng(9);
  int shielded = 0;
  while (!env.done()) {
    std::vector<ActionSet> allowed;
    const auto a = sequential_safe_actions(env, SafetyOptions{}, [&](int n, ActionSet ok) {
      std::vector<int> c;
      for (int k = 0; k < kGridActions; ++k)
        if (ok >> k & 1u) c.push_back(k);
      EXPECT_FALSE(c.empty());
      shielded += ok != allowed_moves(env, n, SafetyOptions{});
      return c[rng.below(c.size())];
    }, &allowed);
    for (int n = 0; n < env.uavs(); ++n) {
      ASSERT_TRUE(allowed[static_cast<std::size_t>(n)] >> a[static_cast<std::size_t>(n)] & 1u);
      ASSERT_EQ(allowed[static_cast<std::size_t>(n)] & ~allowed_moves(env, n, SafetyOptions{}), 0u);
    }
    env.step(a);
  }
  // Without the mask and the shield every action is allowed.
  env.reset();
  for (int n = 0; n < env.uavs(); ++n) EXPECT_EQ(allowed_moves(env, n, SafetyOptions{false, false}), all_actions(env));
}

TEST(Env, SetObservationIgnoresTheOrderOfUsersAndUavs) {
  Config cfg;
  cfg.scenario.users = 9;
  const Positions users = make_users(cfg, 9, 4);
  Positions reversed = users.colwise().reverse();
  UavEnv a = make_env(cfg, users), b = make_env(cfg, reversed);
  // The same UAVs in another order: UAV n of `c` is UAV perm[n] of `a`.
  const std::vector<int> perm{2, 0, 1};
  Config swapped = cfg;
  for (int n = 0; n < 3; ++n) {
    swapped.trajectory.starts[static_cast<std::size_t>(n)] = cfg.trajectory.starts[static_cast<std::size_t>(perm[static_cast<std::size_t>(n)])];
    swapped.trajectory.destinations[static_cast<std::size_t>(n)] = cfg.trajectory.destinations[static_cast<std::size_t>(perm[static_cast<std::size_t>(n)])];
  }
  UavEnv c = make_env(swapped, users);
  const int D = a.set_observation_size();
  Rng rng(1);
  for (int t = 0; t < 6; ++t) {
    for (int n = 0; n < 3; ++n) {
      std::vector<float> oa(static_cast<std::size_t>(D)), ob(oa.size()), oc(oa.size());
      a.write_set_observation(n, oa.data());
      b.write_set_observation(n, ob.data());
      int m = 0;
      while (perm[static_cast<std::size_t>(m)] != n) ++m;
      c.write_set_observation(m, oc.data());
      for (int i = 0; i < D; ++i) {
        ASSERT_NEAR(oa[static_cast<std::size_t>(i)], ob[static_cast<std::size_t>(i)], 1e-6) << "users reordered, feature " << i;
        ASSERT_NEAR(oa[static_cast<std::size_t>(i)], oc[static_cast<std::size_t>(i)], 1e-6) << "UAVs reordered, feature " << i;
      }
    }
    std::vector<int> act(3);
    for (auto& x : act) x = static_cast<int>(rng.below(kGridActions));
    std::vector<int> act_c(3);
    for (int n = 0; n < 3; ++n) act_c[static_cast<std::size_t>(n)] = act[static_cast<std::size_t>(perm[static_cast<std::size_t>(n)])];
    a.step(act), b.step(act), c.step(act_c);
  }
  // The size is independent of K and N.
  Config other = crowded(5);
  UavEnv d = make_env(other, layout_users(other, 3));
  std::vector<float> od(static_cast<std::size_t>(D) + 1, -7.0f);
  d.write_set_observation(0, od.data());
  EXPECT_EQ(od.back(), -7.0f) << "wrote past set_observation_size()";
}

// The users' kernel maps are kept per UAV coordinate between calls: what an environment writes
// stays what a fresh computation writes, over an episode's moves (grid, headings and continuous
// mobility, where every coordinate is new), in a copy (which starts with none kept), after new
// users (set_oracle), and past the bound on what is kept (thousands of continuous slots).
TEST(Env, SetObservationKeptPerCoordinateEqualsAFreshOne) {
  for (const char* mobility : {"grid", "headings", "continuous"}) {
    Config cfg;
    cfg.scenario.users = 40;
    cfg.marl.encoder = ObservationKind::Set;
    cfg.trajectory.mobility = mobility;
    finalise(cfg);
    const bool continuous = std::string(mobility) == "continuous";
    UavEnv env = make_env(cfg, make_users(cfg, 40, 8));
    const int D = env.set_observation_size();
    Rng rng(5);
    auto expect_same = [&](const UavEnv& a, const UavEnv& b, const std::string& what) {
      for (int n = 0; n < a.uavs(); ++n) {
        std::vector<float> oa(static_cast<std::size_t>(D)), ob(oa.size());
        a.write_set_observation(n, oa.data());
        b.write_set_observation(n, ob.data());
        ASSERT_EQ(oa, ob) << mobility << ", " << what << ", UAV " << n << ", t = " << a.t();
      }
    };
    auto random_step = [&](UavEnv& a, UavEnv& b) {
      if (continuous) {
        Positions v(a.uavs(), 2);
        for (int n = 0; n < a.uavs(); ++n) v(n, 0) = 2 * rng.uniform() - 1, v(n, 1) = 2 * rng.uniform() - 1;
        a.step_velocities(v), b.step_velocities(v);
      } else {
        std::vector<int> act(static_cast<std::size_t>(a.uavs()));
        for (auto& x : act) x = static_cast<int>(rng.below(static_cast<std::uint64_t>(a.actions())));
        a.step(act), b.step(act);
      }
    };
    // Episodes of the same environment against a copy made afresh every slot.
    const int episodes = continuous ? 120 : 3;  // continuous: past the bound (2^21 doubles) at K = 40
    for (int e = 0; e < episodes; ++e) {
      env.reset();
      while (!env.done()) {
        UavEnv fresh = env;
        if (e == 0 || e + 1 == episodes) expect_same(env, fresh, "episode " + std::to_string(e));
        else env.write_set_observation(0, std::vector<float>(static_cast<std::size_t>(D)).data());
        random_step(env, fresh);
      }
    }
    // New users: the kernels are theirs, not the kept ones of the users before.
    const Positions other = make_users(cfg, 40, 9);
    env.set_oracle(std::make_shared<RateOracle>(cfg, zf_bf(), other));
    UavEnv built = make_env(cfg, other);
    for (int t = 0; t < 5 && !env.done(); ++t) {
      expect_same(env, built, "new users");
      random_step(env, built);
    }
  }
}

namespace {
/// One slot of uniformly random moves among those the reachability mask allows.
void step_at_random(UavEnv& env, Rng& rng) {
  std::vector<int> act(static_cast<std::size_t>(env.uavs()));
  for (int n = 0; n < env.uavs(); ++n) {
    const auto allowed = allowed_moves(env, n, SafetyOptions{});
    do act[static_cast<std::size_t>(n)] = static_cast<int>(rng.below(static_cast<std::uint64_t>(env.actions())));
    while (!(allowed >> act[static_cast<std::size_t>(n)] & 1u));
  }
  env.step(act);
}

/// The paper scenario with 9 users, the set observation, the moves' gains and a radio map of radius `rate_map`.
Config look_ahead_scene(const char* mobility, int rate_map) {
  Config cfg;
  cfg.scenario.users = 9;
  cfg.marl.encoder = ObservationKind::Set;
  cfg.marl.lookahead = true;
  cfg.marl.rate_map = rate_map;
  cfg.trajectory.mobility = mobility;
  finalise(cfg);
  return cfg;
}
}  // namespace

// marl.lookahead: the set observation's move_gains are tanh(kGainScale (R_a - R) / R), R_a the
// sum rate with this UAV moved by a and the others in place, asked of a separate oracle here; a
// lone UAV's Greedy move has the largest gain among its feasible moves; an arrived UAV sees zeros.
TEST(Env, MoveGainsAreTheOneSlotLookAhead) {
  for (const char* mobility : {"grid", "headings"}) {
    const Config cfg = look_ahead_scene(mobility, 0);
    const Positions users = make_users(cfg, 9, 5);
    UavEnv env = make_env(cfg, users);
    RateOracle reference(cfg, zf_bf(), users);
    const ArraySpec& obs = env.spec().set_obs;
    const SpecField& f = obs.field("move_gains");
    ASSERT_EQ(f.size, env.actions()) << mobility;
    ASSERT_EQ(f.offset + f.size, obs.size) << mobility;
    Rng rng(3);
    int checked = 0;
    while (!env.done()) {
      for (int n = 0; n < env.uavs(); ++n) {
        std::vector<float> o(static_cast<std::size_t>(obs.size));
        env.write_set_observation(n, o.data());
        const double now = reference.sum_rate(env.positions());
        for (int a = 0; a < env.actions(); ++a) {
          Positions p = env.positions();
          const auto l = env.landing(n, a);
          p(n, 0) = l.x, p(n, 1) = l.y;
          const double want = env.arrived(n) ? 0.0 : std::tanh(kGainScale * (reference.sum_rate(p) - now) / now);
          ASSERT_NEAR(o[static_cast<std::size_t>(f.offset + a)], want, 1e-6) << mobility << ", UAV " << n << ", action " << a;
          ++checked;
        }
      }
      step_at_random(env, rng);
    }
    EXPECT_GT(checked, 100) << mobility;
    for (int n = 0; n < env.uavs(); ++n) {
      ASSERT_TRUE(env.arrived(n)) << mobility;
      std::vector<float> o(static_cast<std::size_t>(obs.size));
      env.write_set_observation(n, o.data());
      for (int a = 0; a < f.size; ++a) EXPECT_EQ(o[static_cast<std::size_t>(f.offset + a)], 0.0f) << mobility;
    }
  }
  // One UAV: Greedy's move has the largest gain among the feasible moves, every slot.
  Config one;
  one.scenario.users = 9;
  one.marl.encoder = ObservationKind::Set;
  one.marl.lookahead = true;
  one.trajectory.starts = {{20, 20}};
  one.trajectory.destinations = {{180, 180}};
  finalise(one);
  UavEnv env = make_env(one, make_users(one, 9, 6));
  GreedyPlanner greedy;
  greedy.reset(env);
  const SpecField& f = env.spec().set_obs.field("move_gains");
  while (!env.done()) {
    std::vector<float> o(static_cast<std::size_t>(env.set_observation_size()));
    env.write_set_observation(0, o.data());
    const auto a = greedy.act(env);
    for (int b = 0; b < env.actions(); ++b)
      if (env.feasible(0, b)) {
        EXPECT_GE(o[static_cast<std::size_t>(f.offset + a[0])], o[static_cast<std::size_t>(f.offset + b)]) << "t = " << env.t();
      }
    env.step(a);
  }
  // The paper's observation has no look-ahead: refused in one line.
  Config mlp = one;
  mlp.marl.encoder = ObservationKind::Paper;
  try {
    validate(mlp);
    ADD_FAILURE() << "marl.lookahead with marl.encoder = mlp was accepted";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("marl.lookahead"), std::string::npos) << e.what();
  }
}

// marl.sequential: with UAV m's chosen landing shown (UavEnv::show_decided), another UAV's set
// observation is the one it would read with m standing there: its UAV kernels, and its move gains
// and radio map with m there (asked of a separate oracle); its own fields do not change; clearing,
// stepping and resetting show the UAVs where they are again.
TEST(Env, DecidedLandingsAreWhatTheLaterAgentsSee) {
  const Config cfg = look_ahead_scene("grid", 1);
  const Positions users = make_users(cfg, 9, 5);
  UavEnv env = make_env(cfg, users);
  ASSERT_GE(env.uavs(), 2);
  RateOracle reference(cfg, zf_bf(), users);
  const ArraySpec& obs = env.spec().set_obs;
  const SpecField& gains = obs.field("move_gains");
  const SpecField& wide = obs.field("uavs_wide");
  const auto D = static_cast<std::size_t>(obs.size);
  Rng rng(4);
  step_at_random(env, rng);
  int changed = 0;
  for (int a = 0; a < env.actions(); ++a) {
    if (!env.feasible(0, a) || a == env.hover()) continue;
    std::vector<float> before(D), shown(D), after(D);
    env.write_set_observation(1, before.data());
    const auto l = env.landing(0, a);
    const Positions where = env.positions();
    env.show_decided(0, l.x, l.y, l.z);
    EXPECT_EQ(env.positions(), where) << "the UAVs stay where they are";
    env.write_set_observation(1, shown.data());
    Positions there = env.positions();
    there(0, 0) = l.x, there(0, 1) = l.y;
    EXPECT_EQ(env.seen_positions(), there);
    const double now = reference.sum_rate(there);
    for (int b = 0; b < env.actions(); ++b) {
      Positions p = there;
      const auto m = env.landing(1, b);
      p(1, 0) = m.x, p(1, 1) = m.y;
      ASSERT_NEAR(shown[static_cast<std::size_t>(gains.offset + b)], std::tanh(kGainScale * (reference.sum_rate(p) - now) / now), 1e-6)
          << "UAV 0's move " << a << ", UAV 1's move " << b;
    }
    for (int i = 0; i < obs.field("users_density").offset; ++i)  // own position, destination, slack, time, previous move
      EXPECT_EQ(shown[static_cast<std::size_t>(i)], before[static_cast<std::size_t>(i)]) << "field entry " << i;
    if (!std::equal(shown.begin() + wide.offset, shown.begin() + wide.offset + wide.size, before.begin() + wide.offset)) ++changed;
    env.clear_decided();
    EXPECT_EQ(env.seen_positions(), env.positions());
    env.write_set_observation(1, after.data());
    EXPECT_EQ(after, before) << "cleared";
  }
  EXPECT_GT(changed, 0) << "UAV 0's landing shows in UAV 1's grid of the UAVs around it";
  // A step and a reset show the UAVs where they are.
  const auto l = env.landing(0, env.hover());
  env.show_decided(0, l.x + 10, l.y, l.z);
  env.step(std::vector<int>(static_cast<std::size_t>(env.uavs()), env.hover()));
  EXPECT_EQ(env.seen_positions(), env.positions());
  env.show_decided(1, 3, 4, env.altitude(1));
  env.reset();
  EXPECT_EQ(env.seen_positions(), env.positions());
  EXPECT_THROW(env.show_decided(env.uavs(), 0, 0, 100), std::out_of_range);
  // The paper's observation shows no other UAV; the value-decomposition learners and continuous
  // commands choose at once: each refused in one line naming marl.sequential.
  for (const auto& bad : std::vector<std::pair<const char*, std::function<void(Config&)>>>{
           {"mlp", [](Config& c) { c.marl.encoder = ObservationKind::Paper, c.marl.lookahead = false, c.marl.rate_map = 0; }},
           {"vdn", [](Config& c) { c.marl.algo = "vdn"; }},
           {"continuous", [](Config& c) { c.trajectory.mobility = "continuous"; }}}) {
    Config c = cfg;
    c.marl.sequential = true;
    bad.second(c);
    try {
      validate(c);
      ADD_FAILURE() << "marl.sequential with " << bad.first << " was accepted";
    } catch (const InputError& e) {
      EXPECT_NE(std::string(e.what()).find("marl.sequential"), std::string::npos) << e.what();
      EXPECT_NE(std::string(e.what()).find(bad.first), std::string::npos) << e.what();
    }
  }
}

// marl.rate_map = r: the radio map around the UAV. The cells are every lattice offset within r
// moves, once each, ring by ring; each value is tanh(kGainScale (R_c - R) / R) with R_c the sum
// rate with this UAV at x + D_fly c (asked of a separate oracle here), -1 outside the area, zeros
// once arrived; on the grid model the first ring is the four moves' gains (marl.lookahead).
TEST(Env, RateMapIsTheRadioMapAroundTheUav) {
  for (int r = 1; r <= kMaxRateMap; ++r) {
    const auto cells = rate_map_offsets(r);
    ASSERT_EQ(cells.size(), static_cast<std::size_t>(2 * r * (r + 1))) << "radius " << r;
    std::set<std::array<int, 2>> seen(cells.begin(), cells.end());
    EXPECT_EQ(seen.size(), cells.size()) << "radius " << r << ": a cell twice";
    int ring = 1;
    for (const auto& c : cells) {
      const int d = std::abs(c[0]) + std::abs(c[1]);
      EXPECT_GE(d, ring) << "radius " << r << ": rings out of order";
      ring = d;
      EXPECT_LE(d, r);
    }
  }
  EXPECT_EQ(rate_map_offsets(1), (std::vector<std::array<int, 2>>{{1, 0}, {0, 1}, {-1, 0}, {0, -1}}));
  for (const char* mobility : {"grid", "continuous"}) {
    const Config cfg = look_ahead_scene(mobility, 2);
    const Positions users = make_users(cfg, 9, 5);
    UavEnv env = make_env(cfg, users);
    RateOracle reference(cfg, zf_bf(), users);
    const ArraySpec& obs = env.spec().set_obs;
    const SpecField& f = obs.field("rate_map");
    const SpecField& gains = obs.field("move_gains");
    ASSERT_EQ(f.size, 12) << mobility;
    ASSERT_EQ(f.offset + f.size, obs.size) << mobility << ": rate_map is the last field";
    const auto cells = rate_map_offsets(2);
    Rng rng(4);
    int checked = 0, outside = 0;
    while (!env.done()) {
      for (int n = 0; n < env.uavs(); ++n) {
        std::vector<float> o(static_cast<std::size_t>(obs.size));
        env.write_set_observation(n, o.data());
        const double now = reference.sum_rate(env.positions());
        for (int c = 0; c < f.size; ++c) {
          Positions p = env.positions();
          p(n, 0) += cfg.trajectory.d_fly_m * cells[static_cast<std::size_t>(c)][0];
          p(n, 1) += cfg.trajectory.d_fly_m * cells[static_cast<std::size_t>(c)][1];
          const bool out = p(n, 0) < 0 || p(n, 1) < 0 || p(n, 0) > cfg.scenario.area_x_m || p(n, 1) > cfg.scenario.area_y_m;
          const double want = env.arrived(n) ? 0.0 : out ? -1.0 : std::tanh(kGainScale * (reference.sum_rate(p) - now) / now);
          ASSERT_NEAR(o[static_cast<std::size_t>(f.offset + c)], want, 1e-6) << mobility << ", UAV " << n << ", cell " << c;
          outside += out && !env.arrived(n);
          ++checked;
        }
        if (std::string(mobility) == "grid" && !env.arrived(n))  // UP, DOWN, LEFT, RIGHT are cells 1, 3, 2, 0
          for (const auto& [a, c] : {std::pair{0, 1}, std::pair{1, 3}, std::pair{2, 2}, std::pair{3, 0}})
            if (env.feasible(n, a)) {
              EXPECT_EQ(o[static_cast<std::size_t>(gains.offset + a)], o[static_cast<std::size_t>(f.offset + c)]) << "action " << a;
            }
      }
      step_at_random(env, rng);
    }
    EXPECT_GT(checked, 300) << mobility;
    EXPECT_GT(outside, 0) << mobility << ": the starts sit at the area's edge";
    for (int n = 0; n < env.uavs(); ++n) {
      std::vector<float> o(static_cast<std::size_t>(obs.size));
      env.write_set_observation(n, o.data());
      for (int c = 0; c < f.size; ++c) EXPECT_EQ(o[static_cast<std::size_t>(f.offset + c)], 0.0f) << mobility;
    }
  }
  // The paper's observation has no radio map, and the radius is bounded: each refused in one line.
  for (const auto& [encoder, radius] : {std::pair{"mlp", 2}, std::pair{"set", kMaxRateMap + 1}, std::pair{"set", -1}}) {
    Config bad;
    bad.marl.encoder = parse_choice<ObservationKind>("marl.encoder", encoder);
    std::string error;
    try {
      set_field(bad, *find_field("marl.rate_map"), FieldValue(static_cast<std::int64_t>(radius)));
      validate(bad);
    } catch (const InputError& e) {
      error = e.what();
    }
    EXPECT_NE(error.find("marl.rate_map"), std::string::npos) << encoder << ", " << radius << ": " << error;
    EXPECT_EQ(error.find('\n'), std::string::npos) << error;
  }
}

TEST(Env, ObjectiveRewardSumsToTheObjective) {
  Config cfg;
  cfg.env.reward = Reward::Objective;
  cfg.env.w_bud = cfg.env.w_col = 0;
  UavEnv env = make_env(cfg, make_users(cfg, 12, 5));
  for (std::uint64_t s = 0; s < 3; ++s) {
    RandomPlanner p(s);
    const auto r = run_episode(env, p);
    EXPECT_NEAR(r.reward, r.objective - r.rates.front(), 1e-9 * r.objective);
  }
}

// The slack margin: the mask plans every UAV home m slots early and the shield spends the margin
// only to avoid a collision. Flown from the start with random scores on crowded scenes, every UAV
// is home by T_max with no boundary event, every move is in the plain mask, and fewer slots end in
// a collision than without the margin (head-on meetings of UAVs with no slack left).
TEST(Safety, ASlackMarginLetsTheShieldAvoidHeadOnTraps) {
  int with_margin = 0, without = 0;
  for (int uavs : {5, 6})
    for (std::uint64_t seed = 1; seed <= 20; ++seed) {
      Config cfg = crowded(uavs);
      cfg.trajectory.layout_seed = seed;
      cfg.trajectory.t_max = 16;
      finalise(cfg);
      UavEnv env = make_env(cfg, layout_users(cfg, seed));
      for (const int margin : {0, 2}) {
        Rng rng(seed);
        env.reset();
        int collided = 0;
        while (!env.done()) {
          std::vector<std::vector<float>> scores(static_cast<std::size_t>(uavs), std::vector<float>(kGridActions));
          for (auto& s : scores)
            for (auto& x : s) x = static_cast<float>(rng.normal());
          const SafetyOptions safety{true, true, margin};
          const auto a = shielded_argmax(env, safety, scores);
          for (int n = 0; n < uavs; ++n) {
            ASSERT_TRUE(reachable_moves(env, n, 0) >> a[static_cast<std::size_t>(n)] & 1u);
            EXPECT_EQ(reachable_moves(env, n, margin) & ~reachable_moves(env, n, 0), 0u) << "the margin only removes moves";
          }
          collided += env.collisions(env.next_positions(a)) > 0;
          env.step(a);
        }
        EXPECT_TRUE(env.positions().isApprox(env.destinations())) << uavs << " UAVs, seed " << seed << ", margin " << margin;
        EXPECT_EQ(env.total_boundary(), 0);
        (margin ? with_margin : without) += collided;
      }
    }
  EXPECT_GT(without, 0) << "the scenes should hold head-on traps";
  EXPECT_LT(with_margin, without);
}

// Two UAVs flying past each other on adjacent rows (20 m apart, D_min 25 m), 2 slots of slack
// each, under random scores: without a margin the scores spend the slack and the two meet with
// none left (a collision no move avoids); with a margin of 2 the shield still has it to spend,
// and no episode collides.
TEST(Safety, ASlackMarginAvoidsHeadOnMeetings) {
  Config cfg;
  cfg.scenario.area_x_m = cfg.scenario.area_y_m = 200;
  cfg.trajectory.starts = {{0, 100}, {200, 120}};
  cfg.trajectory.destinations = {{200, 100}, {0, 120}};
  cfg.trajectory.t_max = 13;  // 10 moves each: 11 slots, plus 2 of slack
  UavEnv env = make_env(cfg, layout_users(cfg, 1));
  int collided[2] = {0, 0};
  for (const int margin : {0, 2})
    for (std::uint64_t episode = 0; episode < 50; ++episode) {
      Rng rng(episode);
      env.reset();
      while (!env.done()) {
        std::vector<std::vector<float>> scores(2, std::vector<float>(kGridActions));
        for (auto& s : scores)
          for (auto& x : s) x = static_cast<float>(rng.normal());
        const auto a = shielded_argmax(env, SafetyOptions{true, true, margin}, scores);
        collided[margin ? 1 : 0] += env.collisions(env.next_positions(a)) > 0;
        env.step(a);
      }
      EXPECT_TRUE(env.positions().isApprox(env.destinations())) << "margin " << margin << ", episode " << episode;
    }
  EXPECT_GT(collided[0], 0) << "without a margin the two should sometimes meet with no slack left";
  EXPECT_EQ(collided[1], 0);
}

// UAV 1 parks at (100, 100), on UAV 0's straight way from (0, 100) to (200, 100) (D_fly 20 m,
// D_min 25 m: the parked UAV closes its own point and the four at 20 m). By hand: through it, 10
// moves; around it, UAV 0 must cross x = 100 at y = 60 or 140 (|dy| >= 40 there), 4 moves more.
TEST(Safety, MovesAroundAParkedUavCountTheDetour) {
  Config cfg;
  cfg.scenario.area_x_m = cfg.scenario.area_y_m = 200;
  cfg.trajectory.starts = {{0, 100}, {100, 140}};
  cfg.trajectory.destinations = {{200, 100}, {100, 100}};
  cfg.trajectory.t_max = 15;  // 10 moves + 1, and 4 slots of slack for the detour
  UavEnv env = make_env(cfg, layout_users(cfg, 1));
  auto at = [](double x, double y) {
    UavEnv::Landing l;
    l.x = x, l.y = y;
    return l;
  };
  using C = UavEnv::ClearOf;
  EXPECT_EQ(env.min_moves(0, 0, 100, env.altitude(0)), 10);
  EXPECT_EQ(env.min_moves_around(0, at(0, 100), C::Parked), 10) << "nobody has arrived yet";
  EXPECT_EQ(env.min_moves_around(0, at(0, 100), C::Destinations), 14);
  EXPECT_EQ(env.min_moves_around(0, at(80, 100), C::Destinations), 16) << "a closed point: out of reach (t_max + 1)";
  EXPECT_EQ(env.min_moves_around(0, at(0, 140), C::Destinations), 12);
  EXPECT_EQ(env.min_moves_around(1, at(100, 140), C::Destinations), 2) << "its own destination stays open";
  // Under the destinations clearance UAV 0 has no slack beyond the detour's: it may not wait
  // (STAY); without it, it may (4 slots of slack through the parked point).
  EXPECT_EQ(reachable_moves(env, 0, 0, Clearance::Destinations), action_bit(kUp) | action_bit(kDown) | action_bit(kRight));
  EXPECT_EQ(reachable_moves(env, 0, 0, Clearance::None), action_bit(kUp) | action_bit(kDown) | action_bit(kRight) | action_bit(kStay));
  // UAV 1 parks; the Parked count now sees it.
  env.step({kStay, kDown});
  env.step({kStay, kDown});
  ASSERT_TRUE(env.arrived(1));
  EXPECT_EQ(env.min_moves_around(0, at(0, 100), C::Parked), 14);
  EXPECT_EQ(env.min_moves_around(0, at(0, 100), C::Destinations), 14);
  // Out of slack for the detour (2 slots spent above): the count falls back to going through.
  EXPECT_EQ(reachable_moves(env, 0, 0, Clearance::Destinations), reachable_moves(env, 0, 0, Clearance::None));

  // Under random scores, without the clearance the scores spend UAV 0's slack before it reaches
  // the parked UAV, which it then meets on its only way home; with it, no episode collides.
  int collided[2] = {0, 0};
  for (const Clearance clearance : {Clearance::None, Clearance::Destinations})
    for (std::uint64_t episode = 0; episode < 50; ++episode) {
      Rng rng(episode);
      env.reset();
      while (!env.done()) {
        std::vector<std::vector<float>> scores(2, std::vector<float>(kGridActions));
        for (auto& s : scores)
          for (auto& x : s) x = static_cast<float>(rng.normal());
        const auto a = shielded_argmax(env, SafetyOptions{true, true, 0, clearance}, scores);
        collided[clearance == Clearance::None ? 0 : 1] += env.collisions(env.next_positions(a)) > 0;
        env.step(a);
      }
      EXPECT_TRUE(env.positions().isApprox(env.destinations())) << "episode " << episode;
    }
  EXPECT_GT(collided[0], 0) << "without the clearance UAV 0 should sometimes meet the parked UAV with no slack left";
  EXPECT_EQ(collided[1], 0);
}

// Environments made like another (UavEnv(like, oracle): the VecEnv's copies, the validation and
// evaluation layouts) share its lattice tables instead of making them again. They must mask, count
// the moves around the other UAVs and step exactly as environments made afresh from the
// configuration, under grid and headings mobility with both clearance tables in use, while copies
// on two threads ask for the shared tables at once.
TEST(Env, EnvironmentsMadeLikeAnotherStepAsFreshOnes) {
  for (const std::string mobility : {"grid", "headings"}) {
    Config cfg;
    cfg.scenario.area_x_m = cfg.scenario.area_y_m = 100;
    cfg.scenario.uavs = 4;
    cfg.scenario.users = 6;
    cfg.trajectory.layout = LayoutSource::Generated;
    cfg.trajectory.t_max = 12;
    cfg.trajectory.layout_seed = 7;
    cfg.trajectory.mobility = mobility;
    if (mobility == "headings") cfg.trajectory.speeds_mps = {0, 10, 20};
    cfg.marl.mask_clearance = Clearance::Destinations;
    finalise(cfg);
    const SafetyOptions safety = safety_options(cfg);
    const UavEnv like = make_env(cfg, layout_users(cfg, 1));
    constexpr int kPairs = 4;
    std::vector<int> differ(kPairs, 0), compared(kPairs, 0);
    parallel_for(kPairs, 2, [&](std::size_t p) {
      const Positions users = layout_users(cfg, 10 + p);
      UavEnv fresh = make_env(cfg, users);
      UavEnv copy(like, std::make_shared<RateOracle>(cfg, zf_bf(), users));
      Rng rng(p);
      auto check = [&](bool same) { differ[p] += same ? 0 : 1, ++compared[p]; };
      for (int episode = 0; episode < 3; ++episode) {
        fresh.reset(), copy.reset();
        while (!fresh.done()) {
          for (int n = 0; n < fresh.uavs(); ++n)
            for (int a = 0; a < fresh.actions(); ++a)
              for (const auto what : {UavEnv::ClearOf::Destinations, UavEnv::ClearOf::Parked}) {
                check(fresh.min_moves_around(n, fresh.landing(n, a), what) == copy.min_moves_around(n, copy.landing(n, a), what));
                check(fresh.min_moves(n, fresh.landing(n, a)) == copy.min_moves(n, copy.landing(n, a)));
              }
          std::vector<std::vector<float>> scores(static_cast<std::size_t>(fresh.uavs()),
                                                 std::vector<float>(static_cast<std::size_t>(fresh.actions())));
          for (auto& row : scores)
            for (auto& x : row) x = static_cast<float>(rng.normal());
          const auto a = shielded_argmax(fresh, safety, scores);
          check(a == shielded_argmax(copy, safety, scores));
          const StepInfo f = fresh.step(a), c = copy.step(a);
          check(f.reward == c.reward && f.sum_rate == c.sum_rate && f.collisions == c.collisions && f.done == c.done);
          check(fresh.positions() == copy.positions());
        }
        check(copy.done());
      }
    });
    for (int p = 0; p < kPairs; ++p) {
      EXPECT_EQ(differ[static_cast<std::size_t>(p)], 0) << mobility << ", layout " << 10 + p;
      EXPECT_GT(compared[static_cast<std::size_t>(p)], 1000) << mobility;
    }
  }
}

// Ways home reserved in space and time (ways_home.hpp). Two UAVs whose straight ways cross at
// (100, 100) in the same slot: UAV 0 from (0, 100) to (200, 100), UAV 1 from (100, 0) to (100, 200),
// 10 moves each (D_fly 20 m, D_min 25 m). By hand: UAV 0 passes (80, 100), (100, 100), (120, 100)
// at the end of slots 4, 5, 6; UAV 1 keeps 25 m from it only at (100, 60) or lower at slot 5 and
// (100, 80) or lower at slot 6, so waiting costs UAV 1 two slots of slack (a detour, 2 moves more,
// no less).
namespace {
Config crossing(int t_max) {
  Config cfg;
  cfg.scenario.area_x_m = cfg.scenario.area_y_m = 200;
  cfg.trajectory.starts = {{0, 100}, {100, 0}};
  cfg.trajectory.destinations = {{200, 100}, {100, 200}};
  cfg.trajectory.t_max = t_max;  // 10 moves + 1, and t_max - 11 slots of slack
  finalise(cfg);
  return cfg;
}
}  // namespace

TEST(WaysHome, TheSecondUavPlansAroundTheFirstsReservedWay) {
  {
    // No slack: UAV 0's only way is straight; reserved, it leaves UAV 1 none.
    const Config cfg = crossing(11);
    UavEnv env = make_env(cfg, layout_users(cfg, 1));
    WaysHome ways(env);
    EXPECT_EQ(ways.moves(0), action_bit(kRight));
    ways.reserve(0, kRight);
    EXPECT_EQ(ways.reserved_at(env.t() + 5), (std::vector<std::pair<double, double>>{{100, 100}})) << "after 5 moves";
    EXPECT_EQ(ways.moves(1), 0u);
  }
  {
    // One slot of slack: still none (waiting costs two).
    const Config cfg = crossing(12);
    UavEnv env = make_env(cfg, layout_users(cfg, 1));
    WaysHome ways(env);
    ways.moves(0);
    ways.reserve(0, kRight);
    EXPECT_EQ(ways.moves(1), 0u);
  }
  // Two slots: UAV 1 has a way, and the two ways keep D_min apart in every slot.
  const Config cfg = crossing(13);
  UavEnv env = make_env(cfg, layout_users(cfg, 1));
  WaysHome ways(env);
  ASSERT_NE(ways.moves(0) & action_bit(kRight), 0u);
  ways.reserve(0, kRight);
  const ActionSet second = ways.moves(1);
  ASSERT_NE(second, 0u);
  EXPECT_EQ(second & ~reachable_moves(env, 1, 0), 0u) << "a way home is a way home of the mask";
  const int a = (second & action_bit(kUp)) ? kUp : kStay;
  ASSERT_NE(second & action_bit(a), 0u);
  ways.reserve(1, a);
  for (int tau = env.t() + 1; tau <= env.t_max(); ++tau) {
    const auto at = ways.reserved_at(tau);
    ASSERT_EQ(at.size(), 2u) << "slot " << tau << ": both ways run (parked at the end) to T_max";
    EXPECT_GE(std::hypot(at[0].first - at[1].first, at[0].second - at[1].second), env.d_min() - 1e-9) << "slot " << tau;
  }
  EXPECT_EQ(ways.reserved_at(env.t_max()), (std::vector<std::pair<double, double>>{{200, 100}, {100, 200}}));
  // Not parked yet, UAV 0's destination is clear of UAV 1's way: it may park.
  EXPECT_TRUE(ways.may_park(0));
  EXPECT_THROW(
      {
        Config c = crossing(13);
        c.trajectory.mobility = "continuous";
        finalise(c);
        UavEnv e = make_env(c, layout_users(c, 1));
        WaysHome w(e);
      },
      std::logic_error);
}

// Under random scores with the shield alone, the two spend their slack and meet at the crossing
// with none left; with the ways reserved (from the start: reserve_slack 2) and carried from slot to
// slot (WaysMemory, as a deployed policy carries them), no episode collides and both are home by
// T_max.
// SafeTurns (the Python VecEnv's begin_turns / take_turn) is sequential_safe_actions taken one
// turn at a time: the same order, allowed sets, actions and ways carried, here with every safety
// setting on (mask, shield, slack margin, clearance, ways reserved) on a crowded scene.
TEST(Safety, TurnsTakenOneAtATimeAreTheSequentialChoice) {
  const Config cfg = crowded(6);
  UavEnv env = make_env(cfg, layout_users(cfg, 3));
  SafetyOptions safety{true, true, 1, Clearance::Destinations, 3};
  auto pick = [](Rng& rng, ActionSet ok) {
    std::vector<int> c;
    for (int k = 0; k < kGridActions; ++k)
      if (ok >> k & 1u) c.push_back(k);
    return c.empty() ? -1 : c[rng.below(c.size())];
  };
  WaysMemory whole, turned;
  int turns = 0, reserved = 0;
  for (std::uint64_t slot = 0; !env.done(); ++slot) {
    Rng r1(slot), r2(slot);
    std::vector<ActionSet> allowed;
    std::vector<int> order;
    const auto a = sequential_safe_actions(env, safety, [&](int n, ActionSet ok) {
      order.push_back(n);
      return pick(r1, ok);
    }, &allowed, &whole);
    SafeTurns t(env, safety, &turned);
    for (const int n : order) {
      ASSERT_FALSE(t.done());
      ASSERT_EQ(t.uav(), n);
      ASSERT_EQ(t.allowed(), allowed[static_cast<std::size_t>(n)]);
      t.choose(pick(r2, t.allowed()));
      ++turns;
    }
    ASSERT_TRUE(t.done());
    EXPECT_EQ(t.allowed(), 0u);
    EXPECT_THROW(t.uav(), std::logic_error);
    EXPECT_EQ(t.actions(), a);
    EXPECT_EQ(t.allowed_sets(), allowed);
    ASSERT_EQ(turned.t, whole.t);
    ASSERT_EQ(turned.points.size(), whole.points.size());
    for (std::size_t k = 0; k < whole.points.size(); ++k) {
      EXPECT_EQ(turned.points[k].uav, whole.points[k].uav);
      EXPECT_EQ(turned.points[k].tau, whole.points[k].tau);
      EXPECT_EQ(turned.points[k].x, whole.points[k].x);
      EXPECT_EQ(turned.points[k].y, whole.points[k].y);
    }
    reserved += !whole.points.empty();
    env.step(a);
  }
  EXPECT_GT(turns, 0);
  EXPECT_GT(reserved, 0) << "the scene should reserve some ways home";
  // A move that does not exist is refused.
  env.reset();
  SafeTurns t(env, SafetyOptions{});
  ASSERT_FALSE(t.done());
  EXPECT_THROW(t.choose(kGridActions), std::out_of_range);
  EXPECT_THROW(t.choose(-1), std::out_of_range);
}

// marl.sequential_passes (take_turns): in the first pass each UAV sees the landings of the UAVs
// that chose before it and the others where they are; in each later pass it sees the UAVs after
// it at their moves of the pass before (their intentions), those before it at this pass's moves,
// and itself where it is. The passes choose differently here (first, then last allowed move), so
// an intention shown in place of a move (or the reverse) fails. One pass is sequential_safe_actions.
TEST(Safety, LaterPassesShowTheOthersMovesOfThePassBefore) {
  const Config cfg = crowded(6);
  UavEnv env = make_env(cfg, layout_users(cfg, 3));
  SafetyOptions safety{true, true, 1, Clearance::Destinations, 3};
  int checked = 0, intentions = 0;
  for (int slot = 0; slot < 6 && !env.done(); ++slot) {
    for (const int passes : {1, 2, 3}) {
      std::vector<std::vector<int>> moves(static_cast<std::size_t>(passes), std::vector<int>(static_cast<std::size_t>(env.uavs()), -1));
      int pass = 0;
      auto choose = [&](int n, ActionSet ok, bool last) {
        if (moves[static_cast<std::size_t>(pass)][static_cast<std::size_t>(n)] >= 0) ++pass;  // its second turn: the next pass
        EXPECT_EQ(last, pass + 1 == passes);
        const Positions& seen = env.seen_positions();
        for (int m = 0; m < env.uavs(); ++m) {
          double x = env.positions()(m, 0), y = env.positions()(m, 1);
          const int now = moves[static_cast<std::size_t>(pass)][static_cast<std::size_t>(m)];
          const int before = pass > 0 ? moves[static_cast<std::size_t>(pass - 1)][static_cast<std::size_t>(m)] : -1;
          if (m != n && now >= 0) {
            const auto l = env.landing(m, now);
            x = l.x, y = l.y;
          } else if (m != n && before >= 0 && !env.arrived(m)) {
            const auto l = env.landing(m, before);
            x = l.x, y = l.y;
            intentions += l.x != env.positions()(m, 0) || l.y != env.positions()(m, 1);
          }
          EXPECT_EQ(seen(m, 0), x) << "pass " << pass << ", UAV " << n << " sees UAV " << m;
          EXPECT_EQ(seen(m, 1), y) << "pass " << pass << ", UAV " << n << " sees UAV " << m;
        }
        ++checked;
        int a = -1;
        for (int k = 0; k < kGridActions; ++k)
          if (ok >> k & 1u && (a < 0 || pass % 2 == 1)) a = k;
        moves[static_cast<std::size_t>(pass)][static_cast<std::size_t>(n)] = a;
        return a;
      };
      WaysMemory memory;
      const auto a = take_turns(env, safety, passes, choose, &memory);
      env.clear_decided();
      EXPECT_EQ(pass + 1, passes);
      for (int n = 0; n < env.uavs(); ++n)
        if (!env.arrived(n)) {
          EXPECT_EQ(a[static_cast<std::size_t>(n)], moves.back()[static_cast<std::size_t>(n)]);
        }
      if (passes == 1) {
        WaysMemory whole;
        int p = 0;
        EXPECT_EQ(a, sequential_safe_actions(env, safety, [&](int n, ActionSet ok) {
          (void)n;
          int k = 0;
          while (!(ok >> k & 1u) && k + 1 < kGridActions) ++k;
          ++p;
          return k;
        }, nullptr, &whole));
        EXPECT_GT(p, 0);
      }
    }
    env.step(sequential_safe_actions(env, safety, [&](int, ActionSet ok) {
      int k = 0;
      while (!(ok >> k & 1u) && k + 1 < kGridActions) ++k;
      return k;
    }));
  }
  EXPECT_GT(checked, 50);
  EXPECT_GT(intentions, 10) << "later passes should show UAVs away from where they are";
  EXPECT_THROW(take_turns(env, safety, 0, [](int, ActionSet, bool) { return 0; }), std::invalid_argument);
}

TEST(WaysHome, ReservedWaysAvoidACrossingTheShieldCannotSee) {
  const Config cfg = crossing(13);
  UavEnv env = make_env(cfg, layout_users(cfg, 1));
  int collided[2] = {0, 0};
  for (const int reserve : {-1, 2})
    for (std::uint64_t episode = 0; episode < 50; ++episode) {
      Rng rng(episode);
      env.reset();
      WaysMemory memory;
      while (!env.done()) {
        std::vector<std::vector<float>> scores(2, std::vector<float>(kGridActions));
        for (auto& s : scores)
          for (auto& x : s) x = static_cast<float>(rng.normal());
        SafetyOptions safety{true, true};
        safety.reserve = reserve;
        const auto a = shielded_argmax(env, safety, scores, &memory);
        for (int n = 0; n < 2; ++n) ASSERT_TRUE(reachable_moves(env, n, 0) >> a[static_cast<std::size_t>(n)] & 1u);
        collided[reserve < 0 ? 0 : 1] += env.collisions(env.next_positions(a)) > 0;
        env.step(a);
      }
      EXPECT_TRUE(env.positions().isApprox(env.destinations())) << "reserve " << reserve << ", episode " << episode;
    }
  EXPECT_GT(collided[0], 0) << "without reserved ways the two should sometimes meet at the crossing with no slack left";
  EXPECT_EQ(collided[1], 0) << collided[0] << " without";
}

TEST(WaysHome, DefaultsReserveNothingTrainingSamplesWithoutAndTheContinuousModelIsRefused) {
  Config cfg;
  finalise(cfg);
  EXPECT_EQ(safety_options(cfg).reserve, -1);
  cfg.marl.reserve_slack = 4;
  EXPECT_EQ(safety_options(cfg).reserve, 4);
  EXPECT_EQ(training_safety_options(cfg).reserve, -1) << "an execution setting: training samples without it";
  cfg.trajectory.mobility = "continuous";
  try {
    finalise(cfg);
    FAIL() << "reserve_slack with continuous mobility should be refused";
  } catch (const InputError& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find("marl.reserve_slack = 4"), std::string::npos) << what;
    EXPECT_EQ(what.find('\n'), std::string::npos) << "one line: " << what;
  }
}
