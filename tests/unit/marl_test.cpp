// The learners' building blocks on hand-made numbers, and short seeded learning runs.
#include <gtest/gtest.h>

#include <set>

#include <algorithm>
#include <filesystem>
#include <sstream>

#include "../../src/marl/nets.hpp"
#include "skyloop/beamforming/linear.hpp"
#include "skyloop/core/csv.hpp"
#include "skyloop/core/error.hpp"
#include "skyloop/core/io.hpp"
#include "skyloop/experiments/builtin.hpp"
#include "skyloop/experiments/layout_eval.hpp"
#include "skyloop/core/config_io.hpp"
#include "skyloop/marl/learners.hpp"
#include "skyloop/marl/marl.hpp"
#include "skyloop/planning/safety.hpp"
#include "../scratch.hpp"

using namespace skyloop;

TEST(Marl, GaeWithATerminalInTheMiddle) {
  // rewards 1 2 3 4, values 0.5 1 1.5 2 (bootstrap 2.5), the episode ends after step 1.
  const auto a = gae({1, 2, 3, 4}, {0.5, 1.0, 1.5, 2.0, 2.5}, {0, 1, 0, 0}, 0.9, 0.8);
  ASSERT_EQ(a.size(), 4u);
  EXPECT_NEAR(a[3], 4 + 0.9 * 2.5 - 2.0, 1e-12);               // 4.25
  EXPECT_NEAR(a[2], 3 + 0.9 * 2.0 - 1.5 + 0.72 * 4.25, 1e-12);  // 6.36
  EXPECT_NEAR(a[1], 2 - 1.0, 1e-12);                            // terminal: no bootstrap, no carry
  EXPECT_NEAR(a[0], 1 + 0.9 * 1.0 - 0.5 + 0.72 * 1.0, 1e-12);   // 2.12
  EXPECT_THROW(gae({1}, {1}, {0}, 0.9, 0.9), std::invalid_argument);
}

TEST(Marl, ClippedSurrogateAndValueLoss) {
  const auto logp_old = torch::zeros({3});
  const auto logp_new = torch::log(torch::tensor({1.5f, 0.5f, 1.1f}));
  const auto adv = torch::tensor({2.0f, -1.0f, 1.0f});
  const auto s = marl::clipped_surrogate(logp_new, logp_old, adv, 0.2);
  EXPECT_NEAR(s[0].item<float>(), 2.4f, 1e-5);   // min(3, 1.2 * 2)
  EXPECT_NEAR(s[1].item<float>(), -0.8f, 1e-5);  // min(-0.5, 0.8 * -1)
  EXPECT_NEAR(s[2].item<float>(), 1.1f, 1e-5);   // inside the clip range
  const auto v = torch::tensor({3.0f, 1.2f}), v_old = torch::tensor({1.0f, 1.0f}), ret = torch::tensor({2.0f, 3.0f});
  // sample 0 (eps 0.5 would clip to 1.5; here eps = 0.1): max((3-2)^2, (1.1-2)^2) = 1
  // sample 1: max((1.2-3)^2, (1.1-3)^2) = 3.61
  EXPECT_NEAR(marl::clipped_value_loss(v, v_old, ret, 0.1).item<float>(), (1.0f + 3.61f) / 2, 1e-5);
}

TEST(Marl, MaskedMeanIgnoresMaskedEntries) {
  const auto x = torch::tensor({1.0f, 100.0f, 3.0f, -50.0f});
  const auto m = torch::tensor({1.0f, 0.0f, 1.0f, 0.0f});
  EXPECT_FLOAT_EQ(marl::masked_mean(x, m).item<float>(), 2.0f);
  EXPECT_FLOAT_EQ(marl::masked_mean(x, torch::zeros({4})).item<float>(), 0.0f);  // nothing active: 0, not NaN
}

TEST(Marl, QmixMixerIsMonotonicInEveryAgentQ) {
  torch::manual_seed(4);
  marl::QMixer mixer(3, 10, 8);
  const auto q = torch::randn({64, 3}, torch::requires_grad());
  const auto state = torch::randn({64, 10});
  const auto total = mixer(q, state);
  const auto grad = torch::autograd::grad({total.sum()}, {q})[0];
  EXPECT_GE(grad.min().item<float>(), 0.0f);
  // And it is not constant in q: some agent matters.
  EXPECT_GT(grad.abs().max().item<float>(), 0.0f);
}

