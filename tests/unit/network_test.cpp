// The spectrum models (channel/network.hpp), the coordinated beamformers and the environment
// oracle's joint key under the shared spectrum.
#include <gtest/gtest.h>

#include <cmath>

#include "skyloop/beamforming/coordinated.hpp"
#include "skyloop/beamforming/linear.hpp"
#include "skyloop/beamforming/registry.hpp"
#include "skyloop/beamforming/wmmse.hpp"
#include "skyloop/channel/network.hpp"
#include "skyloop/channel/rates.hpp"
#include "skyloop/core/config_io.hpp"
#include "skyloop/core/error.hpp"
#include "skyloop/core/rng.hpp"
#include "skyloop/env/rate_oracle.hpp"

namespace skyloop {
namespace {

Config shared_config() {
  Config cfg;
  cfg.channel.spectrum = Spectrum::Shared;
  return cfg;
}

Positions rows(std::initializer_list<std::array<double, 2>> xy) {
  Positions p(static_cast<Eigen::Index>(xy.size()), 2);
  Eigen::Index i = 0;
  for (const auto& v : xy) p(i, 0) = v[0], p(i, 1) = v[1], ++i;
  return p;
}

// Two UAVs, one antenna, one user straight below each: every quantity by hand.
//   UAV 0 at (50, 100), user 0 at (50, 100): d = H = 100 m            -> beta = 1e-2 * 1e-4 = 1e-6
//   UAV 1 at (150, 100), user 1 at (150, 100): d = 100 m               -> beta = 1e-6
//   cross: horizontal 100 m, d^2 = 2e4                                 -> beta = 1e-2 / 2e4 = 5e-7
//   With L = 1 the steering vector is 1, h = sqrt(beta), and full power w = sqrt(P) (P = 1 W):
//   shared:     SINR_0 = 1e-6 / (5e-7 + 1e-12)
//   orthogonal: SINR_0 = 1e-6 / 1e-12 = 1e6;  orthogonal-split (N = 2): 1e-6 / 5e-13, rate halved
TEST(Spectrum, SharedSinrMatchesTheHandComputedTwoUavCase) {
  Config cfg = shared_config();
  cfg.channel.antennas = 1;
  const SystemModel model(cfg);
  const Snapshot s{rows({{50, 100}, {150, 100}}), rows({{50, 100}, {150, 100}})};
  const Network net = model.network(s);
  ASSERT_EQ(net.clusters.size(), 2u);
  ASSERT_EQ(net.served_count(), 2);
  EXPECT_NEAR(std::norm(net.cross[0](1, 0)), 5e-7, 1e-18);  // UAV 0 -> user 1
  EXPECT_NEAR(std::norm(net.cross[1](0, 0)), 5e-7, 1e-18);  // UAV 1 -> user 0
  const std::vector<MatrixXcd> W{MatrixXcd::Constant(1, 1, 1.0), MatrixXcd::Constant(1, 1, 1.0)};
  const auto p = user_powers(net, W);
  EXPECT_NEAR(p[0][0].signal, 1e-6, 1e-18);
  EXPECT_EQ(p[0][0].intra, 0.0);
  EXPECT_NEAR(p[0][0].inter, 5e-7, 1e-18);
  EXPECT_NEAR(p[0][0].noise, 1e-12, 1e-24);
  const double sinr = 1e-6 / (5e-7 + 1e-12);
  EXPECT_NEAR(network_sum_rate(net, W), 2 * std::log2(1 + sinr), 1e-12);

  cfg.channel.spectrum = Spectrum::Orthogonal;
  const Network orth = SystemModel(cfg).network(s);
  EXPECT_NEAR(network_sum_rate(orth, W), 2 * std::log2(1 + 1e6), 1e-9);
  EXPECT_EQ(user_powers(orth, W)[0][0].inter, 0.0);

  cfg.channel.spectrum = Spectrum::OrthogonalSplit;
  const Network split = SystemModel(cfg).network(s);
  EXPECT_NEAR(split.clusters[0].noise, 5e-13, 1e-25);
  EXPECT_NEAR(network_sum_rate(split, W), 2 * 0.5 * std::log2(1 + 2e6), 1e-9);
}

// Two users and two antennas: the shared SINR against the explicit sum over every beam.
TEST(Spectrum, SharedSinrCountsEveryBeamOfEveryOtherUav) {
  const Config cfg = shared_config();
  const SystemModel model(cfg);
  const Snapshot s{rows({{40, 60}, {160, 140}}), rows({{30, 50}, {60, 80}, {150, 150}, {170, 120}})};
  const Network net = model.network(s);
  ASSERT_EQ(net.clusters.size(), 2u);
  std::vector<MatrixXcd> W;
  for (std::size_t i = 0; i < net.clusters.size(); ++i) W.push_back(random_beamformer(4, net.clusters[i].size(), 1.0, 7 + i));
  const auto p = user_powers(net, W);
  for (std::size_t a = 0; a < 2; ++a) {
    for (int j = 0; j < net.clusters[a].size(); ++j) {
      const int user = net.clusters[a].users[static_cast<std::size_t>(j)];
      double signal = 0, intra = 0, inter = 0;
      for (std::size_t b = 0; b < 2; ++b) {
        const VectorXcd h = model.channel(s.uavs(net.clusters[b].uav, 0), s.uavs(net.clusters[b].uav, 1), s.users(user, 0), s.users(user, 1));
        for (Eigen::Index jj = 0; jj < W[b].cols(); ++jj) {
          const double q = std::norm(h.dot(W[b].col(jj)));  // |h^H w|^2
          if (b == a && jj == j) signal += q;
          else if (b == a) intra += q;
          else inter += q;
        }
      }
      EXPECT_NEAR(p[a][static_cast<std::size_t>(j)].signal, signal, 1e-12 * signal);
      EXPECT_NEAR(p[a][static_cast<std::size_t>(j)].intra, intra, 1e-12 * (intra + signal));
      EXPECT_NEAR(p[a][static_cast<std::size_t>(j)].inter, inter, 1e-12 * (inter + signal));
      EXPECT_GT(inter, 0.0);
    }
  }
}

// A city's worth of users under the shared spectrum: every UAV's received-power matrix (all served
// users x its beams) is computed in row blocks; each user's powers are the full products' entries,
// summed in the same order, to the bit.
TEST(Spectrum, SharedPowersOfThousandsOfUsersEqualTheFullProducts) {
  const Config cfg = shared_config();
  const SystemModel model(cfg);
  const Network net = model.network(model.random_snapshot(3, 3000, 11));
  ASSERT_GT(net.offset.back() * net.clusters.front().size(), kReceivedPowerBlockEntries) << "the blocks are not used";
  std::vector<MatrixXcd> W;
  for (std::size_t i = 0; i < net.clusters.size(); ++i) W.push_back(random_beamformer(4, net.clusters[i].size(), 1.0, 3 + i));
  const auto p = user_powers(net, W);
  std::vector<Eigen::MatrixXd> full;
  for (std::size_t b = 0; b < W.size(); ++b) full.push_back((net.cross[b] * W[b]).cwiseAbs2());
  for (std::size_t a = 0; a < W.size(); ++a)
    for (int j = 0; j < net.clusters[a].size(); ++j) {
      const Eigen::Index r = net.offset[a] + j;
      double intra = 0, inter = 0;
      for (Eigen::Index jj = 0; jj < full[a].cols(); ++jj)
        if (jj != j) intra += full[a](r, jj);
      for (std::size_t b = 0; b < W.size(); ++b)
        if (b != a) inter += full[b].row(r).sum();
      const UserPowers& u = p[a][static_cast<std::size_t>(j)];
      ASSERT_EQ(u.signal, full[a](r, j));
      ASSERT_EQ(u.intra, intra);
      ASSERT_EQ(u.inter, inter);
    }
}

TEST(Spectrum, OrthogonalNetworkRateIsTheSumOfClusterRates) {
  for (const std::string spectrum : {"orthogonal", "orthogonal-split"}) {
    Config cfg;
    cfg.channel.spectrum = parse_choice<Spectrum>("channel.spectrum", spectrum);
    const SystemModel model(cfg);
    for (std::uint64_t seed = 0; seed < 20; ++seed) {
      const Network net = model.network(model.random_snapshot(3, 12, seed));
      const auto clusters = model.clusters(model.random_snapshot(3, 12, seed));
      ASSERT_EQ(clusters.size(), net.clusters.size());
      std::vector<MatrixXcd> W;
      double total = 0;
      for (const auto& c : clusters) W.push_back(zf_select(c)), total += sum_rate(c, W.back());
      EXPECT_DOUBLE_EQ(network_sum_rate(net, W), total) << spectrum << " seed " << seed;
    }
  }
}

TEST(Spectrum, BadValueIsRefusedNamingTheField) {
  try {
    resolve_config(std::nullopt, {"channel.spectrum=reuse"});
    FAIL() << "accepted";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("channel.spectrum = \"reuse\""), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("orthogonal, orthogonal-split, shared"), std::string::npos) << e.what();
  }
}

BeamformerRegistry classical() {
  BeamformerRegistry reg;
  register_classical_beamformers(reg);
  return reg;
}

// Every UAV keeps its own budget, at extreme budgets and noise too.
TEST(Coordinated, EveryUavStaysWithinItsOwnBudget) {
  const auto reg = classical();
  for (const auto& [p_dbm, noise_dbm] : std::vector<std::pair<double, double>>{{10, -90}, {50, -90}, {-30, 30}, {80, -200}}) {
    Config cfg = shared_config();
    cfg.channel.p_max_dbm = p_dbm;
    cfg.channel.noise_dbm = noise_dbm;
    const SystemModel model(cfg);
    for (const std::string name : {"nwmmse", "nwmmse=czfsel", "crzf", "czf", "czfsel"}) {
      const auto bf = reg.create(name, cfg);
      EXPECT_TRUE(bf->coordinated());
      for (std::uint64_t seed = 0; seed < 10; ++seed) {
        const Network net = model.network(model.random_snapshot(3, 12, seed));
        const auto W = bf->design_network(net);
        EXPECT_NO_THROW(check_network_output(*bf, net, W)) << name << " P " << p_dbm;
        for (std::size_t i = 0; i < W.size(); ++i)
          EXPECT_LE(W[i].squaredNorm(), net.clusters[i].p_max * (1 + 1e-9)) << name << " P " << p_dbm << " seed " << seed;
      }
    }
  }
}

// Block-coordinate ascent: the network sum rate never falls from one iteration to the next (up to
// the bisection's relative tolerance on the budget), and the result is the best iterate.
TEST(Coordinated, NetworkWmmseObjectiveIsMonotone) {
  const Config cfg = shared_config();
  const SystemModel model(cfg);
  const WmmseOptions opt{1e-9, 300, 1e-12};
  for (std::uint64_t seed = 0; seed < 15; ++seed) {
    const Network net = model.network(model.random_snapshot(3, 12, seed));
    std::vector<MatrixXcd> W0;
    for (std::size_t i = 0; i < net.clusters.size(); ++i)
      W0.push_back(random_beamformer(4, net.clusters[i].size(), net.clusters[i].p_max, derive_seed(99, seed + 16 * i)));
    const auto tr = network_wmmse_run(net, W0, opt);
    ASSERT_GE(tr.sum_rates.size(), 2u);
    for (std::size_t t = 1; t < tr.sum_rates.size(); ++t)
      EXPECT_GE(tr.sum_rates[t], tr.sum_rates[t - 1] - 1e-6 * std::abs(tr.sum_rates[t - 1])) << "seed " << seed << " it " << t;
    EXPECT_DOUBLE_EQ(tr.sum_rate, network_sum_rate(net, tr.W));
    EXPECT_GE(tr.sum_rate, tr.sum_rates.front());
    EXPECT_GT(tr.sum_rate, tr.sum_rates.front() + 1.0) << "interference management must gain on a random start";
  }
}

// Coordinated WMMSE starts from per-cluster WMMSE, so it never ends below it under the shared
// spectrum; without interference it is per-cluster WMMSE.
TEST(Coordinated, NetworkWmmseBeatsInterferenceUnawareWmmse) {
  const auto reg = classical();
  Config cfg = shared_config();
  const auto nw = reg.create("nwmmse", cfg), w = reg.create("wmmse", cfg);
  const SystemModel model(cfg);
  double coordinated = 0, alone = 0;
  for (std::uint64_t seed = 0; seed < 20; ++seed) {
    const Network net = model.network(model.random_snapshot(3, 12, seed));
    const double a = network_sum_rate(net, nw->design_network(net)), b = network_sum_rate(net, w->design_network(net));
    EXPECT_GE(a, b - 1e-9 * std::abs(b)) << "seed " << seed;
    coordinated += a, alone += b;
  }
  EXPECT_GT(coordinated, 2 * alone);
  cfg.channel.spectrum = Spectrum::Orthogonal;
  const SystemModel orth(cfg);
  for (std::uint64_t seed = 0; seed < 5; ++seed) {
    const Network net = orth.network(orth.random_snapshot(3, 12, seed));
    EXPECT_NEAR(network_sum_rate(net, nw->design_network(net)), network_sum_rate(net, w->design_network(net)), 1e-9);
  }
}

// Coordinated ZF places its nulls: a user it nulls toward receives nothing from that UAV.
TEST(Coordinated, CoordinatedZfNullsTowardOtherClustersUsers) {
  Config cfg = shared_config();
  const SystemModel model(cfg);
  // One user per UAV: each UAV has L - 1 = 3 antennas left to null toward the other's user.
  const Snapshot s{rows({{40, 60}, {160, 140}}), rows({{30, 50}, {170, 120}})};
  const Network net = model.network(s);
  const auto W = coordinated_zf(net);
  const auto p = user_powers(net, W);
  for (std::size_t a = 0; a < 2; ++a) {
    EXPECT_GT(p[a][0].signal, 0.0);
    EXPECT_LT(p[a][0].inter, 1e-12 * p[a][0].signal) << "cluster " << a;
  }
}

// Network ZF-SEL at the hand-computed two-UAV case above (one antenna, a user below each, -90 dBm,
// 1 W): one antenna cannot null, so at most one user is active. Alone it gets SINR 1e-6 / 1e-12;
// both on would get 2 log2(1 + 1e-6 / (5e-7 + 1e-12)) = 3.17 bit/s/Hz, so the greedy keeps one, the
// first in network order on the tie, and the other UAV stays silent.
TEST(Coordinated, NetworkZfSelectAtTheHandComputedTwoUavCase) {
  Config cfg = shared_config();
  cfg.channel.antennas = 1;
  const SystemModel model(cfg);
  const Network net = model.network(Snapshot{rows({{50, 100}, {150, 100}}), rows({{50, 100}, {150, 100}})});
  const auto W = coordinated_zf_select(net);
  ASSERT_EQ(W.size(), 2u);
  EXPECT_NEAR(W[0].squaredNorm(), 1.0, 1e-12);
  EXPECT_EQ(W[1].squaredNorm(), 0.0);
  EXPECT_NEAR(network_sum_rate(net, W), std::log2(1 + 1e6), 1e-9);
}

// Every active user of network ZF-SEL hears no other beam of the network, at most L users are
// active, and network WMMSE from it is at least as high (its start, then an ascent).
TEST(Coordinated, NetworkZfSelectLeavesActiveUsersInterferenceFree) {
  const Config cfg = shared_config();
  const SystemModel model(cfg);
  const auto reg = classical();
  const auto polished = reg.create("nwmmse=czfsel", cfg);
  for (std::uint64_t seed = 0; seed < 10; ++seed) {
    const Network net = model.network(model.random_snapshot(3, 12, seed));
    const auto W = coordinated_zf_select(net);
    const auto p = user_powers(net, W);
    int active = 0;
    for (std::size_t a = 0; a < W.size(); ++a)
      for (Eigen::Index k = 0; k < W[a].cols(); ++k) {
        if (W[a].col(k).squaredNorm() == 0.0) continue;
        ++active;
        const auto& q = p[a][static_cast<std::size_t>(k)];
        EXPECT_LT(q.intra + q.inter, 1e-9 * q.signal) << "seed " << seed << " cluster " << a << " user " << k;
      }
    EXPECT_GE(active, 1);
    EXPECT_LE(active, cfg.channel.antennas) << "seed " << seed;
    EXPECT_GE(network_sum_rate(net, polished->design_network(net)), network_sum_rate(net, W)) << "seed " << seed;
  }
}

// The starts of network WMMSE: its default runs every start, so it never ends below the three it
// had before network ZF-SEL joined (the same runs, then one more), and at high SNR (the default
// 30 dBm over -90 dBm, N = 3, K = 12) the interference-free start lifts it well above them: the
// per-cluster starts climb toward the nulls slowly and stop at the iteration cap (measured: 54.2
// against 43.0 bit/s/Hz on average over 30 snapshots).
TEST(Coordinated, NetworkWmmseRunsFromEveryStartAndKeepsTheBest) {
  const Config cfg = shared_config();
  const SystemModel model(cfg);
  const auto reg = classical();
  const auto every = reg.create("nwmmse", cfg), three = reg.create("nwmmse=wmmse+crzf+czf", cfg);
  const auto one = reg.create("nwmmse=czfsel", cfg);
  double sum_every = 0, sum_three = 0;
  for (std::uint64_t seed = 0; seed < 8; ++seed) {
    const Network net = model.network(model.random_snapshot(3, 12, seed));
    const double e = network_sum_rate(net, every->design_network(net));
    const double t = network_sum_rate(net, three->design_network(net));
    EXPECT_GE(e, t) << "seed " << seed;
    EXPECT_GE(e, network_sum_rate(net, one->design_network(net))) << "seed " << seed;
    sum_every += e, sum_three += t;
  }
  EXPECT_GT(sum_every, 1.1 * sum_three);
  // The spec names starts joined by '+', each once; they run in the list's order.
  EXPECT_EQ(parse_network_wmmse_starts(""), network_wmmse_starts());
  EXPECT_EQ(parse_network_wmmse_starts("czfsel+crzf"), (std::vector<std::string>{"crzf", "czfsel"}));
  for (const std::string bad : {"czfsel+", "+czf", "zf", "czf+czf"}) {
    try {
      reg.create("nwmmse=" + bad, cfg);
      FAIL() << bad << " accepted";
    } catch (const InputError& e) {
      EXPECT_NE(std::string(e.what()).find("nwmmse=" + bad), std::string::npos) << e.what();
      EXPECT_NE(std::string(e.what()).find("wmmse, crzf, czf, czfsel"), std::string::npos) << e.what();
    }
  }
}

// The oracle under the shared spectrum: a cluster's rate depends on the other UAVs (so the key is
// joint), and a hit returns exactly what a fresh evaluation of the same positions gives.
TEST(SharedOracle, HitsAreExactUnderTheJointKey) {
  const Config cfg = shared_config();
  const SystemModel model(cfg);
  const Positions users = model.random_snapshot(3, 12, 5).users;
  auto bf = std::shared_ptr<const Beamformer>(classical().create("nwmmse", cfg));
  RateOracle oracle(cfg, bf, users);
  const Positions a = rows({{20, 20}, {20, 180}, {180, 180}});
  Positions b = a;
  b(2, 0) = 100, b(2, 1) = 100;  // only UAV 2 moves
  const double ra = oracle.sum_rate(a);
  const auto ca = oracle.cluster_rates(a), cb = oracle.cluster_rates(b);
  EXPECT_NE(ca[0], cb[0]) << "UAV 0's rate must depend on where UAV 2 flies";
  EXPECT_EQ(oracle.stats().misses, 2u);
  EXPECT_EQ(oracle.sum_rate(a), ra);  // a hit, bit for bit
  EXPECT_EQ(oracle.stats().misses, 2u);
  double total = 0;
  for (double r : ca) total += r;
  EXPECT_EQ(total, ra);
  // A fresh oracle (cold cache) and the network evaluation itself give the same doubles.
  RateOracle fresh(cfg, bf, users);
  EXPECT_EQ(fresh.sum_rates({b, a}), (std::vector<double>{oracle.sum_rate(b), ra}));
  const Network net = model.network(Snapshot{a, users});
  EXPECT_DOUBLE_EQ(network_sum_rate(net, bf->design_network(net)), ra);
}

}  // namespace
}  // namespace skyloop
