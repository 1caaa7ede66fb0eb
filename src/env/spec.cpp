#include "skyloop/env/spec.hpp"

#include <algorithm>
#include <cmath>
#include <mutex>

#include "skyloop/core/config.hpp"
#include "skyloop/core/error.hpp"
#include "skyloop/env/dynamics.hpp"

namespace skyloop {

ArraySpec& ArraySpec::add(const std::string& field, int count, float lo, float hi, FieldWriter write) {
  fields.push_back({field, size, count, lo, hi, write});
  size += count;
  return *this;
}

ArraySpec& ArraySpec::append(const ArraySpec& other, const std::string& prefix) {
  for (const auto& f : other.fields) add(prefix + "." + f.name, f.size, f.low, f.high, f.write);
  return *this;
}

const SpecField& ArraySpec::field(const std::string& wanted) const {
  for (const auto& f : fields)
    if (f.name == wanted) return f;
  std::string names;
  for (const auto& f : fields) names += (names.empty() ? "" : ", ") + f.name;
  throw InputError(name + " has no field '" + wanted + "': allowed " + names);
}

float ArraySpec::low() const {
  float v = fields.empty() ? 0.0f : fields.front().low;
  for (const auto& f : fields) v = std::min(v, f.low);
  return v;
}

float ArraySpec::high() const {
  float v = fields.empty() ? 0.0f : fields.front().high;
  for (const auto& f : fields) v = std::max(v, f.high);
  return v;
}

namespace {
ArraySpec named(const std::string& name, const std::string& kind, const std::string& dtype, bool per_agent) {
  ArraySpec s;
  s.name = name, s.kind = kind, s.dtype = dtype, s.per_agent = per_agent;
  return s;
}
}  // namespace

const std::vector<std::array<int, 2>>& rate_map_offsets(int radius) {
  static const auto tables = [] {
    std::vector<std::vector<std::array<int, 2>>> t(kMaxRateMap + 1);
    for (int r = 0; r <= kMaxRateMap; ++r)
      for (int d = 1; d <= r; ++d)
        for (int q = 0; q < 4; ++q)  // quadrant q: from (d, 0) rotated q quarter turns, d steps along the ring
          for (int i = 0; i < d; ++i) {
            int dx = d - i, dy = i;
            for (int k = 0; k < q; ++k) std::swap(dx, dy), dx = -dx;  // (x, y) -> (-y, x)
            t[static_cast<std::size_t>(r)].push_back({dx, dy});
          }
    return t;
  }();
  if (radius < 0 || radius > kMaxRateMap)
    throw InputError("marl.rate_map = " + std::to_string(radius) + ": allowed 0 .. " + std::to_string(kMaxRateMap));
  return tables[static_cast<std::size_t>(radius)];
}

namespace {
/// The fields of observation_fields() that `array` carries under p, appended to s.
void add_observation_fields(ArraySpec& s, const SpecParams& p, int array) {
  for (const auto& f : observation_fields())
    if ((f.arrays & array) && f.on(p)) {
      float low = f.low, high = f.high;
      if (f.bounds) f.bounds(p, low, high);
      s.add(f.name, f.size(p), low, high, f.write);
    }
}
/// The fields of state_fields() in `array`, appended to s.
void add_state_fields(ArraySpec& s, const SpecParams& p, int array) {
  for (const auto& f : state_fields())
    if (f.arrays & array) s.add(f.name, f.size(p), f.low, f.high, f.write);
}
}  // namespace

ArraySpec paper_observation_spec(const SpecParams& p) {
  ArraySpec s = named("obs", "paper", "float32", true);
  add_observation_fields(s, p, ObservationField::kPaper);
  return s;
}

SpecParams spec_params(const Config& cfg, int agents, int users) {
  SpecParams p;
  p.agents = agents, p.users = users;
  p.area_x = cfg.scenario.area_x_m, p.area_y = cfg.scenario.area_y_m, p.d_fly = cfg.trajectory.d_fly_m;
  p.t_max = cfg.trajectory.t_max;
  p.state = cfg.env.state;
  p.observation = cfg.marl.encoder;
  const auto dynamics = make_dynamics(cfg);
  p.action = dynamics->actions();
  p.lookahead = cfg.marl.lookahead;
  p.rate_map = cfg.marl.rate_map;
  p.altitude = dynamics->chooses_altitude();
  return p;
}

ArraySpec set_observation_spec(const SpecParams& p) {
  ArraySpec s = named("obs", "set", "float32", true);
  add_observation_fields(s, p, ObservationField::kSet);
  return s;
}

const ArraySpec& compact_state_spec() {
  static const ArraySpec spec = [] {
    ArraySpec s = named("state", "compact", "float32", false);
    add_state_fields(s, SpecParams{}, StateField::kCompactState);  // sizes independent of N and K
    return s;
  }();
  return spec;
}

EnvSpec make_env_spec(const Config& cfg, int agents, int users) { return make_env_spec(spec_params(cfg, agents, users)); }

namespace {
/// Everything a spec says (every array's fields with their offsets, sizes and bounds, the action
/// space, the kinds), as text: two parameter sets share a spec exactly when they make the same one,
/// whichever parameters they differ in.
std::string spec_text(const EnvSpec& e) {
  std::string s = std::to_string(e.agents) + " " + std::to_string(e.users) + " " + name_of(e.observation_kind) + " " +
                  name_of(e.state_kind) + " " + std::to_string(e.action.hover) + " " + std::to_string(e.action.dims) + ":";
  for (const auto& a : e.action.names) s += a + ",";
  for (const ArraySpec* a : {&e.obs, &e.state, &e.agent_context, &e.agent_state, &e.action_mask, &e.paper_obs, &e.set_obs, &e.compact_state}) {
    s += "\n" + a->name + " " + a->kind + " " + a->dtype + (a->per_agent ? " agent" : " env");
    for (const auto& f : a->fields)
      s += " " + f.name + "@" + std::to_string(f.offset) + "+" + std::to_string(f.size) + "[" + std::to_string(f.low) + "," +
           std::to_string(f.high) + "]";
  }
  return s;
}
}  // namespace

std::shared_ptr<const EnvSpec> shared_env_spec(const SpecParams& p) {
  // Keyed by what the spec says, not by the parameters (a parameter left out of a hand-written
  // comparison would hand one configuration another's spec).
  EnvSpec e = make_env_spec(p);
  std::string key = spec_text(e);
  static std::mutex mutex;
  static std::vector<std::pair<std::string, std::shared_ptr<const EnvSpec>>> made;
  std::lock_guard<std::mutex> lock(mutex);
  for (const auto& [k, spec] : made)
    if (k == key) return spec;
  if (made.size() >= 64) made.erase(made.begin());  // a sweep over many scenarios: keep the newest
  made.emplace_back(std::move(key), std::make_shared<const EnvSpec>(std::move(e)));
  return made.back().second;
}

EnvSpec make_env_spec(const SpecParams& p) {
  const int agents = p.agents, users = p.users;
  EnvSpec e;
  e.agents = agents, e.users = users;
  e.observation_kind = p.observation;
  e.state_kind = p.state;
  e.action = p.action;
  e.paper_obs = paper_observation_spec(p);
  e.set_obs = set_observation_spec(p);
  e.compact_state = compact_state_spec();
  e.obs = e.observation_kind == ObservationKind::Set ? e.set_obs : e.paper_obs;

  if (e.state_kind == StateKind::Compact) {
    e.state = e.compact_state;
    e.agent_context = named("agent_context", "neighbours", "float32", true);
    add_state_fields(e.agent_context, p, StateField::kNeighbourContext);
  } else {
    e.state = named("state", "paper", "float32", false);
    add_state_fields(e.state, p, StateField::kPaperState);
    e.agent_context = named("agent_context", "id", "float32", true);
    add_state_fields(e.agent_context, p, StateField::kIdContext);
  }
  e.agent_state = named("agent_state", e.state.kind, "float32", true);
  e.agent_state.append(e.state, "state").append(e.agent_context, "context").append(e.paper_obs, "obs");

  e.action_mask = named("action_mask", "mask", "int8", true);
  for (const auto& a : e.action.names) e.action_mask.add(a, 1, 0, 1);
  return e;
}

const std::vector<InfoField>& step_info_fields() {
  static const std::vector<InfoField> fields = {
      {"sum_rate", "float64", "R[t] at the new slot (bit/s/Hz)", [](const StepInfo& s) { return s.sum_rate; }},
      {"objective", "float64", "the episode's env.objective so far", [](const StepInfo& s) { return s.objective; }},
      {"collisions", "int32", "UAVs closer than D_min to another at the slot's end", [](const StepInfo& s) { return double(s.collisions); }},
      {"boundary", "int32", "moves cancelled at the area's (or the altitude band's) boundary", [](const StepInfo& s) { return double(s.boundary); }},
      {"arrivals", "int32", "UAVs that arrived in this slot", [](const StepInfo& s) { return double(s.arrivals); }},
      {"home", "int32", "UAVs home so far", [](const StepInfo& s) { return double(s.home); }},
      {"T", "int32", "the slot reached", [](const StepInfo& s) { return double(s.T); }},
      {"success", "bool", "every UAV home within its energy budget", [](const StepInfo& s) { return s.success ? 1.0 : 0.0; }},
      {"episode_reward", "float64", "the rewards summed so far", [](const StepInfo& s) { return s.episode_reward; }},
      {"episode_collisions", "int32", "collisions so far in the episode (final values where it ends)",
       [](const StepInfo& s) { return double(s.episode_collisions); }},
      {"episode_boundary", "int32", "boundary events so far in the episode", [](const StepInfo& s) { return double(s.episode_boundary); }},
      {"energy_j", "float64", "the fleet's propulsion energy in this step (J)", [](const StepInfo& s) { return s.energy_j; }},
      {"episode_energy_j", "float64", "the fleet's propulsion energy so far (J)", [](const StepInfo& s) { return s.episode_energy_j; }},
      {"bits_per_joule", "float64", "B delta_t sum R[t] / E so far", [](const StepInfo& s) { return s.bits_per_joule; }},
      {"sum_rate_objective", "float64", "P2.2's (1/T) sum R[t], whatever env.objective is", [](const StepInfo& s) { return s.sum_rate_objective; }},
  };
  return fields;
}

}  // namespace skyloop