namespace {
/// A small scenario: 2 UAVs on a 120 m square (7 x 7 grid), T_max = 12, ZF as oracle.
Config small_scenario(const std::string& algo, std::int64_t steps) {
  Config cfg;
  cfg.scenario.area_x_m = 120;
  cfg.scenario.area_y_m = 120;
  cfg.scenario.users = 6;
  cfg.trajectory.starts = {{0, 0}, {120, 120}};
  cfg.trajectory.destinations = {{120, 40}, {0, 80}};
  cfg.trajectory.t_max = 12;
  cfg.env.oracle = "zf";
  cfg.marl.algo = algo;
  cfg.marl.total_steps = steps;
  cfg.marl.envs = 4;
  cfg.marl.rollout = 128;
  cfg.run.threads = 1;
  return cfg;
}

std::string fresh(const std::string& name) { return skyloop::test::scratch_path(name).string(); }

BeamformerRegistry& zf_registry() {
  static BeamformerRegistry r = [] {
    BeamformerRegistry x;
    register_classical_beamformers(x);
    return x;
  }();
  return r;
}

/// The small scenario's rate oracle: ZF over its 6 users, drawn with `users_seed`.
std::shared_ptr<RateOracle> zf_oracle(const Config& cfg, std::uint64_t users_seed) {
  return std::make_shared<RateOracle>(cfg, zf_registry().create("zf", cfg), make_users(cfg, 6, users_seed));
}

/// Random's mean objective over seeds 0-4: the baseline a learning test's policy must beat.
double random_mean(UavEnv& env) {
  double random = 0;
  for (std::uint64_t s = 0; s < 5; ++s) {
    RandomPlanner p(s);
    random += run_episode(env, p).objective / 5;
  }
  return random;
}

/// The deterministic evaluation of a policy trained for one step: what shows that a learning
/// test's bounds fail a policy that learned nothing.
EpisodeRecord untrained_evaluation(Config cfg, const std::string& name) {
  cfg.marl.total_steps = 1;
  MarlTrainOptions opt;
  opt.out_dir = fresh(name);
  opt.registry = &zf_registry();
  return train_marl(cfg, opt).evaluation;
}
}  // namespace

// Bounded, seeded MAPPO runs on a small scenario (2 UAVs, 7 x 7 grid, ZF oracle), judged against the
// exact optimum of P2.2. A different rounding path (another CPU's kernels) changes each run's
// trajectory, so the test trains three seeds and asserts of every one what 2e5 steps reliably
// teach: every UAV home by T_max with no collision and no boundary event. Arriving is learned (the
// policy has no reachability mask, and the untrained policy, checked below, does not arrive).
// The objective is held to at least 2/3 of the optimum: measured over seeds 1-3 under
// ATEN_CPU_CAPABILITY = default, avx2 and avx512 it was 72.4-81.5% (Random, which flies with the
// reachability mask, 76.8%), so the bound has a margin of 5 points below the worst run and still
// fails a policy that arrives by a poor route. Beating Random is not asked: in 2e5 steps the
// reward's rate term (w_rate 0.02) is weak next to the arrival terms, and Random is a strong
// baseline in this model (README, "Reproducibility").
// Entropy coefficient 0.03 (the paper's 0.01 lets the policy collapse to STAY for some seeds; see
// the README's MARL status). w_col is the shipped 2, set here so the test keeps its meaning.
TEST(Marl, MappoLearnsToArriveNearTheOptimum) {
  Config cfg = small_scenario("mappo", 200000);
  cfg.marl.action_mask = cfg.marl.shield = false;  // arriving must be learned, as in the paper
  cfg.env.w_col = 2;
  cfg.marl.entropy_coef = 0.03;
  UavEnv env(cfg, zf_oracle(cfg, cfg.marl.users_seed));
  const double optimum = solve_optimal(env).objective;
  const double random = random_mean(env);
  EXPECT_FALSE(untrained_evaluation(cfg, "mappo_untrained").success) << "the untrained policy already arrives: the test proves nothing";
  for (std::uint64_t seed : {1, 2, 3}) {
    cfg.run.seed = seed;
    MarlTrainOptions opt;
    opt.out_dir = fresh("mappo_s" + std::to_string(seed));
    opt.registry = &zf_registry();
    const auto r = train_marl(cfg, opt);
    EXPECT_TRUE(r.evaluation.success) << "seed " << seed << ": arrived " << r.evaluation.arrivals;
    EXPECT_EQ(r.evaluation.collisions, 0) << "seed " << seed;
    EXPECT_EQ(r.evaluation.boundary, 0) << "seed " << seed;
    EXPECT_GE(r.evaluation.objective, 2.0 / 3.0 * optimum)
        << "seed " << seed << ": optimum " << optimum << ", random " << random;
    EXPECT_LE(r.evaluation.objective, optimum * (1 + 1e-12)) << "seed " << seed << ": above the exact optimum";
    if (seed == 1) {
      for (const char* f : {"policy.pt", "last.pt", "metrics.csv", "config.toml"})
        EXPECT_TRUE(std::filesystem::exists(opt.out_dir + "/" + f)) << f;
      // The saved policy reloads and plays the same episode.
      auto policy = MarlPolicy::load(opt.out_dir);
      EXPECT_EQ(run_episode(env, *policy).objective, r.evaluation.objective);
      // The policy as the base of a multiagent rollout (RolloutPlanner): never below the policy's
      // own mission, never above the optimum.
      RolloutPlanner rollout(MarlPolicy::load(opt.out_dir));
      const auto improved = run_episode(env, rollout);
      EXPECT_EQ(rollout.name(), "mappo+rollout");
      EXPECT_TRUE(improved.success);
      EXPECT_EQ(improved.collisions + improved.boundary, 0);
      EXPECT_GE(improved.objective, r.evaluation.objective);
      EXPECT_LE(improved.objective, optimum * (1 + 1e-12));
    }
  }
}

