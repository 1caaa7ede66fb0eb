#include <gtest/gtest.h>

#include <Eigen/QR>
#include <cmath>
#include <numeric>

#include "skyloop/beamforming/linear.hpp"
#include "skyloop/channel/rates.hpp"
#include "skyloop/core/rng.hpp"
#include "test_util.hpp"

using namespace skyloop;

TEST(Zf, NullsInterUserInterferenceWhenKnAtMostL) {
  const Config cfg;
  for (int k = 1; k <= 4; ++k)
    for (const auto& c : test::clusters_of_size(cfg, k, 30, 10 + k)) {
      for (bool wf : {true, false}) {
        const MatrixXcd W = zf(c, wf);
        const MatrixXcd M = c.G * W;  // M(k, j) = h_k^H w_j
        const double scale = M.cwiseAbs().maxCoeff();
        for (int i = 0; i < k; ++i)
          for (int j = 0; j < k; ++j)
            if (i != j) {
              EXPECT_LT(std::abs(M(i, j)), 1e-6 * scale) << "K_n=" << k;
            }
      }
    }
}

TEST(Zf, WaterfillingIsAtLeastEqualPower) {
  const Config cfg;
  for (const auto& c : test::clusters_of_size(cfg, 3, 50, 3))
    EXPECT_GE(sum_rate(c, zf(c, true)), sum_rate(c, zf(c, false)) - 1e-9);
}

TEST(Zf, MoreUsersThanAntennasStillMeetsBudget) {
  const Config cfg;
  for (const auto& c : test::clusters_of_size(cfg, 7, 20, 4)) {
    const MatrixXcd W = zf(c);
    EXPECT_NEAR(W.squaredNorm(), c.p_max, 1e-9 * c.p_max);
    EXPECT_TRUE(W.allFinite());
    EXPECT_GT(sum_rate(c, W), 0.0);
  }
}

TEST(Waterfill, MeetsBudgetAndKkt) {
  VectorXd floor(4);
  floor << 0.1, 0.5, 2.0, 10.0;
  const VectorXd p = waterfill(floor, 1.0);
  EXPECT_NEAR(p.sum(), 1.0, 1e-12);
  // Active channels share one water level; inactive ones have floor above it.
  const double level = p[0] + floor[0];
  for (int k = 0; k < 4; ++k) {
    if (p[k] > 0) EXPECT_NEAR(p[k] + floor[k], level, 1e-12);
    else EXPECT_GE(floor[k], level - 1e-12);
  }
  EXPECT_EQ(p[3], 0.0);
}

TEST(Mrt, SingleUserIsOptimal) {
  const Config cfg;
  for (const auto& c : test::clusters_of_size(cfg, 1, 10, 5)) {
    const double snr = c.p_max * c.G.row(0).squaredNorm() / c.noise;
    EXPECT_NEAR(sum_rate(c, mrt(c)), std::log2(1 + snr), 1e-9);
    EXPECT_NEAR(sum_rate(c, zf(c)), std::log2(1 + snr), 1e-9);
    EXPECT_NEAR(sum_rate(c, rzf(c)), std::log2(1 + snr), 1e-6);
  }
}

TEST(ZfSelect, SelectsAtMostLUsersAndBeatsPlainZfOnAverage) {
  const Config cfg;
  double sel = 0, plain = 0;
  for (const auto& c : test::clusters_of_size(cfg, 6, 40, 6)) {
    std::vector<int> chosen;
    const MatrixXcd W = zf_select(c, &chosen);
    EXPECT_GE(chosen.size(), 1u);
    EXPECT_LE(chosen.size(), 4u);
    for (int k = 0; k < 6; ++k)
      if (std::find(chosen.begin(), chosen.end(), k) == chosen.end()) {
        EXPECT_EQ(W.col(k).norm(), 0.0);
      }
    EXPECT_NEAR(W.squaredNorm(), c.p_max, 1e-9);
    sel += sum_rate(c, W);
    plain += sum_rate(c, zf(c));
  }
  EXPECT_GT(sel, plain);
}

