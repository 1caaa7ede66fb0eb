// Internals of src/nn: checkpoint round trip, segment operations, the batched rate.
#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <filesystem>
#include <limits>
#include <random>

#include "../../src/nn/batch.hpp"
#include "../../src/nn/checkpoint.hpp"
#include "../../src/nn/fast_gemm.hpp"
#include "../../src/nn/fast_model.hpp"
#include "skyloop/channel/rates.hpp"
#include "skyloop/core/rng.hpp"
#include "skyloop/nn/learned.hpp"
#include "skyloop/beamforming/linear.hpp"
#include "test_util.hpp"
#include "../scratch.hpp"

using namespace skyloop;
using namespace skyloop::nn;

namespace {
Graph graph_of(std::vector<int64_t> sizes) {
  Graph g;
  std::vector<int64_t> seg, pos;
  for (std::size_t c = 0; c < sizes.size(); ++c)
    for (int64_t k = 0; k < sizes[c]; ++k) seg.push_back(static_cast<int64_t>(c)), pos.push_back(k);
  g.seg = torch::tensor(seg);
  g.pos = torch::tensor(pos);
  g.count = torch::tensor(sizes).to(torch::kFloat32).unsqueeze(1);
  g.clusters = static_cast<int64_t>(sizes.size());
  g.kmax = *std::max_element(sizes.begin(), sizes.end());
  return g;
}
}  // namespace

TEST(NnInternal, CheckpointRoundTripsBitForBit) {
  for (const char* name : {"gnn", "deepsets", "mspointnet"}) {
    torch::manual_seed(3);
    auto model = make_model(name, 4, 16, 2);
    torch::optim::Adam adam(model->parameters(), torch::optim::AdamOptions(1e-3));
    ModelInfo info;
    info.model = name;
    info.antennas = 4;
    info.hidden = 16;
    info.layers = 2;
    info.feature_scale = 1234.5678;
    info.features = std::string(name) == "deepsets" ? Features::Log : Features::Linear;
    model->set_features(info.features);
    info.parameters = count_parameters(*model);
    info.config_toml = "[run]\nseed = 3\n";
    TrainingState state{7, 99, 5, 42.25};
    const std::string path = (test::scratch_dir(std::string("rt_") + name) / "model.pt").string();
    save_checkpoint(path, info, state, *model, &adam);
    const auto back = load_checkpoint(path, torch::kCPU);
    const auto a = model->named_parameters(), b = back.model->named_parameters();
    ASSERT_EQ(a.size(), b.size());
    for (const auto& p : a) EXPECT_TRUE(torch::equal(p.value(), b[p.key()])) << name << " " << p.key();
    EXPECT_EQ(back.info.feature_scale, 1234.5678);
    EXPECT_EQ(back.info.features, info.features) << name;
    EXPECT_EQ(back.model->features(), model->features()) << name;
    EXPECT_EQ(back.info.config_toml, info.config_toml);
    EXPECT_EQ(back.state.step, 99);
    EXPECT_EQ(back.state.best_val, 42.25);
    EXPECT_TRUE(back.has_optimizer);
  }
}

// nn.features = "log" at points computed by hand: x = (3, 4) has r = 5, so the encoders see
// x * ln(1 + 5000) / (5 ln(1001)) = x * 8.5173932 / (5 * 6.9087548) = x * 0.2465681; a row of
// zeros stays zero (no 0/0), and the direction is kept. "linear" is the identity.
TEST(NnInternal, LogFeaturesCompressTheNormAndKeepTheDirection) {
  const auto x = torch::tensor({3.0, 4.0, 0.0, 0.0, 3e-3, -4e-3}, torch::kFloat64).view({3, 2});
  const auto y = encode_features(x, Features::Log);
  const double s = std::log1p(5000.0) / (5.0 * std::log1p(1000.0));
  EXPECT_NEAR(s, 0.2465681, 1e-7);
  EXPECT_NEAR(y[0][0].item<double>(), 3 * s, 1e-12);
  EXPECT_NEAR(y[0][1].item<double>(), 4 * s, 1e-12);
  EXPECT_EQ(y[1][0].item<double>(), 0.0);
  EXPECT_EQ(y[1][1].item<double>(), 0.0);
  // r = 5e-3 = 5 eps: ln(6) / ln(1001) = 0.25938 of the unit norm, where the linear feature is 5e-3.
  EXPECT_NEAR(y[2].norm().item<double>(), std::log(6.0) / std::log1p(1000.0), 1e-12);
  EXPECT_NEAR((y[2] / y[2].norm() - x[2] / x[2].norm()).norm().item<double>(), 0.0, 1e-15);
  EXPECT_TRUE(torch::equal(encode_features(x, Features::Linear), x));
  EXPECT_THROW(parse_choice<Features>("nn.features", "sqrt"), InputError);
}

