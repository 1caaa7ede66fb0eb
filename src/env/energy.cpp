#include "skyloop/env/energy.hpp"

#include <algorithm>
#include <cmath>

#include "skyloop/core/config.hpp"

namespace skyloop {

PropulsionModel::PropulsionModel(const EnergyConfig& c)
    : enabled_(c.model == Propulsion::RotaryWing),
      kinetic_(c.acceleration == Acceleration::Kinetic),
      p0_(c.p0_w),
      pi_(c.pi_w),
      u_tip_(c.u_tip_mps),
      v0_(c.v0_mps),
      parasite_(0.5 * c.d0 * c.rho_kgm3 * c.solidity * c.rotor_area_m2),
      mass_(c.mass_kg) {}

double PropulsionModel::power(double v) const {
  if (!enabled_) return 0.0;
  const double v2 = v * v, v04 = v0_ * v0_ * v0_ * v0_;
  const double blade = p0_ * (1 + 3 * v2 / (u_tip_ * u_tip_));
  // sqrt(1 + x^2) - x with x = V^2 / (2 v0^2), written as 1 / (sqrt(1 + x^2) + x): no cancellation at speed.
  const double x = v2 / (2 * v0_ * v0_);
  const double induced = pi_ * std::sqrt(1.0 / (std::sqrt(1 + v2 * v2 / (4 * v04)) + x));
  return blade + induced + parasite_ * v2 * v;
}

namespace {
/// argmin of a unimodal f on [lo, hi] by golden-section search to 1e-10 m/s.
template <class F>
double golden_min(F f, double lo, double hi) {
  const double g = (std::sqrt(5.0) - 1) / 2;
  double a = lo, b = hi, c = b - g * (b - a), d = a + g * (b - a);
  double fc = f(c), fd = f(d);
  while (b - a > 1e-10) {
    if (fc < fd) b = d, d = c, fd = fc, c = b - g * (b - a), fc = f(c);
    else a = c, c = d, fc = fd, d = a + g * (b - a), fd = f(d);
  }
  return (a + b) / 2;
}
}  // namespace

// P(V) and P(V) / V are unimodal on (0, U_tip) for Table I-like parameters: the induced term falls
// and the profile and parasite terms rise with V.
double PropulsionModel::max_endurance_speed() const { return golden_min([&](double v) { return power(v); }, 0.0, u_tip_); }

double PropulsionModel::max_range_speed() const {
  return golden_min([&](double v) { return power(v) / v; }, 1e-3, u_tip_);
}

double PropulsionModel::slot_energy(double v, double v_prev, double slot_s) const {
  if (!enabled_) return 0.0;
  const double e = power(v) * slot_s;
  return kinetic_ ? e + std::max(0.0, 0.5 * mass_ * (v * v - v_prev * v_prev)) : e;
}

}  // namespace skyloop