namespace {
// The reference for the selections' incremental set rates: each candidate set's Gram matrix
// G_S G_S^H factorised afresh (LLT) and inverted, ||v_k||^2 its inverse's diagonal.
double fresh_set_rate(const Cluster& c, const std::vector<int>& set) {
  const auto n = static_cast<Eigen::Index>(set.size());
  MatrixXcd rows(n, c.G.cols());
  for (Eigen::Index i = 0; i < n; ++i) rows.row(i) = c.G.row(set[static_cast<std::size_t>(i)]);
  const Eigen::LLT<MatrixXcd> llt(rows * rows.adjoint());
  if (llt.info() != Eigen::Success) return -1.0;
  const MatrixXcd inv = llt.solve(MatrixXcd::Identity(n, n));
  VectorXd floor(n);
  for (Eigen::Index i = 0; i < n; ++i) {
    floor[i] = c.noise * inv(i, i).real();
    if (!(floor[i] > 0) || !std::isfinite(floor[i])) return -1.0;
  }
  const VectorXd p = waterfill(floor, c.p_max);
  double rate = 0.0;
  for (Eigen::Index i = 0; i < n; ++i) rate += std::log2(1.0 + p[i] / floor[i]);
  return rate;
}

// Dimic & Sidiropoulos' greedy search over fresh_set_rate, with the set rates it saw.
std::vector<int> fresh_greedy(const Cluster& c, std::vector<double>* rates) {
  const auto K = c.G.rows();
  std::vector<int> set;
  double best = 0.0;
  while (static_cast<Eigen::Index>(set.size()) < std::min(K, c.G.cols())) {
    int pick = -1;
    double pick_rate = best, runner_up = -1.0;
    for (int k = 0; k < static_cast<int>(K); ++k) {
      if (std::find(set.begin(), set.end(), k) != set.end()) continue;
      std::vector<int> trial = set;
      trial.push_back(k);
      const double r = fresh_set_rate(c, trial);
      if (r > pick_rate) runner_up = pick_rate, pick_rate = r, pick = k;
      else runner_up = std::max(runner_up, r);
    }
    if (pick < 0) break;
    set.push_back(pick);
    rates->push_back(pick_rate);
    rates->push_back(runner_up);
    best = pick_rate;
  }
  std::sort(set.begin(), set.end());
  return set;
}
}  // namespace

// ZF-SEL grows each candidate set's Cholesky factor and inverse by one row instead of factorising
// and inverting every candidate's Gram matrix afresh: the same set rates to rounding, so the same
// users wherever the search's choices are not ties within rounding. Paper clusters (LoS channels
// of users close in angle: Gram matrices with condition numbers of 1e4 and more), L = 4 and 8,
// K from 1 to 30 (K < L and K > L), and users whose channels repeat (no ZF of both).
TEST(ZfSelect, GrowingTheSetsFactorSelectsWhatAFreshFactorisationSelects) {
  for (const int antennas : {4, 8}) {
    Config cfg;
    cfg.channel.antennas = antennas;
    int compared = 0, checked = 0;
    for (const int k : {1, 2, 3, 5, 8, 12, 20, 30})
      for (Cluster c : test::clusters_of_size(cfg, k, 40, 900 + static_cast<std::uint64_t>(k))) {
        if (k >= 3 && compared % 4 == 0) c.G.row(2) = c.G.row(0);  // a repeated channel
        ++compared;
        std::vector<double> rates;
        const std::vector<int> want = fresh_greedy(c, &rates);
        // A pick is only determined where the best and the runner-up differ beyond rounding: a set
        // rate through the Gram matrix carries about eps cond(G_S)^2 of relative error, 1e-8 at the
        // condition numbers of 1e4 these clusters reach.
        bool decided = true;
        for (std::size_t i = 0; i + 1 < rates.size(); i += 2)
          decided = decided && rates[i] - rates[i + 1] > 1e-6 * rates[i];
        if (!decided) continue;
        ++checked;
        std::vector<int> got;
        const MatrixXcd W = zf_select(c, &got);
        EXPECT_EQ(got, want) << "K = " << k << ", L = " << antennas;
        EXPECT_NEAR(sum_rate(c, W), rates[rates.size() - 2], 1e-6 * rates[rates.size() - 2]) << "K = " << k;
      }
    EXPECT_EQ(compared, 8 * 40);
    // Near-ties are few: the repeated channels' twins, when one of them is the best pick (about
    // 290 of the 320 searches are decided at either L).
    EXPECT_GE(checked, compared * 3 / 4) << "L = " << antennas;
  }
}

