#pragma once
// Propulsion energy of a rotary-wing UAV (beyond the paper; its power is what every UAV-network
// paper since reports beside the sum rate).
//
// Source: Y. Zeng, J. Xu and R. Zhang, "Energy Minimization for Wireless Communication With
// Rotary-Wing UAV", IEEE Trans. Wireless Commun. 18(4), 2019, eq. (12) and Table I:
//
//   P(V) = P0 (1 + 3 V^2 / U_tip^2)                                  blade profile
//        + Pi (sqrt(1 + V^4 / (4 v0^4)) - V^2 / (2 v0^2))^(1/2)      induced
//        + (1/2) d0 rho s A V^3                                       parasite
//
// for level flight at speed V (m/s). Table I: P0 = 79.86 W, Pi = 88.63 W, U_tip = 120 m/s,
// v0 = 4.03 m/s, d0 = 0.6, rho = 1.225 kg/m^3, s = 0.05, A = 0.503 m^2 (weight W = 20 N, m = 2.04 kg).
// Hover costs P(0) = P0 + Pi = 168.49 W. Validity: steady level flight, 0 <= V < U_tip (the
// configuration refuses faster moves).
//
// Acceleration (energy.acceleration = "kinetic"): eq. (12) is a steady-flight model and Zeng et
// al. neglect acceleration; between slots of different speeds we add the kinetic energy the
// rotor must supply to speed up, max(0, m (V[t]^2 - V[t-1]^2) / 2), and recover nothing when
// slowing down (no regenerative braking). It is small beside P(V) delta_t at these masses (2 kg
// from 0 to 20 m/s: 408 J vs 2 x 168 J per 2 s slot is not small, which is why it is a setting).
//
// Climbing (dynamics that choose the altitude, trajectory.mobility = "grid-3d"): the work-energy
// theorem's potential term m g dz for a climb of dz > 0, the term by which Zeng, Xu and Zhang
// (Section II) extend the level-flight energy to altitude changes; a descent recovers nothing
// (charged as level flight, as braking is). g = 9.80665 m/s^2, m = energy.mass_kg.
#include <string>

namespace skyloop {

struct EnergyConfig;

class PropulsionModel {
 public:
  explicit PropulsionModel(const EnergyConfig& cfg);
  /// Propulsion power P(V) (W) at ground speed v (m/s); 0 under energy.model = "none".
  double power(double v) const;
  /// P(0) = P0 + Pi.
  double hover_power() const { return power(0.0); }
  /// The speed of least power (maximum endurance), argmin_V P(V).
  double max_endurance_speed() const;
  /// The speed of least energy per metre (maximum range), argmin_V P(V) / V.
  double max_range_speed() const;
  /// Energy (J) of one slot of `slot_s` seconds flown at v after a slot at v_prev.
  double slot_energy(double v, double v_prev, double slot_s) const;
  /// Energy (J) a climb of dz metres adds: m g dz for dz > 0, else 0 (0 under energy.model = "none").
  double climb_energy(double dz) const { return enabled_ && dz > 0 ? mass_ * 9.80665 * dz : 0.0; }
  bool enabled() const { return enabled_; }
  bool kinetic() const { return kinetic_; }

 private:
  bool enabled_, kinetic_;
  double p0_, pi_, u_tip_, v0_, parasite_, mass_;
};

}  // namespace skyloop
