// The trajectory environment, the rate oracle and the planners.
#include <gtest/gtest.h>

#include "skyloop/beamforming/linear.hpp"
#include "skyloop/channel/rates.hpp"
#include "skyloop/core/config_io.hpp"
#include "skyloop/core/error.hpp"
#include "skyloop/env/layouts.hpp"
#include "skyloop/env/vec_env.hpp"
#include "skyloop/planning/planners.hpp"

using namespace skyloop;

namespace {

std::shared_ptr<const Beamformer> zf_bf() { return std::make_shared<ZfBeamformer>(); }

/// An environment with explicit starts, destinations, horizon and reward weights.
std::unique_ptr<UavEnv> make_env(Config cfg, std::uint64_t seed = 1, std::shared_ptr<const Beamformer> bf = zf_bf()) {
  auto oracle = std::make_shared<RateOracle>(cfg, std::move(bf), make_users(cfg, cfg.scenario.users, seed));
  return std::make_unique<UavEnv>(cfg, oracle);
}

Config single(double sx, double sy, double dx, double dy, int t_max) {
  Config c;
  c.trajectory.starts = {{sx, sy}};
  c.trajectory.destinations = {{dx, dy}};
  c.trajectory.t_max = t_max;
  c.env.w_rate = c.env.w_arr = c.env.w_bud = c.env.w_col = c.env.w_fea = 0;
  return c;
}

}  // namespace

TEST(Env, BoundariesAreNeverCrossedAndCounted) {
  Config cfg;
  auto env = make_env(cfg);
  Rng rng(5);
  int attempted = 0;
  for (int episode = 0; episode < 20; ++episode) {
    env->reset();
    while (!env->done()) {
      std::vector<int> a(3);
      for (auto& x : a) x = static_cast<int>(rng.below(5));
      for (int n = 0; n < 3; ++n) {
        attempted += !env->arrived(n) && !env->landing(n, a[n]).inside;
      }
      env->step(a);
      const auto& p = env->positions();
      ASSERT_TRUE((p.col(0).array() >= 0).all() && (p.col(0).array() <= 200).all());
      ASSERT_TRUE((p.col(1).array() >= 0).all() && (p.col(1).array() <= 200).all());
      for (int n = 0; n < 3; ++n)
        for (float v : env->observation(n)) ASSERT_LE(std::abs(v), 1.0f);
    }
  }
  EXPECT_GT(attempted, 0);
}

TEST(Env, BoundaryMoveIsCancelledAndPenalised) {
  Config cfg = single(0, 20, 100, 20, 12);
  cfg.env.w_bud = 5;
  auto env = make_env(cfg);
  const StepInfo s = env->step({kLeft});
  EXPECT_EQ(s.boundary, 1);
  EXPECT_DOUBLE_EQ(env->positions()(0, 0), 0.0);
  EXPECT_DOUBLE_EQ(s.reward, -5.0);
  EXPECT_EQ(env->total_boundary(), 1);
}

TEST(Env, ArrivalLocksAndMasks) {
  Config cfg = single(80, 20, 100, 20, 6);
  cfg.env.w_arr = 10;
  auto env = make_env(cfg);
  EXPECT_EQ(env->mask(0), 1);
  const StepInfo s = env->step({kRight});
  EXPECT_EQ(s.arrivals, 1);
  EXPECT_TRUE(s.done);  // the only UAV is home: the episode ends, T = 2
  EXPECT_TRUE(s.success);
  EXPECT_DOUBLE_EQ(s.reward, 10.0);
  EXPECT_TRUE(env->arrived(0));
  EXPECT_EQ(env->mask(0), 0);
  EXPECT_EQ(env->t(), 2);
  EXPECT_THROW(env->step({kUp}), std::logic_error);

  // Two UAVs: the arrived one ignores its actions (forced STAY) while the other flies on.
  Config two;
  two.trajectory.starts = {{80, 20}, {20, 180}};
  two.trajectory.destinations = {{100, 20}, {20, 100}};
  two.trajectory.t_max = 10;
  two.env.w_rate = two.env.w_bud = two.env.w_col = two.env.w_fea = 0;
  two.env.w_arr = 1;
  auto e2 = make_env(two);
  EXPECT_EQ(e2->step({kRight, kDown}).arrivals, 1);
  const StepInfo s2 = e2->step({kUp, kDown});
  EXPECT_EQ(s2.arrivals, 0);
  EXPECT_DOUBLE_EQ(e2->positions()(0, 1), 20.0);  // did not move up
  EXPECT_EQ(e2->mask(0), 0);
  EXPECT_FALSE(e2->feasible(0, kUp));
  EXPECT_TRUE(e2->feasible(0, kStay));
  EXPECT_EQ(e2->total_arrivals(), 1);
}

