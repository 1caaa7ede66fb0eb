// skyloop._skyloop: the Python module. It reaches the library through the same public headers as
// the CLI; the pure-Python package (python/skyloop) wraps it with the adapters learners use.
//
// Arrays: channels and beamformers are complex128 numpy arrays (G: [K_n, L], row k = h_k^H;
// W: [L, K_n], column k = w_k); the environment's arrays are float32 / int8 / bool, batch first.
// The GIL is released while C++ works (beamformer batches, environment steps, planners).
#include <pybind11/eigen.h>
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <chrono>
#include <cmath>
#include <filesystem>
#include <mutex>

#include "skyloop/marl/learners.hpp"
#include "skyloop/planning/registry.hpp"
#include "skyloop/channel/rates.hpp"
#include "skyloop/core/config_io.hpp"
#include "skyloop/core/error.hpp"
#include "skyloop/core/io.hpp"
#include "skyloop/core/parallel.hpp"
#include "skyloop/core/paths.hpp"
#include "skyloop/core/rng.hpp"
#include "skyloop/env/uav_env.hpp"
#include "skyloop/experiments/builtin.hpp"
#include "skyloop/planning/planners.hpp"
#include "skyloop/planning/safety.hpp"
#ifdef SKYLOOP_HAS_TORCH
#include "skyloop/experiments/bench.hpp"
#include "skyloop/experiments/layout_eval.hpp"
#include "skyloop/marl/marl.hpp"
#include "skyloop/nn/learned.hpp"
#endif

namespace py = pybind11;
using namespace skyloop;

namespace {

template <class T>
using Array = py::array_t<T, py::array::c_style | py::array::forcecast>;

// ---- config ---------------------------------------------------------------------------------

Config make_config(const std::optional<std::string>& path, const std::vector<std::string>& overrides) {
  return resolve_config(path, overrides);
}

py::object field_value(const Config& cfg, const std::string& key) {
  const Field* f = find_field(key);
  if (!f) throw InputError("unknown configuration key '" + key + "': allowed one of Config.keys() (see `skyloop config show`)");
  const FieldValue v = f->get(cfg);
  if (auto b = std::get_if<bool>(&v)) return py::bool_(*b);
  if (auto i = std::get_if<std::int64_t>(&v)) return py::int_(*i);
  if (auto d = std::get_if<double>(&v)) return py::float_(*d);
  if (auto s = std::get_if<std::string>(&v)) return py::str(*s);
  if (auto r = std::get_if<std::vector<double>>(&v)) return py::cast(*r);
  const auto& pts = std::get<std::vector<Point2>>(v);
  py::list out;
  for (const auto& p : pts) out.append(py::make_tuple(p.x, p.y));
  return out;
}

Positions positions_from(const Array<double>& a, const Config& cfg, const std::string& what) {
  if (a.ndim() != 2 || a.shape(1) != 2)
    throw InputError(what + " has shape " + std::to_string(a.ndim()) + "-d: allowed an [n, 2] array of (x, y) in metres");
  std::vector<Point2> pts;
  for (py::ssize_t i = 0; i < a.shape(0); ++i) pts.push_back({a.at(i, 0), a.at(i, 1)});
  if (pts.empty()) throw InputError(what + " is empty: allowed at least one (x, y) point");
  return positions_in_area(pts, cfg, what);
}

// ---- environment ----------------------------------------------------------------------------

py::dict link_dict(const ChannelModel& model, double ux, double uy, double x, double y) {
  py::dict d;
  for (const auto& [name, value] : link_fields(model.link(ux, uy, x, y))) {
    if (name == "los") d[name.c_str()] = value != 0.0;
    else d[name.c_str()] = value;
  }
  return d;
}

py::dict array_spec_dict(const ArraySpec& a, int agents) {
  py::list fields;
  for (const auto& f : a.fields) {
    py::dict d;
    d["name"] = f.name, d["offset"] = f.offset, d["size"] = f.size, d["low"] = f.low, d["high"] = f.high;
    fields.append(d);
  }
  py::dict d;
  d["name"] = a.name, d["kind"] = a.kind, d["dtype"] = a.dtype, d["size"] = a.size;
  d["shape"] = a.per_agent ? py::make_tuple(agents, a.size) : py::make_tuple(a.size);
  d["low"] = a.low(), d["high"] = a.high();
  d["fields"] = fields;
  return d;
}

/// The environment's spec (skyloop/env/spec.hpp) as plain Python values.
py::dict env_spec_dict(const EnvSpec& e) {
  py::dict d;
  d["agents"] = e.agents, d["users"] = e.users;
  d["num_actions"] = e.action.count();
  d["actions"] = py::tuple(py::cast(e.action.names));
  d["hover"] = e.action.hover;  // the action that stays in place (an arrived UAV's only one)
  // The continuous model: commands in [-1, 1]^dims (the actions above are its primitives); 0: discrete.
  d["dims"] = e.action.dims;
  d["observation_kind"] = to_string(e.observation_kind), d["state_kind"] = to_string(e.state_kind);
  d["obs"] = array_spec_dict(e.obs, e.agents);
  d["state"] = array_spec_dict(e.state, e.agents);
  d["agent_context"] = array_spec_dict(e.agent_context, e.agents);
  d["agent_state"] = array_spec_dict(e.agent_state, e.agents);
  d["action_mask"] = array_spec_dict(e.action_mask, e.agents);
  d["paper_obs"] = array_spec_dict(e.paper_obs, e.agents);
  d["set_obs"] = array_spec_dict(e.set_obs, e.agents);
  return d;
}

/// The batch-first environment: M copies of the trajectory environment stepped as one batch.
/// Every array's layout is the environment's spec (UavEnv::spec()); the rows are written by the
/// environment's own writers. Calls from several Python threads are serialised by a mutex (taken
/// with the GIL released): a VecEnv is safe to share, not parallel.
class PyVecEnv {
 public:
  PyVecEnv(const Config& cfg, int num_envs, std::uint64_t seed, const std::string& oracle, std::vector<std::uint64_t> layouts)
      : cfg_(cfg), num_envs_(num_envs), layouts_(std::move(layouts)) {
    if (!layouts_.empty() && static_cast<int>(layouts_.size()) != num_envs)
      throw InputError("layouts has " + std::to_string(layouts_.size()) + " seeds for num_envs = " + std::to_string(num_envs) +
                       ": allowed one layout per environment");
    if (num_envs < 1 || num_envs > kMaxEnvs)
      throw InputError("num_envs = " + std::to_string(num_envs) + " is out of range: allowed an integer in [1, " +
                       std::to_string(kMaxEnvs) + "]");
    if (!oracle.empty()) apply_override(cfg_, "env.oracle=" + toml_string(oracle));
    bf_ = builtin_beamformers().create(cfg_.env.oracle, cfg_);
    build(seed);
  }
  static constexpr int kMaxEnvs = 65536;

  int num_envs() const { return num_envs_; }
  int agents() const { return spec_->agents; }
  const EnvSpec& spec() const { return *spec_; }
  py::dict spec_dict() const { return env_spec_dict(*spec_); }

  py::dict reset(std::optional<std::uint64_t> seed) {
    auto out = allocate();
    {
      py::gil_scoped_release nogil;
      std::lock_guard<std::mutex> lock(mutex_);
      turns_.clear();  // turns in progress refer to the environments: dropped before they go
      if (seed) vec_ = make_vec(*seed);
      else vec_->reset();
      fill(out);
    }
    return out.dict();
  }