// The recipe of configs/generalise.toml in small (2 UAVs, 7 x 7 grid, T_max 12, the shipped GNN
// behind R[t]), judged on 20 held-out test layouts against each layout's exact optimum. A new
// layout every episode, the reachability mask and the collision shield, the objective reward,
// the set observation and minibatches of whole steps; 2e5 steps on three seeds. Measured
// (2026-11-30, AVX2 kernels, seeds 1-3): every mission complete; mean 99.53, 99.37, 99.57% of the
// optimum, 5th percentile 98.2, 95.6, 99.4% (with minibatches of agent samples, 2026-11-28: 99.32,
// 99.14, 99.59%; 98.0, 95.5, 99.5%). The untrained policy (its initial weights, same masks)
// scores 98.2% / 94.9%: the masks alone fly most of a good mission here, so each seed must also
// beat the untrained policy's mean by half a point (the worst seed does by 1.1), besides the
// absolute bounds (mean >= 98%, 5th percentile >= 95%, which the untrained policy's tail misses),
// 1.4 and 0.6 points below the worst seed. Random scored 97.8% / 90.7%, Greedy 99.5% / 99.4%.
TEST(Marl, GeneralisesToHeldOutLayoutsWithTheSafetyMasks) {
  Config cfg = small_scenario("mappo", 200000);
  cfg.env.oracle = "gnn";
  cfg.env.reward = Reward::Objective;
  cfg.env.resample_users = true;
  cfg.marl.encoder = ObservationKind::Set;
  cfg.marl.minibatch = MinibatchLayout::Steps;
  cfg.marl.action_mask = cfg.marl.shield = true;
  LayoutEvalOptions eval;
  eval.layouts = 20;
  eval.cache_dir = fresh("optima");
  eval.threads = 1;
  auto judge = [&](const std::string& dir) {
    LayoutEvalOptions e = eval;
    e.policies = {dir};
    const auto sum = summarise_layouts(evaluate_layouts(cfg, e, builtin_beamformers()));
    EXPECT_EQ(sum.back().planner, "optimal");
    return sum.front();
  };
  LayoutSummary untrained_score;
  {
    Config untrained = cfg;
    untrained.marl.total_steps = 1;
    untrained.marl.learning_rate = 1e-8;  // the one update a run makes leaves the initial weights
    MarlTrainOptions opt;
    opt.out_dir = fresh("gen_untrained");
    opt.registry = &builtin_beamformers();
    train_marl(untrained, opt);
    untrained_score = judge(opt.out_dir);
  }
  for (std::uint64_t seed : {1, 2, 3}) {
    cfg.run.seed = seed;
    MarlTrainOptions opt;
    opt.out_dir = fresh("gen_s" + std::to_string(seed));
    opt.registry = &builtin_beamformers();
    train_marl(cfg, opt);
    const auto s = judge(opt.out_dir);
    EXPECT_EQ(s.layouts, 20);
    EXPECT_EQ(s.complete, 1.0) << "seed " << seed;
    EXPECT_EQ(s.collisions, 0) << "seed " << seed;
    EXPECT_EQ(s.boundary, 0) << "seed " << seed;
    EXPECT_GE(s.fraction_mean, 0.98) << "seed " << seed;
    EXPECT_GE(s.fraction_p5, 0.95) << "seed " << seed;
    EXPECT_GE(s.fraction_mean, untrained_score.fraction_mean + 0.005)
        << "seed " << seed << " against the untrained policy's " << untrained_score.fraction_mean;
    EXPECT_LE(s.fraction_worst, 1 + 1e-12) << "seed " << seed << ": above the exact optimum";
  }
}

namespace {
/// metrics.csv without its last column (charts/steps_per_s, a wall-clock rate).
std::string metrics_without_timing(const std::string& dir) {
  std::istringstream in(read_file(dir + "/metrics.csv"));
  std::string line, out;
  while (std::getline(in, line)) out += line.substr(0, line.rfind(',')) + "\n";
  return out;
}
}  // namespace

