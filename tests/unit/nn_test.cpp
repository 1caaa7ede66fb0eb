// Learned beamformers through the public, torch-free API: equivariance, power budget, batching,
// checkpoint errors, seeded training that learns, and exact resume.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>

#include "skyloop/beamforming/linear.hpp"
#include "skyloop/channel/rates.hpp"
#include "skyloop/core/error.hpp"
#include "skyloop/core/io.hpp"
#include "skyloop/nn/learned.hpp"
#include "test_util.hpp"

using namespace skyloop;
namespace fs = std::filesystem;

namespace {

Config tiny_config(const std::string& model) { return test::tiny_nn_config(model); }

std::string fresh_dir(const std::string& name) {
  const auto d = fs::path(::testing::TempDir()) / ("skyloop_nn_" + std::to_string(::getpid()) + "_" + name);
  fs::remove_all(d);
  return d.string();
}

/// A briefly trained tiny model of each kind (cached per process).
std::string tiny_model(const std::string& model) {
  static std::map<std::string, std::string> cache;
  if (!cache.count(model)) {
    TrainOptions opt;
    opt.out_dir = fresh_dir("tiny_" + model);
    train_beamformer(tiny_config(model), opt);
    cache[model] = opt.out_dir + "/model.pt";
  }
  return cache[model];
}

const char* kModels[] = {"gnn", "deepsets", "mspointnet", "gnn+structured", "deepsets+structured"};

}  // namespace

// Tolerances in these tests follow from the arithmetic, not from one machine's output.
//  * float64 checks: the unit roundoff is u64 = 2^-53 = 1.1e-16. The served map x -> W has a
//    relative condition number kappa of at most ~1.2e3 on these tiny models (measured per cluster
//    in NnInternal.Float32ServingIsWithinRoundingOfFloat64: GraphNorm over 1-3 users and the
//    structured readout's solve are the ill-conditioned parts), so two float64 evaluations that
//    differ only in summation order agree to ~1e-13 relative; kF64Tol = 1e-8 (relative to
//    sqrt(P_max), the norm of every W on the budget) leaves a wide margin for other models, while a
//    fault (a cluster seeing another's users, a permutation applied twice) changes W by O(sqrt(P_max)).
//  * The float32 serving path is held to the float64 evaluation of the same weights, with a bound
//    from float32 rounding and the measured conditioning, in nn_internal_test.cpp
//    (NnInternal.Float32ServingIsWithinRoundingOfFloat64).
constexpr double kF64Tol = 1e-8;

Config f64(Config cfg) {
  cfg.nn.precision = "float64";
  return cfg;
}

TEST(Learned, PermutingUsersPermutesBeamformers) {
  for (const char* m : kModels) {
    const Config cfg = f64(tiny_config(m));
    const auto bf = LearnedBeamformer::load(tiny_model(m), cfg);
    for (int k = 1; k <= 6; ++k)
      for (const auto& c : test::clusters_of_size(cfg, k, 3, 30 + k)) {
        std::vector<int> perm(k);
        for (int i = 0; i < k; ++i) perm[i] = (i + 1) % k;  // cyclic shift
        std::reverse(perm.begin(), perm.end());
        Cluster p = c;
        for (int i = 0; i < k; ++i) p.G.row(i) = c.G.row(perm[i]);
        const MatrixXcd W = bf->design(c), Wp = bf->design(p);
        for (int i = 0; i < k; ++i)
          EXPECT_LT((Wp.col(i) - W.col(perm[i])).norm(), kF64Tol * std::sqrt(c.p_max)) << m << " K_n=" << k;
      }
  }
}

TEST(Learned, PowerBudgetAlwaysHolds) {
  for (const char* m : kModels) {
    for (PowerScaling mode : {PowerScaling::Full, PowerScaling::Cap}) {
      Config cfg = tiny_config(m);
      cfg.beamforming.power_scaling = mode;
      cfg.channel.p_max_dbm = 45;
      const auto bf = LearnedBeamformer::load(tiny_model(m), cfg);
      for (int k = 1; k <= 8; ++k)
        for (const auto& c : test::clusters_of_size(cfg, k, 2, 50 + k)) {
          const MatrixXcd W = bf->design(c);
          ASSERT_EQ(W.cols(), k);
          EXPECT_LE(W.squaredNorm(), c.p_max * (1 + 1e-9)) << m;
          if (mode == PowerScaling::Full) {
            EXPECT_NEAR(W.squaredNorm(), c.p_max, 1e-9 * c.p_max) << m;
          }
        }
    }
  }
}

TEST(Learned, BatchedEqualsOneByOne) {
  for (const char* m : kModels) {
    const Config cfg = f64(tiny_config(m));
    const auto bf = LearnedBeamformer::load(tiny_model(m), cfg);
    std::vector<Cluster> mixed;
    for (int k : {3, 1, 5, 2, 8, 4})
      for (const auto& c : test::clusters_of_size(cfg, k, 2, 70 + k)) mixed.push_back(c);
    const auto batched = bf->design_batch(mixed);
    for (std::size_t i = 0; i < mixed.size(); ++i)
      EXPECT_LT((batched[i] - bf->design(mixed[i])).norm(), kF64Tol * std::sqrt(mixed[i].p_max)) << m << " cluster " << i;
  }
}