  py::dict step(const py::array& actions_in) {
    const int M = num_envs_, N = agents(), A = spec_->action.count(), C = spec_->action.dims;
    const char kind = actions_in.dtype().kind();
    std::string allowed = "allowed an integer array of shape [" + std::to_string(M) + ", " + std::to_string(N) +
                          "] (num_envs, agents) with values 0.." + std::to_string(A - 1) + " (" + action_list() + ")";
    if (C > 0)
      allowed += " or a float array of shape [" + std::to_string(M) + ", " + std::to_string(N) + ", " + std::to_string(C) +
                 "] with values in [-1, 1] (velocity commands)";
    std::vector<Positions> velocities;
    if (kind == 'f' && C > 0) velocities = commands_of(actions_in, allowed);
    else if (kind != 'i' && kind != 'u') throw InputError("actions have dtype " + py::str(actions_in.dtype()).cast<std::string>() + ": " + allowed);
    if (!velocities.empty()) return advance({}, velocities);
    const auto a = Array<std::int64_t>::ensure(actions_in);
    if (a.ndim() != 2 || a.shape(0) != M || a.shape(1) != N) throw InputError("actions have shape " + shape_of(actions_in) + ": " + allowed);
    std::vector<std::vector<int>> joint(static_cast<std::size_t>(M), std::vector<int>(static_cast<std::size_t>(N)));
    const auto r = a.unchecked<2>();
    for (int i = 0; i < M; ++i)
      for (int n = 0; n < N; ++n) {
        const auto v = r(i, n);
        if (v < 0 || v >= A)
          throw InputError("actions[" + std::to_string(i) + ", " + std::to_string(n) + "] = " + std::to_string(v) +
                           " is invalid: allowed 0.." + std::to_string(A - 1) + " (" + action_list() + ")");
        // An arrived UAV is locked to hover (its mask allows only spec["hover"]); any other action is taken as hover.
        joint[static_cast<std::size_t>(i)][static_cast<std::size_t>(n)] = static_cast<int>(v);
      }
    return advance(joint, {});
  }

  /// Continuous commands [M, N, C] in [-1, 1] as velocities (m/s), through the safety layer of
  /// marl.action_mask and marl.shield (safe_velocities) once stepped.
  std::vector<Positions> commands_of(const py::array& in, const std::string& allowed) const {
    const int M = num_envs_, N = agents(), C = spec_->action.dims;
    const auto a = Array<double>::ensure(in);
    if (a.ndim() != 3 || a.shape(0) != M || a.shape(1) != N || a.shape(2) != C)
      throw InputError("actions have shape " + shape_of(in) + ": " + allowed);
    const auto r = a.unchecked<3>();
    std::vector<Positions> v(static_cast<std::size_t>(M), Positions::Zero(N, 2));
    for (int i = 0; i < M; ++i)
      for (int n = 0; n < N; ++n) {
        for (int k = 0; k < C; ++k)
          if (!(r(i, n, k) >= -1.0 && r(i, n, k) <= 1.0))
            throw InputError("actions[" + std::to_string(i) + ", " + std::to_string(n) + ", " + std::to_string(k) + "] = " +
                             format_double(r(i, n, k)) + " is invalid: allowed a command in [-1, 1]");
        vec_->env(i).command_velocity(n, r(i, n, 0), r(i, n, 1), v[static_cast<std::size_t>(i)](n, 0), v[static_cast<std::size_t>(i)](n, 1));
      }
    return v;
  }

  /// One step of every environment: discrete `joint` actions, or velocity commands.
  py::dict advance(const std::vector<std::vector<int>>& joint, std::vector<Positions> velocities) {
    const int M = num_envs_, N = agents();
    auto out = allocate();
    const std::size_t O = static_cast<std::size_t>(N) * static_cast<std::size_t>(spec_->obs.size);
    const std::size_t S = static_cast<std::size_t>(spec_->state.size);
    // Final observations of the environments that finish in this step (zeros elsewhere).
    std::vector<float> fo, fs;
    std::vector<StepInfo> info;
    {
      py::gil_scoped_release nogil;
      std::lock_guard<std::mutex> lock(mutex_);
      turns_.clear();  // a step ends the slot's turns (and every step clears the landings shown)
      auto final_view = [&](std::size_t i) {
        if (fo.empty()) fo.assign(static_cast<std::size_t>(M) * O, 0.0f), fs.assign(static_cast<std::size_t>(M) * S, 0.0f);
        const UavEnv& e = vec_->env(static_cast<int>(i));
        for (int n = 0; n < N; ++n) e.write_obs(n, fo.data() + i * O + static_cast<std::size_t>(n) * static_cast<std::size_t>(spec_->obs.size));
        e.write_state(fs.data() + i * S);
      };
      if (!velocities.empty()) {
        const SafetyOptions safety = safety_options(cfg_);
        for (int i = 0; i < M; ++i)
          velocities[static_cast<std::size_t>(i)] = safe_velocities(vec_->env(i), safety, velocities[static_cast<std::size_t>(i)]);
        info = vec_->step_velocities(velocities, final_view);
      } else {
        info = vec_->step(joint, final_view);
      }
      fill(out);
    }
    py::array final_obs, final_state;
    if (fo.empty()) {
      final_obs = zeros(true);
      final_state = zeros(false);
    } else {
      final_obs = Array<float>({M, N, spec_->obs.size}, fo.data());
      final_state = Array<float>({static_cast<py::ssize_t>(M), static_cast<py::ssize_t>(S)}, fs.data());
    }
    py::dict d = out.dict();
    auto reward = Array<float>({M});
    auto sum_rate = Array<double>({M}), objective = Array<double>({M});
    auto terminated = py::array_t<bool>({M}), truncated = py::array_t<bool>({M});
    auto collisions = Array<std::int32_t>({M}), boundary = Array<std::int32_t>({M}), arrivals = Array<std::int32_t>({M});
    auto home = Array<std::int32_t>({M}), T = Array<std::int32_t>({M});
    auto success = py::array_t<bool>({M});
    auto episode_reward = Array<double>({M});
    auto episode_collisions = Array<std::int32_t>({M}), episode_boundary = Array<std::int32_t>({M});
    auto energy = Array<double>({M}), episode_energy = Array<double>({M}), bits_per_joule = Array<double>({M});
    auto sum_rate_objective = Array<double>({M});
    for (int i = 0; i < M; ++i) {
      const auto& s = info[static_cast<std::size_t>(i)];
      energy.mutable_at(i) = s.energy_j;
      episode_energy.mutable_at(i) = s.episode_energy_j;
      bits_per_joule.mutable_at(i) = s.bits_per_joule;
      sum_rate_objective.mutable_at(i) = s.sum_rate_objective;
      reward.mutable_at(i) = static_cast<float>(s.reward);
      sum_rate.mutable_at(i) = s.sum_rate;
      objective.mutable_at(i) = s.objective;
      // terminated: every UAV home (the MDP's end, whether or not the mission met its energy
      // budget: success says that); truncated: T_max reached first.
      terminated.mutable_at(i) = s.done && s.home == N;
      truncated.mutable_at(i) = s.done && s.home < N;
      collisions.mutable_at(i) = s.collisions;
      boundary.mutable_at(i) = s.boundary;
      arrivals.mutable_at(i) = s.arrivals;
      home.mutable_at(i) = s.home;
      T.mutable_at(i) = s.T;
      success.mutable_at(i) = s.success;
      episode_reward.mutable_at(i) = s.episode_reward;
      episode_collisions.mutable_at(i) = s.episode_collisions;
      episode_boundary.mutable_at(i) = s.episode_boundary;
    }
    d["reward"] = reward;
    d["terminated"] = terminated;
    d["truncated"] = truncated;
    py::dict inf;
    inf["sum_rate"] = sum_rate;
    inf["objective"] = objective;
    inf["collisions"] = collisions;
    inf["boundary"] = boundary;
    inf["arrivals"] = arrivals;
    inf["home"] = home;
    inf["T"] = T;
    inf["success"] = success;
    inf["episode_reward"] = episode_reward;
    inf["episode_collisions"] = episode_collisions;  // so far in the episode (final values where it ends)
    inf["episode_boundary"] = episode_boundary;
    inf["energy_j"] = energy;                  // the fleet's propulsion energy in this step (J)
    inf["episode_energy_j"] = episode_energy;  // so far in the episode
    inf["bits_per_joule"] = bits_per_joule;
    inf["sum_rate_objective"] = sum_rate_objective;  // P2.2's (1/T) sum R[t], whatever env.objective is
    inf["final_obs"] = final_obs;
    inf["final_state"] = final_state;
    d["info"] = inf;
    return d;
  }