TEST(Env, CollisionsAreCountedPerUav) {
  Config cfg;
  cfg.trajectory.starts = {{60, 100}, {100, 100}, {180, 20}};
  cfg.trajectory.destinations = {{100, 180}, {60, 180}, {180, 180}};
  cfg.trajectory.t_max = 20;
  cfg.env.w_rate = cfg.env.w_arr = cfg.env.w_bud = cfg.env.w_fea = 0;
  cfg.env.w_col = 10;
  auto env = make_env(cfg);
  const StepInfo s = env->step({kRight, kStay, kStay});  // 20 m apart < D_min = 25 m
  EXPECT_EQ(s.collisions, 2);
  EXPECT_DOUBLE_EQ(s.reward, -20.0);
  const StepInfo t = env->step({kUp, kStay, kStay});  // diagonal: 28.3 m, no collision
  EXPECT_EQ(t.collisions, 0);
}

TEST(Env, RateTermIsTheCumulativeAverage) {
  Config cfg = single(20, 20, 100, 20, 12);
  cfg.env.w_rate = 1;
  auto env = make_env(cfg);
  const double r1 = env->rates().front();
  const StepInfo s = env->step({kRight});
  Positions p(1, 2);
  p << 40, 20;
  EXPECT_DOUBLE_EQ(s.sum_rate, env->oracle().sum_rate(p));
  EXPECT_DOUBLE_EQ(s.avg_rate, (r1 + s.sum_rate) / 2);
  EXPECT_DOUBLE_EQ(s.reward, s.avg_rate);
  EXPECT_DOUBLE_EQ(env->objective(), (r1 + s.sum_rate) / 2);
}

TEST(Env, ReachabilityIndicatorFourCases) {
  // Destination 4 moves east; T_max = 10: plenty of time.
  Config roomy = single(20, 20, 100, 20, 10);
  roomy.env.w_fea = 1;
  auto a = make_env(roomy);
  EXPECT_EQ(a->step({kRight}).feasibility, +1);  // feasible and approaching
  EXPECT_EQ(a->step({kLeft}).feasibility, -1);   // feasible but moving away
  // T_max = 5: exactly enough at the start (4 moves in slots 1..5).
  Config tight = single(20, 20, 100, 20, 5);
  tight.env.w_fea = 1;
  auto b = make_env(tight);
  EXPECT_EQ(b->step({kStay}).feasibility, -1);   // t = 2: T_min 4 > T_res 3 (infeasible, not farther)
  EXPECT_EQ(b->step({kRight}).feasibility, -1);  // infeasible although approaching (3 > 2)
  auto c = make_env(tight);
  c->step({kStay});
  EXPECT_EQ(c->step({kLeft}).feasibility, -1);   // infeasible and moving away
  auto d = make_env(tight);
  EXPECT_EQ(d->step({kRight}).feasibility, +1);  // on schedule: T_min 3 <= T_res 3
  EXPECT_DOUBLE_EQ(d->step({kRight}).reward, 1.0);
}

TEST(Env, UsersAreSeededAndEpisodesDeterministic) {
  Config cfg;
  auto a = make_env(cfg, 7), b = make_env(cfg, 7), c = make_env(cfg, 8);
  EXPECT_EQ(a->oracle().users(), b->oracle().users());
  EXPECT_NE(a->oracle().users(), c->oracle().users());
  RandomPlanner pa(3), pb(3);
  const auto ra = run_episode(*a, pa), rb = run_episode(*b, pb);
  EXPECT_EQ(ra.rates, rb.rates);
  EXPECT_EQ(ra.actions, rb.actions);
  RandomPlanner pc(3);
  EXPECT_NE(run_episode(*c, pc).rates, ra.rates);
}

