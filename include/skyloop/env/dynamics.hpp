#pragma once
// Dynamics: what one action does to a UAV in one slot of delta_t = trajectory.slot_s (beyond the
// paper's fixed-speed grid; its future work "more realistic UAV mobility models"). One interface,
// `Dynamics`, and one registry (dynamics_models(): trajectory.mobility's allowed values, read by
// the configuration table); the environment, the masks and the shield, the planners, the DP, the
// learners, policy files and Python ask the dynamics, never which model it is.
//
//   grid (the paper, Section V-B): UP, DOWN, LEFT, RIGHT, STAY; a move of D_fly along y or x, or
//     none. Ground speed V = D_fly / delta_t (0 for STAY). src/env/dynamics/grid.cpp.
//   headings: for each positive speed v of trajectory.speeds_mps (in the order given), the 8
//     headings E, NE, N, NW, W, SW, S, SE ("E@10" = east at 10 m/s); then HOVER. Speed v moves
//     k = v delta_t / D_fly lattice steps along each axis the heading uses: ground speed v along
//     the axes and sqrt(2) v on the diagonals (king moves keep the lattice). k must be a whole
//     number. src/env/dynamics/headings.cpp.
//   grid-3d: the grid's five moves, each holding the altitude, climbing or descending by
//     trajectory.climb_m within [trajectory.altitude_min_m, trajectory.altitude_max_m]: 15
//     actions, the grid's five first under their names and indices (STAY = hover), then
//     "UP+CLIMB" .. "STAY+CLIMB", then "UP+DESCEND" .. "STAY+DESCEND".
//     src/env/dynamics/grid3d.cpp.
//   continuous: the action is a velocity command u in [-1, 1]^2 (ActionSpec.dims = 2), stretched
//     radially onto the disc of radius v_max, then projected onto what the UAV can fly this slot:
//     the nearest velocity V[t] with |V[t]| <= v_max and |V[t] - V[t-1]| <= a_max delta_t. The UAV
//     moves V[t] delta_t, off the lattice. Discrete choosers use its primitives (8 headings at
//     v_max / 2 and v_max, HOME, HOVER). skyloop/env/continuous.hpp.
//
// Rules shared by every model (UavEnv):
//  - boundary: a move that would leave the area is cancelled (the UAV hovers) and counted;
//  - arrival: Dynamics::arrived (a lattice point; continuous: within trajectory.arrival_m of it at
//    a slot's end, where it is placed on it); an arrived UAV then hovers (continuous: stops);
//  - reachability: Reachability::slots, the fewest slots from a UAV's state to its destination
//    moving inside the area (grid: ceil(|dx| / D_fly) + ceil(|dy| / D_fly); headings: a
//    breadth-first search over the lattice, exact for any speed set; continuous: the slots the
//    HOME command takes, an upper bound the UAV can always keep to, so masks and shield built on
//    it keep every destination reachable);
//  - collision: two UAVs closer than D_min at the end of a slot (positions are sampled per slot);
//  - energy: the UAV's propulsion power at its ground speed (skyloop/env/energy.hpp) times delta_t,
//    plus m g dz for a climb of dz;
//  - altitude: a UAV flies at scenario.altitude_m unless the model chooses it (grid-3d: levels of
//    trajectory.climb_m in [altitude_min_m, altitude_max_m]); a move out of the band is cancelled.
//
// A model whose positions stay on the D_fly lattice through each UAV's start (lattice() non-null)
// gets the exact optimum (the DP), the best-known planner, reserved ways home and the mask's
// clearances; any other names a lattice twin whose optimum is its reference (reference_twin).
// docs/extending/mobility-model.md: adding a model.
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "skyloop/core/config.hpp"
#include "skyloop/core/registry.hpp"
#include "skyloop/core/types.hpp"
#include "skyloop/env/energy.hpp"
#include "skyloop/env/spec.hpp"

