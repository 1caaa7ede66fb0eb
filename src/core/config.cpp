#include "skyloop/core/config.hpp"
#include "skyloop/core/rng.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <sstream>

#include "skyloop/core/error.hpp"
#include "skyloop/core/io.hpp"
#include "skyloop/beamforming/registry.hpp"
#include "skyloop/channel/path_loss.hpp"
#include "skyloop/env/dynamics.hpp"
#include "skyloop/marl/learners.hpp"

namespace skyloop {

namespace {
using Type = Field::Type;
std::string format_number(double x) { return format_double(x); }
}  // namespace

std::string Field::allowed() const {
  switch (type) {
    case Type::Boolean: return "true or false";
    case Type::Integer:
      return "an integer in [" + std::to_string(static_cast<long long>(lo)) + ", " +
             std::to_string(static_cast<long long>(hi)) + "]";
    case Type::Real: return "a number in [" + format_number(lo) + ", " + format_number(hi) + "]";
    case Type::Text: {
      if (choices.empty()) return "a string";
      std::string s = "one of ";
      for (std::size_t i = 0; i < choices.size(); ++i) s += (i ? ", " : "") + choices[i];
      return s;
    }
    case Type::Points: return "a non-empty list of [x, y] pairs";
    case Type::Reals: return "a non-empty list of numbers, each in [" + format_number(lo) + ", " + format_number(hi) + "]";
  }
  return {};
}


const Field* find_field(const std::string& key) {
  for (const auto& f : config_fields())
    if (f.key == key) return &f;
  return nullptr;
}

std::string toml_string(const std::string& s) {
  std::string out = "\"";
  for (const char ch : s) {
    const auto u = static_cast<unsigned char>(ch);
    switch (ch) {
      case '"': out += "\\\""; break;
      case '\\': out += "\\\\"; break;
      case '\n': out += "\\n"; break;
      case '\t': out += "\\t"; break;
      case '\r': out += "\\r"; break;
      default:
        if (u < 0x20 || u == 0x7f) {
          char buf[8];
          std::snprintf(buf, sizeof buf, "\\u%04X", u);
          out += buf;
        } else {
          out += ch;
        }
    }
  }
  return out + "\"";
}

std::string format_value(const FieldValue& v) {
  struct V {
    std::string operator()(bool b) const { return b ? "true" : "false"; }
    std::string operator()(std::int64_t i) const { return std::to_string(i); }
    std::string operator()(double d) const {
      std::string s = format_double(d);
      if (s.find_first_of(".eninf") == std::string::npos) s += ".0";
      return s;
    }
    std::string operator()(const std::string& s) const { return toml_string(s); }
    std::string operator()(const std::vector<Point2>& p) const {
      std::string s = "[";
      for (std::size_t i = 0; i < p.size(); ++i)
        s += (i ? ", [" : "[") + (*this)(p[i].x) + ", " + (*this)(p[i].y) + "]";
      return s + "]";
    }
    std::string operator()(const std::vector<double>& p) const {
      std::string s = "[";
      for (std::size_t i = 0; i < p.size(); ++i) s += (i ? ", " : "") + (*this)(p[i]);
      return s + "]";
    }
  };
  return std::visit(V{}, v);
}

void set_field(Config& cfg, const Field& field, const FieldValue& value) {
  auto fail = [&](const std::string& why) {
    throw InputError(field.key + " = " + format_value(value) + " " + why + ": allowed " + field.allowed());
  };
  switch (field.type) {
    case Type::Boolean:
      if (!std::holds_alternative<bool>(value)) fail("has the wrong type");
      field.set(cfg, value);
      return;
    case Type::Integer: {
      if (!std::holds_alternative<std::int64_t>(value)) fail("has the wrong type");
      // Compared as integers: a double holds 2^62 + 1 as 2^62 and would let it through.
      const std::int64_t i = std::get<std::int64_t>(value);
      if (i < static_cast<std::int64_t>(field.lo) || i > static_cast<std::int64_t>(field.hi)) fail("is out of range");
      field.set(cfg, value);
      return;
    }
    case Type::Real: {
      double d;
      if (std::holds_alternative<double>(value)) d = std::get<double>(value);
      else if (std::holds_alternative<std::int64_t>(value)) d = static_cast<double>(std::get<std::int64_t>(value));
      else fail("has the wrong type");
      if (!std::isfinite(d) || d < field.lo || d > field.hi) fail("is out of range");
      field.set(cfg, FieldValue(d));
      return;
    }
    case Type::Text: {
      if (!std::holds_alternative<std::string>(value)) fail("has the wrong type");
      const auto& s = std::get<std::string>(value);
      if (!field.choices.empty() && std::find(field.choices.begin(), field.choices.end(), s) == field.choices.end())
        fail("is not allowed");
      field.set(cfg, value);
      return;
    }
    case Type::Points: {
      if (!std::holds_alternative<std::vector<Point2>>(value)) fail("has the wrong type");
      const auto& p = std::get<std::vector<Point2>>(value);
      if (p.empty()) fail("is empty");
      for (const auto& q : p)
        if (!std::isfinite(q.x) || !std::isfinite(q.y)) fail("has a non-finite coordinate");
      field.set(cfg, value);
      return;
    }
    case Type::Reals: {
      std::vector<double> r;
      if (const auto* list = std::get_if<std::vector<double>>(&value)) r = *list;
      else fail("has the wrong type");
      if (r.empty()) fail("is empty");
      for (const double x : r)
        if (!std::isfinite(x) || x < field.lo || x > field.hi) fail("is out of range");
      field.set(cfg, FieldValue(r));
      return;
    }
  }
}

void generate_layout(Config& c) {
  const auto& t = c.trajectory;
  const int N = c.scenario.uavs;
  const double d = t.d_fly_m;
  // Lattice points x = d * i, i = 1 .. nx, inside [d, area - d].
  const int nx = static_cast<int>(std::floor(c.scenario.area_x_m / d + 1e-9)) - 1;
  const int ny = static_cast<int>(std::floor(c.scenario.area_y_m / d + 1e-9)) - 1;
  const std::string what = "trajectory.layout = \"generated\" for scenario.uavs = " + std::to_string(N) + " on a " +
                           format_double(c.scenario.area_x_m) + " x " + format_double(c.scenario.area_y_m) +
                           " m area with trajectory.d_fly_m = " + format_double(d);
  if (nx < 1 || ny < 1 || static_cast<long>(nx) * ny < 2L * N)
    throw InputError(what + " has only " + std::to_string(std::max(0, nx) * std::max(0, ny)) +
                     " lattice points: allowed at least 2 per UAV (a larger area or a smaller D_fly)");
  Rng rng(derive_seed(t.layout_seed, 0x4c41594f5554ULL));  // "LAYOUT"
  auto far_enough = [&](const std::vector<Point2>& pts, const Point2& p) {
    for (const auto& q : pts)
      if (std::hypot(p.x - q.x, p.y - q.y) < t.d_min_m - 1e-9 || p == q) return false;
    return true;
  };
  auto draw = [&] { return Point2{d * static_cast<double>(1 + rng.below(static_cast<std::uint64_t>(nx))),
                                  d * static_cast<double>(1 + rng.below(static_cast<std::uint64_t>(ny)))}; };
  constexpr int kTries = 100000;
  std::vector<Point2> starts, dests;
  for (int n = 0; n < N; ++n) {
    int tries = 0;
    Point2 p = draw();
    while (!far_enough(starts, p) && ++tries < kTries) p = draw();
    if (tries >= kTries)
      throw InputError(what + " cannot place " + std::to_string(N) + " starts D_min = " + format_double(t.d_min_m) +
                       " m apart: allowed fewer UAVs, a larger area or a smaller trajectory.d_min_m");
    starts.push_back(p);
  }
  for (int n = 0; n < N; ++n) {
    const Point2 s0 = starts[static_cast<std::size_t>(n)];
    auto ok = [&](const Point2& p) {
      const double moves = (std::abs(p.x - s0.x) + std::abs(p.y - s0.y)) / d;
      return moves >= 1 - 1e-9 && moves <= t.t_max - 1 + 1e-9 && far_enough(dests, p);
    };
    int tries = 0;
    Point2 p = draw();
    while (!ok(p) && ++tries < kTries) p = draw();
    if (tries >= kTries)
      throw InputError(what + " cannot place destination " + std::to_string(n) + " within trajectory.t_max - 1 = " +
                       std::to_string(t.t_max - 1) + " moves of its start and D_min from the others: allowed a larger "
                       "trajectory.t_max or fewer UAVs");
    dests.push_back(p);
  }
  c.trajectory.starts = std::move(starts);
  c.trajectory.destinations = std::move(dests);
}

long lattice_steps(double v, double slot_s, double pitch) {
  const double k = v * slot_s / pitch;
  const long r = std::lround(k);
  return std::abs(k - static_cast<double>(r)) < 1e-6 ? r : -1;
}

void finalise(Config& c) {
  if (c.trajectory.layout == LayoutSource::Generated) generate_layout(c);
  validate(c);
}

void validate(const Config& c) {
  const auto& t = c.trajectory;
  if (t.starts.size() != t.destinations.size())
    throw InputError("trajectory.destinations has " + std::to_string(t.destinations.size()) +
                     " points but trajectory.starts has " + std::to_string(t.starts.size()) +
                     ": allowed one destination per start");
  auto check_in_area = [&](const std::vector<Point2>& pts, const std::string& key) {
    for (std::size_t i = 0; i < pts.size(); ++i) {
      const auto& p = pts[i];
      if (!(p.x >= 0 && p.x <= c.scenario.area_x_m && p.y >= 0 && p.y <= c.scenario.area_y_m))  // NaN fails too
        throw InputError(key + "[" + std::to_string(i) + "] = [" + format_double(p.x) + ", " + format_double(p.y) + "]" +
                         " is outside the area: allowed x in [0, " + format_double(c.scenario.area_x_m) +
                         "], y in [0, " + format_double(c.scenario.area_y_m) + "]");
    }
  };
  check_in_area(t.starts, "trajectory.starts");
  check_in_area(t.destinations, "trajectory.destinations");
  // A UAV moves D_fly along x or y per slot: its destination must differ from its start and lie on
  // the D_fly lattice through it, or no sequence of moves ever arrives.
  for (std::size_t i = 0; i < t.starts.size(); ++i) {
    const auto& s = t.starts[i];
    const auto& d = t.destinations[i];
    const std::string where = "trajectory.destinations[" + std::to_string(i) + "] = [" + format_double(d.x) + ", " +
                              format_double(d.y) + "]";
    if (std::abs(d.x - s.x) < 1e-6 && std::abs(d.y - s.y) < 1e-6)
      throw InputError(where + " equals trajectory.starts[" + std::to_string(i) + "]: allowed a destination at least one move "
                       "(trajectory.d_fly_m) from its start");
    const double fx = (d.x - s.x) / t.d_fly_m, fy = (d.y - s.y) / t.d_fly_m;
    if (std::abs(fx - std::round(fx)) > 1e-6 || std::abs(fy - std::round(fy)) > 1e-6)
      throw InputError(where + " is not on the D_fly grid of trajectory.starts[" + std::to_string(i) + "] = [" +
                       format_double(s.x) + ", " + format_double(s.y) + "]: allowed a destination whose x and y differ from "
                       "the start's by whole multiples of trajectory.d_fly_m = " + format_double(t.d_fly_m));
  }
  const int kmin = c.env.users_min ? c.env.users_min : c.scenario.users, kmax = c.env.users_max ? c.env.users_max : c.scenario.users;
  if (kmin > kmax)
    throw InputError("env.users_min = " + std::to_string(kmin) + " is above env.users_max = " + std::to_string(kmax) +
                     ": allowed users_min <= users_max (0 = scenario.users)");
  if (kmin != kmax && c.env.state == StateKind::Paper)
    throw InputError("env.users_min = " + std::to_string(kmin) + " and env.users_max = " + std::to_string(kmax) +
                     " give layouts of different sizes, but env.state = \"paper\" has 4N + 2K reals: allowed env.state = \"compact\"");
  if (!(c.scenario.user_height_m < c.scenario.altitude_m))
    throw InputError("scenario.user_height_m = " + format_double(c.scenario.user_height_m) + " is not below scenario.altitude_m = " +
                     format_double(c.scenario.altitude_m) + ": allowed user_height_m < altitude_m");
  // Every link at least the reference distance long: the path-loss models hold from d0 on (the
  // free-space law beta0 (d0 / d)^2 would exceed beta0 below it).
  if (c.scenario.altitude_m - c.scenario.user_height_m < c.channel.d0_m)
    throw InputError("scenario.user_height_m = " + format_double(c.scenario.user_height_m) + " is " +
                     format_double(c.scenario.altitude_m - c.scenario.user_height_m) + " m below scenario.altitude_m = " +
                     format_double(c.scenario.altitude_m) + ", less than channel.d0_m = " + format_double(c.channel.d0_m) +
                     ": allowed user_height_m <= altitude_m - d0_m (the path loss holds from the reference distance on)");
  if (c.channel.rician_k_min_db > c.channel.rician_k_max_db)
    throw InputError("channel.rician_k_min_db = " + format_double(c.channel.rician_k_min_db) + " is above channel.rician_k_max_db = " +
                     format_double(c.channel.rician_k_max_db) + ": allowed rician_k_min_db <= rician_k_max_db (K grows with "
                     "elevation from its value at 0 to its value at 90 deg)");
  if (const PathLossInfo* pl = find_path_loss(c.channel.pathloss)) {
    const double h = c.scenario.altitude_m;
    if (!(h > pl->min_height_m && h <= pl->max_height_m))
      throw InputError("scenario.altitude_m = " + format_double(h) + " is outside channel.pathloss = \"" + c.channel.pathloss +
                       "\"'s range: allowed " + format_double(pl->min_height_m) + " < altitude_m <= " + format_double(pl->max_height_m));
    const double diagonal = std::hypot(c.scenario.area_x_m, c.scenario.area_y_m);
    if (pl->max_horizontal_m > 0 && diagonal > pl->max_horizontal_m)
      throw InputError("scenario.area_x_m = " + format_double(c.scenario.area_x_m) + " and area_y_m = " + format_double(c.scenario.area_y_m) +
                       " give UAV-user distances up to " + format_double(diagonal) + " m, beyond channel.pathloss = \"" +
                       c.channel.pathloss + "\"'s range: allowed an area whose diagonal is at most " +
                       format_double(pl->max_horizontal_m) + " m");
  }
  // The model's own settings (its factory refuses what does not fit it), and what needs the lattice.
  const auto dynamics = make_dynamics(c);
  if (c.marl.reserve_slack >= 0 && !dynamics->lattice())
    throw InputError("marl.reserve_slack = " + std::to_string(c.marl.reserve_slack) + " is not allowed with trajectory.mobility = " +
                     c.trajectory.mobility + ": allowed -1 (ways home are planned on the lattice of " + lattice_dynamics_names() + ")");
  if (c.marl.rate_map > 0 && c.marl.encoder != ObservationKind::Set)
    throw InputError("marl.rate_map = " + std::to_string(c.marl.rate_map) + " with marl.encoder = \"" + std::string(name_of(c.marl.encoder)) +
                     "\": allowed with marl.encoder = \"set\" (the paper's 11-real observation stays the paper's)");
  if (c.marl.lookahead && c.marl.encoder != ObservationKind::Set)
    throw InputError("marl.lookahead = true with marl.encoder = \"" + std::string(name_of(c.marl.encoder)) +
                     "\": allowed with marl.encoder = \"set\" (the paper's 11-real observation stays the paper's)");
  if (c.marl.sequential && c.marl.encoder != ObservationKind::Set)
    throw InputError("marl.sequential = true with marl.encoder = \"" + std::string(name_of(c.marl.encoder)) +
                     "\": allowed with marl.encoder = \"set\" (the paper's 11-real observation shows no other UAV)");
  if (c.marl.sequential && find_learner(c.marl.algo).core != LearnerInfo::Core::Ppo)
    throw InputError("marl.sequential = true with marl.algo = \"" + c.marl.algo +
                     "\": allowed with the PPO learners (mappo, ippo), whose policies sample one agent at a time");
  if (c.marl.sequential && !dynamics->lattice())
    throw InputError("marl.sequential = true with trajectory.mobility = \"" + c.trajectory.mobility + "\": allowed with the " +
                     lattice_dynamics_names() + " mobility models (their moves land where the shield orders them)");
  if (c.marl.sequential_passes > 1 && !c.marl.sequential)
    throw InputError("marl.sequential_passes = " + std::to_string(c.marl.sequential_passes) +
                     " with marl.sequential = false: allowed 1, or more passes with marl.sequential = true (the passes are its turns)");
  if (c.marl.average_decay >= 1)
    throw InputError("marl.average_decay = " + format_double(c.marl.average_decay) +
                     ": allowed 0 <= average_decay < 1 (at 1 the average would never move from the first step's weights)");
  if (c.marl.average_decay > 0 && find_learner(c.marl.algo).core != LearnerInfo::Core::Ppo)
    throw InputError("marl.average_decay = " + format_double(c.marl.average_decay) + " with marl.algo = \"" + c.marl.algo +
                     "\": allowed with the PPO learners (the value-decomposition learners publish their Q-networks as trained)");
  {
    // An objective that scores propulsion energy needs a power model that is not identically 0
    // (eq. (12) of Zeng et al. with P0 = Pi = 0 and no parasite term is 0 at every speed).
    const auto& e = c.energy;
    const bool kinetic = e.acceleration == Acceleration::Kinetic && e.mass_kg > 0;
    const bool zero = e.model == Propulsion::None || (e.p0_w == 0 && e.pi_w == 0 && e.d0 * e.rho_kgm3 * e.solidity * e.rotor_area_m2 == 0 && !kinetic);
    const std::string why = e.model == Propulsion::None ? "energy.model = \"none\"" : "energy.p0_w = 0, energy.pi_w = 0 and no parasite or kinetic term";
    if (zero && (c.env.objective == Objective::EnergyEfficiency || c.env.objective == Objective::Energy))
      throw InputError("env.objective = \"" + std::string(name_of(c.env.objective)) + "\" with " + why +
                       ": no move costs energy, so every mission scores the same; allowed energy.model = \"rotary-wing\" "
                       "with a power above 0, or env.objective = \"sum-rate\"");
    if (zero && c.env.objective == Objective::Weighted && e.weight > 0)
      throw InputError("env.objective = \"weighted\" with energy.weight = " + format_double(e.weight) + " and " + why +
                       ": the energy term is 0 whatever the UAVs do; allowed energy.model = \"rotary-wing\" with a power above 0, "
                       "or env.objective = \"sum-rate\"");
    if (zero && e.budget_j > 0)
      throw InputError("energy.budget_j = " + format_double(e.budget_j) + " with " + why +
                       ": no mission spends energy, so the budget never binds; allowed energy.budget_j = 0 (none) or a power model");
  }
  if (c.channel.coverage_radius_m < c.scenario.altitude_m)
    throw InputError("channel.coverage_radius_m = " + format_double(c.channel.coverage_radius_m) +
                     " is below scenario.altitude_m = " + format_double(c.scenario.altitude_m) +
                     ": no user could ever be covered; allowed coverage_radius_m >= altitude_m");
}

}  // namespace skyloop