TEST(Env, CacheNeverChangesAValue) {
  Config cfg;
  auto bf = zf_bf();
  const Positions users = make_users(cfg, 12, 4);
  RateOracle cached(cfg, bf, users);
  SystemModel model(cfg);
  Rng rng(9);
  for (int i = 0; i < 200; ++i) {
    Positions p(3, 2);
    for (int n = 0; n < 3; ++n) p(n, 0) = 20.0 * static_cast<double>(rng.below(11)), p(n, 1) = 20.0 * static_cast<double>(rng.below(11));
    const double cold = cached.sum_rate(p);
    const double warm = cached.sum_rate(p);
    double direct = 0;
    for (const auto& c : model.clusters(Snapshot{p, users})) direct += sum_rate(c, bf->design(c));
    ASSERT_EQ(cold, warm);
    ASSERT_EQ(cold, direct);
  }
  EXPECT_GT(cached.stats().hits, 0u);
  EXPECT_GT(cached.stats().misses, 0u);
  EXPECT_GT(cached.stats().hit_rate(), 0.0);
}

// The oracle reassociates a position set that moves one UAV from the one before it (RateOracle's
// keys_of, SystemModel::reassociate): batches shaped like a UAV's moves and radio map, and sets
// asked one at a time, give the rates of the clusters built afresh, bit for bit (16 UAVs, 400
// users on 1 km: the spatial index; 3 UAVs: the plain scan).
TEST(Env, OracleRatesOfOneUavsMovesAreTheDirectRates) {
  for (const auto& [uavs, users, side] : {std::tuple{16, 400, 1000.0}, std::tuple{3, 12, 200.0}}) {
    const Config cfg = resolve_config(std::nullopt, {"scenario.uavs=" + std::to_string(uavs), "scenario.area_x_m=" + std::to_string(side),
                                                     "scenario.area_y_m=" + std::to_string(side), "trajectory.layout=generated",
                                                     "trajectory.t_max=" + std::to_string(int(side / 20) + 10)});
    auto bf = zf_bf();
    const Positions u = make_users(cfg, users, 5);
    RateOracle oracle(cfg, bf, u), other(cfg, bf, make_users(cfg, users, 6));
    const SystemModel model(cfg);
    Rng rng(3);
    Positions seen(uavs, 2);
    for (int n = 0; n < uavs; ++n)
      seen(n, 0) = 20.0 * static_cast<double>(rng.below(static_cast<std::uint64_t>(side / 20) + 1)),
      seen(n, 1) = 20.0 * static_cast<double>(rng.below(static_cast<std::uint64_t>(side / 20) + 1));
    for (int round = 0; round < 12; ++round) {
      const int n = static_cast<int>(rng.below(static_cast<std::uint64_t>(uavs)));
      std::vector<Positions> sets(1, seen);
      for (int c = 0; c < 9; ++c) {
        sets.push_back(seen);
        sets.back()(n, 0) += 20.0 * (c % 3 - 1), sets.back()(n, 1) += 20.0 * (c / 3 - 1);
      }
      const auto batch = oracle.sum_rates(sets);
      other.sum_rates(sets);  // another oracle's users in between: its association is not this one's
      for (std::size_t i = 0; i < sets.size(); ++i) {
        double direct = 0;
        for (const auto& c : model.clusters(Snapshot{sets[i], u})) direct += sum_rate(c, bf->design(c));
        ASSERT_EQ(batch[i], direct) << uavs << " UAVs, round " << round << ", set " << i;
      }
      for (std::size_t i = sets.size(); i-- > 0;)  // one at a time, from the memo, in the other order
        ASSERT_EQ(oracle.sum_rate(sets[i]), batch[i]) << uavs << " UAVs, round " << round << ", set " << i;
      seen = sets[1 + rng.below(9)];  // the next slot starts from one of the moves
    }
  }
}

