#include "skyloop/channel/channel_model.hpp"

#include "skyloop/channel/fading.hpp"

#include <cmath>
#include <limits>
#include <stdexcept>

#include "skyloop/core/error.hpp"
#include "skyloop/core/rng.hpp"

namespace skyloop {

namespace {

constexpr double kPi = 3.14159265358979323846;

/// 20 log10(40 pi f_c / 3) with f_c in GHz: the carrier's share of the free-space loss
/// 20 log10(4 pi d f_c / c) (TR 36.777 writes it so).
double carrier_term_db(double fc_ghz) { return 20.0 * std::log10(40.0 * kPi * fc_ghz / 3.0); }

/// Free-space loss 20 log10(4 pi d f_c / c) in dB.
double free_space_db(double d, double fc_ghz) { return 20.0 * std::log10(d) + carrier_term_db(fc_ghz); }

/// TR 36.777 Table B-1's form above the terrestrial heights: 1 within d1, else
/// d1 / d_2D + exp(-d_2D / p1) (1 - d1 / d_2D).
double los_probability(double d2, double d1, double p1) {
  if (d2 <= d1) return 1.0;
  return d1 / d2 + std::exp(-d2 / p1) * (1.0 - d1 / d2);
}

/// The paper's model: always LoS, beta0 (d0 / d)^2, no shadowing.
class FreeSpace final : public PathLossModel {
 public:
  FreeSpace(double beta0_db, double d0) : beta0_db_(beta0_db), d0_(d0) {}
  double p_los(const LinkGeometry&) const override { return 1.0; }
  double path_loss_db(const LinkGeometry& g, bool) const override { return -beta0_db_ + 20.0 * std::log10(g.distance_m / d0_); }
  double shadowing_std_db(const LinkGeometry&, bool) const override { return 0.0; }
  bool paper() const override { return true; }

 private:
  double beta0_db_, d0_;
};

/// TR 36.777 Annex B, UMa-AV, 22.5 m < h_UT <= 300 m.
class UmaAv final : public PathLossModel {
 public:
  explicit UmaAv(double fc) : fc_(fc) {}
  double p_los(const LinkGeometry& g) const override {
    const double h = g.height_m;
    if (h > 100) return 1.0;
    const double p1 = 4300.0 * std::log10(h) - 3800.0, d1 = std::max(460.0 * std::log10(h) - 700.0, 18.0);
    return los_probability(g.horizontal_m, d1, p1);
  }
  double path_loss_db(const LinkGeometry& g, bool los) const override {
    const double d = g.distance_m, h = g.height_m;
    if (los) return 28.0 + 22.0 * std::log10(d) + 20.0 * std::log10(fc_);
    return -17.5 + (46.0 - 7.0 * std::log10(h)) * std::log10(d) + carrier_term_db(fc_);
  }
  double shadowing_std_db(const LinkGeometry& g, bool los) const override {
    return los ? 4.64 * std::exp(-0.0066 * g.height_m) : 6.0;
  }

 private:
  double fc_;
};

/// TR 36.777 Annex B, UMi-AV, 22.5 m < h_UT <= 300 m.
class UmiAv final : public PathLossModel {
 public:
  explicit UmiAv(double fc) : fc_(fc) {}
  double p_los(const LinkGeometry& g) const override {
    const double h = g.height_m;
    const double p1 = 233.98 * std::log10(h) - 0.95, d1 = std::max(294.05 * std::log10(h) - 432.94, 18.0);
    return los_probability(g.horizontal_m, d1, p1);
  }
  double path_loss_db(const LinkGeometry& g, bool los) const override {
    const double d = g.distance_m, h = g.height_m;
    const double los_db = std::max(free_space_db(d, fc_), 30.9 + (22.25 - 0.5 * std::log10(h)) * std::log10(d) + 20.0 * std::log10(fc_));
    if (los) return los_db;
    return std::max(los_db, 32.4 + (43.2 - 7.6 * std::log10(h)) * std::log10(d) + 20.0 * std::log10(fc_));
  }
  double shadowing_std_db(const LinkGeometry& g, bool los) const override {
    return los ? std::max(5.0 * std::exp(-0.01 * g.height_m), 2.0) : 8.0;
  }

