// The channel-model seam (channel/channel_model.hpp): every path-loss formula at points evaluated
// by hand from its source, the LoS and shadowing maps' statistics, Rician fading's moments, the
// paper's channel bit for bit, the refusals, and the oracle's exactness under fast slots.
//
// Hand values: 3GPP TR 36.777 V15.0.0 Annex B, Table B-1 (P_LoS), Table B-2 (path loss), Table B-3
// (shadowing std), f_c = 2 GHz; Al-Hourani, Kandeepan, Lardner, "Optimal LAP altitude for maximum
// coverage", IEEE WCL 3(6) 2014, Table I (a, b, eta_LoS, eta_NLoS). Each value below was evaluated
// from the printed formula (the arithmetic is in the comment).
#include <gtest/gtest.h>

#include <cmath>
#include <limits>

#include "skyloop/beamforming/registry.hpp"
#include "skyloop/channel/channel_model.hpp"
#include "skyloop/channel/fading.hpp"
#include "skyloop/channel/rates.hpp"
#include "skyloop/channel/system_model.hpp"
#include "skyloop/core/error.hpp"
#include "skyloop/core/parallel.hpp"
#include "skyloop/env/rate_oracle.hpp"

using namespace skyloop;

namespace {

Config air(const std::string& model, double altitude = 50) {
  Config c;
  c.channel.pathloss = model;
  c.channel.carrier_ghz = 2.0;
  c.scenario.altitude_m = altitude;
  c.channel.coverage_radius_m = 1e4;
  return c;
}

LinkGeometry at(double altitude, double d2) {
  LinkGeometry g;
  g.height_m = altitude;
  g.horizontal_m = d2;
  g.distance_m = std::hypot(d2, altitude);
  g.elevation_deg = std::asin(altitude / g.distance_m) * 180.0 / M_PI;
  return g;
}

}  // namespace

TEST(ChannelModel, LosProbabilityMatchesTableB1AtHandEvaluatedPoints) {
  const auto uma = make_path_loss(air("3gpp-uma-av").channel);
  // h = 50: p1 = 4300 log10 50 - 3800 = 3505.57, d1 = max(460 log10 50 - 700, 18) = 81.526;
  // d2 = 100: 81.526/100 + exp(-100/3505.57)(1 - 0.81526) = 0.994805
  EXPECT_NEAR(uma->p_los(at(50, 100)), 0.9948046142533703, 1e-12);
  EXPECT_DOUBLE_EQ(uma->p_los(at(50, 81.5)), 1.0);  // within d1
  // h = 23 (just above the 22.5 m boundary): d1 = 18, p1 = 2055.3; d2 = 500: 0.791843
  EXPECT_NEAR(uma->p_los(at(23, 500)), 0.7918426025273984, 1e-12);
  // h = 100 (the last height with the formula): d1 = 220, p1 = 4800; d2 = 1000: 0.853310
  EXPECT_NEAR(uma->p_los(at(100, 1000)), 0.8533103499974952, 1e-12);
  EXPECT_DOUBLE_EQ(uma->p_los(at(100.5, 1000)), 1.0);  // 100 m < h <= 300 m: always LoS

  const auto umi = make_path_loss(air("3gpp-umi-av").channel);
  // h = 50: p1 = 233.98 log10 50 - 0.95 = 396.57, d1 = 66.642; d2 = 300: 0.587203
  EXPECT_NEAR(umi->p_los(at(50, 300)), 0.5872029681255126, 1e-12);
  EXPECT_NEAR(umi->p_los(at(22.6, 200)), 0.5731375393536842, 1e-12);  // d1 = 18 at the lower boundary
  EXPECT_NEAR(umi->p_los(at(300, 1000)), 0.42059071019004063, 1e-12);  // the upper boundary

  const auto rma = make_path_loss(air("3gpp-rma-av", 20).channel);
  // h = 20: p1 = max(15021 log10 20 - 16053, 1000) = 3489.77, d1 = 155.43; d2 = 2000: 0.597675
  EXPECT_NEAR(rma->p_los(at(20, 2000)), 0.5976747604116626, 1e-12);
  EXPECT_NEAR(rma->p_los(at(40, 5000)), 0.5879318819372746, 1e-12);  // the last height below 100% LoS
  EXPECT_DOUBLE_EQ(rma->p_los(at(40.5, 5000)), 1.0);

  // Al-Hourani: 1 / (1 + a exp(-b (theta - a))), theta = asin(50 / 111.80) = 26.565 deg.
  const double expected[] = {0.999564868386379, 0.610640176746366, 0.28942145082825904, 0.03364992907320696};
  const char* names[] = {"suburban", "urban", "dense-urban", "highrise-urban"};
  for (int i = 0; i < 4; ++i) {
    Config c = air("al-hourani");
    c.channel.environment = names[i];
    EXPECT_NEAR(make_path_loss(c.channel)->p_los(at(50, 100)), expected[i], 1e-12) << names[i];
  }
}