TEST(NnInternal, MaxOverOthersHandMade) {
  const Graph g = graph_of({3, 1, 2});
  const auto x = torch::tensor({5.0f, 1.0f, 3.0f, 7.0f, -2.0f, -4.0f}).unsqueeze(1);
  const auto m = max_over_others(x, g).squeeze(1);
  // cluster 0: {5,1,3} -> others' max {3,5,5}; cluster 1: single user -> 0; cluster 2: {-2,-4} -> {-4,-2}.
  const auto expect = torch::tensor({3.0f, 5.0f, 5.0f, 0.0f, -4.0f, -2.0f});
  EXPECT_TRUE(torch::allclose(m, expect)) << m;
  EXPECT_TRUE(torch::allclose(segment_mean(x, g).squeeze(1), torch::tensor({3.0f, 7.0f, -3.0f})));
  EXPECT_TRUE(torch::allclose(segment_max(x, g).squeeze(1), torch::tensor({5.0f, 7.0f, -2.0f})));
}

TEST(NnInternal, GraphNormNormalisesEachCluster) {
  const Graph g = graph_of({4, 2});
  GraphNorm gn(3);
  torch::manual_seed(1);
  const auto x = torch::randn({6, 3}) * 10 + 5;
  const auto y = gn(x, g);  // init: gamma 1, beta 0, alpha 1 -> zero mean, unit variance per cluster
  for (int c = 0; c < 2; ++c) {
    const auto rows = c == 0 ? y.narrow(0, 0, 4) : y.narrow(0, 4, 2);
    EXPECT_TRUE(torch::allclose(rows.mean(0), torch::zeros({3}), 1e-4, 1e-4));
    EXPECT_TRUE(torch::allclose(rows.pow(2).mean(0), torch::ones({3}), 1e-3, 1e-3));
  }
}

TEST(NnInternal, BatchedRateEqualsDoublePrecisionRate) {
  Config cfg;
  std::vector<Cluster> clusters;
  for (int k : {1, 3, 4, 6})
    for (const auto& c : test::clusters_of_size(cfg, k, 2, k)) clusters.push_back(c);
  const std::vector<int> owner(clusters.size(), 0);
  const ClusterSet set = make_cluster_set(clusters, owner, 1);
  const auto ids = torch::arange(static_cast<int64_t>(clusters.size()));
  const Batch b = make_batch(set, ids, 1.0, torch::kCPU);
  // Use RZF (full power) as W for every cluster, laid out as the network's [U, 2L] output.
  std::vector<float> rows;
  std::vector<double> expect;
  for (const auto& c : clusters) {
    const MatrixXcd W = rzf(c);
    for (int k = 0; k < c.size(); ++k) {
      for (int l = 0; l < 4; ++l) rows.push_back(static_cast<float>(W(l, k).real()));
      for (int l = 0; l < 4; ++l) rows.push_back(static_cast<float>(W(l, k).imag()));
    }
    expect.push_back(sum_rate(c, W));
  }
  const auto w = torch::tensor(rows).view({-1, 8});
  const auto got = cluster_sum_rates(scale_to_budget(w, b, PowerScaling::Full), b);
  for (std::size_t i = 0; i < clusters.size(); ++i)
    EXPECT_NEAR(got[static_cast<int64_t>(i)].item<double>(), expect[i], 2e-3 * expect[i] + 1e-3) << "cluster " << i;
}

// The ranked selection orders the users by served_rates: skyloop::rates to rounding, over
// clusters with fewer and more users than antennas (1, 3, 4, 6, 64), under MRT beams
// (interference-limited), ZF (interference nulled: noise-limited) and random beams, with every
// antenna count the vectorised kernel sees (a remainder of 0-3 beams past its packets).
TEST(NnInternal, RankingRatesEqualTheClusterRatesToRounding) {
  Rng rng(11);
  for (int antennas : {1, 4, 8}) {
    Config cfg;
    cfg.channel.antennas = antennas;
    for (int k : {1, 3, 4, 6, 64})
      for (const auto& c : test::clusters_of_size(cfg, k, 2, static_cast<std::uint64_t>(k + antennas))) {
        MatrixXcd random(antennas, k);
        for (Eigen::Index i = 0; i < random.size(); ++i) random(i) = {rng.normal(), rng.normal()};
        for (const MatrixXcd& W : {mrt(c), zf(c, true), MatrixXcd(scale_to_budget(random, c.p_max, PowerScaling::Full))}) {
          const VectorXd want = rates(c, W), got = fast::served_rates(c, W);
          ASSERT_EQ(got.size(), want.size());
          for (Eigen::Index i = 0; i < want.size(); ++i)
            EXPECT_NEAR(got[i], want[i], 1e-9 * (1.0 + want[i])) << "L = " << antennas << ", K = " << k << ", user " << i;
        }
      }
  }
  const auto c = test::clusters_of_size(Config{}, 3, 1, 5).front();
  EXPECT_THROW(fast::served_rates(c, MatrixXcd::Zero(4, 2)), std::invalid_argument);
  const Cluster empty{};
  EXPECT_EQ(fast::served_rates(empty, MatrixXcd(0, 0)).size(), 0);
}