  py::dict positions() {
    const int M = num_envs_, N = agents();
    auto p = Array<double>({M, N, 2});
    auto d = Array<double>({M, N, 2});
    auto t = Array<std::int32_t>({M});
    {
      double* pp = p.mutable_data();
      double* pd = d.mutable_data();
      std::int32_t* pt = t.mutable_data();
      py::gil_scoped_release nogil;
      std::lock_guard<std::mutex> lock(mutex_);
      for (int i = 0; i < M; ++i) {
        const UavEnv& e = vec_->env(i);
        pt[i] = e.t();
        for (int n = 0; n < N; ++n)
          for (int c = 0; c < 2; ++c) {
            pp[(static_cast<std::size_t>(i) * N + n) * 2 + c] = e.positions()(n, c);
            pd[(static_cast<std::size_t>(i) * N + n) * 2 + c] = e.destinations()(n, c);
          }
      }
    }
    py::dict out;
    out["uavs"] = p;
    out["destinations"] = d;
    out["t"] = t;
    return out;
  }

  py::array users(int i) {
    if (i < 0 || i >= num_envs_) throw InputError("env index " + std::to_string(i) + " is out of range: allowed 0.." + std::to_string(num_envs_ - 1));
    Positions u;
    {
      py::gil_scoped_release nogil;
      std::lock_guard<std::mutex> lock(mutex_);
      u = vec_->env(i).oracle().users();
    }
    auto out = Array<double>({static_cast<py::ssize_t>(u.rows()), static_cast<py::ssize_t>(2)});
    for (Eigen::Index k = 0; k < u.rows(); ++k) out.mutable_at(k, 0) = u(k, 0), out.mutable_at(k, 1) = u(k, 1);
    return out;
  }

  const Config& config() const { return cfg_; }

  /// Benchmark helper: `actions` [steps, M, N] stepped by the C++ VecEnv alone (no observation
  /// arrays), on this very environment (same oracles, same warm caches); returns seconds.
  double bench_cpp_steps(const Array<std::int64_t>& actions) {
    if (actions.ndim() != 3 || actions.shape(1) != num_envs_ || actions.shape(2) != agents())
      throw InputError("actions have shape " + shape_of(actions) + ": allowed [steps, num_envs, agents]");
    const auto a = actions.unchecked<3>();
    for (py::ssize_t t = 0; t < actions.shape(0); ++t)
      for (int i = 0; i < num_envs_; ++i)
        for (int n = 0; n < agents(); ++n)
          if (a(t, i, n) < 0 || a(t, i, n) >= spec_->action.count())
            throw InputError("actions: allowed values 0.." + std::to_string(spec_->action.count() - 1));
    std::vector<std::vector<int>> joint(static_cast<std::size_t>(num_envs_), std::vector<int>(static_cast<std::size_t>(agents())));
    py::gil_scoped_release nogil;
    std::lock_guard<std::mutex> lock(mutex_);
    const auto t0 = std::chrono::steady_clock::now();
    for (py::ssize_t t = 0; t < actions.shape(0); ++t) {
      for (int i = 0; i < num_envs_; ++i)
        for (int n = 0; n < agents(); ++n) joint[static_cast<std::size_t>(i)][static_cast<std::size_t>(n)] = static_cast<int>(a(t, i, n));
      vec_->step(joint);
    }
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  }

  /// Environment i's arrays from UavEnv's own per-agent accessors (state(), agent_state(n),
  /// observation(n) / the set observation), for tests that hold the batch arrays to them.
  py::dict reference(int i) {
    if (i < 0 || i >= num_envs_) throw InputError("env index " + std::to_string(i) + " is out of range: allowed 0.." + std::to_string(num_envs_ - 1));
    std::vector<float> state;
    std::vector<std::vector<float>> obs, agent_state;
    {
      py::gil_scoped_release nogil;
      std::lock_guard<std::mutex> lock(mutex_);
      const UavEnv& e = vec_->env(i);
      state = e.state();
      for (int n = 0; n < e.uavs(); ++n) {
        agent_state.push_back(e.agent_state(n));
        if (e.spec().observation_kind == ObservationKind::Set) {
          obs.emplace_back(static_cast<std::size_t>(e.set_observation_size()));
          e.write_set_observation(n, obs.back().data());
        } else {
          obs.push_back(e.observation(n));
        }
      }
    }
    py::dict d;
    d["state"] = py::array_t<float>(static_cast<py::ssize_t>(state.size()), state.data());
    d["obs"] = py::cast(obs);
    d["agent_state"] = py::cast(agent_state);
    return d;
  }

  /// Cache hit rate of the environments' rate oracles so far.
  double hit_rate() {
    py::gil_scoped_release nogil;
    std::lock_guard<std::mutex> lock(mutex_);
    double hits = 0, total = 0;
    for (int i = 0; i < num_envs_; ++i) {
      auto& o = vec_->env(i).oracle();
      hits += static_cast<double>(o.stats().hits);
      total += static_cast<double>(o.stats().hits + o.stats().misses);
    }
    return total > 0 ? hits / total : 0.0;
  }

  /// Sequential turns (the protocol of marl.sequential, with the collision shield) for a learner
  /// in Python. begin_turns starts the slot's turns in every environment: the UAVs not yet home
  /// choose one after another, least slack first, each allowed the moves of the configuration's
  /// training safety (mask, shield against the UAVs placed so far, slack margin, clearance; no
  /// reserved ways: SafeTurns), taken `passes` times (marl.sequential_passes' protocol, TurnPasses;
  /// default the configuration's): in every pass after the first each agent also sees the agents
  /// after it at their moves of the pass before, and the last pass is flown. take_turn records each
  /// environment's move for the agent whose turn it is and shows its landing in the set
  /// observation of the agents after it (UavEnv::show_decided); step_turns steps the joint moves
  /// chosen. reset and step drop turns in progress.
  py::dict begin_turns(std::optional<int> passes_in) {
    if (spec_->action.dims > 0)
      throw InputError("begin_turns: trajectory.mobility = \"continuous\" has no turns: allowed with \"grid\" or \"headings\"");
    const int passes = passes_in.value_or(cfg_.marl.sequential_passes);
    if (passes < 1 || passes > kMaxSequentialPasses)
      throw InputError("begin_turns: passes = " + std::to_string(passes) + " is out of range: allowed an integer in [1, " +
                       std::to_string(kMaxSequentialPasses) + "] (marl.sequential_passes' range)");
    {
      py::gil_scoped_release nogil;
      std::lock_guard<std::mutex> lock(mutex_);
      turns_.clear();
      const SafetyOptions safety = training_safety_options(cfg_);
      for (int i = 0; i < num_envs_; ++i) {
        vec_->env(i).clear_decided();
        turns_.emplace_back(vec_->env(i), safety, passes);
      }
    }
    return turn_dict();
  }