TEST(ChannelModel, PathLossAndShadowingSpreadMatchTablesB2AndB3) {
  // h = 50 m, d2 = 100 m, d3 = 111.803 m, f_c = 2 GHz.
  const LinkGeometry g = at(50, 100);
  const auto uma = make_path_loss(air("3gpp-uma-av").channel);
  EXPECT_NEAR(uma->path_loss_db(g, true), 79.08661005636824, 1e-9);   // 28 + 22 log10 d3 + 20 log10 fc
  EXPECT_NEAR(uma->path_loss_db(g, false), 90.82945711953758, 1e-9);  // -17.5 + (46 - 7 log10 h) log10 d3 + 20 log10(40 pi fc / 3)
  EXPECT_NEAR(uma->shadowing_std_db(g, true), 3.3358061231241374, 1e-12);  // 4.64 exp(-0.0066 h)
  EXPECT_DOUBLE_EQ(uma->shadowing_std_db(g, false), 6.0);
  const auto umi = make_path_loss(air("3gpp-umi-av").channel);
  EXPECT_NEAR(umi->path_loss_db(g, true), 80.75859200235311, 1e-9);    // max(PL_FS, 30.9 + (22.25 - 0.5 log10 h) log10 d3 + 20 log10 fc)
  EXPECT_NEAR(umi->path_loss_db(g, false), 100.46385274850826, 1e-9);  // max(PL_LoS, 32.4 + (43.2 - 7.6 log10 h) log10 d3 + 20 log10 fc)
  EXPECT_NEAR(umi->shadowing_std_db(g, true), 3.032653298563167, 1e-12);  // max(5 exp(-0.01 h), 2)
  EXPECT_DOUBLE_EQ(umi->shadowing_std_db(g, false), 8.0);
  const auto rma = make_path_loss(air("3gpp-rma-av").channel);
  EXPECT_NEAR(rma->path_loss_db(g, true), 81.15597225446645, 1e-9);   // max(23.9 - 1.8 log10 h, 20) log10 d3 + 20 log10(40 pi fc / 3)
  EXPECT_NEAR(rma->path_loss_db(g, false), 81.15597225446645, 1e-9);  // max(PL_LoS, -12 + (35 - 5.3 log10 h) log10 d3 + ...)
  EXPECT_NEAR(rma->shadowing_std_db(g, true), 3.3370411305140033, 1e-12);  // 4.2 exp(-0.0046 h)
  // Al-Hourani urban: FSPL 20 log10(40 pi d3 fc / 3) = 79.4315 plus eta = 1 / 20 dB.
  Config c = air("al-hourani");
  c.channel.environment = "urban";
  const auto ah = make_path_loss(c.channel);
  EXPECT_NEAR(ah->path_loss_db(g, true), 80.43147222940885, 1e-9);
  EXPECT_NEAR(ah->path_loss_db(g, false), 99.43147222940885, 1e-9);
}

TEST(ChannelModel, ThePapersChannelIsUnchangedBitForBit) {
  Config c;  // free-space, no fading
  const SystemModel model(c);
  EXPECT_EQ(model.fast_slots(), 1);
  const double ux = 40, uy = 70, x = 130, y = 20;
  const double dx = ux - x, dy = uy - y, H = c.scenario.altitude_m;
  const double d = std::sqrt(dx * dx + dy * dy + H * H);
  const double r = c.channel.d0_m / d, beta = std::pow(10.0, c.channel.beta0_db / 10.0) * r * r;
  const VectorXcd h = model.channel(ux, uy, x, y);
  for (int l = 0; l < c.channel.antennas; ++l) {
    const std::complex<double> expect = std::sqrt(beta) * std::polar(1.0, 2.0 * M_PI * c.channel.antenna_spacing_wavelengths * (H / d) * l);
    EXPECT_EQ(h[l], expect) << "antenna " << l;
  }
  const LinkState s = model.channel_model().link(ux, uy, x, y);
  EXPECT_TRUE(s.los);
  EXPECT_EQ(s.gain, beta);
  EXPECT_EQ(s.p_los, 1.0);
  EXPECT_EQ(s.shadowing_db, 0.0);
  EXPECT_TRUE(std::isinf(s.k_factor_db) && s.k_factor_db > 0);
}