// The structured readout spans the classical precoders: lambda -> 0 gives MRT directions,
// lambda -> infinity gives ZF directions (interference nulled).
TEST(NnInternal, StructuredReadoutLimitsAreMrtAndZf) {
  Config cfg;
  const auto clusters = test::clusters_of_size(cfg, 3, 4, 21);
  const std::vector<int> owner(clusters.size(), 0);
  const ClusterSet set = make_cluster_set(clusters, owner, 1);
  const double fs = 1.0 / channel_rms(set);
  const Batch b = make_batch(set, torch::arange(static_cast<int64_t>(clusters.size())), fs, torch::kCPU);
  for (double log_lambda : {-25.0, 25.0}) {
    auto head = torch::zeros({b.x.size(0), 2});
    head.select(1, 0).fill_(log_lambda);
    const auto w = structured_beams(head, b.x.to(torch::kFloat64), b.graph).to(torch::kFloat64);
    for (std::size_t c = 0; c < clusters.size(); ++c) {
      MatrixXcd W(4, 3);
      for (int k = 0; k < 3; ++k)
        for (int l = 0; l < 4; ++l)
          W(l, k) = cdouble(w[static_cast<int64_t>(3 * c + k)][l].item<double>(), w[static_cast<int64_t>(3 * c + k)][4 + l].item<double>());
      EXPECT_NEAR(W.squaredNorm(), 1.0, 1e-6);  // power shares come out of a float32 softmax
      const MatrixXcd ref = log_lambda < 0 ? mrt(clusters[c]) : zf(clusters[c], false);
      for (int k = 0; k < 3; ++k) {
        const double cosine = std::abs(W.col(k).dot(ref.col(k))) / (W.col(k).norm() * ref.col(k).norm());
        EXPECT_NEAR(cosine, 1.0, 1e-4) << (log_lambda < 0 ? "MRT" : "ZF") << " cluster " << c << " user " << k;
      }
    }
  }
}