  py::dict take_turn(const py::array& actions_in) {
    const int M = num_envs_, A = spec_->action.count();
    auto allowed = [M] {  // written only for an error: take_turn runs once per agent and slot
      return "allowed an integer array of shape [" + std::to_string(M) +
             "] (num_envs): each environment's move for the agent whose turn it is, one its action_mask allows";
    };
    const char kind = actions_in.dtype().kind();
    if (kind != 'i' && kind != 'u') throw InputError("actions have dtype " + py::str(actions_in.dtype()).cast<std::string>() + ": " + allowed());
    const auto a = Array<std::int64_t>::ensure(actions_in);
    if (a.ndim() != 1 || a.shape(0) != M) throw InputError("actions have shape " + shape_of(actions_in) + ": " + allowed());
    const auto r = a.unchecked<1>();
    std::string error;
    {
      py::gil_scoped_release nogil;
      std::lock_guard<std::mutex> lock(mutex_);
      if (turns_.empty()) error = "take_turn: no turns begun: call begin_turns() first";
      bool any = false;
      for (std::size_t i = 0; i < turns_.size() && error.empty(); ++i) {  // every move checked before any is taken
        const TurnPasses& t = turns_[i];
        if (t.done()) continue;
        any = true;
        const auto v = r(static_cast<py::ssize_t>(i));
        if (v < 0 || v >= A || !(t.allowed() >> v & 1u)) {
          std::string ok;
          for (int k = 0; k < A; ++k)
            if (t.allowed() >> k & 1u) ok += (ok.empty() ? "" : ", ") + spec_->action.names[static_cast<std::size_t>(k)];
          error = "actions[" + std::to_string(i) + "] = " + std::to_string(v) + " is not allowed for agent " +
                  std::to_string(t.uav()) + " this turn: allowed " + ok;
        }
      }
      if (error.empty() && !any) error = "take_turn: every agent has chosen: call step_turns()";
      if (error.empty())
        for (std::size_t i = 0; i < turns_.size(); ++i) {
          TurnPasses& t = turns_[i];
          if (!t.done()) t.choose(static_cast<int>(r(static_cast<py::ssize_t>(i))));  // shows its landing
        }
    }
    if (!error.empty()) throw InputError(error);
    return turn_dict();
  }

  py::dict step_turns() {
    std::vector<std::vector<int>> joint;
    std::string error;
    {
      py::gil_scoped_release nogil;
      std::lock_guard<std::mutex> lock(mutex_);
      if (turns_.empty()) error = "step_turns: no turns begun: call begin_turns() first";
      for (std::size_t i = 0; i < turns_.size() && error.empty(); ++i) {
        if (!turns_[i].done())
          error = "step_turns: agent " + std::to_string(turns_[i].uav()) + " of environment " + std::to_string(i) +
                  " has not chosen: call take_turn until every turn's agent is -1";
        joint.push_back(turns_[i].actions());
      }
    }
    if (!error.empty()) throw InputError(error);
    return advance(joint, {});
  }

 private:
  /// The turn in progress: each environment's agent (-1 once every agent there has chosen), its
  /// observation written now (the landings chosen before it shown), its allowed moves and whether
  /// its move is flown (the last pass).
  py::dict turn_dict() {
    const int M = num_envs_, A = spec_->action.count();
    const std::size_t O = static_cast<std::size_t>(spec_->obs.size), AA = static_cast<std::size_t>(A);
    auto agent = Array<std::int32_t>({M});
    auto obs = Array<float>({M, spec_->obs.size});
    auto mask = Array<std::int8_t>({M, A});
    auto last = Array<bool>({M});
    std::int32_t* pa = agent.mutable_data();
    bool* pl = last.mutable_data();
    float* po = obs.mutable_data();
    std::int8_t* pm = mask.mutable_data();
    {
      py::gil_scoped_release nogil;
      std::lock_guard<std::mutex> lock(mutex_);
      std::fill_n(po, static_cast<std::size_t>(M) * O, 0.0f);
      std::fill_n(pm, static_cast<std::size_t>(M) * AA, std::int8_t{0});
      for (int i = 0; i < M; ++i) {
        const TurnPasses& t = turns_[static_cast<std::size_t>(i)];
        pa[i] = t.done() ? -1 : t.uav();
        pl[i] = !t.done() && t.last();
        if (t.done()) continue;
        vec_->env(i).write_obs(t.uav(), po + static_cast<std::size_t>(i) * O);
        for (std::size_t k = 0; k < AA; ++k) pm[static_cast<std::size_t>(i) * AA + k] = (t.allowed() >> k & 1u) ? 1 : 0;
      }
    }
    py::dict d;
    d["agent"] = agent;
    d["obs"] = obs;
    d["action_mask"] = mask;
    d["last"] = last;
    return d;
  }

  static std::string shape_of(const py::array& a) {
    std::string s = "[";
    for (py::ssize_t d = 0; d < a.ndim(); ++d) s += (d ? ", " : "") + std::to_string(a.shape(d));
    return s + "]";
  }
  std::string action_list() const {
    std::string s;
    for (const auto& n : spec_->action.names) s += (s.empty() ? "" : ", ") + n;
    return s;
  }

  void build(std::uint64_t seed) {
    py::gil_scoped_release nogil;
    std::lock_guard<std::mutex> lock(mutex_);
    vec_ = make_vec(seed);
    spec_ = std::make_shared<const EnvSpec>(vec_->env(0).spec());
  }
  /// The environments: seeded users (or training layouts), or one fixed layout each.
  std::unique_ptr<VecEnv> make_vec(std::uint64_t seed) const {
    if (!layouts_.empty()) return std::make_unique<VecEnv>(cfg_, bf_, layouts_);
    return std::make_unique<VecEnv>(cfg_, bf_, num_envs_, seed);
  }

  /// The arrays of one observation, allocated with the GIL held, filled without it.
  struct Arrays {
    Array<float> obs, state, agent_state;
    Array<std::int8_t> mask;
    py::dict dict() const {
      py::dict out;
      out["obs"] = obs;
      out["state"] = state;
      out["agent_state"] = agent_state;
      out["action_mask"] = mask;
      return out;
    }
  };
  Arrays allocate() const {
    const int M = num_envs_, N = agents();
    return Arrays{Array<float>({M, N, spec_->obs.size}), Array<float>({M, spec_->state.size}),
                  Array<float>({M, N, spec_->agent_state.size}), Array<std::int8_t>({M, N, spec_->action.count()})};
  }

