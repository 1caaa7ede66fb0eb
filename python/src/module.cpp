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
#include <filesystem>

#include "skyloop/channel/rates.hpp"
#include "skyloop/core/config_io.hpp"
#include "skyloop/core/error.hpp"
#include "skyloop/core/paths.hpp"
#include "skyloop/core/rng.hpp"
#include "skyloop/env/uav_env.hpp"
#include "skyloop/experiments/builtin.hpp"
#include "skyloop/planning/planners.hpp"
#include "skyloop/planning/safety.hpp"
#ifdef SKYLOOP_HAS_TORCH
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
  if (!f) {
    Config probe = cfg;
    apply_override(probe, key + "=0");  // throws the one-line "unknown key" error with the allowed keys
  }
  const FieldValue v = f->get(cfg);
  if (auto b = std::get_if<bool>(&v)) return py::bool_(*b);
  if (auto i = std::get_if<std::int64_t>(&v)) return py::int_(*i);
  if (auto d = std::get_if<double>(&v)) return py::float_(*d);
  if (auto s = std::get_if<std::string>(&v)) return py::str(*s);
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

/// The batch-first environment: M copies of the trajectory environment stepped as one batch.
class PyVecEnv {
 public:
  PyVecEnv(const Config& cfg, int num_envs, std::uint64_t seed, const std::string& oracle)
      : cfg_(cfg), num_envs_(num_envs) {
    if (num_envs < 1 || num_envs > 1 << 20)
      throw InputError("num_envs = " + std::to_string(num_envs) + " is out of range: allowed an integer in [1, 1048576]");
    if (!oracle.empty()) apply_override(cfg_, "env.oracle=" + toml_string(oracle));
    bf_ = builtin_beamformers().create(cfg_.env.oracle, cfg_);
    build(seed);
  }

  int num_envs() const { return num_envs_; }
  int agents() const { return vec_->env(0).uavs(); }
  int obs_size() const { return UavEnv::observation_size(); }
  int state_size() const { return vec_->env(0).state_size(); }
  int agent_state_size() const { return vec_->env(0).agent_state_size(); }

  py::dict reset(std::optional<std::uint64_t> seed) {
    if (seed) {
      build(*seed);
    } else {
      py::gil_scoped_release nogil;
      vec_->reset();
    }
    py::dict out = observe();
    return out;
  }

  py::dict step(const py::array& actions_in) {
    const int M = num_envs_, N = agents();
    const char kind = actions_in.dtype().kind();
    if (kind != 'i' && kind != 'u')
      throw InputError("actions have dtype " + py::str(actions_in.dtype()).cast<std::string>() +
                       ": allowed an integer array of shape [num_envs, agents] with values 0..4 (UP, DOWN, LEFT, RIGHT, STAY)");
    const auto a = Array<std::int64_t>::ensure(actions_in);
    if (a.ndim() != 2 || a.shape(0) != M || a.shape(1) != N)
      throw InputError("actions have shape " + shape_of(actions_in) + ": allowed [" + std::to_string(M) + ", " +
                       std::to_string(N) + "] (num_envs, agents)");
    auto& joint = joint_;
    joint.resize(static_cast<std::size_t>(M));
    for (auto& j : joint) j.resize(static_cast<std::size_t>(N));
    const auto r = a.unchecked<2>();
    for (int i = 0; i < M; ++i)
      for (int n = 0; n < N; ++n) {
        const auto v = r(i, n);
        if (v < 0 || v >= kActions)
          throw InputError("actions[" + std::to_string(i) + ", " + std::to_string(n) + "] = " + std::to_string(v) +
                           " is invalid: allowed 0..4 (UP, DOWN, LEFT, RIGHT, STAY)");
        // An arrived UAV is locked to STAY (its mask is [0,0,0,0,1]); any other action is taken as STAY.
        joint[static_cast<std::size_t>(i)][static_cast<std::size_t>(n)] = static_cast<int>(v);
      }
    // Final observations of the environments that finish in this step (zeros elsewhere). Most
    // steps finish none: they share one read-only zero array instead of allocating.
    std::vector<float> fo, fs;
    std::vector<StepInfo> info;
    {
      py::gil_scoped_release nogil;
      info = vec_->step(joint, [&](std::size_t i) {
        if (fo.empty()) fo.assign(static_cast<std::size_t>(M * N * obs_size()), 0.0f), fs.assign(static_cast<std::size_t>(M * state_size()), 0.0f);
        write_obs(vec_->env(static_cast<int>(i)), fo.data() + i * static_cast<std::size_t>(N * obs_size()));
        write_state(vec_->env(static_cast<int>(i)), fs.data() + i * static_cast<std::size_t>(state_size()));
      });
    }
    py::array final_obs, final_state;
    if (fo.empty()) {
      if (zero_obs_.size() == 0) {
        zero_obs_ = Array<float>({M, N, obs_size()});
        zero_state_ = Array<float>({M, state_size()});
        std::fill_n(zero_obs_.mutable_data(), zero_obs_.size(), 0.0f);
        std::fill_n(zero_state_.mutable_data(), zero_state_.size(), 0.0f);
        py::detail::array_proxy(zero_obs_.ptr())->flags &= ~py::detail::npy_api::NPY_ARRAY_WRITEABLE_;
        py::detail::array_proxy(zero_state_.ptr())->flags &= ~py::detail::npy_api::NPY_ARRAY_WRITEABLE_;
      }
      final_obs = zero_obs_;
      final_state = zero_state_;
    } else {
      final_obs = Array<float>({M, N, obs_size()}, fo.data());
      final_state = Array<float>({M, state_size()}, fs.data());
    }
    py::dict out = observe();
    auto reward = Array<float>({M});
    auto sum_rate = Array<double>({M}), objective = Array<double>({M});
    auto terminated = py::array_t<bool>({M}), truncated = py::array_t<bool>({M});
    auto collisions = Array<std::int32_t>({M}), boundary = Array<std::int32_t>({M}), arrivals = Array<std::int32_t>({M});
    auto home = Array<std::int32_t>({M}), T = Array<std::int32_t>({M});
    auto success = py::array_t<bool>({M});
    auto episode_reward = Array<double>({M});
    for (int i = 0; i < M; ++i) {
      const auto& s = info[static_cast<std::size_t>(i)];
      reward.mutable_at(i) = static_cast<float>(s.reward);
      sum_rate.mutable_at(i) = s.sum_rate;
      objective.mutable_at(i) = s.objective;
      // terminated: every UAV home (the MDP's end); truncated: T_max reached first.
      terminated.mutable_at(i) = s.done && s.success;
      truncated.mutable_at(i) = s.done && !s.success;
      collisions.mutable_at(i) = s.collisions;
      boundary.mutable_at(i) = s.boundary;
      arrivals.mutable_at(i) = s.arrivals;
      home.mutable_at(i) = s.home;
      T.mutable_at(i) = s.T;
      success.mutable_at(i) = s.success;
      episode_reward.mutable_at(i) = s.episode_reward;
    }
    out["reward"] = reward;
    out["terminated"] = terminated;
    out["truncated"] = truncated;
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
    inf["final_obs"] = final_obs;
    inf["final_state"] = final_state;
    out["info"] = inf;
    return out;
  }