// The float32 serving path (what the CLI, the environment and reproduce use) agrees with the
// float64 evaluation of the same weights to within float32 rounding, one cluster at a time and
// batched, for every model kind and cluster size.
//
// Where the bound comes from. A float32 forward pass returns, to first order, the exact output of
// the network with every weight and input perturbed by a relative amount of order u32 = 2^-24
// (backward error analysis: each dot product, norm and activation rounds once). So
// ||W32 - W64|| <= u32 * kappa * ||W||, where kappa is the relative condition number of the map
// (weights, input) -> W at this cluster. kappa is measured here in float64, as the largest relative
// change of W over 4 random relative perturbations of size delta = 1e-6 of every weight and every
// channel entry, divided by delta. It includes the internal ill-conditioning a perturbation of the
// input alone misses (GraphNorm over one or two users subtracts nearly equal numbers; the
// structured readout solves with cond(G) ~ 1e4). C = 2.5 sqrt(w) covers a dot product of width w
// (the model's widest) rounding up to sqrt(w) times u32 (random-walk growth) instead of once, and
// the second-order remainder. A wrong weight, a layer skipped or a batch layout mixing clusters gives O(1) errors.
namespace {
constexpr double kU32 = 5.960464477539063e-8, kDelta = 1e-6;

/// Four float64 copies of the checkpoint at `path` with every weight perturbed by a relative
/// U(-kDelta, kDelta), written under `scratch`.
std::vector<std::unique_ptr<LearnedBeamformer>> perturbed_copies(const std::string& path, const Config& cfg64,
                                                                 const std::string& scratch, Rng& rng) {
  std::vector<std::unique_ptr<LearnedBeamformer>> perturbed;
  for (int r = 0; r < 4; ++r) {
    auto ck = load_checkpoint(path, torch::kCPU);
    {
      torch::NoGradGuard no_grad;
      for (auto& p : ck.model->parameters()) {
        auto flat = p.view({-1});
        auto noise = torch::empty_like(flat);
        auto acc = noise.accessor<float, 1>();
        for (int64_t i = 0; i < flat.size(0); ++i) acc[i] = static_cast<float>(1 + kDelta * (2 * rng.uniform() - 1));
        flat.mul_(noise);
      }
    }
    const std::string p = scratch + "/perturbed" + std::to_string(r) + ".pt";
    save_checkpoint(p, ck.info, ck.state, *ck.model, nullptr);
    perturbed.push_back(LearnedBeamformer::load(p, cfg64));
  }
  return perturbed;
}

/// The three serving paths of the checkpoint at `path`: fused float32, LibTorch float32, float64.
struct Paths {
  std::unique_ptr<LearnedBeamformer> fast32, torch32, bf64;
  Paths(const std::string& path, const Config& cfg) {
    Config cfg64 = cfg, cfg_torch = cfg;
    cfg64.nn.precision = Precision::Float64;
    cfg_torch.nn.inference = Inference::Torch;
    fast32 = LearnedBeamformer::load(path, cfg);
    torch32 = LearnedBeamformer::load(path, cfg_torch);
    bf64 = LearnedBeamformer::load(path, cfg64);
  }
  /// The fused path serves fast32, LibTorch the other two.
  testing::AssertionResult served_as_named() const {
    if (fast32->fast() && !torch32->fast() && !bf64->fast()) return testing::AssertionSuccess();
    return testing::AssertionFailure() << "fast " << fast32->fast() << ", torch " << torch32->fast() << ", float64 " << bf64->fast();
  }
};

/// Holds both float32 serving paths (the fused kernels, nn.inference = "fast", and LibTorch) of
/// the checkpoint at `path` to its float64 evaluation on clusters of sizes `sizes`.
void expect_float32_paths_within_rounding(const std::string& label, const Config& cfg, const std::string& path,
                                          const std::string& scratch, const std::vector<int>& sizes) {
  const Paths m(path, cfg);
  ASSERT_TRUE(m.served_as_named()) << label;
  // The widest dot product: GNN 3d (user update), DeepSets 4d (head on [phi, pooled], width 2d
  // each), MS-PointNet also 1.5 d L (the projection of L antennas x 3c channels).
  const ModelInfo& info = m.fast32->info();
  const double d = info.hidden;
  const double width = info.model == "gnn" ? 3 * d : info.model == "deepsets" ? 4 * d : std::max(4 * d, 1.5 * d * info.antennas);
  const double C = 2.5 * std::sqrt(width);
  Rng rng(11);
  Config cfg64 = cfg;
  cfg64.nn.precision = Precision::Float64;
  const auto perturbed = perturbed_copies(path, cfg64, scratch, rng);

  std::vector<Cluster> mixed;
  for (int k : sizes)
    for (const auto& c : test::clusters_of_size(cfg, k, 3, 90 + static_cast<std::uint64_t>(k))) mixed.push_back(c);
  const auto fast_batched = m.fast32->design_batch(mixed), torch_batched = m.torch32->design_batch(mixed);
  for (std::size_t i = 0; i < mixed.size(); ++i) {
    const Cluster& c = mixed[i];
    const MatrixXcd W64 = m.bf64->design(c);
    double kappa = 0;
    for (const auto& bp : perturbed) {
      Cluster p = c;
      for (Eigen::Index a = 0; a < p.G.rows(); ++a)
        for (Eigen::Index b = 0; b < p.G.cols(); ++b) p.G(a, b) *= 1 + kDelta * (2 * rng.uniform() - 1);
      kappa = std::max(kappa, (bp->design(p) - W64).norm() / W64.norm() / kDelta);
    }
    const double tol = C * kU32 * std::max(kappa, 1.0) * W64.norm();
    const std::string where = label + " K_n=" + std::to_string(c.size()) + " kappa " + std::to_string(kappa);
    EXPECT_LT((m.fast32->design(c) - W64).norm(), tol) << "fast " << where;
    EXPECT_LT((fast_batched[i] - W64).norm(), tol) << "fast batched " << where;
    EXPECT_LT((m.torch32->design(c) - W64).norm(), tol) << "torch " << where;
    EXPECT_LT((torch_batched[i] - W64).norm(), tol) << "torch batched " << where;
  }
}

/// A copy of `net` with every channel entry perturbed by a relative U(-kDelta, kDelta) (the cross
/// channels, and each cluster's G, its own rows of them, kept equal).
Network perturbed_network(const Network& net, Rng& rng) {
  Network p = net;
  for (auto& X : p.cross)
    for (Eigen::Index a = 0; a < X.rows(); ++a)
      for (Eigen::Index b = 0; b < X.cols(); ++b) X(a, b) *= 1 + kDelta * (2 * rng.uniform() - 1);
  for (std::size_t c = 0; c < p.clusters.size(); ++c)
    p.clusters[c].G = p.cross[c].middleRows(p.offset[c], p.clusters[c].size());
  return p;
}

/// The same for a network-level model (ignn) on whole shared-spectrum networks of 1-4 UAVs over
/// `users` users (clusters of one user to all of them, one cluster alone): per network, per
/// cluster. Its widest dot product is the user update's 4d.
void expect_network_paths_within_rounding(const std::string& label, const Config& cfg, const std::string& path,
                                          const std::string& scratch, const std::vector<int>& users) {
  const Paths m(path, cfg);
  ASSERT_TRUE(m.served_as_named()) << label;
  const double C = 2.5 * std::sqrt(4.0 * m.fast32->info().hidden);
  Rng rng(12);
  Config cfg64 = cfg;
  cfg64.nn.precision = Precision::Float64;
  const auto perturbed = perturbed_copies(path, cfg64, scratch, rng);

  const SystemModel model(cfg);
  std::vector<Network> nets;
  for (int K : users)
    for (int N = 1; N <= 4; ++N) nets.push_back(model.network(model.random_snapshot(N, K, 500 + static_cast<std::uint64_t>(10 * K + N))));
  nets.push_back(Network::of(nets.back().clusters.front()));
  const auto fast_batched = m.fast32->design_networks(nets), torch_batched = m.torch32->design_networks(nets);
  for (std::size_t i = 0; i < nets.size(); ++i) {
    const auto W64 = m.bf64->design_network(nets[i]);
    std::vector<double> kappa(W64.size(), 0.0);
    for (const auto& bp : perturbed) {
      const auto Wp = bp->design_network(perturbed_network(nets[i], rng));
      for (std::size_t c = 0; c < W64.size(); ++c) kappa[c] = std::max(kappa[c], (Wp[c] - W64[c]).norm() / W64[c].norm() / kDelta);
    }
    const auto fast_one = m.fast32->design_network(nets[i]), torch_one = m.torch32->design_network(nets[i]);
    ASSERT_EQ(fast_one.size(), W64.size()) << label;
    for (std::size_t c = 0; c < W64.size(); ++c) {
      const double tol = C * kU32 * std::max(kappa[c], 1.0) * W64[c].norm();
      const std::string where = label + " network " + std::to_string(i) + " (" + std::to_string(nets[i].clusters.size()) +
                                " clusters) cluster " + std::to_string(c) + " K_n=" + std::to_string(nets[i].clusters[c].size()) +
                                " kappa " + std::to_string(kappa[c]);
      EXPECT_LT((fast_one[c] - W64[c]).norm(), tol) << "fast " << where;
      EXPECT_LT((fast_batched[i][c] - W64[c]).norm(), tol) << "fast batched " << where;
      EXPECT_LT((torch_one[c] - W64[c]).norm(), tol) << "torch " << where;
      EXPECT_LT((torch_batched[i][c] - W64[c]).norm(), tol) << "torch batched " << where;
    }
  }
}
}  // namespace