 private:
  double fc_;
};

/// TR 36.777 Annex B, RMa-AV, 10 m < h_UT <= 300 m (NLoS only below 40 m, where P_LoS < 1).
class RmaAv final : public PathLossModel {
 public:
  explicit RmaAv(double fc) : fc_(fc) {}
  double p_los(const LinkGeometry& g) const override {
    const double h = g.height_m;
    if (h > 40) return 1.0;
    const double p1 = std::max(15021.0 * std::log10(h) - 16053.0, 1000.0), d1 = std::max(1350.8 * std::log10(h) - 1602.0, 18.0);
    return los_probability(g.horizontal_m, d1, p1);
  }
  double path_loss_db(const LinkGeometry& g, bool los) const override {
    const double d = g.distance_m, h = g.height_m;
    const double los_db = std::max(23.9 - 1.8 * std::log10(h), 20.0) * std::log10(d) + carrier_term_db(fc_);
    if (los) return los_db;
    return std::max(los_db, -12.0 + (35.0 - 5.3 * std::log10(h)) * std::log10(d) + carrier_term_db(fc_));
  }
  double shadowing_std_db(const LinkGeometry& g, bool los) const override {
    return los ? 4.2 * std::exp(-0.0046 * g.height_m) : 6.0;
  }

 private:
  double fc_;
};

/// Al-Hourani et al., IEEE WCL 2014: the S-curve in elevation degrees and mean excess losses.
class AlHourani final : public PathLossModel {
 public:
  AlHourani(double fc, const AirToGroundEnvironment& e) : fc_(fc), env_(e) {}
  double p_los(const LinkGeometry& g) const override {
    return 1.0 / (1.0 + env_.a * std::exp(-env_.b * (g.elevation_deg - env_.a)));
  }
  double path_loss_db(const LinkGeometry& g, bool los) const override {
    return free_space_db(g.distance_m, fc_) + (los ? env_.eta_los_db : env_.eta_nlos_db);
  }
  double shadowing_std_db(const LinkGeometry&, bool) const override { return 0.0; }

