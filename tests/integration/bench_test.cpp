// The benchmark (skyloop/experiments/bench.hpp): its statistics at points computed by hand, the
// shipped tasks' fingerprints and references (a sample of layouts recomputed), and scoring.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <nlohmann/json.hpp>
#include <set>

#include "skyloop/core/config_io.hpp"
#include "skyloop/core/error.hpp"
#include "skyloop/core/paths.hpp"
#include "skyloop/experiments/bench.hpp"
#include "skyloop/experiments/builtin.hpp"
#include "skyloop/planning/registry.hpp"

namespace skyloop {
namespace {

TEST(BenchStats, InterquartileMeanTrimsAQuarterFromEachEnd) {
  // scipy.stats.trim_mean(x, 0.25) trims int(0.25 n) scores from each end of the sorted scores:
  // n = 8 -> 2 each: mean(3, 4, 5, 6) = 4.5; n = 10 -> 2 each: mean(3..8) = 5.5; n = 3 -> none.
  EXPECT_DOUBLE_EQ(interquartile_mean({8, 1, 7, 2, 6, 3, 5, 4}), 4.5);
  EXPECT_DOUBLE_EQ(interquartile_mean({10, 9, 8, 7, 6, 5, 4, 3, 2, 1}), 5.5);
  EXPECT_DOUBLE_EQ(interquartile_mean({1, 2, 30}), 11.0);
  // An outlier in the outer quarters does not move it: the point of the IQM.
  EXPECT_DOUBLE_EQ(interquartile_mean({-1000, 1, 2, 3, 4, 5, 6, 1000}), 3.5);
}

TEST(BenchStats, TheStratifiedBootstrapResamplesRunsWithinEachLayout) {
  // One run per layout: every resample is the data itself, so the interval is the point.
  double lo = 0, hi = 0;
  iqm_interval({{0.9}, {0.8}, {0.7}, {0.6}}, 500, 7, lo, hi);
  EXPECT_DOUBLE_EQ(lo, interquartile_mean({0.9, 0.8, 0.7, 0.6}));
  EXPECT_DOUBLE_EQ(hi, lo);
  // Two runs per layout: the interval lies within the extreme resamples and holds the estimate,
  // and the same seed gives the same interval.
  const std::vector<std::vector<double>> runs{{0.9, 0.5}, {0.8, 0.6}, {0.95, 0.7}, {0.85, 0.4}};
  std::vector<double> all;
  for (const auto& r : runs) all.insert(all.end(), r.begin(), r.end());
  iqm_interval(runs, 2000, 11, lo, hi);
  double lo2 = 0, hi2 = 0;
  iqm_interval(runs, 2000, 11, lo2, hi2);
  EXPECT_EQ(lo, lo2);
  EXPECT_EQ(hi, hi2);
  EXPECT_LT(lo, hi);
  EXPECT_LE(lo, interquartile_mean(all));
  EXPECT_GE(hi, interquartile_mean(all));
  EXPECT_GE(lo, interquartile_mean({0.5, 0.6, 0.7, 0.4}) - 1e-12);  // the lowest resample: every layout's worse run
  EXPECT_LE(hi, interquartile_mean({0.9, 0.8, 0.95, 0.85}) + 1e-12);
}

TEST(BenchTasks, TheShippedTasksCoverTheStudiedSettings) {
  const auto ids = bench_task_ids();
  for (const char* id : {"paper-v1", "uma-rician-v1", "shared-wmmse-v2", "energy-headings-v1", "continuous-v1", "fleet16-v1"})
    EXPECT_NE(std::find(ids.begin(), ids.end(), id), ids.end()) << id;
  const auto uma = load_bench_task("uma-rician-v1");
  EXPECT_EQ(uma.config.channel.pathloss, "3gpp-uma-av");
  EXPECT_EQ(uma.config.channel.fading, "rician");
  const auto shared = load_bench_task("shared-wmmse-v2");
  EXPECT_EQ(shared.config.channel.spectrum, Spectrum::Shared);
  EXPECT_EQ(shared.config.env.oracle, "nwmmse=czfsel");
  // A withdrawn version is refused with its reason and successor, not as unknown.
  try {
    load_bench_task("shared-wmmse-v1");
    FAIL();
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("was withdrawn"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("successor: shared-wmmse-v2"), std::string::npos) << e.what();
  }
  const auto energy = load_bench_task("energy-headings-v1");
  EXPECT_EQ(energy.config.trajectory.mobility, "headings");
  EXPECT_EQ(energy.config.env.objective, Objective::EnergyEfficiency);
  EXPECT_EQ(load_bench_task("continuous-v1").config.trajectory.mobility, "continuous");
  const auto fleet = load_bench_task("fleet16-v1");
  EXPECT_EQ(fleet.config.trajectory.starts.size(), 16u);
  for (const auto& r : fleet.references) EXPECT_EQ(r.reference, "bestknown");
  // A name alone is its highest version; an unknown one is refused naming the tasks.
  EXPECT_EQ(load_bench_task("paper").id, "paper-v1");
  try {
    load_bench_task("papr");
    FAIL();
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("allowed"), std::string::npos);
    EXPECT_NE(std::string(e.what()).find("paper-v1"), std::string::npos);
  }
}

// A task's numbers cannot drift: its resolved configuration is the one its references were
// computed for (a value of any field its config.toml fixes changes the fingerprint; a field added
// to the table later meets the task at its default, and the references' recomputation below
// catches one that moves its numbers), and its reference file is the one shipped (load_bench_task
// refuses another checksum). A failure here means the physics or the
// configuration moved: give the task a new version (tasks/<name>-v<N+1>), never edit a shipped one.
TEST(BenchTasks, EveryTaskMatchesItsFingerprintAndItsReferenceChecksum) {
  for (const auto& id : bench_task_ids()) {
    const auto t = load_bench_task(id);
    EXPECT_EQ(config_fingerprint(t.config, t.fixed_keys), t.fingerprint) << id << ": its configuration changed";
    EXPECT_GT(t.fixed_keys.size(), 100u) << id << ": a task's config.toml fixes every field it was frozen with";
    EXPECT_EQ(reference_checksum(t.references), t.reference_checksum) << id;
    EXPECT_GE(t.references.size(), 5u) << id;
    EXPECT_GE(t.protocol.seeds, 5) << id;
    std::set<std::uint64_t> seeds;
    for (const auto& r : t.references) {
      EXPECT_EQ(layout_split(r.users_seed), LayoutSplit::Test) << id;
      EXPECT_GT(r.objective, 0) << id;
      seeds.insert(r.users_seed);
    }
    EXPECT_EQ(seeds.size(), t.references.size()) << id << ": a test layout twice";
  }
}

/// Recomputes 5 layouts of a task, spread over its test layouts, and compares with the shipped
/// references within the task's tolerance (its oracle's arithmetic: 1e-9 in double precision,
/// 1e-5 where a float32 network computes R[t]).
void expect_references_reproduce(const std::string& id) {
  const auto t = load_bench_task(id);
  const auto idx = sample_layouts(t.references.size(), 5);
  ASSERT_EQ(idx.size(), 5u);
  EXPECT_EQ(idx.front(), 0u);
  EXPECT_EQ(idx.back(), t.references.size() - 1);
  const auto got = compute_references(t, idx, 0, nullptr);
  for (std::size_t k = 0; k < idx.size(); ++k) {
    const auto& s = t.references[idx[k]];
    EXPECT_EQ(got[k].reference, s.reference) << id << " layout " << s.layout;
    EXPECT_EQ(got[k].users_seed, s.users_seed);
    EXPECT_EQ(got[k].users, s.users);
    EXPECT_NEAR(got[k].objective, s.objective, t.reference_rtol * std::abs(s.objective)) << id << " layout " << s.layout;
  }
}

TEST(BenchReference, PaperV1) { expect_references_reproduce("paper-v1"); }
TEST(BenchReference, UmaRicianV1) { expect_references_reproduce("uma-rician-v1"); }
TEST(BenchReference, SharedWmmseV2) { expect_references_reproduce("shared-wmmse-v2"); }
TEST(BenchReference, EnergyHeadingsV1) { expect_references_reproduce("energy-headings-v1"); }
TEST(BenchReference, ContinuousV1) { expect_references_reproduce("continuous-v1"); }
TEST(BenchReference, Fleet16V1) { expect_references_reproduce("fleet16-v1"); }

TEST(BenchRun, PlannersAreScoredPerSeedAndLayoutAgainstTheShippedOptimum) {
  const auto t = load_bench_task("paper-v1");
  BenchRunOptions o;
  o.planners = {"greedy", "random"};
  o.seeds = {1, 2};
  const auto rows = run_bench(t, o, nullptr);
  const std::size_t L = t.references.size();
  ASSERT_EQ(rows.size(), 2 * 2 * L);
  for (std::size_t k = 0; k < rows.size(); ++k) {
    const auto& r = rows[k];
    EXPECT_EQ(r.task, "paper");
    EXPECT_EQ(r.reference, "optimal");
    EXPECT_EQ(r.reference_objective, t.references[r.layout].objective);
    EXPECT_NEAR(r.fraction, r.objective / r.reference_objective, 1e-15);
    EXPECT_LE(r.fraction, 1.0 + 1e-9) << r.policy << " beats the exact optimum on layout " << r.layout;
  }
  // Greedy draws nothing (Planner::seeded): it flies once and its rows stand for both seeds, which
  // is what flying it under each seed gives; the random planner's seeds differ.
  EXPECT_FALSE(builtin_planners().create("greedy")->seeded());
  EXPECT_TRUE(builtin_planners().create("random")->seeded());
  for (const std::uint64_t seed : {1u, 2u}) {
    LayoutEvalOptions e;
    e.layouts = static_cast<int>(L);
    for (const auto& r : t.references) e.users_seeds.push_back(r.users_seed);
    e.solve_reference = false;
    e.planners = {"greedy"};
    e.planner_seed = seed;
    const auto flown = evaluate_layouts(t.config, e, builtin_beamformers(), nullptr);
    for (std::size_t l = 0; l < L; ++l) EXPECT_EQ(flown[l].objective, rows[(seed - 1) * L + l].objective);
  }
  bool differ = false;
  for (std::size_t l = 0; l < L; ++l) differ = differ || rows[2 * L + l].objective != rows[3 * L + l].objective;
  EXPECT_TRUE(differ);
  const auto sum = summarise_bench(t, rows);
  ASSERT_EQ(sum.size(), 2u);
  EXPECT_EQ(sum[0].policy, "greedy");
  EXPECT_EQ(sum[0].seeds, 2);
  EXPECT_EQ(sum[0].layouts, static_cast<int>(L));
  EXPECT_EQ(sum[0].iqm_low, sum[0].iqm_high);  // deterministic: no spread over seeds
  EXPECT_GT(sum[0].iqm, sum[1].iqm);           // greedy beats random on the paper's task
  // Fewer seeds than the protocol's are said, never mixed in silently.
  EXPECT_NE(sum[0].protocol.find("2 seeds of the protocol's 5"), std::string::npos) << sum[0].protocol;
  // marl-eval's layout: env -> task -> algorithm -> run -> absolute_metrics, lists over the layouts.
  const auto j = nlohmann::json::parse(bench_marl_eval_json(t, rows));
  EXPECT_EQ(j["skyloop"]["paper-v1"]["greedy"]["seed_1"]["absolute_metrics"]["fraction_of_reference"].size(), L);
  EXPECT_EQ(j["skyloop"]["paper-v1"]["random"]["seed_2"]["step_0"]["step_count"], t.protocol.budget_steps);
}

TEST(BenchRun, APolicyTrainedOffTheProtocolIsLabelledSo) {
  const auto t = load_bench_task("paper-v1");
  Config trained = t.config;
  EXPECT_EQ(policy_protocol(t, trained), "ok");
  apply_override(trained, "channel.p_max_dbm=40");
  apply_override(trained, "marl.total_steps=100000");
  const std::string why = policy_protocol(t, trained);
  EXPECT_NE(why.find("channel.p_max_dbm"), std::string::npos) << why;
  EXPECT_NE(why.find("trained 100000 steps, the budget is 2000000"), std::string::npos) << why;
  Config on_test = t.config;
  apply_override(on_test, "env.resample_users=false");
  apply_override(on_test, "marl.users_seed=4611686018427387904");  // layout 0 of the validation split
  EXPECT_NE(policy_protocol(t, on_test).find("validation split"), std::string::npos) << policy_protocol(t, on_test);
}

}  // namespace
}  // namespace skyloop