// The float32 serving paths (fused kernels and LibTorch) against the float64 evaluation of the
// same weights, on tiny trained models of every kind (d = 16: widths that do not fill a kernel
// block) and clusters of every size up to 12.
TEST(NnInternal, Float32ServingIsWithinRoundingOfFloat64) {
  for (const std::string m : {"gnn", "deepsets", "mspointnet", "gnn+structured", "mspointnet+structured", "gnn+structured+log",
                              "deepsets+log"}) {
    const Config cfg = test::tiny_nn_config(m);
    TrainOptions opt;
    opt.out_dir = test::scratch_path("f32_" + m).string();
    train_beamformer(cfg, opt);
    expect_float32_paths_within_rounding(m, cfg, opt.out_dir + "/model.pt", opt.out_dir,
                                         {1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12});
  }
}

// The same for the shipped models (d = 128, the paper's GNN and its baselines), which the
// environment's oracle, `beamform eval` and the latency figure serve through the fused path.
TEST(NnInternal, ShippedModelsFastPathIsWithinRoundingOfFloat64) {
  for (const std::string m : {"gnn", "gnn_structured", "deepsets", "mspointnet"}) {
    const std::string path = std::string(SKYLOOP_SOURCE_DIR) + "/models/" + m + "/model.pt";
    const std::string scratch = test::scratch_dir("shipped_" + m).string();
    expect_float32_paths_within_rounding(m, Config{}, path, scratch, {1, 3, 6, 12});
    std::filesystem::remove_all(scratch);
  }
}

// The interference-aware GNN's fused path (whole networks: users, clusters and interference edges
// as lists of rows) against its float64 evaluation, as above, for tiny trained models of every
// readout and feature kind, then the shipped ones (d = 64) that the shared-spectrum oracle and the
// DP's joint states are served by.
TEST(NnInternal, NetworkModelFloat32ServingIsWithinRoundingOfFloat64) {
  for (const std::string m : {"ignn", "ignn+structured", "ignn+structured+log"}) {
    const Config cfg = test::tiny_nn_config(m);
    TrainOptions opt;
    opt.out_dir = test::scratch_path("f32_" + m).string();
    train_beamformer(cfg, opt);
    expect_network_paths_within_rounding(m, cfg, opt.out_dir + "/model.pt", opt.out_dir, {1, 2, 5, 12});
  }
  for (const std::string m : {"ignn", "ignn_structured"}) {
    Config cfg;
    cfg.channel.spectrum = Spectrum::Shared;
    const std::string path = std::string(SKYLOOP_SOURCE_DIR) + "/models/" + m + "/model.pt";
    const std::string scratch = test::scratch_dir("shipped_" + m).string();
    expect_network_paths_within_rounding(m, cfg, path, scratch, {3, 12});
    std::filesystem::remove_all(scratch);
  }
}

// A batch of networks larger than one pass (2,048 rows of users and interference edges) is served
// in pieces, on one thread or two: every network gets the same floats it gets alone.
TEST(NnInternal, NetworkBatchesBeyondOnePassEqualOneByOne) {
  const Config cfg = test::tiny_nn_config("ignn+structured");
  TrainOptions opt;
  opt.out_dir = test::scratch_path("pieces_ignn").string();
  train_beamformer(cfg, opt);
  const auto bf = LearnedBeamformer::load(opt.out_dir + "/model.pt", cfg);
  ASSERT_TRUE(bf->fast());
  const SystemModel model(cfg);
  std::vector<Network> nets;
  for (std::uint64_t seed = 0; seed < 600; ++seed) nets.push_back(model.network(model.random_snapshot(3, 12, 900 + seed)));  // ~21,600 rows, 11 passes
  for (int threads : {1, 2}) {
    const auto W = bf->design_networks(nets, threads);
    ASSERT_EQ(W.size(), nets.size());
    for (std::size_t i = 0; i < nets.size(); i += 37) ASSERT_EQ(W[i], bf->design_network(nets[i])) << "network " << i << ", threads " << threads;
    ASSERT_EQ(W.back(), bf->design_network(nets.back()));
  }
}