TEST(Learned, BadCheckpointsAreRejected) {
  const Config cfg = tiny_config("gnn");
  const std::string dir = fresh_dir("bad");
  EXPECT_THROW(LearnedBeamformer::load(dir + "/missing.pt", cfg), InputError);
  write_file_atomic(dir + "/garbage.pt", "this is not a model");
  EXPECT_THROW(LearnedBeamformer::load(dir + "/garbage.pt", cfg), InputError);
  // A truncated copy of a real checkpoint.
  const std::string good = read_file(tiny_model("gnn"));
  write_file_atomic(dir + "/truncated.pt", good.substr(0, good.size() / 2));
  EXPECT_THROW(LearnedBeamformer::load(dir + "/truncated.pt", cfg), InputError);
  // 64 bytes flipped inside the tensor data (the bulk of the file): the archive still parses, but
  // the zip records' CRC-32 no longer match.
  std::string flipped = good;
  for (std::size_t i = 0; i < 64; ++i) flipped[good.size() / 2 + i] = static_cast<char>(~flipped[good.size() / 2 + i]);
  write_file_atomic(dir + "/flipped.pt", flipped);
  try {
    LearnedBeamformer::load(dir + "/flipped.pt", cfg);
    ADD_FAILURE() << "a checkpoint with flipped bytes loaded";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("checksum"), std::string::npos) << e.what();
  }
  // A model trained for L = 4 refused under L = 8.
  Config eight = cfg;
  eight.channel.antennas = 8;
  try {
    LearnedBeamformer::load(tiny_model("gnn"), eight);
    FAIL();
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("channel.antennas = 8"), std::string::npos) << e.what();
  }
}

TEST(Learned, ResumeGivesTheSameModelAsAnUninterruptedRun) {
  Config cfg = tiny_config("gnn");
  cfg.nn.epochs = 2;
  TrainOptions straight;
  straight.out_dir = fresh_dir("straight");
  train_beamformer(cfg, straight);

  Config first = cfg;
  first.nn.epochs = 1;
  TrainOptions part;
  part.out_dir = fresh_dir("resumed");
  train_beamformer(first, part);
  part.resume = true;
  train_beamformer(cfg, part);

  const auto a = LearnedBeamformer::load(straight.out_dir + "/last.pt", cfg);
  const auto b = LearnedBeamformer::load(part.out_dir + "/last.pt", cfg);
  for (const auto& c : test::clusters_of_size(cfg, 4, 5, 9)) EXPECT_EQ(a->design(c), b->design(c));
  EXPECT_EQ(a->info().epoch, 2);
}

TEST(Learned, SameSeedSameModel) {
  const Config cfg = tiny_config("deepsets");
  TrainOptions a, b;
  a.out_dir = fresh_dir("seed_a");
  b.out_dir = fresh_dir("seed_b");
  train_beamformer(cfg, a);
  train_beamformer(cfg, b);
  const auto ma = LearnedBeamformer::load(a.out_dir + "/model.pt", cfg);
  const auto mb = LearnedBeamformer::load(b.out_dir + "/model.pt", cfg);
  for (const auto& c : test::clusters_of_size(cfg, 3, 3, 4)) EXPECT_EQ(ma->design(c), mb->design(c));
  EXPECT_EQ(read_file(a.out_dir + "/metrics.csv").substr(0, 60), read_file(b.out_dir + "/metrics.csv").substr(0, 60));
}

namespace {
/// A short, seeded GNN training run (6 epochs over 800 snapshots, d = 64, 2 layers); returns its
/// test sum rate and a reference from its test report ("mrt", "zf", ...).
std::pair<double, double> short_run(const std::string& readout, const std::string& reference) {
  Config cfg;
  cfg.nn.model = "gnn";
  cfg.nn.readout = readout;
  cfg.nn.hidden = 64;
  cfg.nn.layers = 2;
  cfg.nn.epochs = 6;
  cfg.nn.train_samples = 800;
  cfg.nn.val_samples = 200;
  cfg.nn.test_samples = 200;
  cfg.nn.batch_samples = 16;
  TrainOptions opt;
  opt.out_dir = fresh_dir("learn_" + readout);
  const TrainResult r = train_beamformer(cfg, opt);
  const std::string report = read_file(opt.out_dir + "/test.json");
  const std::string key = "\"" + reference + "\": ";
  const auto at = report.find(key);
  EXPECT_NE(at, std::string::npos) << key;
  return {r.test_sum_rate, at == std::string::npos ? 0.0 : std::stod(report.substr(at + key.size()))};
}
}  // namespace

// A short, seeded GNN training run (bounded steps) learns: the test sum rate ends well above MRT's
// on the same snapshots.
TEST(Learned, ShortTrainingBeatsMrtClearly) {
  const auto [rate, mrt] = short_run("direct", "mrt");
  EXPECT_GT(rate, 2.0 * mrt) << "test " << rate << " vs MRT " << mrt;
}

// The structured readout learns much faster than the paper's direct one: the same short run ends
// above ZF (which the direct readout does not reach in so few steps).
TEST(Learned, StructuredReadoutShortTrainingBeatsZf) {
  const auto [rate, zf] = short_run("structured", "zf");
  EXPECT_GT(rate, zf) << "test " << rate << " vs ZF " << zf;
}