  py::dict positions() const {
    const int M = num_envs_, N = agents();
    auto p = Array<double>({M, N, 2});
    auto d = Array<double>({M, N, 2});
    for (int i = 0; i < M; ++i)
      for (int n = 0; n < N; ++n)
        for (int c = 0; c < 2; ++c) {
          p.mutable_at(i, n, c) = vec_->env(i).positions()(n, c);
          d.mutable_at(i, n, c) = vec_->env(i).destinations()(n, c);
        }
    py::dict out;
    out["uavs"] = p;
    out["destinations"] = d;
    out["t"] = [&] {
      auto t = Array<std::int32_t>({M});
      for (int i = 0; i < M; ++i) t.mutable_at(i) = vec_->env(i).t();
      return t;
    }();
    return out;
  }

  py::array users(int i) const {
    if (i < 0 || i >= num_envs_) throw InputError("env index " + std::to_string(i) + " is out of range: allowed 0.." + std::to_string(num_envs_ - 1));
    const Positions& u = const_cast<VecEnv&>(*vec_).env(i).oracle().users();
    auto out = Array<double>({static_cast<py::ssize_t>(u.rows()), static_cast<py::ssize_t>(2)});
    for (Eigen::Index k = 0; k < u.rows(); ++k) out.mutable_at(k, 0) = u(k, 0), out.mutable_at(k, 1) = u(k, 1);
    return out;
  }

  const Config& config() const { return cfg_; }

  /// Benchmark helper: `actions` [steps, M, N] stepped by the C++ VecEnv alone (no observation
  /// arrays), on this very environment (same oracles, same warm caches); returns seconds.
  double bench_cpp_steps(const Array<std::int64_t>& actions) {
    if (actions.ndim() != 3 || actions.shape(1) != num_envs_ || actions.shape(2) != agents())
      throw InputError("actions: allowed [steps, num_envs, agents]");
    std::vector<std::vector<int>> joint(static_cast<std::size_t>(num_envs_), std::vector<int>(static_cast<std::size_t>(agents())));
    const auto a = actions.unchecked<3>();
    py::gil_scoped_release nogil;
    const auto t0 = std::chrono::steady_clock::now();
    for (py::ssize_t t = 0; t < actions.shape(0); ++t) {
      for (int i = 0; i < num_envs_; ++i)
        for (int n = 0; n < agents(); ++n) joint[static_cast<std::size_t>(i)][static_cast<std::size_t>(n)] = static_cast<int>(a(t, i, n));
      vec_->step(joint);
    }
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  }