// The interference-aware GNN's user and edge rows come from a cache keyed by their features
// (fast_model.cpp, RowCache): networks whose UAVs move among a few positions over fixed users
// (the exact optimum's joint states) repeat their rows. A network's beams must not depend on what
// the cache held before: cold, warm, in any batch, after the cache filled and started again.
TEST(NnInternal, NetworkRowsFromTheCacheEqualRowsComputedAfresh) {
  const Config cfg = test::tiny_nn_config("ignn+structured");
  TrainOptions opt;
  opt.out_dir = test::scratch_path("rowcache_ignn").string();
  train_beamformer(cfg, opt);
  const SystemModel model(cfg);
  const Snapshot base = model.random_snapshot(3, 12, 4242);
  std::vector<Network> nets;  // 3 UAVs over 4 positions each: 64 joint states, 12 rows of users' and edges' features each
  for (int a = 0; a < 4; ++a)
    for (int b = 0; b < 4; ++b)
      for (int c = 0; c < 4; ++c) {
        Snapshot s = base;
        const int at[3] = {a, b, c};
        for (int n = 0; n < 3; ++n) s.uavs(n, 0) = 20.0 + 40.0 * at[n], s.uavs(n, 1) = 30.0 + 50.0 * n;
        nets.push_back(model.network(s));
      }
  // Each model instance its own cache: `cold` sees every network first in one batch; `warm` one by
  // one in reverse order after the others filled its cache; `churned` after 2,000 random networks
  // (72,000 rows: the caches, 4,096 rows each, fill and start again many times, inside a pass too).
  const auto cold = LearnedBeamformer::load(opt.out_dir + "/model.pt", cfg);
  const auto warm = LearnedBeamformer::load(opt.out_dir + "/model.pt", cfg);
  const auto churned = LearnedBeamformer::load(opt.out_dir + "/model.pt", cfg);
  ASSERT_TRUE(cold->fast() && warm->fast() && churned->fast());
  const auto batch = cold->design_networks(nets, 1);
  (void)warm->design_networks(nets, 1);
  std::vector<Network> noise;
  for (std::uint64_t seed = 0; seed < 2000; ++seed) noise.push_back(model.network(model.random_snapshot(3, 12, 7000 + seed)));
  for (std::size_t i = 0; i < noise.size(); i += 50)
    (void)churned->design_networks(std::vector<Network>(noise.begin() + static_cast<long>(i), noise.begin() + static_cast<long>(i) + 50), 1);
  for (std::size_t i = nets.size(); i-- > 0;) {
    ASSERT_EQ(warm->design_network(nets[i]), batch[i]) << "network " << i << " from a warm cache";
    ASSERT_EQ(churned->design_network(nets[i]), batch[i]) << "network " << i << " after the cache started again";
  }
}

// The fast path's vectorised tanh (the learners' fused MLPs) against the float64 tanh, on every
// kernel variant (ATEN_CPU_CAPABILITY picks it). The rational fit's own error is 9.4e-9 relative
// (fast_gemm_kernel.inl); its float32 evaluation, emulated over these points, stays within 1.5
// ulps relative below |x| = 0.4 and 2.5 ulps absolute above, with or without FMA: 3 ulps here.
// Signs, zeros, saturation and infinities hold exactly; a NaN stays a NaN.
TEST(NnInternal, FastTanhIsWithinFloat32RoundingOfTanh) {
  std::vector<float> x;
  for (double v = -20; v <= 20; v += 1.0 / 1024) x.push_back(static_cast<float>(v));
  for (float v : {0.0f, -0.0f, 1e-30f, -1e-30f, 1e-6f, 0.39999998f, 0.4f, 0.40000001f, 100.0f, -100.0f})
    x.push_back(v);
  x.push_back(std::numeric_limits<float>::infinity());
  x.push_back(-std::numeric_limits<float>::infinity());
  std::vector<float> y = x;
  skyloop::nn::fast::tanh_inplace(y.data(), static_cast<long>(y.size()));  // a tail shorter than a vector too
  const double ulp1 = std::ldexp(1.0, -23);
  for (std::size_t i = 0; i < x.size(); ++i) {
    const double ref = std::tanh(static_cast<double>(x[i]));
    const double err = std::abs(static_cast<double>(y[i]) - ref);
    if (std::abs(x[i]) < 0.4f) EXPECT_LE(err, 3 * ulp1 * std::abs(ref)) << "x = " << x[i];
    else EXPECT_LE(err, 3 * ulp1) << "x = " << x[i];
    EXPECT_EQ(std::signbit(y[i]), std::signbit(x[i])) << "x = " << x[i];
  }
  EXPECT_EQ(y[y.size() - 2], 1.0f);
  EXPECT_EQ(y.back(), -1.0f);
  std::vector<float> nan(9, std::numeric_limits<float>::quiet_NaN());  // a whole vector and a tail
  skyloop::nn::fast::tanh_inplace(nan.data(), static_cast<long>(nan.size()));
  for (float v : nan) EXPECT_TRUE(std::isnan(v));
}