// Same seed, same numbers: every learner (PPO on both backends) twice from scratch gives the same
// metrics (every column but the wall-clock rate) and the same greedy episode; --resume continues.
TEST(Marl, EveryAlgorithmRunsSeededAndResumes) {
  std::vector<std::string> variants;
  for (const auto& l : learners().rows()) variants.push_back(l.name);
  variants.push_back("mappo/torch");
  variants.push_back("mappo/steps");
  ASSERT_EQ(learner_names(), (std::vector<std::string>{"mappo", "ippo", "vdn", "qmix"}));
  for (const std::string& variant : variants) {
    const std::string algo = variant.substr(0, variant.find('/'));
    Config cfg = small_scenario(algo, 4096);
    if (variant == "mappo/torch") cfg.marl.backend = PpoBackend::Torch;
    if (variant == "mappo/steps") cfg.marl.minibatch = MinibatchLayout::Steps, cfg.marl.encoder = ObservationKind::Set;  // the state shared per step
    cfg.marl.batch_episodes = 8;
    const std::string tag = algo + (variant == algo ? "" : "_" + variant.substr(variant.find('/') + 1));
    MarlTrainOptions a;
    a.out_dir = fresh("a_" + tag);
    a.registry = &zf_registry();
    MarlTrainOptions b = a;
    b.out_dir = fresh("b_" + tag);
    const auto ra = train_marl(cfg, a), rb = train_marl(cfg, b);
    EXPECT_EQ(ra.evaluation.actions, rb.evaluation.actions) << variant << ": same seed, same policy";
    const auto ma = metrics_without_timing(a.out_dir);
    EXPECT_EQ(ma, metrics_without_timing(b.out_dir)) << variant;
    EXPECT_GE(std::count(ma.begin(), ma.end(), '\n'), 2) << variant << ": a header and at least one row";
    // Resume continues to more steps, on the backend it was trained with.
    Config more = cfg;
    more.marl.total_steps = 8192;
    a.resume = true;
    if (algo == "mappo") {
      Config other = more;
      other.marl.backend = cfg.marl.backend == PpoBackend::Fast ? PpoBackend::Torch : PpoBackend::Fast;
      EXPECT_THROW(train_marl(other, a), InputError) << variant << ": resumed on the other backend";
    }
    const auto rc = train_marl(more, a);
    EXPECT_GE(rc.env_steps, 8192) << variant;
  }
}

// Same seed, same numbers on any thread count, for every learner `skyloop train` runs by default:
// on the paper scenario (its tensors large enough that torch would split a sum across threads),
// the whole metrics file (every column but the wall-clock rate) and the greedy episode on
// run.threads = 1 and 2. QMIX's losses/value used to differ in its 9th digit.
TEST(Marl, EveryLearnerIsTheSameOnAnyThreadCount) {
  for (const auto& l : learners().rows()) {
    Config cfg;  // the paper scenario
    cfg.env.oracle = "zf";
    cfg.marl.algo = l.name;
    cfg.marl.total_steps = 6144;
    std::vector<std::string> metrics;
    std::vector<decltype(MarlTrainResult{}.evaluation.actions)> actions;
    for (int threads : {1, 2}) {
      cfg.run.threads = threads;
      MarlTrainOptions o;
      o.out_dir = fresh(std::string("threads_") + l.name + "_" + std::to_string(threads));
      o.registry = &zf_registry();
      actions.push_back(train_marl(cfg, o).evaluation.actions);
      metrics.push_back(metrics_without_timing(o.out_dir));
    }
    EXPECT_GE(std::count(metrics[0].begin(), metrics[0].end(), '\n'), 3) << l.name;
    EXPECT_EQ(metrics[0], metrics[1]) << l.name << ": run.threads = 1 and 2 logged different numbers";
    EXPECT_EQ(actions[0], actions[1]) << l.name;
  }
}

// The same under one band, where R[t] comes from the shipped interference-aware GNN (ignn, LibTorch)
// designing whole networks in padded batches: the environments keep one lane each and LibTorch
// and its BLAS one thread, whatever run.threads. New users every episode, so every
// environment's oracle is its own and the lanes matter. Each of the two used to differ: the
// lanes in the 9th digit of charts/sum_rate, and the first start's rate, computed before the
// thread count was set (as `skyloop reproduce` under mpirun against one process found).
TEST(Marl, SharedSpectrumLearnedOracleIsTheSameOnAnyThreadCount) {
  Config cfg;
  cfg.channel.spectrum = Spectrum::Shared;
  cfg.env.oracle = "ignn";
  cfg.env.resample_users = true;
  cfg.marl.action_mask = false;
  cfg.marl.shield = false;
  cfg.marl.envs = 4;
  cfg.marl.rollout = 32;
  cfg.marl.epochs = 1;
  cfg.marl.batch_episodes = 2;
  cfg.marl.total_steps = 512;
  std::vector<std::string> metrics;
  for (int threads : {1, 2}) {
    cfg.run.threads = threads;
    MarlTrainOptions o;
    o.out_dir = fresh("threads_shared_" + std::to_string(threads));
    o.registry = &builtin_beamformers();
    train_marl(cfg, o);
    metrics.push_back(metrics_without_timing(o.out_dir));
  }
  EXPECT_GE(std::count(metrics[0].begin(), metrics[0].end(), '\n'), 3);
  EXPECT_EQ(metrics[0], metrics[1]) << "run.threads = 1 and 2 logged different numbers";
}

