#pragma once
// The continuous dynamics (trajectory.mobility = "continuous"): a velocity command u in [-1, 1]^2
// (ActionSpec.dims = 2), stretched radially onto the disc of radius v_max (velocity(): the
// square's boundary onto the circle), then projected onto what the UAV can fly this slot: the
// nearest velocity V[t] with |V[t]| <= v_max and |V[t] - V[t-1]| <= a_max delta_t (project()). The
// UAV moves V[t] delta_t, off the lattice. Discrete choosers (Random, Greedy, seqgreedy, the
// Q-learners, the masks and the shield) use its primitives, ActionSpec.names: 8 headings at
// v_max / 2 and v_max ("E@10"), HOME (towards the destination as fast as the UAV can stop in
// time: home_command()) and HOVER (command 0), each a command projected like any other.
//
// Reachability: the slots the HOME command takes from the UAV's position and velocity (a
// simulation of the same dynamics: an upper bound on the fewest, and one the UAV can always keep
// to, so masks and shield built on it keep every destination reachable); out of reach if HOME
// would meet the boundary on the way (a UAV too fast towards an edge to turn within a_max).
// Arrival: within trajectory.arrival_m of the destination at a slot's end (placed on it).
// Its reference is the optimum of its lattice twin: headings at v_max / 2 and v_max.
#include <string>

#include "skyloop/env/dynamics.hpp"

namespace skyloop {

class ContinuousDynamics : public Dynamics {
 public:
  explicit ContinuousDynamics(const Config& cfg);
  double v_max() const { return v_max_; }
  /// Largest change of velocity in one slot, a_max delta_t (m/s).
  double dv_max() const { return dv_max_; }
  double arrival_m() const { return arrival_m_; }
  /// trajectory.command.
  Command command() const { return command_; }
  /// The HOME primitive's index.
  int home() const { return home_; }
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
  /// The inverse of velocity() for a velocity in the disc (outside: clamped to its rim).
  void command(double vx, double vy, double& u0, double& u1) const;
  /// The nearest velocity to (vx, vy) in {|V| <= v_max} n {|V - (px, py)| <= dv_max}, (px, py) the
  /// last slot's velocity (in the first disc, so the set is never empty).
  void project(double vx, double vy, double px, double py, double& ox, double& oy) const;
  /// The HOME command from displacement (dx, dy) to the destination: along it at
  /// min(v_max, |d| / delta_t, sqrt(2 a_max |d|)) (fast enough to stop in time).
  void home_command(double dx, double dy, double& vx, double& vy) const;
  /// One slot from `now` under command (cx, cy) towards destination (dx, dy): projected, moved,
  /// cancelled outside the area, placed on the destination within arrival_m.
  Flight step(const Flight& now, double cx, double cy, double dx, double dy, const Mission& m) const;
  /// Slots the HOME command takes from `from` to (dx, dy), or limit + 1 when more or when HOME
  /// would meet the boundary (then *blocked, when given, is true).
  int home_slots(const Flight& from, double dx, double dy, const Mission& m, int limit, bool* blocked = nullptr) const;

  std::string command_mode() const override { return name_of(command_); }
  Flight fly(int n, const Flight& now, int a, const Mission& m) const override;
  Flight fly_command(int n, const Flight& now, double vx, double vy, const Mission& m) const override;
  void command_velocity(int n, const Flight& now, double u0, double u1, const Mission& m, double& vx, double& vy) const override;
  void primitive_velocity(int n, const Flight& now, int a, const Mission& m, double& vx, double& vy) const override;
  bool arrived(double x, double y, double dx, double dy) const override;
  std::shared_ptr<const Reachability> reachability(const Mission& m) const override;
  std::string unreachable(int n, const Mission& m, const Reachability& r) const override;
  void write_previous_action(int last_action, const Flight& now, float* out) const override;
  /// Headings at v_max / 2 and v_max on the D_fly lattice, no acceleration limit.
  std::optional<Config> reference_twin(const Config& cfg) const override;

 private:
  double v_max_ = 0, dv_max_ = 0, arrival_m_ = 0, a_max_ = 0, a_max_mps2_ = 0;  // a_max_: dv_max / slot_s
  Command command_ = Command::Velocity;
  bool polar_ = false;  // command_ == Command::Polar
  std::vector<double> prim_vx_, prim_vy_;
  int home_ = -1;
};

}  // namespace skyloop