// A batch of position sets whose channels exceed the oracle's chunk (2^24 complex entries: here
// 4,096 users x 4 antennas, 1,024 sets a chunk) is asked in chunks: every rate is the one the set
// gets alone and from the clusters built afresh, bit for bit, across the chunks' seams.
TEST(Env, OracleChunksOfLargeBatchesGiveTheDirectRates) {
  Config cfg;
  auto bf = zf_bf();
  const Positions users = make_users(cfg, 4096, 8);
  RateOracle oracle(cfg, bf, users), alone(cfg, bf, users);
  const SystemModel model(cfg);
  Positions start(3, 2);
  start << 60, 60, 60, 140, 140, 100;
  std::vector<Positions> sets;
  for (int i = 0; i < 2500; ++i) {  // UAV i % 3 at one of its nine moves: 27 distinct sets
    sets.push_back(start);
    const int n = i % 3, c = (i / 3) % 9;
    sets.back()(n, 0) += 20.0 * (c % 3 - 1), sets.back()(n, 1) += 20.0 * (c / 3 - 1);
  }
  const auto batch = oracle.sum_rates(sets);
  ASSERT_EQ(batch.size(), sets.size());
  for (std::size_t i = 0; i < 27; ++i) {
    double direct = 0;
    for (const auto& c : model.clusters(Snapshot{sets[i], users})) direct += sum_rate(c, bf->design(c));
    ASSERT_EQ(batch[i], direct) << "set " << i;
    ASSERT_EQ(alone.sum_rate(sets[i]), batch[i]) << "set " << i;
    for (std::size_t j = i + 27; j < sets.size(); j += 27) ASSERT_EQ(batch[j], batch[i]) << "set " << j;
  }
}

// The memo's bound (RateOracle::set_memo_limit): past it the next batch starts the memo afresh,
// so it stays bounded however many positions a run visits, and every rate is still the double an
// unbounded oracle gives (orthogonal spectra, per cluster; the shared spectrum, per joint key).
TEST(Env, BoundedMemoGivesTheUnboundedRates) {
  for (const char* spectrum : {"orthogonal", "shared"}) {
    const Config cfg = resolve_config(std::nullopt, {std::string("channel.spectrum=") + spectrum});
    auto bf = zf_bf();
    const Positions users = make_users(cfg, 12, 4);
    RateOracle bounded(cfg, bf, users), unbounded(cfg, bf, users);
    constexpr double kLimit = 4096;  // a few dozen entries
    bounded.set_memo_limit(kLimit);
    Rng rng(5);
    auto random_set = [&] {
      Positions p(3, 2);
      for (int n = 0; n < 3; ++n) p(n, 0) = 20.0 * static_cast<double>(rng.below(11)), p(n, 1) = 20.0 * static_cast<double>(rng.below(11));
      return p;
    };
    double most = 0;
    for (int round = 0; round < 150; ++round) {
      std::vector<Positions> sets;
      for (int i = 0; i < 4; ++i) sets.push_back(random_set());
      sets.push_back(sets.front());  // a repeat within the batch
      const auto a = bounded.sum_rates(sets), b = unbounded.sum_rates(sets);
      for (std::size_t i = 0; i < sets.size(); ++i) ASSERT_EQ(a[i], b[i]) << spectrum << ", round " << round << ", set " << i;
      ASSERT_EQ(bounded.cluster_rates(sets[1]), unbounded.cluster_rates(sets[1])) << spectrum << ", round " << round;
      most = std::max(most, bounded.memo_bytes());
    }
    // Past the bound by at most one batch's entries (each of them about 112 bytes and its arrays).
    EXPECT_LT(most, kLimit + 6 * 3 * 200.0) << spectrum;
    EXPECT_GT(unbounded.memo_bytes(), 4 * kLimit) << spectrum;  // the bound was reached, repeatedly
    EXPECT_GT(bounded.stats().misses, unbounded.stats().misses) << spectrum;  // and values computed again
  }
}