namespace skyloop {

/// A UAV's state at the end of a slot: position (z: its altitude), velocity (m/s) and ground
/// speed (what the slot's energy is charged at); `inside` is false when the move was cancelled at
/// the area's boundary or the altitude band's (the UAV hovers where it was, velocity 0).
struct Flight {
  double x = 0, y = 0, z = 0, vx = 0, vy = 0, vz = 0;
  double speed = 0;
  bool inside = true;
};

/// Writes a flight's position into row n of `p` (its altitude too where p has three columns).
inline void place(Positions& p, Eigen::Index n, const Flight& f) {
  p(n, 0) = f.x, p(n, 1) = f.y;
  if (p.cols() > 2) p(n, 2) = f.z;
}

/// What the dynamics sees of a mission: the area, every UAV's start and destination ([N x 3]:
/// x, y and altitude; the altitude is scenario.altitude_m unless the dynamics choose it), T_max.
struct Mission {
  Positions starts, destinations;
  double area_x = 0, area_y = 0;
  int t_max = 0;
  bool contains(double x, double y) const { return x >= -1e-9 && x <= area_x + 1e-9 && y >= -1e-9 && y <= area_y + 1e-9; }
  double dest_x(int n) const { return destinations(n, 0); }
  double dest_y(int n) const { return destinations(n, 1); }
  double dest_z(int n) const { return destinations(n, 2); }
};

/// A move in lattice steps along x, y and (models that choose the altitude) z.
struct LatticeStep {
  int dx = 0, dy = 0, dz = 0;
};

/// The most points a UAV's lattice may have (2^24: its distance tables are 64 MiB of int).
constexpr double kMaxLatticeCells = 16777216.0;

/// The lattice of pitch D_fly through a point, clipped to the area [0, area_x] x [0, area_y]:
/// origin (ox, oy) in [0, pitch), nx x ny points; with nz altitude levels oz, oz + pz, ...,
/// oz + (nz - 1) pz (one level, the UAV's altitude, unless the dynamics choose it). Cell =
/// (iz * ny + iy) * nx + ix. What the environment's reachability, the DP and the best-known
/// planner index positions by (LatticeDynamics::frame makes a UAV's). More than
/// kMaxLatticeCells points is refused (InputError naming the area and trajectory.d_fly_m).
struct LatticeFrame {
  double ox = 0, oy = 0, pitch = 1, oz = 0, pz = 1;
  int nx = 0, ny = 0, nz = 1;
  LatticeFrame() = default;
  /// One level at altitude z.
  LatticeFrame(double x, double y, double area_x, double area_y, double pitch, double z = 0);
  /// `levels` altitudes from `floor` in steps of `climb`.
  LatticeFrame(double x, double y, double area_x, double area_y, double pitch, double floor, double climb, int levels);
  int cells() const { return nx * ny * nz; }
  /// The cell of (x, y, z) rounded to the nearest lattice point (no range check).
  int cell(double x, double y, double z) const;
  /// The cell of (x, y) on the lowest level (a one-level frame's only one).
  int cell(double x, double y) const { return cell(x, y, oz); }
  /// The cell of (x, y, z), or -1 off the frame.
  int find(double x, double y, double z) const;
  int find(double x, double y) const { return find(x, y, oz); }
  /// The cell one step s from c, or -1 off the frame.
  int move(int c, LatticeStep s) const {
    const int ix = c % nx + s.dx, iy = c / nx % ny + s.dy, iz = c / (nx * ny) + s.dz;
    if (ix < 0 || iy < 0 || iz < 0 || ix >= nx || iy >= ny || iz >= nz) return -1;
    return (iz * ny + iy) * nx + ix;
  }
  double x(int c) const { return ox + pitch * (c % nx); }
  double y(int c) const { return oy + pitch * (c / nx % ny); }
  double z(int c) const { return oz + pz * (c / (nx * ny)); }
};

/// The fewest slots home of one mission's UAVs, made once per environment (copies share it):
/// what the masks, the shield, the feasibility check and the reward's T_min-free bound ask.
class Reachability {
 public:
  virtual ~Reachability() = default;
  /// Fewest slots from `from` (position; continuous: and velocity) to UAV n's destination, or
  /// more than `limit` when it cannot be done within `limit` (a model may return any value above).
  virtual int slots(int n, const Flight& from, int limit) const = 0;
  /// Bytes of tables it keeps (for the memory checks).
  virtual double table_bytes() const { return 0; }
};

class LatticeDynamics;

class Dynamics {
 public:
  virtual ~Dynamics() = default;
  /// trajectory.mobility.
  const std::string& name() const { return name_; }
  /// The action space: names, index = action (continuous: the primitives; dims = 2).
  const ActionSpec& actions() const { return actions_; }
  int count() const { return actions_.count(); }
  /// The action that stays in place (grid: STAY = 4; headings and continuous: HOVER, the last).
  int hover() const { return actions_.hover; }
  /// Lattice pitch D_fly (m) and slot duration delta_t (s).
  double pitch() const { return pitch_; }
  double slot_s() const { return slot_s_; }
  /// The longest move along one axis in one slot (m): the paper's T_min = ceil(distance / reach).
  double reach() const { return reach_; }