// --resume keeps model selection going: the earlier validation rows stay in validation.csv, and
// the best of them (policy.pt) stays the one to beat. The pre-resume best is made unbeatable
// here, so a resumed run that forgot it would flag its first new row best and replace policy.pt.
// Rows scored on another number of layouts are kept, and selection starts over.
TEST(Marl, ResumeKeepsTheBestValidatedPolicy) {
  Config cfg = small_scenario("mappo", 4096);  // 8 updates of 512 steps
  cfg.marl.val_layouts = 2;
  cfg.marl.checkpoint_every = 2;
  MarlTrainOptions opt;
  opt.out_dir = fresh("resume_best");
  opt.registry = &zf_registry();
  train_marl(cfg, opt);
  const std::string csv_path = opt.out_dir + "/validation.csv", policy_path = opt.out_dir + "/policy.pt";
  auto rows = text_lines(read_file(csv_path));
  ASSERT_EQ(rows.size(), 5u) << "a header and 4 validations (updates 2, 4, 6, 8)";
  ASSERT_EQ(rows[0], "seed,env_steps,layouts,complete,objective,best");
  std::size_t best = 0;
  for (std::size_t i = 1; i < rows.size(); ++i)
    if (split_csv_line(rows[i]).back() == "1") best = i;
  ASSERT_GT(best, 0u);
  auto fields = split_csv_line(rows[best]);
  fields[4] = "1000000000";  // an objective no checkpoint reaches
  rows[best] = fields[0];
  for (std::size_t k = 1; k < fields.size(); ++k) rows[best] += "," + fields[k];
  std::string before;
  for (const auto& r : rows) before += r + "\n";
  write_file_atomic(csv_path, before);
  const std::string policy_before = read_file(policy_path);

  Config more = cfg;
  more.marl.total_steps = 6144;  // 4 more updates: validations at updates 10 and 12
  opt.resume = true;
  train_marl(more, opt);
  const std::string after = read_file(csv_path);
  ASSERT_EQ(after.substr(0, before.size()), before) << "the earlier rows are kept as they were";
  const auto added = text_lines(after.substr(before.size()));
  ASSERT_EQ(added.size(), 2u) << after;
  for (const auto& r : added) EXPECT_EQ(split_csv_line(r).back(), "0") << "no checkpoint beats the best: " << r;
  EXPECT_EQ(read_file(policy_path), policy_before) << "policy.pt is still the best validated policy";

  // Another validation set: rows kept, selection over the new one starts afresh.
  Config wider = more;
  wider.marl.total_steps = 7168;  // 2 more updates: one validation, at update 14
  wider.marl.val_layouts = 3;
  train_marl(wider, opt);
  const std::string last = read_file(csv_path);
  ASSERT_EQ(last.substr(0, after.size()), after);
  const auto fresh_rows = text_lines(last.substr(after.size()));
  ASSERT_EQ(fresh_rows.size(), 1u) << last;
  EXPECT_EQ(split_csv_line(fresh_rows[0])[2], "3");
  EXPECT_EQ(split_csv_line(fresh_rows[0]).back(), "1");
  EXPECT_NE(read_file(policy_path), policy_before);
}

// Every learner reads the action space from the mobility model: under `headings` (17 actions) each
// trains, writes a policy that names its actions, and flies it with allowed moves only; an
// environment of another mobility model refuses the policy in one line.
TEST(Marl, EveryLearnerTrainsAndFliesTheHeadingsModel) {
  for (const std::string algo : {"mappo", "ippo", "vdn", "qmix"}) {
    Config cfg = small_scenario(algo, 2048);
    cfg.trajectory.mobility = "headings";
    cfg.marl.batch_episodes = 8;
    validate(cfg);
    MarlTrainOptions opt;
    opt.out_dir = fresh("headings_" + algo);
    opt.registry = &zf_registry();
    const auto r = train_marl(cfg, opt);
    for (const auto& a : r.evaluation.actions)
      for (int x : a) EXPECT_TRUE(x >= 0 && x < 17) << algo;
    auto policy = MarlPolicy::load(opt.out_dir);
    UavEnv env(cfg, zf_oracle(cfg, 3));
    ASSERT_EQ(env.actions(), 17);
    const auto a = policy->act(env);
    for (int n = 0; n < env.uavs(); ++n)
      EXPECT_TRUE(allowed_moves(env, n, SafetyOptions{}) >> a[static_cast<std::size_t>(n)] & 1u) << algo;
    // Flown with ways home reserved (an execution setting, as `skyloop eval --set
    // marl.reserve_slack=S` sets it): every UAV home, each move among the mask's.
    EXPECT_EQ(policy->reserve_slack(), -1);
    policy->set_reserve_slack(1000);
    policy->reset(env);
    env.reset();
    while (!env.done()) {
      const auto b = policy->act(env);
      for (int n = 0; n < env.uavs(); ++n)
        ASSERT_TRUE(reachable_moves(env, n) >> b[static_cast<std::size_t>(n)] & 1u) << algo << ", t = " << env.t();
      env.step(b);
    }
    EXPECT_TRUE(env.positions().isApprox(env.destinations())) << algo;
    EXPECT_THROW(policy->set_reserve_slack(-2), InputError);
    Config grid = cfg;
    grid.trajectory.mobility = "grid";
    UavEnv genv(grid, zf_oracle(grid, 3));
    try {
      policy->act(genv);
      ADD_FAILURE() << algo << ": a headings policy flew the grid model";
    } catch (const InputError& e) {
      EXPECT_NE(std::string(e.what()).find("trajectory.mobility = \"headings\""), std::string::npos) << e.what();
    }
  }
}