// Every element the GEMM kernels write is its sum over the inner dimension in order, from the bias
// (or zero, or what C held), one multiply-add at a time: fused (one rounding) on the AVX2 and
// AVX-512 variants, a product then a sum on the default one. The learners' pieces, chunks and
// lanes rely on it (a row's floats do not depend on the rows beside it, nor a weight gradient's on
// where the batch is cut). Checked against a scalar loop bit for bit: row counts on and off the
// kernel's 6-row blocks and the 12-row blocks of one-vector outputs (the actor's 5 logits, the
// critic's value), inner widths off the vector width, A^T B (the weight gradients) as well.
TEST(NnInternal, KernelsSumEachElementInOrder) {
  namespace fast = skyloop::nn::fast;
  const bool fused = fast::kernel_isa() != "default";
  auto madd = [&](float a, float b, float s) { return fused ? std::fmaf(a, b, s) : s + a * b; };
  std::mt19937 g(19);
  std::uniform_real_distribution<float> u(-1.0f, 1.0f);
  for (const int rows : {1, 5, 12, 13, 25, 192})
    for (const int inner : {1, 11, 64})
      for (const int cols : {1, 5, 8, 16, 64}) {
        const int pad = fast::pad_cols(cols), ldc = pad + 16;
        std::vector<float> A(static_cast<std::size_t>(rows) * inner), B(static_cast<std::size_t>(inner) * pad, 0.0f), bias(pad, 0.0f);
        for (auto& x : A) x = u(g);
        for (int k = 0; k < inner; ++k)
          for (int c = 0; c < cols; ++c) B[static_cast<std::size_t>(k) * pad + c] = u(g);
        for (int c = 0; c < cols; ++c) bias[static_cast<std::size_t>(c)] = u(g);
        std::vector<float> C(static_cast<std::size_t>(rows) * ldc, 0.0f);
        fast::matmul(A.data(), inner, rows, B.data(), inner, pad, bias.data(), C.data(), ldc, false, cols);
        for (int r = 0; r < rows; ++r)
          for (int c = 0; c < cols; ++c) {
            float want = bias[static_cast<std::size_t>(c)];
            for (int k = 0; k < inner; ++k)
              want = madd(A[static_cast<std::size_t>(r) * inner + k], B[static_cast<std::size_t>(k) * pad + c], want);
            const float got = C[static_cast<std::size_t>(r) * ldc + c];
            ASSERT_EQ(std::memcmp(&got, &want, sizeof(float)), 0) << "A B: rows " << rows << " inner " << inner << " cols " << cols << " at " << r << ", " << c;
          }
        // A^T B: A [rows x inner] read as the batch (rows) of an input of width inner; C [inner x pad] accumulated.
        std::vector<float> D(static_cast<std::size_t>(rows) * pad, 0.0f), W(static_cast<std::size_t>(inner) * ldc);
        for (int k = 0; k < rows; ++k)
          for (int c = 0; c < cols; ++c) D[static_cast<std::size_t>(k) * pad + c] = u(g);
        for (auto& x : W) x = u(g);
        const std::vector<float> start = W;
        fast::matmul_at(A.data(), inner, inner, D.data(), rows, pad, W.data(), ldc, cols);
        for (int i = 0; i < inner; ++i)
          for (int c = 0; c < cols; ++c) {
            float want = start[static_cast<std::size_t>(i) * ldc + c];
            for (int k = 0; k < rows; ++k)
              want = madd(A[static_cast<std::size_t>(k) * inner + i], D[static_cast<std::size_t>(k) * pad + c], want);
            const float got = W[static_cast<std::size_t>(i) * ldc + c];
            ASSERT_EQ(std::memcmp(&got, &want, sizeof(float)), 0) << "A^T B: batch " << rows << " width " << inner << " cols " << cols << " at " << i << ", " << c;
          }
      }
}

// The weight gradient of a layer of one output (the critic's value) by its own kernel
// (matmul_at_column) is matmul_at's column 0 bit for bit, on every kernel variant: batches off the
// kernel's blocks and past its 128-row chunks, column counts off the vector width (the tail
// lanes), strides wider than the columns; the other columns of C are left alone.
TEST(NnInternal, OneColumnWeightGradientEqualsTheBlockKernels) {
  std::mt19937 g(13);
  std::uniform_real_distribution<float> u(-1.0f, 1.0f);
  for (const int batch : {1, 7, 192, 300})
    for (const int cols : {3, 37, 64})
      for (const int lda : {64, 80}) {
        const int ldb = 16, ldc = 16;
        std::vector<float> A(static_cast<std::size_t>(batch) * lda), B(static_cast<std::size_t>(batch) * ldb, 0.0f);
        for (auto& x : A) x = u(g);
        for (int k = 0; k < batch; ++k) B[static_cast<std::size_t>(k) * ldb] = u(g);  // column 0; the padding zero
        std::vector<float> start(static_cast<std::size_t>(cols) * ldc);
        for (auto& x : start) x = u(g);
        std::vector<float> block = start, column = start;
        skyloop::nn::fast::matmul_at(A.data(), lda, cols, B.data(), batch, ldb, block.data(), ldc, 1);
        skyloop::nn::fast::matmul_at_column(A.data(), lda, cols, B.data(), ldb, batch, column.data(), ldc);
        for (int j = 0; j < cols; ++j) {
          const std::size_t i = static_cast<std::size_t>(j) * ldc;
          ASSERT_NE(column[i], start[i]) << "column 0 was not written at " << j;
          ASSERT_EQ(std::memcmp(&block[i], &column[i], sizeof(float)), 0) << "batch " << batch << " cols " << cols << " at " << j;
          for (int c = 1; c < ldc; ++c) ASSERT_EQ(column[i + static_cast<std::size_t>(c)], start[i + static_cast<std::size_t>(c)]);
        }
      }
}

