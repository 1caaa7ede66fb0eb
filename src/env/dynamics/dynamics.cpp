// The Dynamics interface's shared parts: the registry, the lattice frame and the lattice move
// sets' breadth-first reachability (skyloop/env/dynamics.hpp).
#include "skyloop/env/dynamics.hpp"

#include <algorithm>
#include <cmath>
#include <deque>
#include <stdexcept>

#include "skyloop/core/error.hpp"
#include "skyloop/core/io.hpp"

namespace skyloop {

// The models' factories (one file each).
std::shared_ptr<const Dynamics> make_grid_dynamics(const Config& cfg);
std::shared_ptr<const Dynamics> make_headings_dynamics(const Config& cfg);
std::shared_ptr<const Dynamics> make_continuous_dynamics(const Config& cfg);
std::shared_ptr<const Dynamics> make_grid3d_dynamics(const Config& cfg);

const Registry<DynamicsFactory>& dynamics_models() {
  static const Registry<DynamicsFactory> models(
      "trajectory.mobility = \"{}\"",
      {
          {"grid", "the paper's five moves of D_fly", make_grid_dynamics},
          {"headings", "8 headings x trajectory.speeds_mps on the D_fly lattice", make_headings_dynamics},
          {"continuous", "a velocity in the disc of v_max_mps, its change bounded by a_max_mps2", make_continuous_dynamics},
          {"grid-3d", "the grid's moves, each holding, climbing or descending by climb_m in [altitude_min_m, altitude_max_m]",
           make_grid3d_dynamics},
      });
  return models;
}

std::shared_ptr<const Dynamics> make_dynamics(const Config& cfg) { return dynamics_models().at(cfg.trajectory.mobility)(cfg); }

std::string lattice_dynamics_names() {
  std::vector<std::string> names;
  for (const auto& m : dynamics_models().rows()) {
    Config c;
    c.trajectory.mobility = m.name;
    if (m.entry(c)->lattice()) names.push_back(m.name);
  }
  std::string out;
  for (std::size_t i = 0; i < names.size(); ++i) out += (i == 0 ? "" : i + 1 == names.size() ? " or " : ", ") + names[i];
  return out;
}

// ---- Dynamics ------------------------------------------------------------------------------------

Dynamics::Dynamics(const Config& cfg) : name_(cfg.trajectory.mobility), pitch_(cfg.trajectory.d_fly_m), slot_s_(cfg.trajectory.slot_s) {}

namespace {
[[noreturn]] void no_commands(const std::string& name, const char* what) {
  throw std::logic_error(std::string("Dynamics::") + what + ": trajectory.mobility = " + name +
                         " takes discrete actions, not velocity commands");
}
}  // namespace

Flight Dynamics::fly_command(int, const Flight&, double, double, const Mission&) const { no_commands(name_, "fly_command"); }

void Dynamics::command_velocity(int, const Flight&, double, double, const Mission&, double&, double&) const {
  no_commands(name_, "command_velocity");
}

void Dynamics::primitive_velocity(int, const Flight&, int, const Mission&, double&, double&) const {
  no_commands(name_, "primitive_velocity");
}

bool Dynamics::chooses_altitude() const { return lattice() && lattice()->levels() > 1; }

bool Dynamics::arrived(double x, double y, double dx, double dy) const { return std::abs(x - dx) < 1e-6 && std::abs(y - dy) < 1e-6; }

void Dynamics::write_previous_action(int last_action, const Flight&, float* o) const {
  for (int a = 0; a < count(); ++a) o[a] = a == last_action ? 1.0f : 0.0f;
}

// ---- the lattice ---------------------------------------------------------------------------------

LatticeFrame::LatticeFrame(double x, double y, double area_x, double area_y, double d, double z)
    : LatticeFrame(x, y, area_x, area_y, d, z, 1.0, 1) {}

LatticeFrame::LatticeFrame(double x, double y, double area_x, double area_y, double d, double floor, double climb, int levels)
    : ox(std::fmod(x, d)), oy(std::fmod(y, d)), pitch(d), oz(floor), pz(climb), nz(levels) {
  const double fx = std::floor((area_x - ox) / d + 1e-9) + 1, fy = std::floor((area_y - oy) / d + 1e-9) + 1;
  if (fx * fy * levels > kMaxLatticeCells) {
    if (levels > 1)
      throw InputError("the lattice of the " + format_double(area_x) + " x " + format_double(area_y) +
                       " m area (scenario.area_x_m x scenario.area_y_m) at trajectory.d_fly_m = " + format_double(d) + " over " +
                       std::to_string(levels) + " altitude levels (trajectory.altitude_min_m .. altitude_max_m by climb_m) has " +
                       format_double(fx * fy * levels) + " points: allowed at most 2^24 (16,777,216): a coarser lattice, "
                       "fewer levels or a smaller area");
    // The finest pitch within the limit: (area_x / d + 1) (area_y / d + 1) <= kMaxLatticeCells.
    const double a = kMaxLatticeCells - 1, b = -(area_x + area_y), c = -area_x * area_y;
    const double finest = (-b + std::sqrt(b * b - 4 * a * c)) / (2 * a);
    throw InputError("the D_fly lattice of the " + format_double(area_x) + " x " + format_double(area_y) +
                     " m area (scenario.area_x_m x scenario.area_y_m) at trajectory.d_fly_m = " + format_double(d) + " has " +
                     format_double(fx * fy) + " points: allowed at most 2^24 (16,777,216), i.e. trajectory.d_fly_m >= " +
                     format_double(std::ceil(finest * 1000) / 1000) + " m on this area (the planners, the headings model and "
                     "the mask's clearances plan on it)");
  }
  nx = static_cast<int>(fx);
  ny = static_cast<int>(fy);
}

int LatticeFrame::cell(double x, double y, double z) const {
  const int iz = nz > 1 ? static_cast<int>(std::lround((z - oz) / pz)) : 0;  // one level: whatever z
  return (iz * ny + static_cast<int>(std::lround((y - oy) / pitch))) * nx + static_cast<int>(std::lround((x - ox) / pitch));
}

int LatticeFrame::find(double x, double y, double z) const {
  const long ix = std::lround((x - ox) / pitch), iy = std::lround((y - oy) / pitch);
  const long iz = nz > 1 ? std::lround((z - oz) / pz) : 0;
  if (ix < 0 || iy < 0 || iz < 0 || ix >= nx || iy >= ny || iz >= nz) return -1;
  return static_cast<int>((iz * ny + iy) * nx + ix);
}

void LatticeDynamics::add(const std::string& name, LatticeStep s, double speed) {
  actions_.names.push_back(name);
  steps_.push_back(s);
  speeds_.push_back(speed);
}

std::vector<int> LatticeDynamics::slots_to(const LatticeFrame& f, int to, const std::vector<char>* closed) const {
  std::vector<int> dist(static_cast<std::size_t>(f.cells()), -1);
  std::deque<int> queue{to};
  dist[static_cast<std::size_t>(to)] = 0;
  // The move set is symmetric (every step has its opposite), so distances to `to` are distances from it.
  while (!queue.empty()) {
    const int c = queue.front();
    queue.pop_front();
    for (const auto& s : steps_) {
      if (s.dx == 0 && s.dy == 0 && s.dz == 0) continue;
      const int j = f.move(c, s);
      if (j < 0) continue;
      auto& d = dist[static_cast<std::size_t>(j)];
      if (closed && (*closed)[static_cast<std::size_t>(j)]) continue;
      if (d < 0) d = dist[static_cast<std::size_t>(c)] + 1, queue.push_back(j);
    }
  }
  return dist;
}

std::vector<int> LatticeDynamics::slots_to(int nx, int ny, int to, const std::vector<char>* closed) const {
  LatticeFrame f;
  f.nx = nx, f.ny = ny;
  return slots_to(f, to, closed);
}

LatticeFrame LatticeDynamics::frame(const Mission& m, int n) const {
  if (levels_ > 1) return LatticeFrame(m.starts(n, 0), m.starts(n, 1), m.area_x, m.area_y, pitch_, floor_, climb_, levels_);
  return LatticeFrame(m.starts(n, 0), m.starts(n, 1), m.area_x, m.area_y, pitch_, m.starts.cols() > 2 ? m.starts(n, 2) : 0.0);
}

double LatticeDynamics::move_energy(int a, const PropulsionModel& propulsion) const {
  return propulsion.slot_energy(speed(a), 0.0, slot_s_) + propulsion.climb_energy(step(a).dz * climb_);
}

Flight LatticeDynamics::fly(int, const Flight& now, int a, const Mission& m) const {
  const LatticeStep s = step(a);
  Flight f;
  f.x = now.x, f.y = now.y, f.z = now.z;
  double nx = now.x, ny = now.y, nz = now.z;
  if (s.dx) nx += s.dx * pitch_;
  if (s.dy) ny += s.dy * pitch_;
  if (s.dz) nz = floor_ + climb_ * (std::lround((now.z - floor_) / climb_) + s.dz);  // on the levels, no drift
  const bool band = !s.dz || (nz >= floor_ - 1e-9 && nz <= floor_ + climb_ * (levels_ - 1) + 1e-9);
  if (!band || !m.contains(nx, ny)) {
    f.inside = false;
    return f;
  }
  f.x = nx, f.y = ny, f.z = nz;
  f.vx = s.dx * pitch_ / slot_s_, f.vy = s.dy * pitch_ / slot_s_, f.vz = s.dz * climb_ / slot_s_;
  f.speed = speed(a);
  return f;
}

namespace {
/// Breadth-first slots over each UAV's lattice through its start.
class LatticeReachability : public Reachability {
 public:
  LatticeReachability(const LatticeDynamics& d, const Mission& m) {
    for (int n = 0; n < static_cast<int>(m.starts.rows()); ++n) {
      Table t;
      t.frame = d.frame(m, n);
      t.slots = d.slots_to(t.frame, t.frame.cell(m.dest_x(n), m.dest_y(n), m.destinations.cols() > 2 ? m.dest_z(n) : 0.0));
      tables_.push_back(std::move(t));
    }
  }
  int slots(int n, const Flight& from, int limit) const override {
    const Table& t = tables_[static_cast<std::size_t>(n)];
    const int c = t.frame.find(from.x, from.y, from.z);
    const int d = c < 0 ? -1 : t.slots[static_cast<std::size_t>(c)];
    return d < 0 ? limit + 1 : d;  // off the lattice or cut off: never reachable in time
  }
  double table_bytes() const override {
    double b = 0;
    for (const auto& t : tables_) b += sizeof(int) * static_cast<double>(t.slots.size());
    return b;
  }

 private:
  struct Table {
    LatticeFrame frame;
    std::vector<int> slots;
  };
  std::vector<Table> tables_;
};
}  // namespace

std::shared_ptr<const Reachability> LatticeDynamics::reachability(const Mission& m) const {
  return std::make_shared<LatticeReachability>(*this, m);
}

std::string LatticeDynamics::unreachable(int n, const Mission& m, const Reachability& r) const {
  Flight start;
  start.x = m.starts(n, 0), start.y = m.starts(n, 1), start.z = m.starts.cols() > 2 ? m.starts(n, 2) : 0.0;
  const int moves = r.slots(n, start, m.t_max);
  return "trajectory: UAV " + std::to_string(n) + " needs " + std::to_string(moves) + " moves from its start to its destination with " +
         moves_text() + " but trajectory.t_max = " + std::to_string(m.t_max) + " allows " + std::to_string(m.t_max - 1) +
         ": allowed trajectory.t_max >= " + std::to_string(moves + 1) + ", or longer moves";
}

}  // namespace skyloop