// UAVs that choose their altitude (trajectory.mobility = "grid-3d", 15 actions): each learner
// trains on the altitude levels with the observations' altitude field, and its policy flies
// every UAV home at its destination's altitude with moves the mask allows only.
TEST(Marl, EveryLearnerTrainsAndFliesTheAltitudeLevels) {
  for (const std::string algo : {"mappo", "ippo", "vdn", "qmix"}) {
    Config cfg = small_scenario(algo, 2048);
    cfg.trajectory.mobility = "grid-3d";
    cfg.marl.batch_episodes = 8;
    validate(cfg);
    MarlTrainOptions opt;
    opt.out_dir = fresh("grid3d_" + algo);
    opt.registry = &zf_registry();
    const auto r = train_marl(cfg, opt);
    EXPECT_TRUE(r.evaluation.success) << algo;
    auto policy = MarlPolicy::load(opt.out_dir);
    UavEnv env(cfg, zf_oracle(cfg, 3));
    ASSERT_EQ(env.actions(), 15);
    ASSERT_NO_THROW(env.spec().obs.field("altitude")) << algo;
    policy->reset(env);
    std::set<double> altitudes;
    while (!env.done()) {
      const auto b = policy->act(env);
      for (int n = 0; n < env.uavs(); ++n)
        ASSERT_TRUE(reachable_moves(env, n) >> b[static_cast<std::size_t>(n)] & 1u) << algo << ", t = " << env.t();
      env.step(b);
      for (int n = 0; n < env.uavs(); ++n) altitudes.insert(env.altitude(n));
    }
    EXPECT_TRUE(env.positions().isApprox(env.destinations())) << algo;
    EXPECT_GE(*altitudes.begin(), 60.0) << algo;
    EXPECT_LE(*altitudes.rbegin(), 140.0) << algo;
  }
}

TEST(Marl, UnknownLearnersAreRefusedWithTheRegisteredNames) {
  Config cfg = small_scenario("mappo", 1024);
  cfg.marl.algo = "sac";
  MarlTrainOptions opt;
  opt.out_dir = fresh("unknown");
  opt.registry = &zf_registry();
  try {
    train_marl(cfg, opt);
    FAIL() << "trained an unknown learner";
  } catch (const InputError& e) {
    EXPECT_STREQ(e.what(), "marl.algo = \"sac\" is unknown: allowed mappo, ippo, vdn, qmix");
  }
  EXPECT_THROW(resolve_config(std::nullopt, {"marl.algo=sac"}), InputError);
}

// train_marl holds every configuration to the cross-field rules, however it was built: a task's
// recipe handed to another learner (uma-rician-v1's sequential PPO turns given to VDN, which once
// trained and then crashed in its first validation) is refused in one line, before the run exists.
TEST(Marl, ACombinationTheLearnerCannotRunIsRefusedBeforeTraining) {
  for (const char* algo : {"vdn", "qmix"}) {
    Config cfg = small_scenario(algo, 1024);
    cfg.marl.encoder = ObservationKind::Set;
    cfg.marl.sequential = true;  // set directly, past apply_override's checks
    MarlTrainOptions opt;
    opt.out_dir = fresh(std::string("sequential_") + algo);
    opt.registry = &zf_registry();
    try {
      train_marl(cfg, opt);
      ADD_FAILURE() << algo << " trained with sequential turns";
    } catch (const InputError& e) {
      EXPECT_NE(std::string(e.what()).find("marl.sequential = true with marl.algo = \"" + std::string(algo) + "\""), std::string::npos)
          << e.what();
    }
    EXPECT_FALSE(std::filesystem::exists(opt.out_dir + "/last.pt")) << algo;
  }
}