  /// Current arrays of every environment, each row written by the environment itself; the action
  /// mask is the reachability mask of marl.action_mask (skyloop/planning/safety.hpp), else every
  /// action; an arrived UAV may only hover (spec["hover"]). Called with the lock held.
  void fill(Arrays& out) const {
    const int M = num_envs_, N = agents();
    const std::size_t O = static_cast<std::size_t>(spec_->obs.size), S = static_cast<std::size_t>(spec_->state.size);
    const std::size_t A = static_cast<std::size_t>(spec_->agent_state.size), K = static_cast<std::size_t>(spec_->action.count());
    float* po = out.obs.mutable_data();
    float* ps = out.state.mutable_data();
    float* pa = out.agent_state.mutable_data();
    std::int8_t* pm = out.mask.mutable_data();
    for (int i = 0; i < M; ++i) {
      const UavEnv& e = vec_->env(i);
      check_layout(e);
      e.write_state(ps + static_cast<std::size_t>(i) * S);
      for (int n = 0; n < N; ++n) {
        const std::size_t row = static_cast<std::size_t>(i) * static_cast<std::size_t>(N) + static_cast<std::size_t>(n);
        e.write_obs(n, po + row * O);
        e.write_agent_state(n, pa + row * A);
        const ActionSet allowed = allowed_moves(e, n, [&] {
          SafetyOptions s = safety_options(cfg_);
          s.shield = false;
          return s;
        }());
        for (std::size_t a = 0; a < K; ++a) pm[row * K + a] = (allowed >> a & 1u) ? 1 : 0;
      }
    }
  }
  /// Every environment of the batch has the layout the arrays were sized for.
  void check_layout(const UavEnv& e) const {
    const EnvSpec& s = e.spec();
    if (s.obs.size != spec_->obs.size || s.state.size != spec_->state.size || s.agent_state.size != spec_->agent_state.size)
      throw std::logic_error("VecEnv: an environment's layout changed within the batch");
  }

  /// Read-only zeros: final_obs / final_state when no episode ends in a step.
  py::array zeros(bool obs) {
    Array<float>& z = obs ? zero_obs_ : zero_state_;
    if (z.size() == 0) {
      z = obs ? Array<float>({num_envs_, agents(), spec_->obs.size}) : Array<float>({num_envs_, spec_->state.size});
      std::fill_n(z.mutable_data(), z.size(), 0.0f);
      py::detail::array_proxy(z.ptr())->flags &= ~py::detail::npy_api::NPY_ARRAY_WRITEABLE_;
    }
    return z;
  }

  Config cfg_;
  int num_envs_;
  std::vector<std::uint64_t> layouts_;    // one users seed per environment, or empty
  std::shared_ptr<const Beamformer> bf_;
  std::unique_ptr<VecEnv> vec_;
  std::shared_ptr<const EnvSpec> spec_;
  std::mutex mutex_;                      // serialises every use of vec_ across Python threads
  std::vector<TurnPasses> turns_;         // the slot's turns, one per environment (begin_turns), else empty
  Array<float> zero_obs_, zero_state_;
};

// ---- planners -------------------------------------------------------------------------------

py::dict episode_dict(const EpisodeRecord& r) {
  const int T = r.T, N = r.positions.empty() ? 0 : static_cast<int>(r.positions.front().rows());
  auto pos = Array<double>({T, N, 2});
  for (int t = 0; t < T; ++t)
    for (int n = 0; n < N; ++n) pos.mutable_at(t, n, 0) = r.positions[static_cast<std::size_t>(t)](n, 0),
                                pos.mutable_at(t, n, 1) = r.positions[static_cast<std::size_t>(t)](n, 1);
  auto act = Array<std::int32_t>({std::max(T - 1, 0), N});
  for (std::size_t t = 0; t < r.actions.size(); ++t)
    for (int n = 0; n < N; ++n) act.mutable_at(static_cast<py::ssize_t>(t), n) = r.actions[t][static_cast<std::size_t>(n)];
  auto speed = Array<double>({std::max(T - 1, 0), N}), power = Array<double>({std::max(T - 1, 0), N});
  for (std::size_t t = 0; t < r.speeds.size() && t + 1 < static_cast<std::size_t>(T); ++t)
    for (int n = 0; n < N; ++n)
      speed.mutable_at(static_cast<py::ssize_t>(t), n) = r.speeds[t][static_cast<std::size_t>(n)],
      power.mutable_at(static_cast<py::ssize_t>(t), n) = r.powers[t][static_cast<std::size_t>(n)];
  py::dict d;
  d["planner"] = r.planner;
  d["positions"] = pos;
  d["actions"] = act;
  d["action_names"] = py::tuple(py::cast(r.action_names.names));
  d["speed_mps"] = speed;   // [T - 1, N]: ground speed flown in each slot
  d["power_w"] = power;     // [T - 1, N]: propulsion power in each slot
  d["energy_j"] = Array<double>(static_cast<py::ssize_t>(r.uav_energy_j.size()), r.uav_energy_j.data());  // per UAV
  d["total_energy_j"] = r.energy_j;
  d["bits_per_joule"] = r.bits_per_joule;
  d["sum_rate_objective"] = r.sum_rate_objective;
  d["over_budget"] = r.over_budget;
  d["rates"] = Array<double>(static_cast<py::ssize_t>(r.rates.size()), r.rates.data());
  d["objective"] = r.objective;
  d["T"] = r.T;
  d["success"] = r.success;
  d["arrivals"] = r.arrivals;
  d["collisions"] = r.collisions;
  d["boundary"] = r.boundary;
  d["reward"] = r.reward;
  return d;
}

py::dict plan(const Config& cfg, const std::string& planner, std::uint64_t users_seed, std::optional<py::array> users_xy,
              std::optional<std::uint64_t> planner_seed) {
  // The planner first (a wrong name is the caller's first error), then the scenario.
  std::unique_ptr<Planner> p;
  if (builtin_planners().contains(planner)) {
    PlannerArgs args;
    // The random planner's stream: as `skyloop plan --seed S` (derive_seed(S, "RAND")) unless given.
    args.seed = planner_seed ? *planner_seed : derive_seed(users_seed, 0x52414e44ULL);
    args.safety = safety_options(cfg);
    p = builtin_planners().create(planner, args);
  }
#ifdef SKYLOOP_HAS_TORCH
  if (!p && !planner.empty() && (std::filesystem::is_directory(planner) || std::filesystem::exists(planner)))
    p = MarlPolicy::load(planner);
#endif
  if (!p)
    throw InputError("planner '" + planner + "' is unknown: allowed " + builtin_planners().names_text() + ", or a trained policy directory");
  auto bf = builtin_beamformers().create(cfg.env.oracle, cfg);
  const Positions users = users_xy ? positions_from(Array<double>::ensure(*users_xy), cfg, "users")
                                   : make_users(cfg, cfg.scenario.users, users_seed);
  EpisodeRecord rec;
  {
    py::gil_scoped_release nogil;
    auto oracle = std::make_shared<RateOracle>(cfg, std::shared_ptr<const Beamformer>(std::move(bf)), users);
    UavEnv env(cfg, oracle);
    rec = run_episode(env, *p);
  }
  return episode_dict(rec);
}

#ifdef SKYLOOP_HAS_TORCH
/// skyloop.evaluate_layouts: rows and summary as lists of dicts (the CSV columns).
py::dict evaluate_layouts_py(const Config& cfg, std::vector<std::string> policies, std::vector<std::string> planners,
                             int layouts, const std::string& split, std::uint64_t first, bool unsafe, bool rollout,
                             const std::string& cache, int threads) {
  LayoutEvalOptions opt;
  opt.layouts = layouts;
  opt.split = parse_layout_split(split, "split");
  opt.first = first;
  opt.policies = std::move(policies);
  opt.planners = std::move(planners);
  opt.unsafe = unsafe;
  opt.rollout = rollout;
  opt.cache_dir = cache;
  opt.threads = threads;
  std::vector<LayoutRow> rows;
  {
    py::gil_scoped_release nogil;
    rows = evaluate_layouts(cfg, opt, builtin_beamformers(), nullptr);
  }
  py::list rl, sl;
  for (const auto& r : rows) {
    py::dict d;
    d["seed"] = cfg.run.seed, d["split"] = split, d["layout"] = r.layout, d["users_seed"] = r.users_seed;
    d["users"] = r.users, d["uavs"] = r.uavs, d["planner"] = r.planner, d["objective"] = r.objective;
    d["reference"] = r.reference, d["reference_objective"] = r.reference_objective, d["fraction"] = r.fraction, d["T"] = r.T, d["home"] = r.home, d["complete"] = r.complete;
    d["collisions"] = r.collisions, d["boundary_events"] = r.boundary, d["seconds"] = r.seconds;
    d["energy_j"] = r.energy_j, d["bits_per_joule"] = r.bits_per_joule;
    rl.append(d);
  }
  for (const auto& x : summarise_layouts(rows)) {
    py::dict d;
    d["seed"] = cfg.run.seed, d["split"] = split, d["planner"] = x.planner, d["layouts"] = x.layouts;
    d["complete_rate"] = x.complete, d["collisions"] = x.collisions, d["boundary_events"] = x.boundary;
    d["mean_home"] = x.arrivals, d["mean_objective"] = x.objective, d["reference"] = x.reference;
    d["fraction_mean"] = x.fraction_mean;
    d["fraction_p5"] = x.fraction_p5, d["fraction_worst"] = x.fraction_worst;
    d["mean_energy_j"] = x.energy_j, d["mean_bits_per_joule"] = x.bits_per_joule;
    sl.append(d);
  }
  py::dict out;
  out["rows"] = rl;
  out["summary"] = sl;
  return out;
}

// ---- the benchmark (skyloop/experiments/bench.hpp) ------------------------------------------

py::dict bench_row_dict(const BenchRow& r) {
  py::dict d;
  d["task"] = r.task, d["version"] = r.version, d["policy"] = r.policy, d["seed"] = r.seed, d["layout"] = r.layout;
  d["users_seed"] = r.users_seed, d["users"] = r.users, d["objective"] = r.objective, d["reference"] = r.reference;
  d["reference_objective"] = r.reference_objective, d["fraction"] = r.fraction, d["complete"] = r.complete;
  d["home"] = r.home, d["collisions"] = r.collisions, d["boundary_events"] = r.boundary, d["energy_j"] = r.energy_j;
  d["protocol"] = r.protocol;
  return d;
}

BenchRow bench_row_of(const py::dict& d) {
  BenchRow r;
  r.task = d["task"].cast<std::string>(), r.version = d["version"].cast<int>(), r.policy = d["policy"].cast<std::string>();
  r.seed = d["seed"].cast<std::uint64_t>(), r.layout = d["layout"].cast<std::uint64_t>();
  r.users_seed = d["users_seed"].cast<std::uint64_t>(), r.users = d["users"].cast<int>();
  r.objective = d["objective"].cast<double>(), r.reference = d["reference"].cast<std::string>();
  r.reference_objective = d["reference_objective"].cast<double>(), r.fraction = d["fraction"].cast<double>();
  r.complete = d["complete"].cast<bool>(), r.home = d["home"].cast<int>(), r.collisions = d["collisions"].cast<int>();
  r.boundary = d["boundary_events"].cast<int>(), r.energy_j = d["energy_j"].cast<double>();
  r.protocol = d["protocol"].cast<std::string>();
  return r;
}

py::dict bench_task_dict(const BenchTask& t) {
  py::dict d;
  d["id"] = t.id, d["name"] = t.name, d["version"] = t.version, d["title"] = t.title, d["dir"] = t.dir;
  d["reference_note"] = t.reference_note, d["reference_rtol"] = t.reference_rtol;
  d["fingerprint"] = t.fingerprint, d["reference_checksum"] = t.reference_checksum;
  d["config"] = t.config;
  py::dict p;
  p["budget_steps"] = t.protocol.budget_steps, p["seeds"] = t.protocol.seeds, p["train_split"] = t.protocol.train_split;
  d["protocol"] = p;
  py::list refs;
  for (const auto& r : t.references) {
    py::dict x;
    x["layout"] = r.layout, x["users_seed"] = r.users_seed, x["users"] = r.users, x["reference"] = r.reference;
    x["objective"] = r.objective;
    refs.append(x);
  }
  d["references"] = refs;
  return d;
}

py::dict bench_summary_dict(const BenchSummary& x) {
  py::dict d;
  d["task"] = x.task, d["version"] = x.version, d["policy"] = x.policy, d["seeds"] = x.seeds, d["layouts"] = x.layouts;
  d["reference"] = x.reference, d["mean"] = x.mean, d["iqm"] = x.iqm, d["iqm_ci_low"] = x.iqm_low, d["iqm_ci_high"] = x.iqm_high;
  d["p5"] = x.p5, d["complete_rate"] = x.complete_rate, d["protocol"] = x.protocol;
  return d;
}
#endif

}  // namespace