// The learners' backward pass through a tanh layer in one pass (matmul_tanh_backward) gives the
// floats of the two passes it replaces (matmul, then tanh_backward) bit for bit, on every kernel
// variant: row counts off the 6-row block, an inner width of 5 (the actor's logits) and 64, and a
// stride wider than the columns.
TEST(NnInternal, FusedTanhBackwardEqualsItsTwoPasses) {
  std::mt19937 g(11);
  std::uniform_real_distribution<float> u(-1.0f, 1.0f);
  for (const int rows : {1, 7, 13, 192})
    for (const int inner : {5, 64})
      for (const int ldc : {64, 80}) {
        const int cols = 64;
        std::vector<float> A(static_cast<std::size_t>(rows) * inner), B(static_cast<std::size_t>(inner) * cols);
        std::vector<float> h(static_cast<std::size_t>(rows) * ldc);
        for (auto* v : {&A, &B, &h})
          for (auto& x : *v) x = u(g);
        std::vector<float> two(h.size(), 7.0f), one(h.size(), 7.0f);
        skyloop::nn::fast::matmul(A.data(), inner, rows, B.data(), inner, cols, nullptr, two.data(), ldc, false);
        for (int r = 0; r < rows; ++r)
          skyloop::nn::fast::tanh_backward(h.data() + static_cast<std::size_t>(r) * ldc, two.data() + static_cast<std::size_t>(r) * ldc, cols);
        skyloop::nn::fast::matmul_tanh_backward(A.data(), inner, rows, B.data(), inner, cols, h.data(), one.data(), ldc);
        for (int r = 0; r < rows; ++r)
          for (int c = 0; c < ldc; ++c) {
            const std::size_t i = static_cast<std::size_t>(r) * ldc + static_cast<std::size_t>(c);
            ASSERT_EQ(std::memcmp(&one[i], &two[i], sizeof(float)), 0) << "rows " << rows << " inner " << inner << " at " << r << ", " << c;
          }
      }
}

// A Dense layer (fast::pack: W^T in column panels of 16, the beamformers' layout) gives the
// floats of the same W^T row-major through matmul bit for bit, on every kernel variant: row
// counts off the 6-row block, input widths off and on the kernel's vectors, output widths below,
// at and past one panel and past the 2-vector blocks (the tail of V columns), with and without a
// bias, overwriting and accumulating, and a row stride of C wider than the padded columns.
TEST(NnInternal, DensePanelsEqualTheRowMajorKernel) {
  std::mt19937 g(17);
  std::uniform_real_distribution<float> u(-1.0f, 1.0f);
  namespace fast = skyloop::nn::fast;
  for (const int rows : {1, 5, 6, 13, 40, 73})
    for (const int in : {1, 8, 130})
      for (const int out : {1, 5, 16, 17, 33, 48, 128, 130}) {
        const int out_pad = fast::pad_cols(out), ldc = out_pad + 16;
        std::vector<float> w(static_cast<std::size_t>(out) * in), bias(static_cast<std::size_t>(out));
        for (auto& x : w) x = u(g);
        for (auto& x : bias) x = u(g);
        std::vector<float> wt(static_cast<std::size_t>(in) * out_pad, 0.0f), bias_pad(static_cast<std::size_t>(out_pad), 0.0f);
        for (int o = 0; o < out; ++o) {
          for (int i = 0; i < in; ++i) wt[static_cast<std::size_t>(i) * out_pad + o] = w[static_cast<std::size_t>(o) * in + i];
          bias_pad[static_cast<std::size_t>(o)] = bias[static_cast<std::size_t>(o)];
        }
        std::vector<float> A(static_cast<std::size_t>(rows) * in);
        for (auto& x : A) x = u(g);
        for (const bool with_bias : {false, true}) {
          const fast::Dense d = fast::pack(w.data(), out, in, 0, in, with_bias ? bias.data() : nullptr);
          std::vector<float> panels(static_cast<std::size_t>(rows) * ldc, 0.5f), rowmajor = panels;
          for (const bool accumulate : {false, true}) {
            fast::gemm(A.data(), in, rows, d, panels.data(), ldc, accumulate);
            fast::matmul(A.data(), in, rows, wt.data(), in, out_pad, with_bias ? bias_pad.data() : nullptr, rowmajor.data(), ldc,
                         accumulate);
            ASSERT_EQ(std::memcmp(panels.data(), rowmajor.data(), sizeof(float) * panels.size()), 0)
                << "rows " << rows << " in " << in << " out " << out << " bias " << with_bias << " accumulate " << accumulate;
            if (accumulate) continue;
            // And both are the layer: the last row's last output against a sum in double
            // (|terms| <= 1, so float32 rounding over `in` terms stays below in * 1e-6).
            double ref = with_bias ? bias[static_cast<std::size_t>(out - 1)] : 0.0;
            for (int i = 0; i < in; ++i)
              ref += static_cast<double>(A[static_cast<std::size_t>(rows - 1) * in + i]) * w[static_cast<std::size_t>(out - 1) * in + i];
            EXPECT_NEAR(panels[static_cast<std::size_t>(rows - 1) * ldc + out - 1], ref, 1e-6 * (in + 1));
          }
        }
      }
}