TEST(Env, VectorEnvMatchesSingleEnvs) {
  Config cfg;
  VecEnv vec(cfg, zf_bf(), 4, 11);
  std::vector<std::unique_ptr<UavEnv>> single;
  for (int i = 0; i < 4; ++i) single.push_back(make_env(cfg, derive_seed(11, static_cast<std::uint64_t>(i))));
  Rng rng(2);
  for (int step = 0; step < 30; ++step) {
    std::vector<std::vector<int>> actions(4, std::vector<int>(3));
    for (auto& a : actions)
      for (auto& x : a) x = static_cast<int>(rng.below(5));
    const auto infos = vec.step(actions);
    for (int i = 0; i < 4; ++i) {
      const StepInfo s = single[static_cast<std::size_t>(i)]->step(actions[static_cast<std::size_t>(i)]);
      EXPECT_EQ(s.reward, infos[static_cast<std::size_t>(i)].reward);
      EXPECT_EQ(s.sum_rate, infos[static_cast<std::size_t>(i)].sum_rate);
      if (s.done) single[static_cast<std::size_t>(i)]->reset();
    }
  }
}

TEST(Env, ResampledVectorEnvMatchesSingleEnvs) {
  // With env.resample_users, finish() makes the next episode's oracle and asks for its start's
  // rate in the batch of the step that ends an episode (every UAV home, or T_max). An environment
  // stepped alone, given the same layouts (training_layout_seed) by set_oracle, must see the same
  // rates, rewards and ends; the first reward of each episode reads R at the start.
  Config cfg;
  cfg.env.resample_users = true;
  cfg.env.reward = Reward::Objective;
  const int M = 4;
  VecEnv vec(cfg, zf_bf(), M, 11);
  std::vector<std::unique_ptr<UavEnv>> single;
  std::vector<std::uint64_t> episode(M, 0);
  auto layout = [&](int i) {
    return std::make_shared<RateOracle>(cfg, zf_bf(), layout_users(cfg, training_layout_seed(11, static_cast<std::size_t>(i), episode[static_cast<std::size_t>(i)])));
  };
  for (int i = 0; i < M; ++i) single.push_back(std::make_unique<UavEnv>(cfg, layout(i)));
  Rng rng(5);
  int homes = 0, timeouts = 0;
  for (int step = 0; step < 24 * 8; ++step) {
    std::vector<std::vector<int>> actions(M, std::vector<int>(3));
    for (int i = 0; i < M; ++i)
      for (int n = 0; n < 3; ++n) {  // mostly a move that brings the UAV nearer home, so episodes end both ways
        const UavEnv& e = vec.env(i);
        int best = static_cast<int>(rng.below(5));
        if (rng.uniform() < 0.8)
          for (int a = 0; a < e.actions(); ++a)
            if (e.feasible(n, a) && e.min_moves(n, e.landing(n, a)) < e.min_moves(n, e.landing(n, best))) best = a;
        actions[static_cast<std::size_t>(i)][static_cast<std::size_t>(n)] = best;
      }
    const auto infos = vec.step(actions);
    for (int i = 0; i < M; ++i) {
      const auto ii = static_cast<std::size_t>(i);
      const StepInfo s = single[ii]->step(actions[ii]);
      ASSERT_EQ(s.sum_rate, infos[ii].sum_rate) << "step " << step << ", environment " << i;
      ASSERT_EQ(s.reward, infos[ii].reward) << "step " << step << ", environment " << i;
      ASSERT_EQ(s.done, infos[ii].done) << "step " << step << ", environment " << i;
      ASSERT_EQ(s.objective, infos[ii].objective);
      if (!s.done) continue;
      (s.T < single[ii]->t_max() ? homes : timeouts) += 1;
      ++episode[ii];
      single[ii]->set_oracle(layout(i));
      ASSERT_EQ(single[ii]->oracle().users(), vec.env(i).oracle().users());
    }
  }
  EXPECT_GT(homes, 0) << "episodes that end with every UAV home";
  EXPECT_GT(timeouts, 0) << "episodes that end at T_max";
}