  // ---- capabilities ----------------------------------------------------------------------------
  /// The lattice move set when positions stay on the D_fly lattice through each UAV's start (the
  /// DP, best-known, ways home and clearances plan on it); null otherwise.
  virtual const LatticeDynamics* lattice() const { return nullptr; }
  /// Whether each UAV chooses its altitude (several altitude levels): the observations' altitude field.
  bool chooses_altitude() const;
  /// Whether the model takes velocity commands (fly_command) beside its discrete primitives.
  bool commands_velocities() const { return actions_.continuous(); }
  /// How a command in [-1, 1]^dims is read (trajectory.command), where the model takes commands;
  /// empty otherwise. A policy file records it.
  virtual std::string command_mode() const { return {}; }

  // ---- one slot --------------------------------------------------------------------------------
  /// Where UAV n at `now` ends the slot under action (primitive) a, inside the mission's area or
  /// cancelled (inside = false). Not called for arrived UAVs (they hover).
  virtual Flight fly(int n, const Flight& now, int a, const Mission& m) const = 0;
  /// Where UAV n at `now` ends the slot under velocity command (vx, vy) m/s (models that take
  /// commands; the others throw std::logic_error).
  virtual Flight fly_command(int n, const Flight& now, double vx, double vy, const Mission& m) const;
  /// The velocity (m/s) command u in [-1, 1]^dims asks for of UAV n at `now` (trajectory.command).
  virtual void command_velocity(int n, const Flight& now, double u0, double u1, const Mission& m, double& vx, double& vy) const;
  /// Primitive a's velocity command (m/s) for UAV n at `now` (HOME depends on where it is).
  virtual void primitive_velocity(int n, const Flight& now, int a, const Mission& m, double& vx, double& vy) const;
  /// Whether a UAV at (x, y) counts as arrived at (dx, dy) (at a reset; fly places a UAV on its
  /// destination where it arrives during a slot).
  virtual bool arrived(double x, double y, double dx, double dy) const;

  // ---- reachability ----------------------------------------------------------------------------
  /// The mission's reachability (tables made here, once; InputError when a destination lies where
  /// the model can never go).
  virtual std::shared_ptr<const Reachability> reachability(const Mission& m) const = 0;
  /// Bytes reachability(m) keeps for a mission over these UAVs' lattices (`cells`: each UAV's
  /// lattice points), for the memory check before it is made.
  virtual double reachability_bytes(double cells) const { return 0; }
  /// Why UAV n cannot reach its destination within T_max - 1 slots: one line naming the settings.
  virtual std::string unreachable(int n, const Mission& m, const Reachability& r) const = 0;

