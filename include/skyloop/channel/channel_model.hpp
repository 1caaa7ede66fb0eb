#pragma once
// The channel-model seam: every UAV-user link's large-scale state (LoS probability and state, path
// loss, shadowing, Rician K) and its small-scale realisation in each fast slot. The system model
// owns one; clusters, networks, the rate oracle, the DP, snapshot reports and Python ask it. The
// path-loss models are listed in channel/path_loss.hpp.
//
// Signal model (shapes as in system_model.hpp). UAV at (x_n, y_n, z_n), user at (x_k, y_k, h_u);
// z_n = H = scenario.altitude_m unless the dynamics choose the altitude (trajectory.mobility =
// grid-3d):
//   d_2D, d_3D, cos(theta_z) = (z_n - h_u) / d_3D, elevation theta = asin((z_n - h_u) / d_3D)
//   beta        = 10^(-(PL_state(d) + S) / 10)     (free-space: beta0 (d0 / d_3D)^2, as the paper)
//   a           = steering vector of cos(theta_z)  [L]
//   h(m)        = sqrt(beta) (sqrt(K / (K + 1)) a + sqrt(1 / (K + 1)) g(m)),  g(m) ~ CN(0, I_L)
//                 (the fading seam, channel/fading.hpp: "none" is h = sqrt(beta) a, K = infinity,
//                 the paper's channel exactly; an NLoS link under "rician" is Rayleigh, K = 0)
//
// Randomness is a fixed map of the city, so a position's channel is a pure function of the
// positions and channel.seed (the rate oracle's memo stays exact, the DP stays the optimum of the
// same problem, and any thread count gives the same numbers):
//   - LoS state and shadowing: for each user, two Gaussian fields over the UAV's horizontal
//     position, i.i.d. N(0, 1) on a lattice of pitch channel.correlation_m keyed by (seed, the
//     user's position, the lattice point), interpolated bilinearly and renormalised to unit variance
//     (continuous, correlated over about one pitch). LoS iff Phi(z_1) < P_LoS(geometry), so the
//     state is LoS with probability exactly P_LoS; S = sigma_state * z_2.
//   - small-scale g(m): i.i.d. per (seed, UAV position (with its altitude where it is not H), user
//     position, fast slot m, antenna), as
//     multipath decorrelates within a wavelength. Revisiting a cell sees the same realisations.
#include <cmath>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "skyloop/channel/path_loss.hpp"
#include "skyloop/core/config.hpp"
#include "skyloop/core/types.hpp"

namespace skyloop {

class FadingModel;

/// Geometry of one link.
struct LinkGeometry {
  double horizontal_m = 0;  // d_2D
  double distance_m = 0;    // d_3D
  double height_m = 0;      // z_n, the UAV's altitude (TR 36.777's h_UT)
  double elevation_deg = 0; // asin((z_n - h_u) / d_3D) in degrees: 90 right above the user
};

/// P_LoS and the mean path loss and shadowing spread of each state, for one path-loss model.
class PathLossModel {
 public:
  virtual ~PathLossModel() = default;
  virtual double p_los(const LinkGeometry& g) const = 0;
  /// Mean path loss of the state (dB, positive).
  virtual double path_loss_db(const LinkGeometry& g, bool los) const = 0;
  /// Standard deviation of the log-normal shadowing of the state (dB).
  virtual double shadowing_std_db(const LinkGeometry& g, bool los) const = 0;
  /// True for the paper's beta0 (d0 / d)^2 itself, which the channel then computes in closed
  /// form, bit for bit as the paper's formula (free-space).
  virtual bool paper() const { return false; }
};

/// The model named by channel.pathloss (with channel.carrier_ghz, channel.environment).
std::unique_ptr<PathLossModel> make_path_loss(const ChannelConfig& c);

/// One link's large-scale state.
struct LinkState {
  LinkGeometry geometry;
  double p_los = 1;          // probability of LoS at this geometry
  bool los = true;           // the state drawn from the city's map
  double path_loss_db = 0;   // mean path loss of the state (free-space: -10 log10 of beta0 (d0/d)^2)
  double shadowing_db = 0;   // the drawn shadowing (0 without)
  double k_factor_db = 0;    // Rician K of the link (+infinity: no scattered part; -infinity: Rayleigh)
  double gain = 1;           // beta = 10^(-(path_loss_db + shadowing_db) / 10)
};

/// The link's reported fields, in order, with their values (los as 0/1; infinities for K as
/// +-inf): what `snapshot --json` and Python's SystemModel.link give.
std::vector<std::pair<std::string, double>> link_fields(const LinkState& s);

class ChannelModel {
 public:
  explicit ChannelModel(const Config& cfg);

