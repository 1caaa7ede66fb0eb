// skyloop.VecEnv: the batch-first environment of the Python module (EnvPool's protocol): M copies
// of the trajectory environment stepped as one batch, every array laid out by the environment's
// spec, the GIL released while C++ steps.
#include "bindings.hpp"

#include <pybind11/stl.h>

#include <cmath>
#include <mutex>
#include <optional>

#include "skyloop/core/config_io.hpp"
#include "skyloop/core/error.hpp"
#include "skyloop/core/io.hpp"
#include "skyloop/core/parallel.hpp"
#include "skyloop/core/rng.hpp"
#include "skyloop/env/uav_env.hpp"
#include "skyloop/env/vec_env.hpp"
#include "skyloop/experiments/builtin.hpp"
#include "skyloop/planning/safety.hpp"

namespace py = pybind11;

namespace skyloop::pybind {

namespace {

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

/// The batch-first environment: M copies of the trajectory environment stepped as one batch.
/// Every array's layout is the environment's spec (UavEnv::spec()); the rows are written by the
/// environment's own writers. Calls from several Python threads are serialised by a mutex (taken
/// with the GIL released): a VecEnv is safe to share, not parallel.
/// One info field over the environments: an [M] array of its dtype.
py::array info_column(const InfoField& f, const std::vector<StepInfo>& info) {
  const auto M = static_cast<py::ssize_t>(info.size());
  const std::string dtype = f.dtype;
  if (dtype == "bool") {
    py::array_t<bool> a({M});
    for (py::ssize_t i = 0; i < M; ++i) a.mutable_at(i) = f.get(info[static_cast<std::size_t>(i)]) != 0;
    return std::move(a);
  }
  if (dtype == "int32") {
    py::array_t<std::int32_t> a({M});
    for (py::ssize_t i = 0; i < M; ++i) a.mutable_at(i) = static_cast<std::int32_t>(f.get(info[static_cast<std::size_t>(i)]));
    return std::move(a);
  }
  py::array_t<double> a({M});
  for (py::ssize_t i = 0; i < M; ++i) a.mutable_at(i) = f.get(info[static_cast<std::size_t>(i)]);
  return std::move(a);
}

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
    auto terminated = py::array_t<bool>({M}), truncated = py::array_t<bool>({M});
    for (int i = 0; i < M; ++i) {
      const auto& s = info[static_cast<std::size_t>(i)];
      reward.mutable_at(i) = static_cast<float>(s.reward);
      // terminated: every UAV home (the MDP's end, whether or not the mission met its energy
      // budget: success says that); truncated: T_max reached first.
      terminated.mutable_at(i) = s.done && s.home == N;
      truncated.mutable_at(i) = s.done && s.home < N;
    }
    d["reward"] = reward;
    d["terminated"] = terminated;
    d["truncated"] = truncated;
    py::dict inf;
    for (const InfoField& f : step_info_fields()) inf[f.name] = info_column(f, info);  // the spec's info fields
    inf["final_obs"] = final_obs;
    inf["final_state"] = final_state;
    d["info"] = inf;
    return d;
  }

  py::dict positions() {
    const int M = num_envs_, N = agents();
    auto p = Array<double>({M, N, 3});  // (x, y, altitude z)
    auto d = Array<double>({M, N, 3});
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
          for (int c = 0; c < 3; ++c) {
            pp[(static_cast<std::size_t>(i) * N + n) * 3 + c] = e.positions()(n, c);
            pd[(static_cast<std::size_t>(i) * N + n) * 3 + c] = e.destinations()(n, c);
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

  /// Benchmark helper: `actions` [steps, M, N] stepped by the C++ VecEnv on this very environment
  /// (same oracles, same warm caches), each step's observation, state, agent-state and mask arrays
  /// written as step() writes them (fill), into arrays allocated once; returns seconds. The same
  /// work as a Python step: what the step adds beyond it is the binding (checks, new arrays, the
  /// info columns, the dicts).
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
    Arrays out = allocate();
    py::gil_scoped_release nogil;
    std::lock_guard<std::mutex> lock(mutex_);
    const auto t0 = std::chrono::steady_clock::now();
    for (py::ssize_t t = 0; t < actions.shape(0); ++t) {
      for (int i = 0; i < num_envs_; ++i)
        for (int n = 0; n < agents(); ++n) joint[static_cast<std::size_t>(i)][static_cast<std::size_t>(n)] = static_cast<int>(a(t, i, n));
      vec_->step(joint);
      fill(out);
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
      throw InputError("begin_turns: trajectory.mobility = \"" + cfg_.trajectory.mobility + "\" takes velocity commands, which have no turns: allowed with " + lattice_dynamics_names());
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

}  // namespace

/// The environment's spec (skyloop/env/spec.hpp) as plain Python values.
py::dict env_spec_dict(const EnvSpec& e) {
  py::dict d;
  d["agents"] = e.agents, d["users"] = e.users;
  d["num_actions"] = e.action.count();
  d["actions"] = py::tuple(py::cast(e.action.names));
  d["hover"] = e.action.hover;  // the action that stays in place (an arrived UAV's only one)
  // The continuous model: commands in [-1, 1]^dims (the actions above are its primitives); 0: discrete.
  d["dims"] = e.action.dims;
  d["observation_kind"] = name_of(e.observation_kind), d["state_kind"] = name_of(e.state_kind);  // marl.encoder, env.state
  d["obs"] = array_spec_dict(e.obs, e.agents);
  d["state"] = array_spec_dict(e.state, e.agents);
  d["agent_context"] = array_spec_dict(e.agent_context, e.agents);
  d["agent_state"] = array_spec_dict(e.agent_state, e.agents);
  d["action_mask"] = array_spec_dict(e.action_mask, e.agents);
  d["paper_obs"] = array_spec_dict(e.paper_obs, e.agents);
  d["set_obs"] = array_spec_dict(e.set_obs, e.agents);
  py::list info;  // the step's info fields (step_info_fields): what every info dict holds, per environment
  for (const InfoField& f : step_info_fields()) {
    py::dict x;
    x["name"] = f.name, x["dtype"] = f.dtype, x["help"] = f.help;
    info.append(x);
  }
  d["info"] = info;
  return d;
}

void bind_vec_env(py::module_& m) {
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
      .def("_bench_cpp_steps", &PyVecEnv::bench_cpp_steps, py::arg("actions"));}

}  // namespace skyloop::pybind