  // ---- observation and reference --------------------------------------------------------------
  /// The observations' previous-action field (ActionSpec's width: one-hot of the last action; a
  /// commanding model: its last velocity / v_max).
  virtual void write_previous_action(int last_action, const Flight& now, float* out) const;
  /// The lattice model whose exact optimum is this model's reference (layout evaluation, the
  /// benchmark), for a model off the lattice; nullopt for a lattice model (its own DP).
  virtual std::optional<Config> reference_twin(const Config& cfg) const { return std::nullopt; }

 protected:
  explicit Dynamics(const Config& cfg);
  std::string name_;
  ActionSpec actions_;
  double pitch_ = 1, slot_s_ = 1, reach_ = 1;
};

/// A model whose moves are lattice steps (grid, headings, grid-3d): each action's step and
/// ground speed, and the breadth-first slots over a lattice. A new lattice move set is a list of
/// steps and speeds (a subclass's constructor) and a line in the registry; one that also climbs
/// sets levels_, floor_ and climb_ (the altitude band).
class LatticeDynamics : public Dynamics {
 public:
  const LatticeDynamics* lattice() const override { return this; }
  LatticeStep step(int a) const { return steps_[static_cast<std::size_t>(a)]; }
  /// Ground speed of action a (m/s).
  double speed(int a) const { return speeds_[static_cast<std::size_t>(a)]; }
  /// Altitude levels a UAV may fly at (1: it keeps its altitude), the lowest (m) and the step
  /// between two (m).
  int levels() const { return levels_; }
  double floor_m() const { return floor_; }
  double climb_m() const { return climb_; }
  /// UAV n's lattice in mission m: through its start, over the model's altitude levels (its
  /// start's altitude alone for a level model).
  LatticeFrame frame(const Mission& m, int n) const;
  /// Propulsion energy (J) of one slot of action a from the hover (PropulsionModel::slot_energy
  /// at its ground speed, plus the climb's m g dz): what the planners price a move at.
  double move_energy(int a, const PropulsionModel& propulsion) const;
  /// Fewest slots from every cell of `frame` to cell `to`, moving inside the lattice
  /// (breadth-first over the moves; -1 where unreachable). With `closed` (one entry per cell,
  /// nonzero = closed), moves never land on a closed cell.
  std::vector<int> slots_to(const LatticeFrame& frame, int to, const std::vector<char>* closed = nullptr) const;
  /// The same on a one-level nx x ny lattice (cell = iy * nx + ix).
  std::vector<int> slots_to(int nx, int ny, int to, const std::vector<char>* closed = nullptr) const;

  Flight fly(int n, const Flight& now, int a, const Mission& m) const override;
  /// Breadth-first tables per UAV lattice (exact for any move set).
  std::shared_ptr<const Reachability> reachability(const Mission& m) const override;
  double reachability_bytes(double cells) const override { return sizeof(int) * cells; }
  std::string unreachable(int n, const Mission& m, const Reachability& r) const override;

 protected:
  explicit LatticeDynamics(const Config& cfg) : Dynamics(cfg) {}
  /// What the moves are, for unreachable()'s message ("moves of trajectory.d_fly_m = 20 m").
  virtual std::string moves_text() const = 0;
  /// Adds action `name` moving `s` lattice steps at ground speed `speed` (m/s).
  void add(const std::string& name, LatticeStep s, double speed);
  std::vector<LatticeStep> steps_;
  std::vector<double> speeds_;
  int levels_ = 1;
  double floor_ = 0, climb_ = 0;
};

/// A model's factory; it validates the model's settings (InputError naming the field).
using DynamicsFactory = std::shared_ptr<const Dynamics> (*)(const Config&);
/// Every model, the paper's first: trajectory.mobility's allowed values, their help and factories.
const Registry<DynamicsFactory>& dynamics_models();
/// The model of cfg.trajectory.mobility (InputError for another name, listing the allowed).
std::shared_ptr<const Dynamics> make_dynamics(const Config& cfg);
/// "grid or headings": the models on the lattice (what the DP and ways home accept).
std::string lattice_dynamics_names();

}  // namespace skyloop
