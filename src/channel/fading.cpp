// The fading models (skyloop/channel/fading.hpp).
#include "skyloop/channel/fading.hpp"

#include <cmath>
#include <complex>
#include <limits>

#include "skyloop/channel/channel_model.hpp"
#include "skyloop/core/error.hpp"
#include "skyloop/core/rng.hpp"

namespace skyloop {

namespace {

constexpr double kPi = 3.14159265358979323846;

/// The paper's channel: the direct path alone.
class NoFading final : public FadingModel {
 public:
  int fast_slots() const override { return 1; }
  bool random() const override { return false; }
  double k_factor_db(const LinkState&) const override { return std::numeric_limits<double>::infinity(); }
  VectorXcd realise(const LinkState& s, const VectorXcd& a, std::uint64_t) const override { return std::sqrt(s.gain) * a; }
};

/// Rician fading: K fixed or rising with the elevation on LoS links, Rayleigh on NLoS links.
class Rician final : public FadingModel {
 public:
  explicit Rician(const ChannelConfig& c)
      : elevation_(c.rician_k == RicianK::Elevation), k_db_(c.rician_k_db), k_min_db_(c.rician_k_min_db), k_max_db_(c.rician_k_max_db),
        fast_slots_(c.fast_slots) {}
  int fast_slots() const override { return fast_slots_; }
  bool random() const override { return true; }
  double k_factor_db(const LinkState& s) const override {
    return s.los ? linear_to_db(k_factor(s.geometry.elevation_deg)) : -std::numeric_limits<double>::infinity();
  }
  VectorXcd realise(const LinkState& s, const VectorXcd& a, std::uint64_t draws) const override {
    const double k = s.los ? k_factor(s.geometry.elevation_deg) : 0.0;
    const double direct = std::sqrt(k / (k + 1.0)), scattered = std::sqrt(1.0 / (k + 1.0));
    VectorXcd out(a.size());
    for (Eigen::Index l = 0; l < a.size(); ++l) {
      const auto [re, im] = unit_normals(derive_seed(draws, static_cast<std::uint64_t>(l)));
      out[l] = std::sqrt(s.gain) * (direct * a[l] + scattered * std::complex<double>(re, im) / std::sqrt(2.0));
    }
    return out;
  }
  /// K (linear) of a LoS link at the elevation (degrees).
  double k_factor(double elevation_deg) const {
    if (!elevation_) return db_to_linear(k_db_);
    return db_to_linear(k_min_db_ + (k_max_db_ - k_min_db_) * elevation_deg / 90.0);
  }

 private:
  bool elevation_;
  double k_db_, k_min_db_, k_max_db_;
  int fast_slots_;
};

}  // namespace

std::pair<double, double> unit_normals(std::uint64_t key) {
  const std::uint64_t a = mix64(key), b = mix64(key ^ 0x9e3779b97f4a7c15ULL);
  const double u1 = (static_cast<double>(a >> 11) + 0.5) * 0x1.0p-53;  // (0, 1)
  const double u2 = static_cast<double>(b >> 11) * 0x1.0p-53;
  const double r = std::sqrt(-2.0 * std::log(u1));
  return {r * std::cos(2.0 * kPi * u2), r * std::sin(2.0 * kPi * u2)};
}

const Registry<FadingFactory>& fading_models() {
  static const Registry<FadingFactory> models(
      "channel.fading = \"{}\"",
      {
          {"none", "the paper: h = sqrt(beta) a, no scattered part",
           [](const ChannelConfig&) -> std::unique_ptr<FadingModel> { return std::make_unique<NoFading>(); }},
          {"rician", "Rician with K per channel.rician_k; Rayleigh on NLoS links",
           [](const ChannelConfig& c) -> std::unique_ptr<FadingModel> { return std::make_unique<Rician>(c); }},
      });
  return models;
}

std::unique_ptr<FadingModel> make_fading(const ChannelConfig& c) { return fading_models().at(c.fading)(c); }

}  // namespace skyloop
