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


UavEnv::UavEnv(const Config& cfg, std::shared_ptr<RateOracle> oracle) : UavEnv(cfg, std::move(oracle), make_dynamics(cfg)) {}

UavEnv::UavEnv(const Config& cfg, std::shared_ptr<RateOracle> oracle, std::shared_ptr<const Dynamics> dynamics)
    : n_(static_cast<int>(cfg.trajectory.starts.size())),
      t_max_(cfg.trajectory.t_max),
      d_fly_(cfg.trajectory.d_fly_m),
      d_min_(cfg.trajectory.d_min_m),
      w_rate_(cfg.env.w_rate),
      w_arr_(cfg.env.w_arr),
      w_bud_(cfg.env.w_bud),
      w_col_(cfg.env.w_col),
      w_fea_(cfg.env.w_fea),
      dynamics_(std::move(dynamics)),
      propulsion_(cfg.energy),
      objective_kind_(cfg.env.objective),
      bandwidth_hz_(cfg.channel.bandwidth_hz),
      w_energy_(cfg.energy.weight),
      budget_j_(cfg.energy.budget_j),
      objective_reward_(cfg.env.reward == Reward::Objective),
      spec_params_(spec_params(cfg, n_, 0)),
      oracle_(std::move(oracle)) {
  // Every UAV starts and ends at the scenario's altitude H (the third column; dynamics that
  // choose the altitude fly other levels in between).
  auto at_altitude = [&](const Positions& xy) {
    Positions p(xy.rows(), 3);
    p.leftCols(2) = xy;
    p.col(2).setConstant(cfg.scenario.altitude_m);
    return p;
  };
  mission_.starts = at_altitude(positions_in_area(cfg.trajectory.starts, cfg, "trajectory.starts"));
  mission_.destinations = at_altitude(positions_in_area(cfg.trajectory.destinations, cfg, "trajectory.destinations"));
  mission_.area_x = cfg.scenario.area_x_m, mission_.area_y = cfg.scenario.area_y_m;
  mission_.t_max = t_max_;
  spec_params_.users = users();
  spec_params_.action = dynamics_->actions();
  spec_params_.altitude = dynamics_->chooses_altitude();
  spec_ = shared_env_spec(spec_params_);
  world_.velocity = Positions::Zero(n_, 2);
  require_table_memory(cfg, *dynamics_, 1);
  tables_ = std::make_shared<SharedTables>();
  tables_->destinations.resize(static_cast<std::size_t>(n_));
  tables_->made = std::make_unique<std::once_flag[]>(static_cast<std::size_t>(n_));
  reach_ = dynamics_->reachability(mission_);  // InputError where a destination is out of the model's reach
  for (int n = 0; n < n_; ++n)
    if (min_moves(n, mission_.starts(n, 0), mission_.starts(n, 1), mission_.starts(n, 2)) > t_max_ - 1) throw InputError(dynamics_->unreachable(n, mission_, *reach_));
  reset();
}

UavEnv::UavEnv(const UavEnv& like, std::shared_ptr<RateOracle> oracle) : UavEnv(like) { set_oracle(std::move(oracle)); }

