#pragma once
// Mobility models (beyond the paper's fixed-speed grid; its future work "more realistic UAV
// mobility models"): what one action does to a UAV in one slot of delta_t = trajectory.slot_s.
// Every model moves on the D_fly lattice through the UAV's start, so that reachability is exact
// and the DP stays exact; the action space is the model's ActionSpec, read by the environment,
// the masks and shield, the planners, the DP, the learners, policy files and Python.
//
//   grid (the paper, eq. of Section V-B): UP, DOWN, LEFT, RIGHT, STAY; a move of D_fly along y
//     or x, or none. Ground speed V = D_fly / delta_t (0 for STAY).
//   headings: for each positive speed v of trajectory.speeds_mps (in the order given), the 8
//     headings E, NE, N, NW, W, SW, S, SE ("E@10" = east at 10 m/s); then HOVER. Speed v moves
//     k = v delta_t / D_fly lattice steps along each axis the heading uses: ground speed v along
//     the axes and sqrt(2) v on the diagonals (king moves keep the lattice). k must be a whole number.
//   continuous: the action is a velocity command u in [-1, 1]^2 (ActionSpec.dims = 2), stretched
//     radially onto the disc of radius v_max (velocity(): the square's boundary onto the circle),
//     then projected onto what the UAV can fly this slot: the nearest velocity V[t] with
//     |V[t]| <= v_max and |V[t] - V[t-1]| <= a_max delta_t (project()). The UAV moves V[t] delta_t.
//     Off the lattice: positions are continuous. Planners that choose among discrete actions
//     (Random, Greedy, seqgreedy, the Q-learners, the masks and the shield) use the model's
//     primitives, ActionSpec.names: 8 headings at v_max / 2 and v_max ("E@10"), HOME (towards the
//     destination as fast as the UAV can stop in time: home_command()) and HOVER (command 0), each
//     a command projected like any other.
//
// Rules shared by the models (UavEnv):
//  - boundary: a move that would leave the area is cancelled (the UAV hovers) and counted;
//  - arrival: a UAV is arrived when it stands on its destination (a lattice point; continuous:
//    within trajectory.arrival_m of it at a slot's end, where it is placed on it); it then hovers
//    (continuous: stops, whatever a_max);
//  - reachability: the fewest slots from a lattice point to the destination moving inside the area
//    (grid: ceil(|dx| / D_fly) + ceil(|dy| / D_fly); headings: a breadth-first search over the
//    lattice, exact for any speed set); continuous: the slots the HOME command takes from the
//    UAV's position and velocity (a simulation of the same dynamics: an upper bound on the fewest,
//    and one the UAV can always keep to, so masks and shield built on it keep every destination
//    reachable); out of reach if HOME would meet the boundary on the way (a UAV too fast towards
//    an edge to turn within a_max);
//  - collision: two UAVs closer than D_min at the end of a slot (positions are sampled per slot);
//  - energy: the UAV's propulsion power at its ground speed (skyloop/env/energy.hpp) times delta_t.
#include <string>
#include <vector>

#include "skyloop/core/config.hpp"
#include "skyloop/env/spec.hpp"

namespace skyloop {

struct Config;

struct MobilityInfo {
  const char* name;
  const char* description;
};
/// The mobility models (trajectory.mobility), the paper's first.
extern const MobilityInfo kMobilityModels[3];

/// A move in lattice steps along x and y.
struct LatticeStep {
  int dx = 0, dy = 0;
};

/// The most points a UAV's lattice may have (2^24: its distance tables are 64 MiB of int).
constexpr double kMaxLatticeCells = 16777216.0;

/// The lattice of pitch D_fly through a point, clipped to the area [0, area_x] x [0, area_y]:
/// origin (ox, oy) in [0, pitch), nx x ny points, cell = iy * nx + ix. What the environment's
/// reachability, the DP and the best-known planner index positions by. More than
/// kMaxLatticeCells points is refused (InputError naming the area and trajectory.d_fly_m).
struct LatticeFrame {
  double ox = 0, oy = 0, pitch = 1;
  int nx = 0, ny = 0;
  LatticeFrame() = default;
  LatticeFrame(double x, double y, double area_x, double area_y, double pitch);
  int cells() const { return nx * ny; }
  /// The cell of (x, y) rounded to the nearest lattice point (no range check).
  int cell(double x, double y) const;
  double x(int c) const { return ox + pitch * (c % nx); }
  double y(int c) const { return oy + pitch * (c / nx); }
};

class MobilityModel {
 public:
  explicit MobilityModel(const Config& cfg);
  const std::string& name() const { return name_; }
  bool is_grid() const { return grid_; }
  /// The continuous model: positions off the lattice, actions in [-1, 1]^2 (primitives for
  /// discrete choosers); step() and speed() are the lattice models' only.
  bool continuous() const { return continuous_; }
  /// The discrete action space: names, index = action.
  const ActionSpec& actions() const { return actions_; }
  int count() const { return actions_.count(); }
  /// The action that stays in place (grid: STAY = 4; headings: HOVER, the last).
  int hover() const { return hover_; }
  LatticeStep step(int a) const { return steps_[static_cast<std::size_t>(a)]; }
  /// Lattice pitch D_fly (m) and slot duration delta_t (s).
  double pitch() const { return pitch_; }
  double slot_s() const { return slot_s_; }
  /// Ground speed of action a (m/s).
  double speed(int a) const { return speeds_[static_cast<std::size_t>(a)]; }
  /// The longest move along one axis (m): the paper's T_min = ceil(distance / reach).
  double reach() const { return reach_; }