namespace {
/// A cluster with the given channel rows (h_k^H), noise 1 W and budget p W.
Cluster hand_cluster(const std::vector<std::vector<cdouble>>& rows, double p) {
  Cluster c;
  c.p_max = p;
  c.noise = 1.0;
  c.G.resize(static_cast<Eigen::Index>(rows.size()), static_cast<Eigen::Index>(rows.front().size()));
  for (std::size_t i = 0; i < rows.size(); ++i)
    for (std::size_t l = 0; l < rows[i].size(); ++l) c.G(static_cast<Eigen::Index>(i), static_cast<Eigen::Index>(l)) = rows[i][l];
  return c;
}
}  // namespace

// Worked by hand (L = 2, noise 1 W, P = 2 W). Users 0 and 1 are orthogonal with gains 1 and 0.5;
// user 2 is parallel to user 0. Ranking (0, 2, 1): user 0 joins (log2(1 + 2) = 1.585); {0, 2} cannot
// be zero-forced (parallel rows) so user 2 is passed over; {0, 1} has floors 1 and 2, water level
// mu = 2.5, powers 1.5 and 0.5, sum rate log2(2.5) + log2(1.25) = 1.6439 > 1.585, so user 1 joins.
// With user 1's gain 0.01 its floor (100) lies above the water and the sum rate does not rise:
// user 0 is served alone.
TEST(ZfRanked, HandComputedOrthogonalCluster) {
  const double g1 = std::sqrt(0.5);
  const Cluster c = hand_cluster({{1.0, 0.0}, {0.0, g1}, {3.0, 0.0}}, 2.0);
  std::vector<int> chosen;
  const MatrixXcd W = zf_ranked(c, {0, 2, 1}, &chosen);
  EXPECT_EQ(chosen, (std::vector<int>{0, 1}));
  EXPECT_NEAR(sum_rate(c, W), std::log2(2.5) + std::log2(1.25), 1e-12);
  EXPECT_NEAR(W.col(0).squaredNorm(), 1.5, 1e-12);
  EXPECT_NEAR(W.col(1).squaredNorm(), 0.5, 1e-12);
  EXPECT_EQ(W.col(2).norm(), 0.0);
  // Ranked first, user 2 (gain 9) is served, and user 0 can never join it.
  zf_ranked(c, {2, 0, 1}, &chosen);
  EXPECT_EQ(chosen, (std::vector<int>{1, 2}));

  const Cluster weak = hand_cluster({{1.0, 0.0}, {0.0, 0.1}, {3.0, 0.0}}, 2.0);
  const MatrixXcd Ww = zf_ranked(weak, {0, 1, 2}, &chosen);
  EXPECT_EQ(chosen, (std::vector<int>{0}));
  EXPECT_NEAR(sum_rate(weak, Ww), std::log2(3.0), 1e-12);
}