PYBIND11_MODULE(_skyloop, m) {
  m.doc() = "skyloop: joint beamforming and trajectory optimisation for multi-UAV downlink networks (C++ core)";
  m.attr("__version__") = SKYLOOP_VERSION;  // the VERSION file, through CMake
  // Subnormal floats flushed to zero on the importing thread, as the command line does from its
  // first line (and as torch.set_flush_denormal(True)): the same numbers in Python as there.
  skyloop::flush_denormals();
  static py::exception<InputError> input_error(m, "InputError", PyExc_ValueError);
  py::register_exception_translator([](std::exception_ptr p) {
    try {
      if (p) std::rethrow_exception(p);
    } catch (const InputError& e) {
      PyErr_SetString(input_error.ptr(), e.what());
    }
  });

  m.def("set_data_dir", [](const std::string& d) { set_data_dir(d); },
        "where the shipped models and configs are (models/, configs/); set by the package at import");
  m.def("data_dir", &data_dir);

  py::class_<Config>(m, "Config", "A validated skyloop configuration (see `skyloop config show`).")
      .def(py::init([](std::optional<std::string> path, std::vector<std::string> overrides) {
             return make_config(path, overrides);
           }),
           py::arg("path") = py::none(), py::arg("overrides") = std::vector<std::string>{})
      .def("__getitem__", &field_value, py::arg("key"))
      .def("toml", [](const Config& c) { return to_toml(c); }, "the whole configuration as TOML (reloadable)")
      .def_static("keys", [] {
        std::vector<std::string> k;
        for (const auto& f : config_fields()) k.push_back(f.key);
        return k;
      });

  py::class_<Cluster>(m, "Cluster", "One UAV's cluster: G [K_n, L] complex (row k = h_k^H), its users, budget and noise.")
      .def(py::init([](Eigen::MatrixXcd G, double p_max, double noise, int uav, std::vector<int> users) {
             if (!(p_max > 0) || !std::isfinite(p_max))
               throw InputError("p_max = " + std::to_string(p_max) + " is out of range: allowed a finite power > 0 (W)");
             if (!(noise > 0) || !std::isfinite(noise))
               throw InputError("noise = " + std::to_string(noise) + " is out of range: allowed a finite power > 0 (W)");
             if (G.rows() < 1 || G.cols() < 1)
               throw InputError("G has shape [" + std::to_string(G.rows()) + ", " + std::to_string(G.cols()) +
                                "]: allowed a complex [K_n, L] array with K_n >= 1 users and L >= 1 antennas");
             if (!G.allFinite()) throw InputError("G has non-finite entries: allowed a finite complex [K_n, L] array");
             Cluster c;
             c.G = std::move(G);
             c.p_max = p_max;
             c.noise = noise;
             c.uav = uav;
             if (users.empty())
               for (int k = 0; k < c.G.rows(); ++k) users.push_back(k);
             if (static_cast<Eigen::Index>(users.size()) != c.G.rows())
               throw InputError("users has " + std::to_string(users.size()) + " entries: allowed one user index per row of G (" +
                                std::to_string(c.G.rows()) + ")");
             c.users = std::move(users);
             return c;
           }),
           py::arg("G"), py::arg("p_max"), py::arg("noise"), py::arg("uav") = 0, py::arg("users") = std::vector<int>{})
      .def_readonly("uav", &Cluster::uav)
      .def_readonly("users", &Cluster::users)
      .def_readonly("G", &Cluster::G)
      .def_readonly("p_max", &Cluster::p_max)
      .def_readonly("noise", &Cluster::noise)
      .def_readonly("bandwidth", &Cluster::bandwidth)
      .def_property_readonly("size", &Cluster::size)
      .def_property_readonly("antennas", &Cluster::antennas)
      .def("__repr__", [](const Cluster& c) {
        return "<Cluster uav " + std::to_string(c.uav) + ", " + std::to_string(c.size()) + " users, L = " +
               std::to_string(c.antennas()) + ">";
      });

  py::class_<Snapshot>(m, "Snapshot", "UAV positions [N, 2] and user positions [K, 2] (metres).")
      .def_readonly("uavs", &Snapshot::uavs)
      .def_readonly("users", &Snapshot::users);

  py::class_<Network>(m, "Network",
                      "Every non-empty cluster of a snapshot, the cross channels and the spectrum model "
                      "(channel.spectrum): cross[i] is [K_s, L] complex, row r = h^H from cluster i's UAV to served user r.")
      .def_property_readonly("spectrum", [](const Network& n) { return to_string(n.spectrum); })
      .def_readonly("uavs", &Network::uavs)
      .def_readonly("clusters", &Network::clusters)
      .def_readonly("served", &Network::served)
      .def_readonly("offset", &Network::offset)
      .def_readonly("cross", &Network::cross)
      .def("__repr__", [](const Network& n) {
        return "<Network " + to_string(n.spectrum) + ", " + std::to_string(n.clusters.size()) + " clusters, " +
               std::to_string(n.served_count()) + " served users>";
      });

  py::class_<SystemModel>(m, "SystemModel", "The paper's Section III model: LoS channels, association, clusters.")
      .def(py::init<const Config&>(), py::arg("config"))
      .def("random_snapshot", &SystemModel::random_snapshot, py::arg("uavs"), py::arg("users"), py::arg("seed"))
      .def("snapshot", [](const SystemModel&, const Config& cfg, const Array<double>& uavs, const Array<double>& users) {
             return Snapshot{positions_from(uavs, cfg, "uavs"), positions_from(users, cfg, "users")};
           }, py::arg("config"), py::arg("uavs"), py::arg("users"))
      .def("associate", [](const SystemModel& model, const Snapshot& s) { return model.associate(s).serving; }, py::arg("snapshot"),
           "serving UAV of every user, -1 where no UAV covers it")
      .def("clusters", py::overload_cast<const Snapshot&>(&SystemModel::clusters, py::const_), py::arg("snapshot"))
      .def("network", py::overload_cast<const Snapshot&>(&SystemModel::network, py::const_), py::arg("snapshot"),
           "the whole network of a snapshot under channel.spectrum")
      .def("channel", &SystemModel::channel, py::arg("ux"), py::arg("uy"), py::arg("x"), py::arg("y"), py::arg("slot") = 0,
           "h of the link from a UAV at (ux, uy) to the user at (x, y) in fast slot `slot` (0 <= slot < fast_slots)")
      .def_property_readonly("fast_slots", &SystemModel::fast_slots)
      .def("link", [](const SystemModel& self, double ux, double uy, double x, double y) {
             const char* names[4] = {"ux", "uy", "x", "y"};
             const double v[4] = {ux, uy, x, y};
             for (int i = 0; i < 4; ++i)
               if (!std::isfinite(v[i]))
                 throw InputError(std::string(names[i]) + " = " + format_double(v[i]) + " is not finite: allowed a finite position (m)");
             return link_dict(self.channel_model(), ux, uy, x, y);
           },
           py::arg("ux"), py::arg("uy"), py::arg("x"), py::arg("y"),
           "the link's large-scale state: p_los, los, path_loss_db, shadowing_db, k_factor_db, gain, distance_m, elevation_deg");

  py::class_<Beamformer, std::shared_ptr<Beamformer>>(m, "Beamformer", "A registered beamformer, by its spec string.")
      .def_property_readonly("name", &Beamformer::name)
      .def("design", [](const Beamformer& b, const Cluster& c) {
             py::gil_scoped_release nogil;
             return b.design(c);
           }, py::arg("cluster"), "W [L, K_n] complex, column k = w_k")
      .def("design_batch", [](const Beamformer& b, const std::vector<Cluster>& cs, int threads) {
             py::gil_scoped_release nogil;
             return b.design_batch(cs, threads);
           }, py::arg("clusters"), py::arg("threads") = 1)
      .def("design_network", [](const Beamformer& b, const Network& n) {
             py::gil_scoped_release nogil;
             return b.design_network(n);
           }, py::arg("network"), "one W per cluster of the network (coordinated beamformers see the cross channels)")
      .def("design_networks", [](const Beamformer& b, const std::vector<Network>& ns, int threads) {
             py::gil_scoped_release nogil;
             return b.design_networks(ns, threads);
           }, py::arg("networks"), py::arg("threads") = 1, "design_network of each; learned models batch them in one pass")
      .def_property_readonly("coordinated", &Beamformer::coordinated);
  m.def("beamformer", [](const std::string& spec, const Config& cfg) {
          return std::shared_ptr<Beamformer>(builtin_beamformers().create(spec, cfg));
        }, py::arg("spec"), py::arg("config"));
  m.def("beamformers", [] { return builtin_beamformers().list(); }, "(name, description) of every registered beamformer");

  const auto check_w = [](const Cluster& c, const Eigen::MatrixXcd& W) {
    if (W.rows() != c.antennas() || W.cols() != c.size())
      throw InputError("W has shape [" + std::to_string(W.rows()) + ", " + std::to_string(W.cols()) + "]: allowed [" +
                       std::to_string(c.antennas()) + ", " + std::to_string(c.size()) + "] (antennas, users of the cluster)");
  };
  m.def("sinr", [check_w](const Cluster& c, const Eigen::MatrixXcd& W) { check_w(c, W); return skyloop::sinr(c, W); },
        py::arg("cluster"), py::arg("W"));
  m.def("rates", [check_w](const Cluster& c, const Eigen::MatrixXcd& W) { check_w(c, W); return skyloop::rates(c, W); },
        py::arg("cluster"), py::arg("W"));
  m.def("sum_rate", [check_w](const Cluster& c, const Eigen::MatrixXcd& W) { check_w(c, W); return skyloop::sum_rate(c, W); },
        py::arg("cluster"), py::arg("W"));
  const auto check_net = [check_w](const Network& n, const std::vector<Eigen::MatrixXcd>& W) {
    if (W.size() != n.clusters.size())
      throw InputError("W has " + std::to_string(W.size()) + " matrices: allowed one per cluster (" +
                       std::to_string(n.clusters.size()) + ")");
    for (std::size_t i = 0; i < W.size(); ++i) check_w(n.clusters[i], W[i]);
  };
  m.def("network_sum_rate", [check_net](const Network& n, const std::vector<Eigen::MatrixXcd>& W) {
          check_net(n, W);
          return skyloop::network_sum_rate(n, W);
        }, py::arg("network"), py::arg("W"), "network sum rate under the network's spectrum model");
  m.def("user_powers", [check_net](const Network& n, const std::vector<Eigen::MatrixXcd>& W) {
          check_net(n, W);
          std::vector<std::vector<std::map<std::string, double>>> out;
          for (const auto& cluster : skyloop::user_powers(n, W)) {
            out.emplace_back();
            for (const auto& u : cluster)
              out.back().push_back({{"signal", u.signal}, {"intra", u.intra}, {"inter", u.inter}, {"noise", u.noise}, {"sinr", u.sinr()}});
          }
          return out;
        }, py::arg("network"), py::arg("W"),
        "per cluster, per user: received signal, intra- and inter-cluster interference and noise (W), and the SINR");

  py::class_<PyVecEnv>(m, "VecEnv")
      .def(py::init<const Config&, int, std::uint64_t, const std::string&, std::vector<std::uint64_t>>(), py::arg("config"),
           py::arg("num_envs"), py::arg("seed"), py::arg("oracle") = "", py::arg("layouts") = std::vector<std::uint64_t>{})
      .def_property_readonly("num_envs", &PyVecEnv::num_envs)
      .def_property_readonly("agents", &PyVecEnv::agents)
      .def_property_readonly("spec", &PyVecEnv::spec_dict, "every array's layout: fields, offsets, sizes, bounds")
      .def_property_readonly("config", &PyVecEnv::config)
      .def("reset", &PyVecEnv::reset, py::arg("seed") = py::none())
      .def("step", &PyVecEnv::step, py::arg("actions"))
      .def("begin_turns", &PyVecEnv::begin_turns, py::arg("passes") = py::none())
      .def("take_turn", &PyVecEnv::take_turn, py::arg("actions"))
      .def("step_turns", &PyVecEnv::step_turns)
      .def("positions", &PyVecEnv::positions)
      .def("users", &PyVecEnv::users, py::arg("env") = 0)
      .def("hit_rate", &PyVecEnv::hit_rate, "the rate oracles' cache hit rate so far")
      .def("_reference", &PyVecEnv::reference, py::arg("env"))
      .def("_bench_cpp_steps", &PyVecEnv::bench_cpp_steps, py::arg("actions"));

  // Benchmark helpers: the same work in C++ alone, timed in the same process (python/bench).
  m.def("_bench_cpp_batch", [](const Beamformer& b, const std::vector<Cluster>& cs, int repeats) {
    py::gil_scoped_release nogil;
    const auto t0 = std::chrono::steady_clock::now();
    for (int r = 0; r < repeats; ++r) (void)b.design_batch(cs, 1);
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count() / repeats;
  });

  m.def("config_from_toml", [](const std::string& text) {
          Config cfg;
          apply_toml(cfg, text, "configuration");
          finalise(cfg);
          return cfg;
        }, py::arg("text"), "a configuration from its TOML text (Config.toml()); how a Config unpickles");
#ifdef SKYLOOP_HAS_TORCH
  m.def("policy_config", &policy_config, py::arg("path"), "the training configuration a policy (a run directory or its policy.pt) holds");
  m.def("evaluate_layouts", &evaluate_layouts_py, py::arg("config"), py::arg("policies"), py::arg("planners"),
        py::arg("layouts"), py::arg("split"), py::arg("first"), py::arg("unsafe"), py::arg("rollout"), py::arg("cache"),
        py::arg("threads"));
#endif
#ifdef SKYLOOP_HAS_TORCH
  m.def("bench_tasks", &bench_task_ids, "every benchmark task's id");
  m.def("bench_task", [](const std::string& id) { return bench_task_dict(load_bench_task(id)); }, py::arg("task"));
  m.def("bench_run", [](const std::string& id, std::vector<std::string> planners, std::vector<std::string> policies,
                        std::vector<std::uint64_t> seeds, const std::string& label, int threads) {
          const auto t = load_bench_task(id);
          BenchRunOptions o;
          o.planners = std::move(planners), o.policies = std::move(policies), o.seeds = std::move(seeds);
          o.policy_label = label, o.threads = threads;
          std::vector<BenchRow> rows;
          {
            py::gil_scoped_release nogil;
            rows = run_bench(t, o, nullptr);
          }
          py::list out;
          for (const auto& r : rows) out.append(bench_row_dict(r));
          return out;
        }, py::arg("task"), py::arg("planners"), py::arg("policies"), py::arg("seeds"), py::arg("label"), py::arg("threads"));
  m.def("bench_outputs", [](const std::string& id, const py::list& rows_in) {
          const auto t = load_bench_task(id);
          std::vector<BenchRow> rows;
          for (const auto& r : rows_in) rows.push_back(bench_row_of(r.cast<py::dict>()));
          const auto summary = summarise_bench(t, rows);
          py::list sum;
          for (const auto& x : summary) sum.append(bench_summary_dict(x));
          py::dict files;
          files["rows.csv"] = bench_rows_csv(rows);
          files["summary.csv"] = bench_summary_csv(summary);
          files["profile.csv"] = bench_profile_csv(rows);
          files["marl_eval.json"] = bench_marl_eval_json(t, rows);
          files["config.toml"] = to_toml(t.config);
          py::dict out;
          out["summary"] = sum;
          out["files"] = files;
          return out;
        }, py::arg("task"), py::arg("rows"), "the summary (mean, IQM and its 95% stratified bootstrap interval, p5, completion) and the output files");
  m.def("interquartile_mean", &interquartile_mean, py::arg("scores"));
  m.def("iqm_interval", [](const std::vector<std::vector<double>>& runs_by_layout, int reps, std::uint64_t seed) {
          double lo = 0, hi = 0;
          iqm_interval(runs_by_layout, reps, seed, lo, hi);
          return py::make_tuple(lo, hi);
        }, py::arg("runs_by_layout"), py::arg("reps"), py::arg("seed"));
#endif
  m.def("plan", &plan, py::arg("config"), py::arg("planner"), py::arg("users_seed") = 3, py::arg("users") = py::none(),
        py::arg("planner_seed") = py::none());
  m.attr("ACTIONS") = py::tuple(py::cast(grid_actions().names));
  m.attr("PLANNERS") = py::tuple(py::cast(builtin_planners().names()));
  m.attr("LEARNERS") = py::tuple(py::cast(learner_names()));
  m.attr("MAX_SEED") = static_cast<std::uint64_t>(find_field("run.seed")->hi);  // the seeds every entry point takes: run.seed's range
  m.attr("MAX_SEQUENTIAL_PASSES") = kMaxSequentialPasses;
#ifdef SKYLOOP_HAS_TORCH
  m.attr("HAS_TORCH") = true;
#else
  m.attr("HAS_TORCH") = false;
#endif
  m.def("env_spec", [](const Config& cfg, int users) {
          if (users < 1) throw InputError("users = " + std::to_string(users) + " is out of range: allowed at least 1");
          return env_spec_dict(make_env_spec(cfg, static_cast<int>(cfg.trajectory.starts.size()), users));
        }, py::arg("config"), py::arg("users"), "the environment's spec for a configuration and a user count");
  m.def("derive_seed", [](std::uint64_t base, std::uint64_t i) { return derive_seed(base, i); }, py::arg("base"), py::arg("index"),
        "the seed of item `index` of a stream (snapshot i of `beamform eval --seed base` is random_snapshot(.., derive_seed(base, i)))");
}