// A policy trained with the look-ahead (marl.lookahead) flies an environment that writes it, and
// one that does not is refused in one line (not a shape error from the network).
/// A MAPPO policy on the set observation with the look-ahead, trained briefly into `dir`.
static std::unique_ptr<MarlPolicy> look_ahead_policy(Config& cfg, const std::string& dir, bool sequential, int passes = 1) {
  cfg = small_scenario("mappo", 1024);
  cfg.marl.encoder = ObservationKind::Set;
  cfg.marl.lookahead = true;
  cfg.marl.sequential = sequential;
  cfg.marl.sequential_passes = passes;
  validate(cfg);
  MarlTrainOptions opt;
  opt.out_dir = fresh(dir);
  opt.registry = &zf_registry();
  train_marl(cfg, opt);
  return MarlPolicy::load(opt.out_dir);
}

TEST(Marl, LookAheadPoliciesNeedTheLookAhead) {
  Config cfg;
  auto policy = look_ahead_policy(cfg, "lookahead", false);
  EXPECT_FALSE(policy->sequential());
  UavEnv env(cfg, zf_oracle(cfg, 3));
  const auto a = policy->act(env);
  for (int n = 0; n < env.uavs(); ++n)
    EXPECT_TRUE(allowed_moves(env, n, SafetyOptions{}) >> a[static_cast<std::size_t>(n)] & 1u);
  Config plain = cfg;
  plain.marl.lookahead = false;
  UavEnv penv(plain, zf_oracle(plain, 3));
  try {
    policy->act(penv);
    ADD_FAILURE() << "a look-ahead policy flew an environment without it";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("marl.lookahead"), std::string::npos) << e.what();
  }
}

// marl.sequential: a policy trained choosing one UAV after another flies that way (its training
// config says so), every move allowed by the mask and the shield, every mission complete on held-out
// users; same policy, same environment, same moves.
TEST(Marl, SequentialPoliciesFlyAsTrained) {
  Config cfg;
  auto policy = look_ahead_policy(cfg, "sequential", true);
  EXPECT_TRUE(policy->sequential());
  for (const std::uint64_t seed : {3u, 4u}) {
    UavEnv env(cfg, zf_oracle(cfg, seed)), twin(cfg, zf_oracle(cfg, seed));
    policy->reset(env);
    while (!env.done()) {
      const auto a = policy->act(env);
      EXPECT_EQ(env.seen_positions(), env.positions()) << "act leaves no landing shown";
      for (int n = 0; n < env.uavs(); ++n)
        EXPECT_TRUE(allowed_moves(env, n, SafetyOptions{}) >> a[static_cast<std::size_t>(n)] & 1u);
      EXPECT_EQ(policy->act(twin), a);
      env.step(a);
      twin.step(a);
    }
    for (int n = 0; n < env.uavs(); ++n) EXPECT_TRUE(env.arrived(n)) << "seed " << seed << ", UAV " << n;
  }
}

// marl.sequential_passes: a policy trained taking its turns twice a slot flies that way; a
// sequential policy flown with more passes than it trained with changes some moves and keeps
// every move allowed and every mission complete; a policy that does not choose in turn, or a pass
// count outside 1 .. kMaxSequentialPasses, is refused in one line.
TEST(Marl, SequentialPassesFlyAsTrainedOrAsSet) {
  Config cfg;
  auto twice = look_ahead_policy(cfg, "passes", true, 2);
  EXPECT_TRUE(twice->sequential());
  EXPECT_EQ(twice->sequential_passes(), 2);
  auto once = look_ahead_policy(cfg, "one_pass", true);
  EXPECT_EQ(once->sequential_passes(), 1);
  auto thrice = MarlPolicy::load((skyloop::test::ScratchRoot::get().path() / "one_pass").string());
  thrice->set_sequential_passes(3);
  int differ = 0;
  for (MarlPolicy* policy : {twice.get(), thrice.get()})
    for (const std::uint64_t seed : {3u, 4u}) {
      UavEnv env(cfg, zf_oracle(cfg, seed)), twin(cfg, zf_oracle(cfg, seed));
      policy->reset(env);
      once->reset(twin);
      while (!env.done()) {
        const auto a = policy->act(env);
        EXPECT_EQ(env.seen_positions(), env.positions()) << "act leaves no landing shown";
        for (int n = 0; n < env.uavs(); ++n)
          EXPECT_TRUE(allowed_moves(env, n, SafetyOptions{}) >> a[static_cast<std::size_t>(n)] & 1u);
        if (policy == thrice.get()) {
          differ += once->act(twin) != a;
          twin.step(a);
        }
        env.step(a);
      }
      for (int n = 0; n < env.uavs(); ++n) EXPECT_TRUE(env.arrived(n)) << "seed " << seed << ", UAV " << n;
    }
  EXPECT_GT(differ, 0) << "three passes should change some of the one-pass policy's moves";
  for (const int bad : {0, kMaxSequentialPasses + 1}) {
    try {
      once->set_sequential_passes(bad);
      ADD_FAILURE() << "marl.sequential_passes = " << bad << " was accepted";
    } catch (const InputError& e) {
      EXPECT_NE(std::string(e.what()).find("marl.sequential_passes = " + std::to_string(bad)), std::string::npos) << e.what();
    }
  }
  once->set_sequential(false);
  EXPECT_EQ(once->sequential_passes(), 1);
  EXPECT_THROW(once->set_sequential_passes(2), InputError);
  Config plain = small_scenario("mappo", 1024);
  plain.marl.encoder = ObservationKind::Set;
  plain.marl.sequential_passes = 2;
  try {
    validate(plain);
    ADD_FAILURE() << "marl.sequential_passes = 2 without marl.sequential was accepted";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("marl.sequential = false"), std::string::npos) << e.what();
  }
}

