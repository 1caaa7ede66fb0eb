#include "skyloop/env/uav_env.hpp"

#include <algorithm>

#include <cmath>
#include <cstring>
#include <stdexcept>

#include "skyloop/core/config_io.hpp"
#include "skyloop/core/error.hpp"
#include "skyloop/core/io.hpp"
#include "skyloop/core/memory.hpp"
#include "skyloop/core/parallel.hpp"
#include "skyloop/core/rng.hpp"
#include "skyloop/env/layouts.hpp"

namespace skyloop {

Positions make_users(const Config& cfg, int users, std::uint64_t seed) {
  if (!cfg.env.users_file.empty()) {
    const auto lists = read_point_lists(read_file(cfg.env.users_file, "env.users_file"), cfg.env.users_file, {"users"});
    return positions_in_area(lists[0], cfg, cfg.env.users_file + ": users");
  }
  Rng rng(seed);
  return draw_users(cfg.scenario, users, rng);
}

namespace {
bool same(double a, double b) { return std::abs(a - b) < 1e-6; }
}  // namespace

Objective parse_objective(const std::string& s) {
  if (s == "sum-rate") return Objective::SumRate;
  if (s == "energy-efficiency") return Objective::EnergyEfficiency;
  if (s == "weighted") return Objective::Weighted;
  if (s == "energy") return Objective::Energy;
  throw InputError("env.objective = \"" + s + "\" is not allowed: allowed one of sum-rate, energy-efficiency, weighted, energy");
}

UavEnv::UavEnv(const Config& cfg, std::shared_ptr<RateOracle> oracle)
    : n_(static_cast<int>(cfg.trajectory.starts.size())),
      t_max_(cfg.trajectory.t_max),
      d_fly_(cfg.trajectory.d_fly_m),
      d_min_(cfg.trajectory.d_min_m),
      area_x_(cfg.scenario.area_x_m),
      area_y_(cfg.scenario.area_y_m),
      w_rate_(cfg.env.w_rate),
      w_arr_(cfg.env.w_arr),
      w_bud_(cfg.env.w_bud),
      w_col_(cfg.env.w_col),
      w_fea_(cfg.env.w_fea),
      mobility_(std::make_shared<const MobilityModel>(cfg)),
      propulsion_(cfg.energy),
      objective_kind_(parse_objective(cfg.env.objective)),
      bandwidth_hz_(cfg.channel.bandwidth_hz),
      w_energy_(cfg.energy.weight),
      budget_j_(cfg.energy.budget_j),
      compact_(cfg.env.state == "compact"),
      objective_reward_(cfg.env.reward == "objective"),
      spec_params_(spec_params(cfg, n_, 0)),
      start_(positions_in_area(cfg.trajectory.starts, cfg, "trajectory.starts")),
      dest_(positions_in_area(cfg.trajectory.destinations, cfg, "trajectory.destinations")),
      oracle_(std::move(oracle)) {
  spec_params_.users = users();
  spec_ = shared_env_spec(spec_params_);
  vel_ = Positions::Zero(n_, 2);
  require_table_memory(cfg, 1);
  tables_ = std::make_shared<SharedTables>();
  tables_->destinations.resize(static_cast<std::size_t>(n_));
  tables_->made = std::make_unique<std::once_flag[]>(static_cast<std::size_t>(n_));
  if (!mobility_->is_grid() && !mobility_->continuous()) {
    // Each UAV's lattice through its start; its destination must lie on it (validate() checks).
    for (int n = 0; n < n_; ++n) {
      DistanceTable l;
      l.frame = LatticeFrame(start_(n, 0), start_(n, 1), area_x_, area_y_, d_fly_);
      l.slots = mobility_->slots_to(l.frame.nx, l.frame.ny, l.frame.cell(dest_(n, 0), dest_(n, 1)));
      tables_->headings.push_back(std::move(l));
    }
  }
  for (int n = 0; n < n_; ++n) {
    if (!mobility_->is_grid() && !mobility_->continuous()) {
      const DistanceTable& l = tables_->headings[static_cast<std::size_t>(n)];
      if (l.slots[static_cast<std::size_t>(l.frame.cell(start_(n, 0), start_(n, 1)))] < 0)
        throw InputError("trajectory.destinations[" + std::to_string(n) + "] cannot be reached from trajectory.starts[" +
                         std::to_string(n) + "] with trajectory.speeds_mps = " + format_value(FieldValue(cfg.trajectory.speeds_mps)) +
                         " (no speed flies a single lattice step per slot, so some lattice points are out of reach): allowed "
                         "speeds that include trajectory.d_fly_m / trajectory.slot_s = " +
                         format_double(d_fly_ / mobility_->slot_s()) + " m/s");
    }
    if (min_moves(n, start_(n, 0), start_(n, 1)) > t_max_ - 1) throw InputError(unreachable_message(n, cfg));
  }
  reset();
}

UavEnv::UavEnv(const UavEnv& like, std::shared_ptr<RateOracle> oracle) : UavEnv(like) { set_oracle(std::move(oracle)); }

void UavEnv::set_oracle(std::shared_ptr<RateOracle> oracle) {
  const double r = oracle->sum_rate(start_);
  set_oracle(std::move(oracle), r);
}

void UavEnv::set_oracle(std::shared_ptr<RateOracle> oracle, double start_rate) {
  oracle_ = std::move(oracle);
  kernel_axes_.clear();
  if (users() != spec_params_.users) {
    spec_params_.users = users();
    spec_ = shared_env_spec(spec_params_);
  }
  reset(start_rate);
}

void UavEnv::reset() { reset(oracle_->sum_rate(start_)); }

void UavEnv::reset(double start_rate) {
  pos_ = start_;
  any_decided_ = false;
  t_ = 1;
  arrived_.assign(static_cast<std::size_t>(n_), false);
  parked_ = 0;
  parked_tables_.resize(static_cast<std::size_t>(n_));
  for (DistanceTable& table : parked_tables_) table.version = -1;  // made again as the UAVs arrive
  prev_action_.assign(static_cast<std::size_t>(n_), hover());
  energy_.assign(static_cast<std::size_t>(n_), 0.0);
  speed_.assign(static_cast<std::size_t>(n_), 0.0);
  power_.assign(static_cast<std::size_t>(n_), propulsion_.hover_power());
  vel_ = Positions::Zero(n_, 2);
  energy_total_ = 0;
  prev_tmin_.assign(static_cast<std::size_t>(n_), 0);
  bool all = true;
  for (int n = 0; n < n_; ++n) {
    arrived_[static_cast<std::size_t>(n)] = mobility_->continuous()
                                                ? std::hypot(pos_(n, 0) - dest_(n, 0), pos_(n, 1) - dest_(n, 1)) <= mobility_->arrival_m()
                                                : same(pos_(n, 0), dest_(n, 0)) && same(pos_(n, 1), dest_(n, 1));
    all = all && arrived_[static_cast<std::size_t>(n)];
    parked_ += arrived_[static_cast<std::size_t>(n)] ? 1 : 0;
    const double d = std::hypot(dest_(n, 0) - pos_(n, 0), dest_(n, 1) - pos_(n, 1));
    prev_tmin_[static_cast<std::size_t>(n)] = static_cast<int>(std::ceil(d / mobility_->reach() - 1e-9));
  }
  rates_.assign(1, start_rate);
  rate_sum_ = start_rate;
  done_ = all;
  tot_arr_ = tot_bud_ = tot_col_ = 0;
  tot_reward_ = 0;
}

bool UavEnv::move(double x, double y, int a, double& nx, double& ny) const {
  const LatticeStep s = mobility_->step(a);
  nx = x, ny = y;
  if (s.dx) nx += s.dx * d_fly_;
  if (s.dy) ny += s.dy * d_fly_;
  return nx >= -1e-9 && nx <= area_x_ + 1e-9 && ny >= -1e-9 && ny <= area_y_ + 1e-9;
}

UavEnv::Landing UavEnv::landing(int n, int a) const {
  Landing l;
  l.x = pos_(n, 0), l.y = pos_(n, 1);
  if (arrived(n)) return l;
  if (mobility_->continuous()) {
    double vx, vy;
    primitive_velocity(n, a, vx, vy);
    return landing_velocity(n, vx, vy);
  }
  double nx, ny;
  if (!move(l.x, l.y, a, nx, ny)) {
    l.inside = false;
    return l;
  }
  const LatticeStep st = mobility_->step(a);
  l.x = nx, l.y = ny;
  l.vx = st.dx * d_fly_ / mobility_->slot_s(), l.vy = st.dy * d_fly_ / mobility_->slot_s();
  l.speed = mobility_->speed(a);
  return l;
}

namespace {
/// One slot of the continuous dynamics from (x, y) at last velocity (px, py) under command
/// (cx, cy): projected, moved, cancelled outside the area, placed on (dx, dy) within arrival_m.
UavEnv::Landing fly(const MobilityModel& m, double x, double y, double px, double py, double cx, double cy, double area_x,
                    double area_y, double dx, double dy) {
  UavEnv::Landing l;
  m.project(cx, cy, px, py, l.vx, l.vy);
  l.x = x + l.vx * m.slot_s(), l.y = y + l.vy * m.slot_s();
  if (l.x < -1e-9 || l.x > area_x + 1e-9 || l.y < -1e-9 || l.y > area_y + 1e-9) {
    l.x = x, l.y = y, l.vx = l.vy = 0, l.inside = false;
    return l;
  }
  l.speed = std::hypot(l.vx, l.vy);
  if (std::hypot(l.x - dx, l.y - dy) <= m.arrival_m()) l.x = dx, l.y = dy;
  return l;
}
}  // namespace

UavEnv::Landing UavEnv::landing_velocity(int n, double vx, double vy) const {
  if (!mobility_->continuous())
    throw std::logic_error("UavEnv::landing_velocity: velocity commands need trajectory.mobility = continuous");
  if (arrived(n)) return landing(n, hover());
  return fly(*mobility_, pos_(n, 0), pos_(n, 1), vel_(n, 0), vel_(n, 1), vx, vy, area_x_, area_y_, dest_(n, 0), dest_(n, 1));
}

void UavEnv::command_velocity(int n, double u0, double u1, double& vx, double& vy) const {
  mobility_->commanded_velocity(u0, u1, vel_(n, 0), vel_(n, 1), dest_(n, 0) - pos_(n, 0), dest_(n, 1) - pos_(n, 1), vx, vy);
}

void UavEnv::home_velocity(int n, double& vx, double& vy) const {
  mobility_->home_command(dest_(n, 0) - pos_(n, 0), dest_(n, 1) - pos_(n, 1), vx, vy);
}

int UavEnv::home_slots(int n, double x, double y, double vx, double vy, int limit, bool* blocked) const {
  const double dx = dest_(n, 0), dy = dest_(n, 1);
  if (blocked) *blocked = false;
  for (int k = 0; k <= limit; ++k) {
    if (std::hypot(x - dx, y - dy) <= 1e-9) return k;
    double cx, cy;
    mobility_->home_command(dx - x, dy - y, cx, cy);
    const Landing l = fly(*mobility_, x, y, vx, vy, cx, cy, area_x_, area_y_, dx, dy);
    if (!l.inside) {  // HOME would hit the boundary: no way home that keeps a_max
      if (blocked) *blocked = true;
      break;
    }
    x = l.x, y = l.y, vx = l.vx, vy = l.vy;
  }
  return limit + 1;
}

std::string UavEnv::unreachable_message(int n, const Config& cfg) const {
  const std::string who = "trajectory: UAV " + std::to_string(n);
  const std::string allows = "trajectory.t_max = " + std::to_string(t_max_) + " allows " + std::to_string(t_max_ - 1);
  const auto& t = cfg.trajectory;
  if (mobility_->continuous()) {
    // The HOME flight from a standstill without t_max's cap (bounded: a flight that takes more
    // than kLongest slots is reported as such).
    constexpr int kLongest = 10000000;
    const std::string cause = "(trajectory.v_max_mps = " + format_double(t.v_max_mps) + ", a_max_mps2 = " + format_double(t.a_max_mps2) +
                              ", slot_s = " + format_double(t.slot_s) + ")";
    bool blocked = false;
    const int k = home_slots(n, start_(n, 0), start_(n, 1), 0, 0, kLongest, &blocked);
    if (blocked)
      return who + " cannot fly home from its start within the area at its speed and acceleration " + cause +
             ": allowed a start and destination it can fly between without meeting the boundary";
    if (k > kLongest)
      return who + " needs more than " + std::to_string(kLongest) + " slots to fly home from its start " + cause + " but " + allows +
             ": allowed a faster UAV (trajectory.v_max_mps, a_max_mps2) or longer slots (trajectory.slot_s)";
    return who + " needs " + std::to_string(k) + " slots to fly home from its start at its speed and acceleration " + cause + " but " +
           allows + ": allowed trajectory.t_max >= " + std::to_string(k + 1) + ", or a faster UAV";
  }
  const int moves = min_moves(n, start_(n, 0), start_(n, 1));
  const std::string cause = mobility_->is_grid() ? "moves of trajectory.d_fly_m = " + format_double(t.d_fly_m) + " m"
                                                 : "trajectory.speeds_mps = " + format_value(FieldValue(t.speeds_mps)) +
                                                       " on the lattice of trajectory.d_fly_m = " + format_double(t.d_fly_m) + " m";
  return who + " needs " + std::to_string(moves) + " moves from its start to its destination with " + cause + " but " + allows +
         ": allowed trajectory.t_max >= " + std::to_string(moves + 1) + ", or longer moves";
}

int UavEnv::min_moves(int n, double x, double y) const {
  if (mobility_->continuous()) return home_slots(n, x, y, vel_(n, 0), vel_(n, 1), t_max_);
  if (mobility_->is_grid()) {
    const double dx = std::abs(dest_(n, 0) - x), dy = std::abs(dest_(n, 1) - y);
    return static_cast<int>(std::ceil(dx / d_fly_ - 1e-9)) + static_cast<int>(std::ceil(dy / d_fly_ - 1e-9));
  }
  const DistanceTable& l = tables_->headings[static_cast<std::size_t>(n)];
  const long ix = std::lround((x - l.frame.ox) / d_fly_), iy = std::lround((y - l.frame.oy) / d_fly_);
  const int far = t_max_ + 1;  // off the lattice or cut off: never reachable in time
  if (ix < 0 || iy < 0 || ix >= l.frame.nx || iy >= l.frame.ny) return far;
  const int d = l.slots[static_cast<std::size_t>(iy * l.frame.nx + ix)];
  return d < 0 ? far : d;
}

int UavEnv::min_moves(int n, const Landing& l) const {
  if (mobility_->continuous()) return home_slots(n, l.x, l.y, l.vx, l.vy, t_max_);
  return min_moves(n, l.x, l.y);
}

UavEnv::Landing UavEnv::current(int n) const {
  Landing l;
  l.x = pos_(n, 0), l.y = pos_(n, 1), l.vx = vel_(n, 0), l.vy = vel_(n, 1);
  l.speed = speed_[static_cast<std::size_t>(n)];
  return l;
}

UavEnv::DistanceTable UavEnv::clear_table(int n, ClearOf what) const {
  const bool parked = what == ClearOf::Parked;
  DistanceTable table;
  table.version = parked ? parked_ : 0;
  table.frame = mobility_->is_grid() ? LatticeFrame(start_(n, 0), start_(n, 1), area_x_, area_y_, d_fly_)
                                     : tables_->headings[static_cast<std::size_t>(n)].frame;
  const LatticeFrame& f = table.frame;
  std::vector<char> closed(static_cast<std::size_t>(f.cells()), 0);
  // The lattice points strictly within D_min of the other UAVs' destinations or parked
  // positions (collisions()' rule).
  const int r = static_cast<int>(std::ceil(d_min_ / d_fly_)) + 1;
  for (int m = 0; m < n_; ++m) {
    if (m == n || (parked && !arrived(m))) continue;
    const double px = parked ? pos_(m, 0) : dest_(m, 0), py = parked ? pos_(m, 1) : dest_(m, 1);
    const long cx = std::lround((px - f.ox) / d_fly_), cy = std::lround((py - f.oy) / d_fly_);
    for (long iy = std::max(0L, cy - r); iy <= std::min<long>(f.ny - 1, cy + r); ++iy)
      for (long ix = std::max(0L, cx - r); ix <= std::min<long>(f.nx - 1, cx + r); ++ix)
        if (std::hypot(f.ox + d_fly_ * static_cast<double>(ix) - px, f.oy + d_fly_ * static_cast<double>(iy) - py) < d_min_ - 1e-9)
          closed[static_cast<std::size_t>(iy * f.nx + ix)] = 1;
  }
  const int to = f.cell(dest_(n, 0), dest_(n, 1));
  closed[static_cast<std::size_t>(to)] = 0;
  table.slots = mobility_->slots_to(f.nx, f.ny, to, &closed);
  return table;
}

int UavEnv::min_moves_around(int n, const Landing& l, ClearOf what) const {
  const bool parked = what == ClearOf::Parked;
  if (mobility_->continuous() || n_ == 1 || (parked && (parked_ == 0 || (parked_ == 1 && arrived(n))))) return min_moves(n, l);
  const std::size_t i = static_cast<std::size_t>(n);
  const DistanceTable* table = nullptr;
  if (parked) {
    if (parked_tables_[i].version != parked_) parked_tables_[i] = clear_table(n, what);
    table = &parked_tables_[i];
  } else {
    // The destinations never change: the table is made once for every copy of this environment.
    std::call_once(tables_->made[i], [&] { tables_->destinations[i] = clear_table(n, what); });
    table = &tables_->destinations[i];
  }
  const LatticeFrame& f = table->frame;
  const long ix = std::lround((l.x - f.ox) / d_fly_), iy = std::lround((l.y - f.oy) / d_fly_);
  const int far = t_max_ + 1;
  if (ix < 0 || iy < 0 || ix >= f.nx || iy >= f.ny) return far;
  const int d = table->slots[static_cast<std::size_t>(iy * f.nx + ix)];
  return d < 0 ? far : d;
}

void UavEnv::require_table_memory(const Config& cfg, int envs) {
  const MobilityModel mobility(cfg);
  const bool headings = !mobility.is_grid() && !mobility.continuous();
  const bool clearance = cfg.marl.mask_clearance != "none" && !mobility.continuous();
  if (!headings && !clearance) return;  // no lattice tables
  const auto& t = cfg.trajectory;
  double cells = 0, most = 0;  // every UAV's lattice points, and the largest lattice's
  for (const Point2& s : t.starts) {
    const double c = LatticeFrame(s.x, s.y, cfg.scenario.area_x_m, cfg.scenario.area_y_m, t.d_fly_m).cells();
    cells += c, most = std::max(most, c);
  }
  const double table = sizeof(int);  // bytes a lattice point takes in one distance table
  const double shared = ((headings ? 1 : 0) + (clearance ? 1 : 0)) * table * cells;
  const double per_env = (clearance ? table * cells : 0) + (2 * table + 1) * most;  // Parked; the search's
  const double bytes = shared + per_env * envs, limit = memory_limit_bytes();
  if (limit <= 0 || bytes <= limit) return;  // the message only when it fails
  const std::string tables = headings && clearance ? "trajectory.mobility = \"headings\" and marl.mask_clearance = \"" + cfg.marl.mask_clearance + "\""
                             : headings            ? "trajectory.mobility = \"headings\""
                                                   : "marl.mask_clearance = \"" + cfg.marl.mask_clearance + "\"";
  const int uavs = static_cast<int>(t.starts.size());
  require_memory(bytes,
                 "the distance tables of " + tables + " over " + std::to_string(uavs) + " UAVs' lattices of " +
                     format_double(std::round(cells / uavs)) + " points on average (trajectory.d_fly_m = " + format_double(t.d_fly_m) +
                     ") x " + std::to_string(envs) + (envs == 1 ? " environment" : " environments"),
                 envs > 1 && shared + per_env < limit
                     ? "allowed marl.envs <= " + format_double(std::floor((limit - shared) / per_env)) +
                           " for this scenario, or a coarser lattice (trajectory.d_fly_m)"
                     : "allowed a coarser lattice (trajectory.d_fly_m), a smaller area or fewer UAVs");
}

bool UavEnv::feasible(int n, int a) const {
  if (arrived(n)) return a == hover();
  const Landing l = landing(n, a);
  if (!l.inside) return false;
  return min_moves(n, l) <= t_max_ - (t_ + 1);
}

Positions UavEnv::next_positions(const std::vector<int>& actions) const {
  Positions next = pos_;
  for (int n = 0; n < n_; ++n) {
    const Landing l = landing(n, arrived(n) ? hover() : actions[static_cast<std::size_t>(n)]);
    next(n, 0) = l.x, next(n, 1) = l.y;
  }
  return next;
}

void UavEnv::primitive_velocity(int n, int a, double& vx, double& vy) const {
  if (a == mobility_->home()) home_velocity(n, vx, vy);
  else vx = mobility_->primitive_vx(a), vy = mobility_->primitive_vy(a);
}

Positions UavEnv::primitive_velocities(const std::vector<int>& actions) const {
  Positions v = Positions::Zero(n_, 2);
  for (int n = 0; n < n_; ++n) primitive_velocity(n, actions[static_cast<std::size_t>(n)], v(n, 0), v(n, 1));
  return v;
}

int UavEnv::collisions(const Positions& p) const {
  int count = 0;
  for (int n = 0; n < n_; ++n)
    for (int m = 0; m < n_; ++m)
      if (m != n && std::hypot(p(n, 0) - p(m, 0), p(n, 1) - p(m, 1)) < d_min_ - 1e-9) {
        ++count;
        break;
      }
  return count;
}

void UavEnv::check_step(std::size_t count) const {
  if (done_) throw std::logic_error("UavEnv::step called on a finished episode; call reset()");
  if (static_cast<int>(count) != n_)
    throw std::invalid_argument("UavEnv::step: " + std::to_string(count) + " actions for " + std::to_string(n_) + " UAVs");
}

void UavEnv::land(int n, const Landing& l, StepInfo& info) {
  const auto i = static_cast<std::size_t>(n);
  if (!l.inside) ++info.boundary;  // cancelled: the UAV hovers
  const double e = propulsion_.slot_energy(l.speed, speed_[i], mobility_->slot_s());
  speed_[i] = l.speed;
  power_[i] = e / mobility_->slot_s();
  energy_[i] += e;
  info.energy_j += e;
  vel_(n, 0) = l.vx, vel_(n, 1) = l.vy;
}

Positions UavEnv::begin_step(const std::vector<int>& actions, StepInfo& info) {
  check_step(actions.size());
  any_decided_ = false;
  Positions next = pos_;
  for (int n = 0; n < n_; ++n) {
    const int requested = actions[static_cast<std::size_t>(n)];
    if (requested < 0 || requested >= mobility_->count())
      throw std::invalid_argument("UavEnv::step: action " + std::to_string(requested) + " of UAV " + std::to_string(n) +
                                  " is not one of 0.." + std::to_string(mobility_->count() - 1) + " (trajectory.mobility = " +
                                  mobility_->name() + ")");
    const int a = arrived(n) ? hover() : requested;  // arrival-aware: arrived UAVs are locked
    const Landing l = landing(n, a);
    next(n, 0) = l.x, next(n, 1) = l.y;
    prev_action_[static_cast<std::size_t>(n)] = a;
    land(n, l, info);
  }
  info.collisions = collisions(next);
  return next;
}

Positions UavEnv::begin_step_velocities(const Positions& v, StepInfo& info) {
  any_decided_ = false;
  check_step(static_cast<std::size_t>(v.rows()));
  if (!mobility_->continuous())
    throw std::invalid_argument("UavEnv::step_velocities: trajectory.mobility = " + mobility_->name() +
                                " takes discrete actions; velocity commands need continuous");
  Positions next = pos_;
  for (int n = 0; n < n_; ++n) {
    if (!std::isfinite(v(n, 0)) || !std::isfinite(v(n, 1)))
      throw std::invalid_argument("UavEnv::step_velocities: the command of UAV " + std::to_string(n) + " is not finite");
    const Landing l = arrived(n) ? landing(n, hover()) : landing_velocity(n, v(n, 0), v(n, 1));
    next(n, 0) = l.x, next(n, 1) = l.y;
    prev_action_[static_cast<std::size_t>(n)] = hover();
    land(n, l, info);
  }
  info.collisions = collisions(next);
  return next;
}

bool UavEnv::at_destination(const Positions& p, int n) const { return same(p(n, 0), dest_(n, 0)) && same(p(n, 1), dest_(n, 1)); }

bool UavEnv::ends_episode(const Positions& next) const {
  if (t_ + 1 >= t_max_) return true;
  for (int n = 0; n < n_; ++n)
    if (!arrived(n) && !at_destination(next, n)) return false;
  return true;
}

void UavEnv::end_step(const Positions& next, double rate, StepInfo& info) {
  pos_ = next;
  ++t_;
  bool all = true;
  for (int n = 0; n < n_; ++n) {
    auto&& arrived_n = arrived_[static_cast<std::size_t>(n)];
    if (!arrived_n && at_destination(pos_, n)) {
      arrived_n = true;
      ++info.arrivals;
      ++parked_;
    }
    all = all && arrived_n;
    info.feasibility += feasibility_indicator(n, pos_(n, 0), pos_(n, 1), t_);
  }
  const double before = rate_sum_ / static_cast<double>(t_ - 1);
  const double j_before = objective_kind_ == Objective::SumRate ? before : objective_of(rate_sum_, t_ - 1, energy_total_);
  energy_total_ += info.energy_j;
  rates_.push_back(rate);
  rate_sum_ += rate;
  info.sum_rate = rate;
  info.avg_rate = rate_sum_ / static_cast<double>(t_);
  if (objective_reward_ && objective_kind_ == Objective::SumRate)
    info.reward = info.avg_rate - before - w_bud_ * info.boundary - w_col_ * info.collisions;
  else if (objective_reward_)
    info.reward = objective_at() - j_before - w_bud_ * info.boundary - w_col_ * info.collisions;
  else
    info.reward = w_rate_ * info.avg_rate + w_arr_ * info.arrivals - w_bud_ * info.boundary - w_col_ * info.collisions +
                  w_fea_ * info.feasibility;
  info.over_budget = over_budget();
  info.success = all && info.over_budget == 0;
  info.done = done_ = all || t_ >= t_max_;
  tot_arr_ += info.arrivals;
  tot_bud_ += info.boundary;
  tot_col_ += info.collisions;
  tot_reward_ += info.reward;
  info.objective = objective();
  info.T = t_;
  info.home = 0;
  for (int n = 0; n < n_; ++n) info.home += arrived(n);
  info.episode_collisions = tot_col_;
  info.episode_boundary = tot_bud_;
  info.episode_reward = tot_reward_;
  info.episode_energy_j = energy_total_;
  info.sum_rate_objective = sum_rate_objective();
  info.bits_per_joule = bits_per_joule();
}

int UavEnv::feasibility_indicator(int n, double x, double y, int t) {
  const double d = std::hypot(dest_(n, 0) - x, dest_(n, 1) - y);
  const int tmin = static_cast<int>(std::ceil(d / mobility_->reach() - 1e-9));
  const int phi = (tmin <= t_max_ - t && tmin <= prev_tmin_[static_cast<std::size_t>(n)]) ? 1 : -1;
  prev_tmin_[static_cast<std::size_t>(n)] = tmin;
  return phi;
}

StepInfo UavEnv::step(const std::vector<int>& actions) {
  StepInfo info;
  const Positions next = begin_step(actions, info);
  end_step(next, oracle_->sum_rate(next), info);
  return info;
}

StepInfo UavEnv::step_velocities(const Positions& v) {
  StepInfo info;
  const Positions next = begin_step_velocities(v, info);
  end_step(next, oracle_->sum_rate(next), info);
  return info;
}

double UavEnv::sum_rate_objective() const { return rate_sum_ / static_cast<double>(t_); }

double UavEnv::objective_of(double rate_sum, int T, double energy_j) const {
  const double dt = mobility_->slot_s();
  switch (objective_kind_) {
    case Objective::SumRate: return rate_sum / static_cast<double>(T);
    case Objective::EnergyEfficiency: return energy_j > 0 ? bandwidth_hz_ * dt * rate_sum / energy_j / 1e3 : 0.0;
    case Objective::Weighted: return (rate_sum - w_energy_ * energy_j / dt) / static_cast<double>(T);
    case Objective::Energy: return -energy_j / 1e3;
  }
  return 0;
}

double UavEnv::objective_at() const { return objective_of(rate_sum_, t_, energy_total_); }

double UavEnv::step_energy(const std::vector<int>& actions) const {
  double e = 0;
  for (int n = 0; n < n_; ++n) {
    const Landing l = landing(n, arrived(n) ? hover() : actions[static_cast<std::size_t>(n)]);
    e += propulsion_.slot_energy(l.speed, speed_[static_cast<std::size_t>(n)], mobility_->slot_s());
  }
  return e;
}

double UavEnv::objective() const { return objective_at(); }

double UavEnv::bits_per_joule() const {
  return energy_total_ > 0 ? bandwidth_hz_ * mobility_->slot_s() * rate_sum_ / energy_total_ : 0.0;
}

int UavEnv::over_budget() const {
  if (budget_j_ <= 0) return 0;
  int count = 0;
  for (const double e : energy_) count += e > budget_j_;
  return count;
}

void UavEnv::write_observation(int n, float* o) const {
  const auto& users = oracle_->users();
  double mx = 0, my = 0;
  for (Eigen::Index k = 0; k < users.rows(); ++k) mx += users(k, 0) - pos_(n, 0), my += users(k, 1) - pos_(n, 1);
  const double K = static_cast<double>(std::max<Eigen::Index>(1, users.rows()));
  o[0] = static_cast<float>(pos_(n, 0) / area_x_);
  o[1] = static_cast<float>(pos_(n, 1) / area_y_);
  o[2] = static_cast<float>(mx / K / area_x_);
  o[3] = static_cast<float>(my / K / area_y_);
  o[4] = static_cast<float>((dest_(n, 0) - pos_(n, 0)) / area_x_);
  o[5] = static_cast<float>((dest_(n, 1) - pos_(n, 1)) / area_y_);
  write_previous_action(n, o + 6);
}

void UavEnv::write_previous_action(int n, float* o) const {
  if (mobility_->continuous()) {
    o[0] = static_cast<float>(vel_(n, 0) / mobility_->v_max());
    o[1] = static_cast<float>(vel_(n, 1) / mobility_->v_max());
    return;
  }
  for (int a = 0; a < actions(); ++a) o[a] = a == prev_action_[static_cast<std::size_t>(n)] ? 1.0f : 0.0f;
}

std::vector<float> UavEnv::observation(int n) const {
  std::vector<float> o(static_cast<std::size_t>(observation_size()));
  write_observation(n, o.data());
  return o;
}

int UavEnv::users() const { return static_cast<int>(oracle_->users().rows()); }

namespace {
/// The Gaussian kernel of width `width` on a G x G grid of spacing `step` centred on 0 is
/// separable: exp(-(dx - c_i)^2 / (2 s^2)) * exp(-(dy - c_j)^2 / (2 s^2)). One axis's G factors
/// for offset d come from three exponentials and a recurrence (f_{i+1} = f_i r_i, r_{i+1} = r_i q);
/// false (and no factors) where every factor is below e^-24 (4e-11): a point out of reach along
/// one axis adds nothing.
bool kernel_axis(int G, double step, double width, double d, double* f) {
  const double half = (G - 1) / 2.0, inv = 1.0 / (2 * width * width);
  const double g = std::max(0.0, std::abs(d) - half * step);
  if (g * g * inv > 24.0) return false;
  const double q = std::exp(-2 * step * step * inv);
  const double c0 = -half * step;
  f[0] = std::exp(-(d - c0) * (d - c0) * inv);
  double r = std::exp((2 * (d - c0) * step - step * step) * inv);  // f_1 / f_0
  for (int i = 1; i < G; ++i) {
    f[i] = f[i - 1] * r;
    r *= q;
  }
  return true;
}

/// Adds w * fx[i] * fy[j] at every grid point (i, j).
void add_kernel(float* map, int G, const double* fx, const double* fy, double w) {
  for (int j = 0; j < G; ++j)
    for (int i = 0; i < G; ++i) map[j * G + i] += static_cast<float>(w * fx[i] * fy[j]);
}

#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__)
#define SKYLOOP_ENV_CLONES __attribute__((target_clones("avx2", "default"), noinline))
#else
#define SKYLOOP_ENV_CLONES
#endif

/// add_kernel of the points `users` (ascending) on a 7 x 7 map, from factor rows of 8 doubles (the
/// eighth zero). The map is summed in registers, a row of 8 floats per map row, each entry's terms
/// in the same order, each term the same two products and the same float addition as
/// add_kernel's (nothing to contract), so every instruction set writes the same floats as
/// add_kernel point by point.
static_assert(kWideGrid == 7, "add_kernels: a map row is one 8-float vector");
SKYLOOP_ENV_CLONES void add_kernels(float* map, const double* fx, const double* fy, const int* users, std::size_t count,
                                    double w) {
  typedef double d4 __attribute__((vector_size(32), aligned(8), may_alias));
  typedef float f4 __attribute__((vector_size(16)));
  typedef float f8 __attribute__((vector_size(32)));
  constexpr int G = 7, P = 8;
  f8 acc[G];
  for (int j = 0; j < G; ++j)
    for (int i = 0; i < P; ++i) acc[j][i] = i < G ? map[j * G + i] : 0.0f;
  for (std::size_t u = 0; u < count; ++u) {
    const auto k = static_cast<std::size_t>(users[u]) * P;
    const d4 wlo = w * *reinterpret_cast<const d4*>(fx + k), whi = w * *reinterpret_cast<const d4*>(fx + k + 4);
    for (int j = 0; j < G; ++j) {
      const double y = fy[k + static_cast<std::size_t>(j)];
      const f4 lo = __builtin_convertvector(wlo * y, f4), hi = __builtin_convertvector(whi * y, f4);
      acc[j] += __builtin_shufflevector(lo, hi, 0, 1, 2, 3, 4, 5, 6, 7);
    }
  }
  for (int j = 0; j < G; ++j)
    for (int i = 0; i < G; ++i) map[j * G + i] = acc[j][i];
}

/// The kernel of a point at offset (dx, dy), computed afresh.
void add_kernel(float* map, int G, double step, double width, double dx, double dy, double w) {
  double fx[16], fy[16];
  if (!kernel_axis(G, step, width, dx, fx) || !kernel_axis(G, step, width, dy, fy)) return;
  add_kernel(map, G, fx, fy, w);
}
}  // namespace

void UavEnv::write_set_observation(int n, float* o) const {
  const double x = pos_(n, 0), y = pos_(n, 1);
  const int left = t_max_ - t_;
  *o++ = static_cast<float>(x / area_x_);
  *o++ = static_cast<float>(y / area_y_);
  *o++ = static_cast<float>((dest_(n, 0) - x) / area_x_);
  *o++ = static_cast<float>((dest_(n, 1) - y) / area_y_);
  *o++ = static_cast<float>(left - min_moves(n, x, y)) / static_cast<float>(t_max_);
  *o++ = static_cast<float>(t_) / static_cast<float>(t_max_);
  write_previous_action(n, o);
  o += spec_->action.continuous() ? spec_->action.dims : actions();
  constexpr int W = kWideGrid * kWideGrid, Q = kNearGrid * kNearGrid;
  std::fill(o, o + 2 * W + Q, 0.0f);
  const auto& users = oracle_->users();
  const double per_user = 4.0 / static_cast<double>(std::max<Eigen::Index>(1, users.rows()));
  // The users' factors along each axis depend on the UAV's coordinate alone (the users are fixed
  // until set_oracle): computed once per coordinate, a few dozen per episode, where each UAV's
  // each slot would otherwise take five exponentials per user. A user out of reach along one axis
  // has zero factors there: its kernel would add +0 to every (non-negative) entry, so only the
  // users within reach along the axis with fewer of them are visited, in order. The same floats
  // as every kernel computed and added afresh.
  const auto K = users.rows();
  constexpr std::size_t P = kWideGrid + 1;  // factor rows padded with a zero
  auto axis = [&](std::unordered_map<std::uint64_t, KernelAxes::Axis>& index, double at, int dim) {
    std::uint64_t bits;
    std::memcpy(&bits, &at, sizeof bits);
    const auto [it, fresh] = index.try_emplace(bits);
    if (fresh) {
      auto& t = kernel_axes_;
      KernelAxes::Axis& a = it->second;
      a.factors = t.f.size();
      a.reach = t.reach.size();
      t.f.resize(t.f.size() + static_cast<std::size_t>(K) * P, 0.0);
      for (Eigen::Index k = 0; k < K; ++k)
        if (kernel_axis(kWideGrid, 2 * d_fly_, 2 * d_fly_, users(k, dim) - at, t.f.data() + a.factors + static_cast<std::size_t>(k) * P))
          t.reach.push_back(static_cast<int>(k));
      a.count = t.reach.size() - a.reach;
    }
    return it->second;
  };
  // Bounded: continuous moves visit new coordinates every slot (a lattice, a few hundred at most).
  if (kernel_axes_.f.size() + 2 * static_cast<std::size_t>(K) * P > (std::size_t{1} << 21)) kernel_axes_.clear();
  const KernelAxes::Axis ax = axis(kernel_axes_.x, x, 0), ay = axis(kernel_axes_.y, y, 1);
  const KernelAxes::Axis& fewer = ax.count <= ay.count ? ax : ay;
  add_kernels(o, kernel_axes_.f.data() + ax.factors, kernel_axes_.f.data() + ay.factors,
              kernel_axes_.reach.data() + fewer.reach, fewer.count, per_user);
  const Positions& seen = seen_positions();
  for (int m = 0; m < n_; ++m) {
    if (m == n) continue;
    add_kernel(o + W, kWideGrid, 2 * d_fly_, 2 * d_fly_, seen(m, 0) - x, seen(m, 1) - y, 1.0);
    add_kernel(o + 2 * W, kNearGrid, d_fly_, d_fly_ / 2, seen(m, 0) - x, seen(m, 1) - y, 1.0);
  }
  o += 2 * W + Q;
  if (spec_params_.lookahead) {
    write_move_gains(n, o);
    o += actions();
  }
  if (spec_params_.rate_map > 0) write_rate_map(n, o);
}

void UavEnv::show_decided(int m, double x, double y) {
  if (m < 0 || m >= n_) throw std::out_of_range("UavEnv::show_decided: no UAV " + std::to_string(m));
  if (!any_decided_) seen_ = pos_;
  any_decided_ = true;
  seen_(m, 0) = x, seen_(m, 1) = y;
}

void UavEnv::clear_decided() { any_decided_ = false; }

void UavEnv::write_rate_map(int n, float* o) const {
  const auto& cells = rate_map_offsets(spec_params_.rate_map);
  const int C = static_cast<int>(cells.size());
  std::fill(o, o + C, 0.0f);
  if (arrived(n)) return;
  const Positions& seen = seen_positions();
  std::vector<Positions> sets(1, seen);  // sets[0]: where the UAVs are now (the decided ones landed)
  std::vector<int> at(static_cast<std::size_t>(C), -1);
  for (int c = 0; c < C; ++c) {
    const double x = pos_(n, 0) + d_fly_ * cells[static_cast<std::size_t>(c)][0];
    const double y = pos_(n, 1) + d_fly_ * cells[static_cast<std::size_t>(c)][1];
    if (x < 0 || y < 0 || x > area_x_ || y > area_y_) {
      o[c] = -1.0f;
      continue;
    }
    at[static_cast<std::size_t>(c)] = static_cast<int>(sets.size());
    sets.push_back(seen);
    sets.back()(n, 0) = x;
    sets.back()(n, 1) = y;
  }
  const auto r = oracle_->sum_rates(sets);
  const double now = r[0];
  if (!(now > 0)) return;  // the cells inside the area stay 0
  for (int c = 0; c < C; ++c)
    if (const int i = at[static_cast<std::size_t>(c)]; i >= 0)
      o[c] = static_cast<float>(std::tanh(kGainScale * (r[static_cast<std::size_t>(i)] - now) / now));
}

void UavEnv::write_move_gains(int n, float* o) const {
  const int A = actions();
  std::fill(o, o + A, 0.0f);
  if (arrived(n)) return;
  // sets[0]: where the UAVs are now; sets[1 + a]: UAV n after move a. Each set moves one UAV from
  // the one before it (the first: the UAV that chose before n, shown landed), which the oracle
  // reassociates for that UAV alone (RateOracle::keys_of).
  std::vector<Positions> sets(static_cast<std::size_t>(A) + 1, seen_positions());
  for (int a = 0; a < A; ++a) {
    const Landing l = landing(n, a);
    sets[static_cast<std::size_t>(a) + 1](n, 0) = l.x;
    sets[static_cast<std::size_t>(a) + 1](n, 1) = l.y;
  }
  const auto r = oracle_->sum_rates(sets);
  const double now = r[0];
  if (!(now > 0)) return;
  for (int a = 0; a < A; ++a) o[a] = static_cast<float>(std::tanh(kGainScale * (r[static_cast<std::size_t>(a) + 1] - now) / now));
}

void UavEnv::write_compact_state(float* s) const {
  const auto& users = oracle_->users();
  {
    constexpr int G = kStateGrid;
    std::fill(s, s + compact_state_size(), 0.0f);
    auto cell = [&](double x, double y) {
      const int ix = std::min(G - 1, std::max(0, static_cast<int>(x / area_x_ * G)));
      const int iy = std::min(G - 1, std::max(0, static_cast<int>(y / area_y_ * G)));
      return iy * G + ix;
    };
    const float per_user = 1.0f / static_cast<float>(std::max<Eigen::Index>(1, users.rows()));
    const float per_uav = 1.0f / static_cast<float>(n_);
    for (Eigen::Index k = 0; k < users.rows(); ++k) s[cell(users(k, 0), users(k, 1))] += per_user;
    int home = 0;
    for (int n = 0; n < n_; ++n) {
      s[G * G + cell(pos_(n, 0), pos_(n, 1))] += per_uav;
      if (arrived(n)) ++home;
      else s[2 * G * G + cell(dest_(n, 0), dest_(n, 1))] += per_uav;
    }
    s[3 * G * G] = static_cast<float>(t_) / static_cast<float>(t_max_);
    s[3 * G * G + 1] = static_cast<float>(home) * per_uav;
  }
}

void UavEnv::write_state(float* s) const {
  const auto& users = oracle_->users();
  if (compact_) {
    write_compact_state(s);
    return;
  }
  for (int n = 0; n < n_; ++n) *s++ = static_cast<float>(pos_(n, 0) / area_x_), *s++ = static_cast<float>(pos_(n, 1) / area_y_);
  for (Eigen::Index k = 0; k < users.rows(); ++k)
    *s++ = static_cast<float>(users(k, 0) / area_x_), *s++ = static_cast<float>(users(k, 1) / area_y_);
  for (int n = 0; n < n_; ++n) *s++ = static_cast<float>(dest_(n, 0) / area_x_), *s++ = static_cast<float>(dest_(n, 1) / area_y_);
}

void UavEnv::write_agent_context(int n, float* out) const {
  if (!compact_) {
    for (int m = 0; m < n_; ++m) out[m] = m == n ? 1.0f : 0.0f;
    return;
  }
  // The kNeighbours nearest other UAVs (distance, then index), nearest first.
  std::vector<std::pair<double, int>> near;
  for (int m = 0; m < n_; ++m)
    if (m != n) near.emplace_back(std::hypot(pos_(m, 0) - pos_(n, 0), pos_(m, 1) - pos_(n, 1)), m);
  const std::size_t take = std::min<std::size_t>(kNeighbours, near.size());
  std::partial_sort(near.begin(), near.begin() + static_cast<std::ptrdiff_t>(take), near.end());
  std::fill(out, out + 2 * kNeighbours, 0.0f);
  for (std::size_t i = 0; i < take; ++i) {
    const int m = near[i].second;
    out[2 * i] = static_cast<float>((pos_(m, 0) - pos_(n, 0)) / area_x_);
    out[2 * i + 1] = static_cast<float>((pos_(m, 1) - pos_(n, 1)) / area_y_);
  }
}

std::vector<float> UavEnv::state() const {
  std::vector<float> s(static_cast<std::size_t>(state_size()));
  write_state(s.data());
  return s;
}

void UavEnv::write_agent_state(int n, float* out) const {
  write_state(out);
  write_agent_context(n, out + state_size());
  write_observation(n, out + state_size() + agent_context_size());
}

std::vector<float> UavEnv::agent_state(int n) const {
  std::vector<float> s(static_cast<std::size_t>(agent_state_size()));
  write_agent_state(n, s.data());
  return s;
}

void UavEnv::write_obs(int n, float* out) const {
  if (spec_->observation_kind == ObservationKind::Set) write_set_observation(n, out);
  else write_observation(n, out);
}

// ---- VecEnv ---------------------------------------------------------------------------------

VecEnv::VecEnv(const Config& cfg, std::shared_ptr<const Beamformer> beamformer, int count, std::uint64_t seed)
    : cfg_(cfg), beamformer_(std::move(beamformer)), seed_(seed), episodes_(static_cast<std::size_t>(count), 0),
      settled_(static_cast<std::size_t>(count), 0), cost_(static_cast<std::size_t>(count), -1.0),
      prepared_(static_cast<std::size_t>(count)) {
  if (count < 1) throw std::invalid_argument("VecEnv: count = " + std::to_string(count) + ", allowed at least 1");
  // One environment made from the configuration (over environment 0's users), the others copies
  // of it (sharing its lattice tables) with their own users.
  UavEnv::require_table_memory(cfg_, count);
  like_ = std::make_unique<const UavEnv>(cfg_, std::make_shared<RateOracle>(cfg_, beamformer_, users_of(0, 0)));
  envs_.push_back(std::make_unique<UavEnv>(*like_));
  for (int i = 1; i < count; ++i)
    envs_.push_back(std::make_unique<UavEnv>(*like_, std::make_shared<RateOracle>(cfg_, beamformer_, users_of(static_cast<std::size_t>(i), 0))));
}

VecEnv::VecEnv(const Config& cfg, std::shared_ptr<const Beamformer> beamformer, const std::vector<std::uint64_t>& layouts)
    : cfg_(cfg), beamformer_(std::move(beamformer)), seed_(0), episodes_(layouts.size(), 0), settled_(layouts.size(), 0),
      cost_(layouts.size(), -1.0), prepared_(layouts.size()), layouts_(layouts) {
  if (layouts.empty()) throw std::invalid_argument("VecEnv: no layouts, allowed at least 1");
  for (const auto s : layouts) layout_split(s);  // a layout's seed (InputError otherwise)
  UavEnv::require_table_memory(cfg_, static_cast<int>(layouts.size()));
  like_ = std::make_unique<const UavEnv>(cfg_, std::make_shared<RateOracle>(cfg_, beamformer_, users_of(0, 0)));
  envs_.push_back(std::make_unique<UavEnv>(*like_));
  for (std::size_t i = 1; i < layouts.size(); ++i)
    envs_.push_back(std::make_unique<UavEnv>(*like_, std::make_shared<RateOracle>(cfg_, beamformer_, users_of(i, 0))));
}

bool VecEnv::sampling() const {
  return !shared_ && layouts_.empty() && cfg_.env.resample_users && cfg_.env.users_file.empty();
}

Positions VecEnv::users_of(std::size_t i, std::uint64_t episode) const {
  if (!layouts_.empty()) return layout_users(cfg_, layouts_[i]);
  if (sampling()) return layout_users(cfg_, training_layout_seed(seed_, i, episode));
  return make_users(cfg_, cfg_.scenario.users, derive_seed(seed_, static_cast<std::uint64_t>(i)));
}

std::shared_ptr<RateOracle> VecEnv::next_oracle(std::size_t i) const {
  return std::make_shared<RateOracle>(cfg_, beamformer_, users_of(i, episodes_[i] + 1));
}

VecEnv::VecEnv(const Config& cfg, std::shared_ptr<RateOracle> oracle, int count)
    : cfg_(cfg), seed_(0), episodes_(static_cast<std::size_t>(count), 0), settled_(static_cast<std::size_t>(count), 0),
      cost_(static_cast<std::size_t>(count), -1.0), prepared_(static_cast<std::size_t>(count)), shared_(true) {
  if (count < 1) throw std::invalid_argument("VecEnv: count = " + std::to_string(count) + ", allowed at least 1");
  UavEnv::require_table_memory(cfg_, count);
  like_ = std::make_unique<const UavEnv>(cfg_, oracle);
  for (int i = 0; i < count; ++i) envs_.push_back(std::make_unique<UavEnv>(*like_));  // sharing its lattice tables
}

void VecEnv::reset_env(std::size_t i) {
  if (sampling()) {
    // The oracle finish() prepared with its start's rate, else a new one.
    Prepared p = std::move(prepared_[i]);
    prepared_[i] = Prepared{};
    if (!p.oracle) {
      p.oracle = next_oracle(i);
      p.start_rate = p.oracle->sum_rate(envs_[i]->starts());
    }
    ++episodes_[i];
    envs_[i]->set_oracle(std::move(p.oracle), p.start_rate);
  } else {
    ++episodes_[i];
    envs_[i]->reset();
  }
}

void VecEnv::reset() {
  for (std::size_t i = 0; i < envs_.size(); ++i) reset_env(i);
}

Positions VecEnv::begin(int i, const std::vector<int>& actions, StepInfo& info) {
  settled_[static_cast<std::size_t>(i)] = 0;
  cost_[static_cast<std::size_t>(i)] = -1.0;
  return envs_[static_cast<std::size_t>(i)]->begin_step(actions, info);
}

Positions VecEnv::begin_velocities(int i, const Positions& velocities, StepInfo& info) {
  settled_[static_cast<std::size_t>(i)] = 0;
  cost_[static_cast<std::size_t>(i)] = -1.0;
  return envs_[static_cast<std::size_t>(i)]->begin_step_velocities(velocities, info);
}

bool VecEnv::settle(int i, const Positions& next, StepInfo& info) {
  if (shared_) return false;
  const auto ii = static_cast<std::size_t>(i);
  const auto rate = envs_[ii]->oracle().cached_sum_rate(next, &cost_[ii]);
  if (!rate) return false;
  envs_[ii]->end_step(next, *rate, info);
  if (info.done) reset_env(ii);
  settled_[ii] = 1;
  return true;
}

std::vector<StepInfo> VecEnv::step(const std::vector<std::vector<int>>& actions,
                                   const std::function<void(std::size_t)>& before_reset) {
  std::vector<StepInfo> info(envs_.size());
  std::vector<Positions> next(envs_.size());
  for (int i = 0; i < size(); ++i) next[static_cast<std::size_t>(i)] = begin(i, actions[static_cast<std::size_t>(i)], info[static_cast<std::size_t>(i)]);
  return finish(next, info, before_reset);
}

std::vector<StepInfo> VecEnv::step_velocities(const std::vector<Positions>& velocities,
                                              const std::function<void(std::size_t)>& before_reset) {
  std::vector<StepInfo> info(envs_.size());
  std::vector<Positions> next(envs_.size());
  for (int i = 0; i < size(); ++i)
    next[static_cast<std::size_t>(i)] = begin_velocities(i, velocities[static_cast<std::size_t>(i)], info[static_cast<std::size_t>(i)]);
  return finish(next, info, before_reset);
}

std::vector<StepInfo> VecEnv::finish(std::vector<Positions>& next, std::vector<StepInfo>& info,
                                     const std::function<void(std::size_t)>& before_reset) {
  const std::size_t m = envs_.size();
  std::vector<std::size_t> open;  // the environments whose step is still to end
  for (std::size_t i = 0; i < m; ++i)
    if (!settled_[i]) open.push_back(i);
  // Oracles of their own (no memo shared): the open environments in lanes, one per thread (below).
  // A shared oracle: one batch, its misses split over the threads. The steps end once every rate
  // is known.
  int threads = 1;
  if (!shared_ && !in_parallel_for())
    for (std::size_t i : open) threads = std::max(threads, envs_[i]->oracle().threads());
  // Under one band a network's beams may depend, in their last bits, on the other networks of
  // its batch (RateOracle::joint): oracles of their own then keep one lane per environment, the
  // same company on any thread count (an MPI rank's one core or a machine's all).
  bool per_environment = !shared_;
  for (std::size_t i : open) per_environment = per_environment && envs_[i]->oracle().joint();
  per_environment = per_environment && !open.empty();
  const std::size_t lanes = per_environment ? open.size() : std::min(open.size(), static_cast<std::size_t>(threads));
  // The environments whose episode this step ends: their next oracle's start in the same batch.
  std::vector<char> ends(open.size(), 0);
  for (std::size_t j = 0; j < open.size() && sampling(); ++j) ends[j] = envs_[open[j]]->ends_episode(next[open[j]]);
  // The lanes: each open environment's place in `open`, in order. Where settle() weighed every
  // open environment by its misses (and an ending one by its next start's, every cluster a miss),
  // the heaviest first to the lighter lane; else contiguous runs of equal count.
  std::vector<std::vector<std::size_t>> lane_of(lanes);
  bool weighed = lanes > 1 && !per_environment;
  for (std::size_t i : open) weighed = weighed && cost_[i] >= 0;
  if (weighed) {
    std::vector<double> weight(open.size());
    std::vector<std::size_t> heaviest(open.size());
    for (std::size_t j = 0; j < open.size(); ++j) {
      const UavEnv& e = *envs_[open[j]];
      weight[j] = cost_[open[j]] + (ends[j] ? static_cast<double>(e.users() + e.uavs()) : 0.0);
      heaviest[j] = j;
    }
    std::stable_sort(heaviest.begin(), heaviest.end(), [&](std::size_t a, std::size_t b) { return weight[a] > weight[b]; });
    std::vector<double> load(lanes, 0.0);
    for (std::size_t j : heaviest) {
      const auto lane = static_cast<std::size_t>(std::min_element(load.begin(), load.end()) - load.begin());
      load[lane] += weight[j];
      lane_of[lane].push_back(j);
    }
    for (auto& l : lane_of) std::sort(l.begin(), l.end());
  } else {
    for (std::size_t lane = 0; lane < lanes; ++lane)
      for (std::size_t j = open.size() * lane / lanes; j < open.size() * (lane + 1) / lanes; ++j) lane_of[lane].push_back(j);
  }
  // Each lane's misses one batch on a thread of its own: a cluster's rate is designed per cluster,
  // so the rates do not depend on the lanes (nor, one lane per environment, a network's).
  std::vector<double> rates(open.size());
  parallel_for(lanes, static_cast<int>(std::min(lanes, static_cast<std::size_t>(threads))), [&](std::size_t lane) {
    const auto& mine = lane_of[lane];
    std::vector<RateOracle*> oracles;
    std::vector<const Positions*> ptrs;
    for (std::size_t j : mine) {
      oracles.push_back(&envs_[open[j]]->oracle());
      ptrs.push_back(&next[open[j]]);
    }
    // An episode this step ends: its environment's next oracle, the start's rate in the same batch
    // (kept for reset_env only once the batch has succeeded).
    std::vector<std::size_t> ending;
    std::vector<std::shared_ptr<RateOracle>> fresh;
    for (std::size_t j : mine) {
      if (!ends[j]) continue;
      const std::size_t i = open[j];
      ending.push_back(i);
      fresh.push_back(next_oracle(i));
      oracles.push_back(fresh.back().get());
      ptrs.push_back(&envs_[i]->starts());
    }
    const auto r = batch_sum_rates(oracles, ptrs);
    for (std::size_t k = 0; k < mine.size(); ++k) rates[mine[k]] = r[k];
    for (std::size_t k = 0; k < ending.size(); ++k) prepared_[ending[k]] = Prepared{std::move(fresh[k]), r[mine.size() + k]};
  });
  for (std::size_t j = 0; j < open.size(); ++j) {
    const std::size_t i = open[j];
    envs_[i]->end_step(next[i], rates[j], info[i]);
    if (info[i].done) {
      if (before_reset) before_reset(i);
      reset_env(i);
    }
  }
  std::fill(settled_.begin(), settled_.end(), 0);
  return info;
}

}  // namespace skyloop