  /// Cache hit rate of the environments' rate oracles so far.
  double hit_rate() const {
    double hits = 0, total = 0;
    for (int i = 0; i < num_envs_; ++i) {
      auto& o = const_cast<VecEnv&>(*vec_).env(i).oracle();
      hits += static_cast<double>(o.stats().hits);
      total += static_cast<double>(o.stats().hits + o.stats().misses);
    }
    return total > 0 ? hits / total : 0.0;
  }

 private:
  static std::string shape_of(const py::array& a) {
    std::string s = "[";
    for (py::ssize_t d = 0; d < a.ndim(); ++d) s += (d ? ", " : "") + std::to_string(a.shape(d));
    return s + "]";
  }

  void build(std::uint64_t seed) {
    py::gil_scoped_release nogil;
    vec_ = std::make_unique<VecEnv>(cfg_, bf_, num_envs_, seed);
  }

  void write_obs(const UavEnv& e, float* dst) const {
    for (int n = 0; n < e.uavs(); ++n) e.write_observation(n, dst + n * obs_size());
  }
  void write_state(const UavEnv& e, float* dst) const { e.write_state(dst); }

  /// Current observations of every environment: obs [M, N, 11], state [M, S], agent_state
  /// [M, N, S + N + 11], action_mask [M, N, 5] (int8: the reachability mask of marl.action_mask,
  /// skyloop/planning/safety.hpp, else every action; an arrived UAV: [0, 0, 0, 0, 1]).
  py::dict observe() const {
    const int M = num_envs_, N = agents(), O = obs_size(), S = state_size(), A = agent_state_size();
    auto obs = Array<float>({M, N, O});
    auto state = Array<float>({M, S});
    auto agent_state = Array<float>({M, N, A});
    auto mask = Array<std::int8_t>({M, N, kActions});
    {
      float* po = obs.mutable_data();
      float* ps = state.mutable_data();
      float* pa = agent_state.mutable_data();
      std::int8_t* pm = mask.mutable_data();
      py::gil_scoped_release nogil;
      for (int i = 0; i < M; ++i) {
        const UavEnv& e = vec_->env(i);
        write_obs(e, po + static_cast<std::size_t>(i) * N * O);
        write_state(e, ps + static_cast<std::size_t>(i) * S);
        for (int n = 0; n < N; ++n) {
          float* row = pa + (static_cast<std::size_t>(i) * N + n) * A;
          std::copy(ps + static_cast<std::size_t>(i) * S, ps + static_cast<std::size_t>(i + 1) * S, row);
          for (int m = 0; m < N; ++m) row[S + m] = m == n ? 1.0f : 0.0f;
          std::copy(po + (static_cast<std::size_t>(i) * N + n) * O, po + (static_cast<std::size_t>(i) * N + n + 1) * O, row + S + N);
          std::int8_t* mk = pm + (static_cast<std::size_t>(i) * N + n) * kActions;
          const unsigned allowed = allowed_moves(e, n, SafetyOptions{cfg_.marl.action_mask, false});
          for (int a = 0; a < kActions; ++a) mk[a] = (allowed >> a & 1u) ? 1 : 0;
        }
      }
    }
    py::dict out;
    out["obs"] = obs;
    out["state"] = state;
    out["agent_state"] = agent_state;
    out["action_mask"] = mask;
    return out;
  }