  /// The paper's channel: free-space, no fading.
  bool paper() const;
  /// Fast slots per trajectory slot: channel.fast_slots under a random fading model, else 1
  /// (without small-scale fading every fast slot sees the same channel).
  int fast_slots() const;
  /// The fading model (skyloop/channel/fading.hpp).
  const FadingModel& fading() const { return *fading_; }
  int antennas() const { return antennas_; }

  /// d_3D from a UAV at (ux, uy, uz) to the user at (x, y, h_u) (the association's distance;
  /// inline: the association asks it for every user and UAV).
  double distance(double ux, double uy, double uz, double x, double y) const {
    const double dx = ux - x, dy = uy - y, dz = uz - user_height_;
    return std::sqrt(dx * dx + dy * dy + dz * dz);
  }
  /// The same at the scenario's altitude H (uz = scenario.altitude_m).
  double distance(double ux, double uy, double x, double y) const { return distance(ux, uy, altitude_, x, y); }
  /// H - h_u: the height of the UAVs above the users' antennas at the scenario's altitude.
  double height_above_users() const { return altitude_ - user_height_; }
  /// The scenario's altitude H (scenario.altitude_m): where a UAV flies unless its dynamics
  /// choose another.
  double altitude() const { return altitude_; }
  /// The paper's beta0 (d0 / d)^2.
  double free_space_gain(double d) const {
    const double r = d0_ / d;
    return beta0_ * r * r;
  }
  /// The link of a UAV at (ux, uy, uz) to the user at (x, y): its geometry (elevation, height),
  /// large-scale state (P_LoS, path loss, shadowing, K) and its channel h in fast slot `slot`
  /// (0 <= slot < fast_slots()): [L] complex. The overloads without uz fly at H. (channel_at has
  /// a name of its own: channel(ux, uy, x, y, slot) takes five numbers too.)
  LinkGeometry geometry(double ux, double uy, double uz, double x, double y) const;
  LinkState link(double ux, double uy, double uz, double x, double y) const;
  VectorXcd channel_at(double ux, double uy, double uz, double x, double y, int slot = 0) const;
  LinkGeometry geometry(double ux, double uy, double x, double y) const { return geometry(ux, uy, altitude_, x, y); }
  LinkState link(double ux, double uy, double x, double y) const { return link(ux, uy, altitude_, x, y); }
  VectorXcd channel(double ux, double uy, double x, double y, int slot = 0) const { return channel_at(ux, uy, altitude_, x, y, slot); }
  /// Steering vector of cos(theta_z): [L].
  VectorXcd steering(double cos_theta) const;

  /// The fields' values at a UAV position for a user (unit-variance Gaussians; exposed for tests).
  double field(int which, double ux, double uy, double x, double y) const;

 private:
  int antennas_;
  double spacing_, altitude_, user_height_, beta0_, d0_;
  bool free_space_, shadowing_;
  double correlation_;
  std::uint64_t seed_;
  std::shared_ptr<const PathLossModel> path_loss_;
  std::shared_ptr<const FadingModel> fading_;
};

}  // namespace skyloop