void UavEnv::set_oracle(std::shared_ptr<RateOracle> oracle) {
  const double r = oracle->sum_rate(mission_.starts);
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

void UavEnv::reset() { reset(oracle_->sum_rate(mission_.starts)); }

void UavEnv::reset(double start_rate) {
  world_.positions = mission_.starts;
  any_decided_ = false;
  world_.slot = 1;
  world_.arrived.assign(static_cast<std::size_t>(n_), false);
  parked_ = 0;
  parked_tables_.resize(static_cast<std::size_t>(n_));
  for (DistanceTable& table : parked_tables_) table.version = -1;  // made again as the UAVs arrive
  world_.previous_action.assign(static_cast<std::size_t>(n_), hover());
  world_.energy_j.assign(static_cast<std::size_t>(n_), 0.0);
  world_.speed_mps.assign(static_cast<std::size_t>(n_), 0.0);
  world_.power_w.assign(static_cast<std::size_t>(n_), propulsion_.hover_power());
  world_.velocity = Positions::Zero(n_, 2);
  world_.energy_total_j = 0;
  prev_tmin_.assign(static_cast<std::size_t>(n_), 0);
  bool all = true;
  for (int n = 0; n < n_; ++n) {
    world_.arrived[static_cast<std::size_t>(n)] =
        dynamics_->arrived(world_.positions(n, 0), world_.positions(n, 1), mission_.destinations(n, 0), mission_.destinations(n, 1)) && same(world_.positions(n, 2), mission_.destinations(n, 2));
    all = all && world_.arrived[static_cast<std::size_t>(n)];
    parked_ += world_.arrived[static_cast<std::size_t>(n)] ? 1 : 0;
    const double d = std::hypot(mission_.destinations(n, 0) - world_.positions(n, 0), mission_.destinations(n, 1) - world_.positions(n, 1));
    prev_tmin_[static_cast<std::size_t>(n)] = static_cast<int>(std::ceil(d / dynamics_->reach() - 1e-9));
  }
  world_.rates.assign(1, start_rate);
  world_.rate_sum = start_rate;
  done_ = all;
  tot_arr_ = tot_bud_ = tot_col_ = 0;
  tot_reward_ = 0;
}

UavEnv::Landing UavEnv::landing(int n, int a) const {
  if (arrived(n)) {
    Landing l;
    l.x = world_.positions(n, 0), l.y = world_.positions(n, 1), l.z = world_.positions(n, 2);
    return l;
  }
  return dynamics_->fly(n, current(n), a, mission_);
}

UavEnv::Landing UavEnv::landing_velocity(int n, double vx, double vy) const {
  if (!dynamics_->commands_velocities())
    throw std::logic_error("UavEnv::landing_velocity: trajectory.mobility = " + dynamics_->name() + " takes no velocity commands");
  if (arrived(n)) return landing(n, hover());
  return dynamics_->fly_command(n, current(n), vx, vy, mission_);
}

void UavEnv::command_velocity(int n, double u0, double u1, double& vx, double& vy) const {
  dynamics_->command_velocity(n, current(n), u0, u1, mission_, vx, vy);
}

int UavEnv::min_moves(int n, double x, double y, double z) const {
  Landing from;  // at UAV n's current velocity
  from.x = x, from.y = y, from.z = z, from.vx = world_.velocity(n, 0), from.vy = world_.velocity(n, 1);
  return reach_->slots(n, from, t_max_);
}

int UavEnv::min_moves(int n, const Landing& l) const { return reach_->slots(n, l, t_max_); }

UavEnv::Landing UavEnv::current(int n) const {
  Landing l;
  l.x = world_.positions(n, 0), l.y = world_.positions(n, 1), l.z = world_.positions(n, 2), l.vx = world_.velocity(n, 0), l.vy = world_.velocity(n, 1);
  l.speed = world_.speed_mps[static_cast<std::size_t>(n)];
  return l;
}

UavEnv::DistanceTable UavEnv::clear_table(int n, ClearOf what) const {
  const bool parked = what == ClearOf::Parked;
  DistanceTable table;
  table.version = parked ? parked_ : 0;
  table.frame = dynamics_->lattice()->frame(mission_, n);
  const LatticeFrame& f = table.frame;
  std::vector<char> closed(static_cast<std::size_t>(f.cells()), 0);
  // The lattice points strictly within D_min of the other UAVs' destinations or parked
  // positions (collisions()' rule), on every altitude level.
  const int r = static_cast<int>(std::ceil(d_min_ / d_fly_)) + 1;
  for (int m = 0; m < n_; ++m) {
    if (m == n || (parked && !arrived(m))) continue;
    const Positions& at = parked ? world_.positions : mission_.destinations;
    const double px = at(m, 0), py = at(m, 1), pz = at(m, 2);
    const long cx = std::lround((px - f.ox) / d_fly_), cy = std::lround((py - f.oy) / d_fly_);
    for (int iz = 0; iz < f.nz; ++iz) {
      const double dz = f.nz > 1 ? f.oz + f.pz * iz - pz : 0.0;
      for (long iy = std::max(0L, cy - r); iy <= std::min<long>(f.ny - 1, cy + r); ++iy)
        for (long ix = std::max(0L, cx - r); ix <= std::min<long>(f.nx - 1, cx + r); ++ix) {
          const double dx = f.ox + d_fly_ * static_cast<double>(ix) - px, dy = f.oy + d_fly_ * static_cast<double>(iy) - py;
          if (separation(dx, dy, dz) < d_min_ - 1e-9) closed[static_cast<std::size_t>((iz * f.ny + iy) * f.nx + ix)] = 1;
        }
    }
  }
  const int to = f.cell(mission_.destinations(n, 0), mission_.destinations(n, 1), mission_.destinations(n, 2));
  closed[static_cast<std::size_t>(to)] = 0;
  table.slots = dynamics_->lattice()->slots_to(f, to, &closed);
  return table;
}

int UavEnv::min_moves_around(int n, const Landing& l, ClearOf what) const {
  const bool parked = what == ClearOf::Parked;
  if (!dynamics_->lattice() || n_ == 1 || (parked && (parked_ == 0 || (parked_ == 1 && arrived(n))))) return min_moves(n, l);
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
  const int c = table->frame.find(l.x, l.y, l.z);
  const int d = c < 0 ? -1 : table->slots[static_cast<std::size_t>(c)];
  return d < 0 ? t_max_ + 1 : d;
}

void UavEnv::require_table_memory(const Config& cfg, int envs) {
  require_table_memory(cfg, *make_dynamics(cfg), envs);
}

void UavEnv::require_table_memory(const Config& cfg, const Dynamics& dynamics, int envs) {
  const bool clearance = cfg.marl.mask_clearance != Clearance::None && dynamics.lattice();
  const auto& t = cfg.trajectory;
  double cells = 0, most = 0;  // every UAV's lattice points, and the largest lattice's
  for (const Point2& s : t.starts) {
    const double levels = dynamics.lattice() ? dynamics.lattice()->levels() : 1;
    const double c = LatticeFrame(s.x, s.y, cfg.scenario.area_x_m, cfg.scenario.area_y_m, t.d_fly_m).cells() * levels;
    cells += c, most = std::max(most, c);
  }
  const double table = sizeof(int);  // bytes a lattice point takes in one distance table
  const double reach = dynamics.reachability_bytes(cells);
  if (reach <= 0 && !clearance) return;  // no lattice tables
  const bool headings = reach > 0;  // the dynamics keeps tables of its own
  const double shared = reach + (clearance ? table * cells : 0);
  const double per_env = (clearance ? table * cells : 0) + (2 * table + 1) * most;  // Parked; the search's
  const double bytes = shared + per_env * envs, limit = memory_limit_bytes();
  if (limit <= 0 || bytes <= limit) return;  // the message only when it fails
  const std::string model = "trajectory.mobility = \"" + dynamics.name() + "\"";
  const std::string tables = headings && clearance ? model + " and marl.mask_clearance = \"" + name_of(cfg.marl.mask_clearance) + "\""
                             : headings            ? model
                                                   : "marl.mask_clearance = \"" + std::string(name_of(cfg.marl.mask_clearance)) + "\"";
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
  return min_moves(n, l) <= t_max_ - (world_.slot + 1);
}

Positions UavEnv::next_positions(const std::vector<int>& actions) const {
  Positions next = world_.positions;
  for (int n = 0; n < n_; ++n) {
    place(next, n, landing(n, arrived(n) ? hover() : actions[static_cast<std::size_t>(n)]));
  }
  return next;
}

void UavEnv::primitive_velocity(int n, int a, double& vx, double& vy) const {
  dynamics_->primitive_velocity(n, current(n), a, mission_, vx, vy);
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
      if (m != n && separation(p, n, m) < d_min_ - 1e-9) {
        ++count;
        break;
      }
  return count;
}

double UavEnv::separation(const Positions& p, Eigen::Index n, Eigen::Index m) {
  const double dx = p(n, 0) - p(m, 0), dy = p(n, 1) - p(m, 1);
  return separation(dx, dy, p.cols() > 2 ? p(n, 2) - p(m, 2) : 0.0);
}

void UavEnv::check_step(std::size_t count) const {
  if (done_) throw std::logic_error("UavEnv::step called on a finished episode; call reset()");
  if (static_cast<int>(count) != n_)
    throw std::invalid_argument("UavEnv::step: " + std::to_string(count) + " actions for " + std::to_string(n_) + " UAVs");
}

void UavEnv::land(int n, const Landing& l, StepInfo& info) {
  const auto i = static_cast<std::size_t>(n);
  if (!l.inside) ++info.boundary;  // cancelled: the UAV hovers
  const double e = propulsion_.slot_energy(l.speed, world_.speed_mps[i], dynamics_->slot_s()) + propulsion_.climb_energy(l.z - world_.positions(n, 2));
  world_.speed_mps[i] = l.speed;
  world_.power_w[i] = e / dynamics_->slot_s();
  world_.energy_j[i] += e;
  info.energy_j += e;
  world_.velocity(n, 0) = l.vx, world_.velocity(n, 1) = l.vy;
}

Positions UavEnv::begin_step(const std::vector<int>& actions, StepInfo& info) {
  check_step(actions.size());
  any_decided_ = false;
  Positions next = world_.positions;
  for (int n = 0; n < n_; ++n) {
    const int requested = actions[static_cast<std::size_t>(n)];
    if (requested < 0 || requested >= dynamics_->count())
      throw std::invalid_argument("UavEnv::step: action " + std::to_string(requested) + " of UAV " + std::to_string(n) +
                                  " is not one of 0.." + std::to_string(dynamics_->count() - 1) + " (trajectory.mobility = " +
                                  dynamics_->name() + ")");
    const int a = arrived(n) ? hover() : requested;  // arrival-aware: arrived UAVs are locked
    const Landing l = landing(n, a);
    place(next, n, l);
    world_.previous_action[static_cast<std::size_t>(n)] = a;
    land(n, l, info);
  }
  info.collisions = collisions(next);
  return next;
}

Positions UavEnv::begin_step_velocities(const Positions& v, StepInfo& info) {
  any_decided_ = false;
  check_step(static_cast<std::size_t>(v.rows()));
  if (!dynamics_->commands_velocities())
    throw std::invalid_argument("UavEnv::step_velocities: trajectory.mobility = " + dynamics_->name() +
                                " takes discrete actions, not velocity commands");
  Positions next = world_.positions;
  for (int n = 0; n < n_; ++n) {
    if (!std::isfinite(v(n, 0)) || !std::isfinite(v(n, 1)))
      throw std::invalid_argument("UavEnv::step_velocities: the command of UAV " + std::to_string(n) + " is not finite");
    const Landing l = arrived(n) ? landing(n, hover()) : landing_velocity(n, v(n, 0), v(n, 1));
    place(next, n, l);
    world_.previous_action[static_cast<std::size_t>(n)] = hover();
    land(n, l, info);
  }
  info.collisions = collisions(next);
  return next;
}

bool UavEnv::at_destination(const Positions& p, int n) const {
  return same(p(n, 0), mission_.destinations(n, 0)) && same(p(n, 1), mission_.destinations(n, 1)) && same(p(n, 2), mission_.destinations(n, 2));
}

bool UavEnv::ends_episode(const Positions& next) const {
  if (world_.slot + 1 >= t_max_) return true;
  for (int n = 0; n < n_; ++n)
    if (!arrived(n) && !at_destination(next, n)) return false;
  return true;
}

void UavEnv::end_step(const Positions& next, double rate, StepInfo& info) {
  world_.positions = next;
  ++world_.slot;
  bool all = true;
  for (int n = 0; n < n_; ++n) {
    auto&& arrived_n = world_.arrived[static_cast<std::size_t>(n)];
    if (!arrived_n && at_destination(world_.positions, n)) {
      arrived_n = true;
      ++info.arrivals;
      ++parked_;
    }
    all = all && arrived_n;
    info.feasibility += feasibility_indicator(n, world_.positions(n, 0), world_.positions(n, 1), world_.slot);
  }
  const double before = world_.rate_sum / static_cast<double>(world_.slot - 1);
  const double j_before = objective_kind_ == Objective::SumRate ? before : objective_of(world_.rate_sum, world_.slot - 1, world_.energy_total_j);
  world_.energy_total_j += info.energy_j;
  world_.rates.push_back(rate);
  world_.rate_sum += rate;
  info.sum_rate = rate;
  info.avg_rate = world_.rate_sum / static_cast<double>(world_.slot);
  if (objective_reward_ && objective_kind_ == Objective::SumRate)
    info.reward = info.avg_rate - before - w_bud_ * info.boundary - w_col_ * info.collisions;
  else if (objective_reward_)
    info.reward = objective_at() - j_before - w_bud_ * info.boundary - w_col_ * info.collisions;
  else
    info.reward = w_rate_ * info.avg_rate + w_arr_ * info.arrivals - w_bud_ * info.boundary - w_col_ * info.collisions +
                  w_fea_ * info.feasibility;
  info.over_budget = over_budget();
  info.success = all && info.over_budget == 0;
  info.done = done_ = all || world_.slot >= t_max_;
  tot_arr_ += info.arrivals;
  tot_bud_ += info.boundary;
  tot_col_ += info.collisions;
  tot_reward_ += info.reward;
  info.objective = objective();
  info.T = world_.slot;
  info.home = 0;
  for (int n = 0; n < n_; ++n) info.home += arrived(n);
  info.episode_collisions = tot_col_;
  info.episode_boundary = tot_bud_;
  info.episode_reward = tot_reward_;
  info.episode_energy_j = world_.energy_total_j;
  info.sum_rate_objective = sum_rate_objective();
  info.bits_per_joule = bits_per_joule();
}

int UavEnv::feasibility_indicator(int n, double x, double y, int t) {
  const double d = std::hypot(mission_.destinations(n, 0) - x, mission_.destinations(n, 1) - y);
  const int tmin = static_cast<int>(std::ceil(d / dynamics_->reach() - 1e-9));
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

double UavEnv::sum_rate_objective() const { return world_.rate_sum / static_cast<double>(world_.slot); }

double UavEnv::objective_of(double rate_sum, int T, double energy_j) const {
  const double dt = dynamics_->slot_s();
  switch (objective_kind_) {
    case Objective::SumRate: return rate_sum / static_cast<double>(T);
    case Objective::EnergyEfficiency: return energy_j > 0 ? bandwidth_hz_ * dt * rate_sum / energy_j / 1e3 : 0.0;
    case Objective::Weighted: return (rate_sum - w_energy_ * energy_j / dt) / static_cast<double>(T);
    case Objective::Energy: return -energy_j / 1e3;
  }
  return 0;
}

double UavEnv::objective_at() const { return objective_of(world_.rate_sum, world_.slot, world_.energy_total_j); }

double UavEnv::step_energy(const std::vector<int>& actions) const {
  double e = 0;
  for (int n = 0; n < n_; ++n) {
    const Landing l = landing(n, arrived(n) ? hover() : actions[static_cast<std::size_t>(n)]);
    e += propulsion_.slot_energy(l.speed, world_.speed_mps[static_cast<std::size_t>(n)], dynamics_->slot_s()) + propulsion_.climb_energy(l.z - world_.positions(n, 2));
  }
  return e;
}

double UavEnv::objective() const { return objective_at(); }

double UavEnv::bits_per_joule() const {
  return world_.energy_total_j > 0 ? bandwidth_hz_ * dynamics_->slot_s() * world_.rate_sum / world_.energy_total_j : 0.0;
}

int UavEnv::over_budget() const {
  if (budget_j_ <= 0) return 0;
  int count = 0;
  for (const double e : world_.energy_j) count += e > budget_j_;
  return count;
}

int UavEnv::users() const { return static_cast<int>(oracle_->users().rows()); }

}  // namespace skyloop