TEST(ChannelModel, LosFrequencyAndShadowingSpreadFollowTheModelAcrossTheCity) {
  Config c = air("3gpp-uma-av");
  const ChannelModel m(c);
  // One geometry (h = 50, d2 = 100: P_LoS = 0.994805 is too close to 1; use d2 = 600) seen from
  // 20000 places of the city: both ends shifted together, far apart (independent maps).
  const double d2 = 600;
  const double p = make_path_loss(c.channel)->p_los(at(50, d2));
  int los = 0;
  double sum = 0, sum2 = 0;
  const int n = 20000;
  for (int i = 0; i < n; ++i) {
    const double ox = 1000.0 * (i % 200), oy = 1000.0 * (i / 200);
    const LinkState s = m.link(ox + 13.0, oy + 7.0, ox + 13.0 + d2, oy + 7.0);
    los += s.los;
    const double z = s.shadowing_db / make_path_loss(c.channel)->shadowing_std_db(s.geometry, s.los);
    sum += z, sum2 += z * z;
    EXPECT_DOUBLE_EQ(s.p_los, p);
  }
  const double freq = static_cast<double>(los) / n, se = std::sqrt(p * (1 - p) / n);
  EXPECT_NEAR(freq, p, 5 * se) << "LoS in " << los << " of " << n;
  const double mean = sum / n, sd = std::sqrt(sum2 / n - mean * mean);
  EXPECT_NEAR(mean, 0.0, 5.0 / std::sqrt(n));
  EXPECT_NEAR(sd, 1.0, 0.03) << "shadowing / sigma has unit spread";
  // The maps are continuous: a UAV 1 cm away sees nearly the same shadowing.
  const double a = m.field(1, 100.0, 100.0, 37.0, 55.0), b = m.field(1, 100.01, 100.0, 37.0, 55.0);
  EXPECT_NEAR(a, b, 1e-3);
  // ... and decorrelated a few correlation distances away (sample correlation over users).
  double sab = 0, saa = 0, sbb = 0;
  for (int k = 0; k < 5000; ++k) {
    const double x = 3.0 * k, y = 1.0 * k;
    const double f0 = m.field(1, 500.0, 500.0, x, y), f1 = m.field(1, 500.0 + 4 * c.channel.correlation_m, 500.0, x, y);
    sab += f0 * f1, saa += f0 * f0, sbb += f1 * f1;
  }
  EXPECT_LT(std::abs(sab / std::sqrt(saa * sbb)), 0.06);
}

TEST(ChannelModel, RicianDrawsHaveMeanPowerBetaLAndTheirKFactor) {
  for (double k_db : {0.0, 10.0}) {
    Config c;  // free-space keeps beta and the LoS state fixed while the city varies
    c.channel.fading = "rician";
    c.channel.rician_k_db = k_db;
    c.channel.antennas = 4;
    const ChannelModel m(c);
    const double K = std::pow(10.0, k_db / 10.0);
    const int n = 100000;
    // Same geometry everywhere: UAV at (ox, oy), user 60 m east; a and beta are the same.
    const LinkState s0 = m.link(0, 0, 60, 0);
    const VectorXcd a = m.steering(c.scenario.altitude_m / s0.geometry.distance_m);
    std::complex<double> mean = 0;
    double power = 0, second = 0;
    for (int i = 0; i < n; ++i) {
      const double ox = 37.0 * i, oy = 11.0 * (i % 977);
      const VectorXcd h = m.channel(ox, oy, ox + 60, oy, 0) / std::sqrt(s0.gain);
      power += h.squaredNorm();
      for (int l = 0; l < c.channel.antennas; ++l) {
        const std::complex<double> u = h[l] * std::conj(a[l]);  // direct part rotated onto the real axis
        mean += u;
        second += std::norm(u);
      }
    }
    const double count = static_cast<double>(n) * c.channel.antennas;
    EXPECT_NEAR(power / n / c.channel.antennas, 1.0, 0.01) << "E||h||^2 = beta L";
    const double direct = std::norm(mean / count), scattered = second / count - direct;
    EXPECT_NEAR(direct / scattered, K, 0.03 * K) << "K = " << k_db << " dB";
  }
}