  // ---- continuous ------------------------------------------------------------------------------
  double v_max() const { return v_max_; }
  /// Largest change of velocity in one slot, a_max delta_t (m/s).
  double dv_max() const { return dv_max_; }
  double arrival_m() const { return arrival_m_; }
  /// The velocity (m/s) of command u in [-1, 1]^2 (each coordinate clamped first): u stretched
  /// radially by |u|_inf / |u|_2, so the square maps onto the disc of radius v_max one to one.
  void velocity(double u0, double u1, double& vx, double& vy) const;
  /// What trajectory.command makes of command u for a UAV whose last velocity is (px, py) and whose
  /// destination lies at displacement (tx, ty).
  ///   velocity: velocity(u0, u1), whatever the UAV flew before;
  ///   polar: speed s = v_max (u0 + 1) / 2 at the UAV's heading (that of its last velocity, or the
  ///     bearing to its destination from a standstill, east on it) turned by u1 times the widest
  ///     turn that a_max allows at s (|V[t] - V[t-1]| <= dv_max; none if the speed change alone
  ///     takes more): u = 0 cruises straight on at v_max / 2, a constant u1 flies a circle, and a
  ///     speed within reach comes with a turn the UAV can make.
  void commanded_velocity(double u0, double u1, double px, double py, double tx, double ty, double& vx, double& vy) const;
  /// trajectory.command (continuous).
  const std::string& command() const { return command_; }
  /// The inverse of velocity() for a velocity in the disc (outside: clamped to its rim).
  void command(double vx, double vy, double& u0, double& u1) const;
  /// The nearest velocity to (vx, vy) in {|V| <= v_max} n {|V - (px, py)| <= dv_max}, (px, py) the
  /// last slot's velocity (in the first disc, so the set is never empty).
  void project(double vx, double vy, double px, double py, double& ox, double& oy) const;
  /// The HOME command from displacement (dx, dy) to the destination: along it at
  /// min(v_max, |d| / delta_t, sqrt(2 a_max |d|)) (fast enough to stop in time).
  void home_command(double dx, double dy, double& vx, double& vy) const;
  /// Primitive a's fixed command velocity (headings and HOVER; HOME is home_command's).
  double primitive_vx(int a) const { return prim_vx_[static_cast<std::size_t>(a)]; }
  double primitive_vy(int a) const { return prim_vy_[static_cast<std::size_t>(a)]; }
  /// The HOME primitive's index.
  int home() const { return home_; }
  /// Fewest slots from every cell of an nx x ny lattice to cell `to`, moving inside the lattice
  /// (breadth-first over the model's moves; -1 where unreachable). Cell = iy * nx + ix. With
  /// `closed` (one entry per cell, nonzero = closed), moves never land on a closed cell.
  std::vector<int> slots_to(int nx, int ny, int to, const std::vector<char>* closed = nullptr) const;

 private:
  std::string name_;
  bool grid_ = true, continuous_ = false, polar_ = false;  // polar_: command_ == "polar", resolved once
  std::string command_ = "velocity";
  ActionSpec actions_;
  std::vector<LatticeStep> steps_;
  std::vector<double> speeds_;
  int hover_ = 0;
  double pitch_ = 1, slot_s_ = 1, reach_ = 1;
  double v_max_ = 0, dv_max_ = 0, arrival_m_ = 0;
  std::vector<double> prim_vx_, prim_vy_;
  int home_ = -1;
};

}  // namespace skyloop