  Config cfg_;
  int num_envs_;
  std::shared_ptr<const Beamformer> bf_;
  std::unique_ptr<VecEnv> vec_;
  std::vector<std::vector<int>> joint_;  // the joint actions, reused across steps
  Array<float> zero_obs_, zero_state_;    // read-only zeros: final_obs / final_state when no episode ends
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
  py::dict d;
  d["planner"] = r.planner;
  d["positions"] = pos;
  d["actions"] = act;
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
  auto bf = builtin_beamformers().create(cfg.env.oracle, cfg);
  const Positions users = users_xy ? positions_from(Array<double>::ensure(*users_xy), cfg, "users")
                                   : make_users(cfg, cfg.scenario.users, users_seed);
  // The random planner's stream: as `skyloop plan --seed S` (derive_seed(S, "RAND")) unless given.
  std::unique_ptr<Planner> p = make_planner(planner, planner_seed ? *planner_seed : derive_seed(users_seed, 0x52414e44ULL));
#ifdef SKYLOOP_HAS_TORCH
  if (!p && !planner.empty() && (std::filesystem::is_directory(planner) || std::filesystem::exists(planner)))
    p = MarlPolicy::load(planner);
#endif
  if (!p)
    throw InputError("planner '" + planner + "' is unknown: allowed " + kPlannerNames + ", or a trained policy directory");
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
                             int layouts, const std::string& split, std::uint64_t first, bool unsafe, const std::string& cache,
                             int threads) {
  LayoutEvalOptions opt;
  opt.layouts = layouts;
  opt.split = parse_layout_split(split, "split");
  opt.first = first;
  opt.policies = std::move(policies);
  opt.planners = std::move(planners);
  opt.unsafe = unsafe;
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
    d["optimum"] = r.optimum, d["fraction"] = r.fraction, d["T"] = r.T, d["home"] = r.home, d["complete"] = r.complete;
    d["collisions"] = r.collisions, d["boundary_events"] = r.boundary, d["seconds"] = r.seconds;
    rl.append(d);
  }
  for (const auto& x : summarise_layouts(rows)) {
    py::dict d;
    d["seed"] = cfg.run.seed, d["split"] = split, d["planner"] = x.planner, d["layouts"] = x.layouts;
    d["complete_rate"] = x.complete, d["collisions"] = x.collisions, d["boundary_events"] = x.boundary;
    d["mean_home"] = x.arrivals, d["mean_objective"] = x.objective, d["fraction_mean"] = x.fraction_mean;
    d["fraction_p5"] = x.fraction_p5, d["fraction_worst"] = x.fraction_worst;
    sl.append(d);
  }
  py::dict out;
  out["rows"] = rl;
  out["summary"] = sl;
  return out;
}
#endif

}  // namespace

PYBIND11_MODULE(_skyloop, m) {
  m.doc() = "skyloop: joint beamforming and trajectory optimisation for multi-UAV downlink networks (C++ core)";
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
             if (!(p_max > 0) || !(noise > 0)) throw InputError("p_max and noise must be positive (W)");
             if (!G.allFinite()) throw InputError("G has non-finite entries: allowed a finite complex [K_n, L] array");
             Cluster c;
             c.G = std::move(G);
             c.p_max = p_max;
             c.noise = noise;
             c.uav = uav;
             if (users.empty())
               for (int k = 0; k < c.G.rows(); ++k) users.push_back(k);
             if (static_cast<Eigen::Index>(users.size()) != c.G.rows()) throw InputError("users must name one user per row of G");
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
      .def("channel", &SystemModel::channel, py::arg("ux"), py::arg("uy"), py::arg("x"), py::arg("y"));

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
      .def(py::init<const Config&, int, std::uint64_t, const std::string&>(), py::arg("config"), py::arg("num_envs"),
           py::arg("seed"), py::arg("oracle") = "")
      .def_property_readonly("num_envs", &PyVecEnv::num_envs)
      .def_property_readonly("agents", &PyVecEnv::agents)
      .def_property_readonly("obs_size", &PyVecEnv::obs_size)
      .def_property_readonly("state_size", &PyVecEnv::state_size)
      .def_property_readonly("agent_state_size", &PyVecEnv::agent_state_size)
      .def_property_readonly("config", &PyVecEnv::config)
      .def("reset", &PyVecEnv::reset, py::arg("seed") = py::none())
      .def("step", &PyVecEnv::step, py::arg("actions"))
      .def("positions", &PyVecEnv::positions)
      .def("users", &PyVecEnv::users, py::arg("env") = 0)
      .def("hit_rate", &PyVecEnv::hit_rate, "the rate oracles' cache hit rate so far")
      .def("_bench_cpp_steps", &PyVecEnv::bench_cpp_steps, py::arg("actions"));

  // Benchmark helpers: the same work in C++ alone, timed in the same process (python/bench).
  m.def("_bench_cpp_batch", [](const Beamformer& b, const std::vector<Cluster>& cs, int repeats) {
    py::gil_scoped_release nogil;
    const auto t0 = std::chrono::steady_clock::now();
    for (int r = 0; r < repeats; ++r) (void)b.design_batch(cs, 1);
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count() / repeats;
  });

#ifdef SKYLOOP_HAS_TORCH
  m.def("evaluate_layouts", &evaluate_layouts_py, py::arg("config"), py::arg("policies"), py::arg("planners"),
        py::arg("layouts"), py::arg("split"), py::arg("first"), py::arg("unsafe"), py::arg("cache"), py::arg("threads"));
#endif
  m.def("plan", &plan, py::arg("config"), py::arg("planner"), py::arg("users_seed") = 3, py::arg("users") = py::none(),
        py::arg("planner_seed") = py::none());
  m.attr("ACTIONS") = py::make_tuple("UP", "DOWN", "LEFT", "RIGHT", "STAY");
  m.def("derive_seed", [](std::uint64_t base, std::uint64_t i) { return derive_seed(base, i); }, py::arg("base"), py::arg("index"),
        "the seed of item `index` of a stream (snapshot i of `beamform eval --seed base` is random_snapshot(.., derive_seed(base, i)))");
}