// On random clusters of every size: at most L users, the others silent, the selected ones
// zero-forced on the full budget, the beams those of water-filled ZF over the selected users, and
// never below serving the first-ranked user alone. ZF-GAIN is zf_ranked in the order of the gains.
TEST(ZfRanked, InvariantsOnRandomClusters) {
  const Config cfg;
  const ZfGainBeamformer gain;
  for (int k = 1; k <= 9; ++k)
    for (const auto& c : test::clusters_of_size(cfg, k, 12, 70 + k)) {
      std::vector<int> ranking(static_cast<std::size_t>(k));  // last user first
      std::iota(ranking.begin(), ranking.end(), 0);
      std::reverse(ranking.begin(), ranking.end());
      std::vector<int> chosen;
      const MatrixXcd W = zf_ranked(c, ranking, &chosen);
      ASSERT_GE(chosen.size(), 1u);
      EXPECT_LE(chosen.size(), 4u);
      EXPECT_NEAR(W.squaredNorm(), c.p_max, 1e-9 * c.p_max);
      Cluster sub = c;
      sub.G.resize(static_cast<Eigen::Index>(chosen.size()), c.G.cols());
      for (std::size_t i = 0; i < chosen.size(); ++i) sub.G.row(static_cast<Eigen::Index>(i)) = c.G.row(chosen[i]);
      const MatrixXcd Z = zf(sub, true);
      for (int j = 0, i = 0; j < k; ++j) {
        const bool in = i < static_cast<int>(chosen.size()) && chosen[static_cast<std::size_t>(i)] == j;
        if (in) EXPECT_LE((W.col(j) - Z.col(i++)).norm(), 1e-9 * std::sqrt(c.p_max)) << "K=" << k;
        else EXPECT_EQ(W.col(j).norm(), 0.0);
      }
      const double alone = std::log2(1.0 + c.p_max * c.G.row(ranking[0]).squaredNorm() / c.noise);
      EXPECT_GE(sum_rate(c, W), alone - 1e-9) << "K=" << k;
      // ZF-GAIN: the same pass over the users sorted by gain.
      std::vector<int> by_gain(static_cast<std::size_t>(k));
      std::iota(by_gain.begin(), by_gain.end(), 0);
      std::stable_sort(by_gain.begin(), by_gain.end(),
                       [&](int a, int b) { return c.G.row(a).squaredNorm() > c.G.row(b).squaredNorm(); });
      EXPECT_EQ(gain.design(c), zf_ranked(c, by_gain));
    }
}

TEST(ZfRanked, RefusesARankingThatIsNotOfTheCluster) {
  const Cluster c = hand_cluster({{1.0, 0.0}, {0.0, 1.0}}, 1.0);
  EXPECT_THROW(zf_ranked(c, {0, 0, 1}), std::invalid_argument);
  EXPECT_THROW(zf_ranked(c, {2}), std::invalid_argument);
  EXPECT_THROW(zf_ranked(c, {-1}), std::invalid_argument);
}

// A cluster of thousands of users (one UAV over a city): ZF takes the pseudo-inverse through the
// L x K adjoint and the SINRs come from the received powers in row blocks, so neither builds a
// K x K matrix. What they compute is what the direct forms compute: G^+ to rounding (the same
// Moore-Penrose inverse by another decomposition), the SINRs to the bit (the same L-term products
// and sums).
TEST(Zf, ThousandsOfUsersNeedNoKByKMatrix) {
  Rng rng(5);
  for (const Eigen::Index K : {257, 1500}) {
    Cluster c;
    c.G = MatrixXcd(K, 4);
    for (Eigen::Index i = 0; i < K; ++i)
      for (Eigen::Index l = 0; l < 4; ++l) c.G(i, l) = {1e-5 * rng.normal(), 1e-5 * rng.normal()};
    c.noise = 1e-13;
    const MatrixXcd W = zf(c);
    Eigen::CompleteOrthogonalDecomposition<MatrixXcd> cod(c.G);
    MatrixXcd V = cod.pseudoInverse();  // the direct form: a K x K identity solved
    for (Eigen::Index k = 0; k < K; ++k) V.col(k) *= std::sqrt(c.p_max / K) / V.col(k).norm();  // equal power
    EXPECT_LT((W - V).norm(), 1e-9 * V.norm()) << "K = " << K;
    EXPECT_NEAR(W.squaredNorm(), c.p_max, 1e-9 * c.p_max);
    // Every SINR from the full K x K product, summed in the same order.
    const Eigen::MatrixXd P = (c.G * W).cwiseAbs2();
    const VectorXd got = sinr(c, W);
    for (Eigen::Index k = 0; k < K; ++k) {
      double interference = 0;
      for (Eigen::Index j = 0; j < K; ++j)
        if (j != k) interference += P(k, j);
      ASSERT_EQ(got[k], P(k, k) / (interference + c.noise)) << "K = " << K << ", user " << k;
    }
  }
}