 private:
  double fc_;
  AirToGroundEnvironment env_;
};

std::uint64_t key_of(std::uint64_t seed, std::uint64_t which, double x, double y) {
  std::uint64_t h = hash_bytes(&seed, sizeof seed);
  h = hash_bytes(&which, sizeof which, h);
  h = hash_bytes(&x, sizeof x, h);
  return hash_bytes(&y, sizeof y, h);
}

}  // namespace

std::vector<std::pair<std::string, double>> link_fields(const LinkState& s) {
  return {{"distance_m", s.geometry.distance_m},
          {"elevation_deg", s.geometry.elevation_deg},
          {"p_los", s.p_los},
          {"los", s.los ? 1.0 : 0.0},
          {"path_loss_db", s.path_loss_db},
          {"shadowing_db", s.shadowing_db},
          {"k_factor_db", s.k_factor_db},
          {"gain", s.gain}};
}

const Registry<PathLossInfo>& path_loss_models() {
  using Made = std::unique_ptr<PathLossModel>;
  static const Registry<PathLossInfo> models(
      "channel.pathloss = \"{}\"",
      {
          {"free-space", "the paper: beta0 (d0/d)^2, line of sight everywhere",
           {0, 1e300, 0, [](const ChannelConfig& c) -> Made { return std::make_unique<FreeSpace>(c.beta0_db, c.d0_m); }}},
          {"3gpp-uma-av", "3GPP TR 36.777 urban macro, aerial UAV (22.5 m < H <= 300 m, d_2D <= 4 km)",
           {22.5, 300, 4000, [](const ChannelConfig& c) -> Made { return std::make_unique<UmaAv>(c.carrier_ghz); }}},
          {"3gpp-umi-av", "3GPP TR 36.777 urban micro, aerial UAV (22.5 m < H <= 300 m, d_2D <= 4 km)",
           {22.5, 300, 4000, [](const ChannelConfig& c) -> Made { return std::make_unique<UmiAv>(c.carrier_ghz); }}},
          {"3gpp-rma-av", "3GPP TR 36.777 rural macro, aerial UAV (10 m < H <= 300 m, d_2D <= 10 km)",
           {10, 300, 10000, [](const ChannelConfig& c) -> Made { return std::make_unique<RmaAv>(c.carrier_ghz); }}},
          {"al-hourani", "Al-Hourani et al. (IEEE WCL 2014): sigmoid P_LoS in elevation, excess losses over free space",
           {0, 1e300, 0, [](const ChannelConfig& c) -> Made {
              const AirToGroundEnvironment* e = find_environment(c.environment);
              if (!e) {
                std::string names;
                for (const auto& x : kAlHouraniEnvironments) names += (names.empty() ? "" : ", ") + std::string(x.name);
                throw InputError("channel.environment = \"" + c.environment + "\" is unknown: allowed " + names);
              }
              return std::make_unique<AlHourani>(c.carrier_ghz, *e);
            }}},
      });
  return models;
}

std::unique_ptr<PathLossModel> make_path_loss(const ChannelConfig& c) { return path_loss_models().at(c.pathloss).make(c); }

ChannelModel::ChannelModel(const Config& cfg)
    : antennas_(cfg.channel.antennas),
      spacing_(cfg.channel.antenna_spacing_wavelengths),
      altitude_(cfg.scenario.altitude_m),
      user_height_(cfg.scenario.user_height_m),
      beta0_(db_to_linear(cfg.channel.beta0_db)),
      d0_(cfg.channel.d0_m),
      shadowing_(cfg.channel.shadowing),
      correlation_(cfg.channel.correlation_m),
      seed_(cfg.channel.seed),
      path_loss_(make_path_loss(cfg.channel)),
      fading_(make_fading(cfg.channel)) {
  free_space_ = path_loss_->paper();
}

bool ChannelModel::paper() const { return free_space_ && !fading_->random(); }

int ChannelModel::fast_slots() const { return fading_->fast_slots(); }

LinkGeometry ChannelModel::geometry(double ux, double uy, double uz, double x, double y) const {
  const double dx = ux - x, dy = uy - y, dz = uz - user_height_;
  LinkGeometry g;
  g.horizontal_m = std::sqrt(dx * dx + dy * dy);
  g.distance_m = distance(ux, uy, uz, x, y);
  g.height_m = uz;
  g.elevation_deg = std::asin(std::min(1.0, dz / g.distance_m)) * 180.0 / kPi;
  return g;
}

double ChannelModel::field(int which, double ux, double uy, double x, double y) const {
  const double fx = ux / correlation_, fy = uy / correlation_;
  const double ix = std::floor(fx), iy = std::floor(fy);
  const double tx = fx - ix, ty = fy - iy;
  const std::uint64_t user = key_of(seed_, static_cast<std::uint64_t>(which), x, y);
  double sum = 0, weights = 0;
  for (int cy = 0; cy < 2; ++cy)
    for (int cx = 0; cx < 2; ++cx) {
      const double w = (cx ? tx : 1.0 - tx) * (cy ? ty : 1.0 - ty);
      if (w == 0.0) continue;
      const auto px = static_cast<std::int64_t>(ix) + cx, py = static_cast<std::int64_t>(iy) + cy;
      sum += w * unit_normals(derive_seed(user, static_cast<std::uint64_t>(px), static_cast<std::uint64_t>(py))).first;
      weights += w * w;
    }
  return sum / std::sqrt(weights);
}

LinkState ChannelModel::link(double ux, double uy, double uz, double x, double y) const {
  LinkState s;
  s.geometry = geometry(ux, uy, uz, x, y);
  if (free_space_) {
    s.gain = free_space_gain(s.geometry.distance_m);  // the paper's beta, bit for bit
    s.path_loss_db = -linear_to_db(s.gain);
  } else {
    s.p_los = path_loss_->p_los(s.geometry);
    s.los = s.p_los >= 1.0 || 0.5 * std::erfc(-field(0, ux, uy, x, y) / std::sqrt(2.0)) < s.p_los;
    s.path_loss_db = path_loss_->path_loss_db(s.geometry, s.los);
    const double spread = shadowing_ ? path_loss_->shadowing_std_db(s.geometry, s.los) : 0.0;
    if (spread > 0) s.shadowing_db = spread * field(1, ux, uy, x, y);
    s.gain = db_to_linear(-(s.path_loss_db + s.shadowing_db));
  }
  s.k_factor_db = fading_->k_factor_db(s);
  return s;
}

VectorXcd ChannelModel::steering(double cos_theta) const {
  VectorXcd a(antennas_);
  const double phase = 2.0 * kPi * spacing_ * cos_theta;
  for (int l = 0; l < antennas_; ++l) a[l] = std::polar(1.0, phase * l);
  return a;
}

VectorXcd ChannelModel::channel_at(double ux, double uy, double uz, double x, double y, int slot) const {
  if (slot < 0 || slot >= fast_slots())
    throw InputError("slot = " + std::to_string(slot) + " is out of range: allowed 0 <= slot < fast_slots = " +
                     std::to_string(fast_slots()) + " (channel.fast_slots; 1 without fading)");
  if (paper()) {
    // The paper's h = sqrt(beta) a(theta), computed exactly as before the seam existed.
    const double d = distance(ux, uy, uz, x, y);
    return std::sqrt(free_space_gain(d)) * steering((uz - user_height_) / d);
  }
  const LinkState s = link(ux, uy, uz, x, y);
  const VectorXcd a = steering((uz - user_height_) / s.geometry.distance_m);
  if (!fading_->random()) return fading_->realise(s, a, 0);
  // The slot's draws: a pure function of (channel.seed, the UAV's position, the user's, the slot).
  std::uint64_t h = key_of(seed_, 2, ux, uy);
  if (uz != altitude_) h = hash_bytes(&uz, sizeof uz, h);  // at H: the draws of the fixed-altitude channel
  h = hash_bytes(&x, sizeof x, h);
  h = hash_bytes(&y, sizeof y, h);
  const auto m = static_cast<std::uint64_t>(slot);
  h = hash_bytes(&m, sizeof m, h);
  return fading_->realise(s, a, h);
}

}  // namespace skyloop