TEST(Env, SettlingAStepEarlyChangesNothing) {
  // VecEnv::settle ends a step from the environment's own memo (the PPO learner's lanes); finish()
  // ends the rest with their misses in one batch per thread, the environments shared out among
  // the threads by the misses settle counted. Stepping through settle on three threads must give
  // what finish alone gives on one: the same rewards, rates and ends, the same resets (new
  // layouts), the same hits.
  struct Case {
    const char* name;
    std::function<void(Config&)> set;
  };
  const std::vector<Case> cases{
      {"fixed users", [](Config&) {}},
      {"resampled layouts", [](Config& c) { c.env.resample_users = true; }},
      {"shared spectrum (joint memo)", [](Config& c) { c.channel.spectrum = Spectrum::Shared; }},
  };
  for (const Case& k : cases) {
    SCOPED_TRACE(k.name);
    Config cfg;
    k.set(cfg);
    cfg.run.threads = 1;
    Config threaded = cfg;
    threaded.run.threads = 3;
    VecEnv plain(cfg, zf_bf(), 4, 11), settled(threaded, zf_bf(), 4, 11);
    Rng rng(2);
    int early = 0, late = 0, resets = 0;
    for (int step = 0; step < 80; ++step) {
      std::vector<std::vector<int>> actions(4, std::vector<int>(3));
      for (auto& a : actions)
        for (auto& x : a) x = static_cast<int>(rng.below(5));
      const auto want = plain.step(actions);
      std::vector<StepInfo> info(4);
      std::vector<Positions> next(4);
      for (int i = 0; i < 4; ++i) {
        const auto ii = static_cast<std::size_t>(i);
        next[ii] = settled.begin(i, actions[ii], info[ii]);
        if (settled.settle(i, next[ii], info[ii])) ++early;
        else ++late;
      }
      const auto got = settled.finish(next, info);
      for (std::size_t i = 0; i < 4; ++i) {
        ASSERT_EQ(got[i].sum_rate, want[i].sum_rate) << "step " << step << ", environment " << i;
        ASSERT_EQ(got[i].reward, want[i].reward);
        ASSERT_EQ(got[i].done, want[i].done);
        ASSERT_EQ(got[i].objective, want[i].objective);
        resets += want[i].done;
        const auto ie = static_cast<int>(i);
        ASSERT_EQ(settled.env(ie).oracle().users(), plain.env(ie).oracle().users());
        ASSERT_EQ(settled.env(ie).positions(), plain.env(ie).positions());
        ASSERT_EQ(settled.env(ie).oracle().stats().hits, plain.env(ie).oracle().stats().hits);
        ASSERT_EQ(settled.env(ie).oracle().stats().misses, plain.env(ie).oracle().stats().misses);
      }
    }
    EXPECT_GT(early, 0) << "steps whose rates the memo knew end at once";
    EXPECT_GT(late, 0) << "steps with a new position wait for finish's batch";
    EXPECT_GE(resets, 12) << "80 steps of T_max = 24: every environment ends three episodes";
  }
  // What a miss will take: per cluster not in the memo, its users plus one; nothing on a hit.
  {
    Config cfg;
    RateOracle oracle(cfg, zf_bf(), make_users(cfg, 12, 5));
    Positions uavs(3, 2);
    uavs << 40, 40, 160, 60, 100, 170;
    const Association a = oracle.model().associate(uavs, oracle.users());
    double want = 0;
    int clusters = 0;
    for (const auto& members : a.users)
      if (!members.empty()) want += static_cast<double>(members.size() + 1), ++clusters;
    ASSERT_GE(clusters, 2);
    double cost = -1;
    EXPECT_FALSE(oracle.cached_sum_rate(uavs, &cost).has_value());
    EXPECT_EQ(cost, want);
    EXPECT_EQ(oracle.stats().hits + oracle.stats().misses, 0u) << "a miss counts nothing";
    const double r = oracle.sum_rate(uavs);
    cost = -1;
    EXPECT_EQ(oracle.cached_sum_rate(uavs, &cost), std::optional<double>(r));
    EXPECT_EQ(cost, -1) << "a hit leaves the cost alone";
  }
  // Environments that share one oracle never settle early (another's batch may be filling its memo).
  Config cfg;
  auto oracle = std::make_shared<RateOracle>(cfg, zf_bf(), make_users(cfg, 6, 3));
  VecEnv shared(cfg, oracle, 2);
  StepInfo info;
  const int h = shared.env(0).hover();
  const Positions stay = shared.begin(0, {h, h, h}, info);
  oracle->sum_rate(stay);
  EXPECT_FALSE(shared.settle(0, stay, info));
}