TEST(ChannelModel, LargeKApproachesThePapersChannelAndNlosLinksAreRayleigh) {
  Config c;
  c.channel.fading = "rician";
  c.channel.rician_k_db = 100;
  const SystemModel faded(c);
  const SystemModel paper{Config{}};
  const VectorXcd h = faded.channel(10, 20, 90, 150, 0), h0 = paper.channel(10, 20, 90, 150);
  EXPECT_LT((h - h0).norm(), 1e-4 * h0.norm());
  // Elevation-dependent K: k_min at 0 deg, k_max at 90, linear in dB between.
  c.channel.rician_k = RicianK::Elevation;
  c.channel.rician_k_min_db = 5, c.channel.rician_k_max_db = 15;
  const ChannelModel m(c);
  auto k_at = [&](double elevation_deg) {  // a LoS link's K at this elevation (dB)
    LinkState s;
    s.geometry.elevation_deg = elevation_deg;
    return m.fading().k_factor_db(s);
  };
  EXPECT_NEAR(k_at(0), 5, 1e-12);
  EXPECT_NEAR(k_at(45), 10, 1e-12);
  EXPECT_NEAR(k_at(90), 15, 1e-12);
  // Under a 3GPP model the NLoS links carry K = 0 (-infinity dB).
  Config u = air("3gpp-uma-av");
  u.channel.fading = "rician";
  const ChannelModel mu(u);
  int nlos = 0;
  for (int i = 0; i < 400 && nlos == 0; ++i) {
    const LinkState s = mu.link(1000.0 * i, 0, 1000.0 * i + 900, 0);
    if (!s.los) {
      ++nlos;
      EXPECT_TRUE(std::isinf(s.k_factor_db) && s.k_factor_db < 0);
    } else {
      EXPECT_NEAR(s.k_factor_db, 10.0, 1e-12);
    }
  }
  EXPECT_EQ(nlos, 1) << "some link of 400 at 900 m is NLoS";
}

TEST(ChannelModel, OutOfRangeModelsAreRefusedInOneLine) {
  auto refused = [](Config c, const std::string& needle) {
    try {
      validate(c);
    } catch (const InputError& e) {
      const std::string what = e.what();
      EXPECT_NE(what.find(needle), std::string::npos) << what;
      EXPECT_EQ(what.find('\n'), std::string::npos);
      return;
    }
    ADD_FAILURE() << "accepted: " << needle;
  };
  refused(air("3gpp-uma-av", 20), "scenario.altitude_m = 20");
  refused(air("3gpp-umi-av", 301), "scenario.altitude_m = 301");
  refused(air("3gpp-rma-av", 10), "scenario.altitude_m = 10");
  Config wide = air("3gpp-uma-av");
  wide.scenario.area_x_m = wide.scenario.area_y_m = 3000;
  refused(wide, "diagonal is at most 4000");
  Config low;
  low.scenario.user_height_m = 100;
  refused(low, "scenario.user_height_m = 100");
  EXPECT_NO_THROW(validate(air("3gpp-rma-av", 10.5)));
}

TEST(ChannelModel, ChannelsAreAPureFunctionOfPositionsOnAnyThreadCount) {
  Config c = air("3gpp-uma-av");
  c.channel.fading = "rician";
  c.channel.fast_slots = 4;
  const SystemModel m(c);
  auto draw = [&](int threads) {
    std::vector<VectorXcd> out(64);
    parallel_for(64, threads, [&](std::size_t i) {
      out[i] = m.channel(5.0 * static_cast<double>(i), 30, 100, 80, static_cast<int>(i % 4));
    });
    return out;
  };
  const auto one = draw(1), two = draw(2);
  for (std::size_t i = 0; i < one.size(); ++i) EXPECT_EQ(one[i], two[i]);
  // Another city seed is another map.
  Config other = c;
  other.channel.seed = 2;
  EXPECT_NE(SystemModel(other).channel(0, 30, 100, 80, 0), m.channel(0, 30, 100, 80, 0));
}

TEST(ChannelModel, TheOracleAveragesFastSlotsAndItsMemoStaysExact) {
  Config c = air("3gpp-uma-av");
  c.scenario.area_x_m = c.scenario.area_y_m = 200;
  c.channel.coverage_radius_m = 400;
  c.channel.fading = "rician";
  c.channel.fast_slots = 3;
  const SystemModel model(c);
  Rng rng(5);
  const Positions users = draw_users(c.scenario, 9, rng);
  BeamformerRegistry reg;
  register_classical_beamformers(reg);
  std::shared_ptr<const Beamformer> bf = reg.create("zfsel", c);
  RateOracle oracle(c, bf, users);
  Positions uavs(2, 2);
  uavs << 40, 60, 150, 120;
  const double first = oracle.sum_rate(uavs);
  // By hand: each fast slot's network designed and rated, then the mean.
  const Association a = model.associate(uavs, users);
  double expect = 0;
  for (int slot = 0; slot < 3; ++slot) {
    double slot_rate = 0;
    for (int n = 0; n < 2; ++n) {
      if (a.users[static_cast<std::size_t>(n)].empty()) continue;
      const Cluster cl = model.make_cluster(n, uavs(n, 0), uavs(n, 1), users, a.users[static_cast<std::size_t>(n)], 2, slot);
      slot_rate += sum_rate(cl, bf->design(cl));
    }
    expect += slot_rate;
  }
  expect /= 3;
  EXPECT_NEAR(first, expect, 1e-9 * expect);
  // A hit gives the same number; a fresh oracle too (the rate is a function of positions).
  EXPECT_EQ(oracle.sum_rate(uavs), first);
  RateOracle fresh(c, bf, users);
  EXPECT_EQ(fresh.sum_rate(uavs), first);
}