TEST(Marl, BadPoliciesAreRejected) {
  EXPECT_THROW(MarlPolicy::load("/nonexistent/policy.pt"), InputError);
  const std::string dir = fresh("bad");
  write_file_atomic(dir + "/policy.pt", "not a policy");
  EXPECT_THROW(MarlPolicy::load(dir), InputError);
  // A real policy with 64 bytes flipped in its weights, or truncated, is refused on load.
  Config cfg = small_scenario("mappo", 1024);
  MarlTrainOptions opt;
  opt.out_dir = fresh("flip_src");
  opt.registry = &zf_registry();
  train_marl(cfg, opt);
  const std::string good = read_file(opt.out_dir + "/policy.pt");
  std::string flipped = good;
  for (std::size_t i = 0; i < 64; ++i) flipped[good.size() / 2 + i] = static_cast<char>(~flipped[good.size() / 2 + i]);
  write_file_atomic(dir + "/policy.pt", flipped);
  EXPECT_THROW(MarlPolicy::load(dir), InputError);
  write_file_atomic(dir + "/policy.pt", good.substr(0, good.size() - 100));
  EXPECT_THROW(MarlPolicy::load(dir), InputError);
  write_file_atomic(dir + "/policy.pt", good);
  EXPECT_NO_THROW(MarlPolicy::load(dir));
}

// The reference of eval --layouts under continuous mobility, the optimum of the lattice twin, does not
// depend on trajectory.command: policies of either command share its cached optima.
TEST(Marl, ContinuousPoliciesOfEitherCommandShareTheTwinsOptima) {
  Config velocity;
  velocity.trajectory.mobility = "continuous";
  validate(velocity);
  Config polar = velocity;
  polar.trajectory.command = Command::Polar;
  validate(polar);
  EXPECT_EQ(lattice_twin(polar).trajectory.mobility, "headings");
  EXPECT_EQ(to_toml(lattice_twin(polar)), to_toml(lattice_twin(velocity)));
}

// Continuous-action MAPPO (the squashed Gaussian, ppo.hpp) on the small scenario under the
// continuous model, energy efficiency, the objective reward, the mask and the shield, no entropy
// bonus: 2e5 steps on three seeds. The deployed policy, tanh(mu) through the safety layer, is judged
// on its training users (a learning test, not a generalisation one) against the untrained policy
// and Random (primitives, mask): every mission completes (the safety layer's guarantee) and the
// learned policy beats Random by 5%. Measured (kbit/J), seeds 1-3: ATen default 197.4 / 192.4 /
// 191.3, avx2 and avx512 201.6 / 224.6 / 209.4; untrained 152.8, Random 170.2 (so the bound,
// 178.7, sits 12.6 below the worst run).
TEST(Marl, ContinuousMappoLearnsEnergyEfficientFlight) {
  Config cfg = small_scenario("mappo", 200000);
  cfg.trajectory.mobility = "continuous";
  cfg.marl.entropy_coef = 0;
  cfg.env.objective = Objective::EnergyEfficiency;
  cfg.env.reward = Reward::Objective;
  validate(cfg);
  const auto oracle = zf_oracle(cfg, cfg.marl.users_seed);
  UavEnv env(cfg, oracle);
  const double random = random_mean(env);
  const double before = untrained_evaluation(cfg, "continuous_untrained").objective;
  for (std::uint64_t seed : {1, 2, 3}) {
    cfg.run.seed = seed;
    MarlTrainOptions opt;
    opt.out_dir = fresh("continuous_s" + std::to_string(seed));
    opt.registry = &zf_registry();
    const auto r = train_marl(cfg, opt);
    EXPECT_TRUE(r.evaluation.success) << "seed " << seed;
    EXPECT_GT(r.evaluation.objective, before) << "seed " << seed;
    EXPECT_GE(r.evaluation.objective, 1.05 * random) << "seed " << seed << ": untrained " << before;
    auto policy = MarlPolicy::load(opt.out_dir);
    EXPECT_TRUE(policy->commands_velocities());
    EXPECT_EQ(run_episode(env, *policy).objective, r.evaluation.objective) << "the saved policy replays its evaluation";
    Config polar = cfg;  // a policy flies the command it was trained with (trajectory.command)
    polar.trajectory.command = Command::Polar;
    validate(polar);
    UavEnv other(polar, oracle);
    EXPECT_THROW(policy->act_velocities(other), InputError);
  }
}