TEST(Planners, RandomAndGreedyRespectTheMasks) {
  Config cfg;
  auto env = make_env(cfg, 3);
  for (int seed = 0; seed < 5; ++seed) {
    RandomPlanner random(static_cast<std::uint64_t>(seed));
    const auto r = run_episode(*env, random);
    EXPECT_TRUE(r.success) << "the reachability mask always brings the UAVs home";
    EXPECT_EQ(r.boundary, 0);
  }
  GreedyPlanner greedy;
  const auto g = run_episode(*env, greedy);
  EXPECT_TRUE(g.success);
  EXPECT_EQ(g.boundary, 0);
}

TEST(Planners, OptimumEqualsBruteForceOnTinyGrids) {
  for (std::uint64_t seed : {1u, 2u, 3u}) {
    Config cfg;
    cfg.scenario.area_x_m = 60;
    cfg.scenario.area_y_m = 40;
    cfg.scenario.users = 5;
    cfg.trajectory.starts = {{0, 0}, {60, 40}};
    cfg.trajectory.destinations = {{40, 0}, {20, 40}};
    cfg.trajectory.t_max = 5;
    auto env = make_env(cfg, seed);
    const OptimalPlan plan = solve_optimal(*env);
    const double brute = brute_force_optimum(*env);
    EXPECT_NEAR(plan.objective, brute, 1e-9 * brute) << "seed " << seed;
    // Replaying the plan in the environment gives the same objective, home, collision-free.
    OptimalPlanner optimal;
    const auto r = run_episode(*env, optimal);
    EXPECT_NEAR(r.objective, plan.objective, 1e-12 * brute);
    EXPECT_TRUE(r.success);
    EXPECT_EQ(r.collisions, 0);
  }
  // One UAV with slack: T is free (the best average may come home early or late).
  Config one = single(0, 0, 40, 0, 6);
  one.scenario.area_x_m = 60;
  one.scenario.area_y_m = 40;
  one.scenario.users = 4;
  auto env = make_env(one, 4);
  EXPECT_NEAR(solve_optimal(*env).objective, brute_force_optimum(*env), 1e-9);
}

TEST(Planners, OptimumIsAtLeastEveryOtherPlanner) {
  Config cfg;
  cfg.scenario.area_x_m = 120;
  cfg.scenario.area_y_m = 120;
  cfg.trajectory.starts = {{0, 0}, {0, 120}, {120, 120}};
  cfg.trajectory.destinations = {{120, 60}, {120, 0}, {0, 60}};
  cfg.trajectory.t_max = 14;
  for (std::uint64_t seed : {1u, 2u}) {
    auto env = make_env(cfg, seed);
    OptimalPlanner optimal;
    GreedyPlanner greedy;
    const auto o = run_episode(*env, optimal);
    const auto g = run_episode(*env, greedy);
    EXPECT_TRUE(o.success);
    EXPECT_EQ(o.collisions, 0);
    EXPECT_GE(o.objective, g.objective - 1e-12);
    for (std::uint64_t s = 0; s < 5; ++s) {
      RandomPlanner random(s);
      const auto r = run_episode(*env, random);
      if (r.collisions == 0) {
        EXPECT_GE(o.objective, r.objective - 1e-12);
      }
    }
  }
}

TEST(Planners, OffGridStartsAreRejected) {
  Config cfg;
  cfg.trajectory.starts = {{20, 20}, {25, 180}, {180, 180}};
  auto env = make_env(cfg);
  try {
    solve_optimal(*env);
    FAIL();
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("trajectory.starts[1]"), std::string::npos) << e.what();
  }
}
