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

#include "bindings.hpp"

#include <chrono>
#include <cmath>
#include <optional>
#include <filesystem>
#include <mutex>

#include "skyloop/env/vec_env.hpp"
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

using skyloop::pybind::Array;
using skyloop::pybind::bind_vec_env;
using skyloop::pybind::env_spec_dict;

namespace {

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

/// Points [n, 2] (x, y) in the area; with `altitudes`, [n, 3] (x, y, z) too, z above the users' antennas.
Positions positions_from(const Array<double>& a, const Config& cfg, const std::string& what, bool altitudes = false) {
  const bool three = altitudes && a.ndim() == 2 && a.shape(1) == 3;
  if (a.ndim() != 2 || (a.shape(1) != 2 && !three))
    throw InputError(what + " has shape " + std::to_string(a.ndim()) + "-d: allowed an [n, 2] array of (x, y) in metres" +
                     (altitudes ? " or an [n, 3] array of (x, y, altitude z)" : ""));
  std::vector<Point2> pts;
  for (py::ssize_t i = 0; i < a.shape(0); ++i) pts.push_back({a.at(i, 0), a.at(i, 1)});
  if (pts.empty()) throw InputError(what + " is empty: allowed at least one (x, y) point");
  const Positions xy = positions_in_area(pts, cfg, what);
  if (!three) return xy;
  Positions p(xy.rows(), 3);
  p.leftCols(2) = xy;
  for (py::ssize_t i = 0; i < a.shape(0); ++i) {
    const double z = a.at(i, 2);
    if (!std::isfinite(z) || z - cfg.scenario.user_height_m < cfg.channel.d0_m)
      throw InputError(what + "[" + std::to_string(i) + "] has altitude z = " + format_double(z) + ": allowed a finite z at least " +
                       "channel.d0_m above scenario.user_height_m (" + format_double(cfg.scenario.user_height_m + cfg.channel.d0_m) + " m)");
    p(static_cast<Eigen::Index>(i), 2) = z;
  }
  return p;
}

// ---- environment ----------------------------------------------------------------------------

/// A link's coordinates: finite, the UAV above the users' antennas.
void check_link(double ux, double uy, double uz, double x, double y) {
  const char* names[5] = {"ux", "uy", "uz", "x", "y"};
  const double v[5] = {ux, uy, uz, x, y};
  for (int i = 0; i < 5; ++i)
    if (!std::isfinite(v[i]))
      throw InputError(std::string(names[i]) + " = " + format_double(v[i]) + " is not finite: allowed a finite position (m)");
  if (!(uz > 0)) throw InputError("uz = " + format_double(uz) + " is not above the ground: allowed an altitude uz > 0 (m)");
}

py::dict link_dict(const ChannelModel& model, double ux, double uy, double uz, double x, double y) {
  py::dict d;
  for (const auto& [name, value] : link_fields(model.link(ux, uy, uz, x, y))) {
    if (name == "los") d[name.c_str()] = value != 0.0;
    else d[name.c_str()] = value;
  }
  return d;
}


// ---- planners -------------------------------------------------------------------------------

py::dict episode_dict(const EpisodeRecord& r) {
  const int T = r.T, N = r.positions.empty() ? 0 : static_cast<int>(r.positions.front().rows());
  auto pos = Array<double>({T, N, 3});  // (x, y, altitude z) of each UAV at each slot
  for (int t = 0; t < T; ++t)
    for (int n = 0; n < N; ++n) {
      const Positions& p = r.positions[static_cast<std::size_t>(t)];
      for (int c = 0; c < 3; ++c) pos.mutable_at(t, n, c) = c < p.cols() ? p(n, c) : std::nan("");
    }
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

/// skyloop.Config and where the shipped data are.
void bind_config(py::module_& m) {
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

  m.def("config_from_toml", [](const std::string& text) {
          Config cfg;
          apply_toml(cfg, text, "configuration");
          finalise(cfg);
          return cfg;
        }, py::arg("text"), "a configuration from its TOML text (Config.toml()); how a Config unpickles");
}

/// The system model (Section III): clusters, snapshots, networks and the model that makes them.
void bind_channel(py::module_& m) {
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

  py::class_<Snapshot>(m, "Snapshot", "UAV positions [N, 2] (at scenario.altitude_m) or [N, 3] (x, y, altitude z) and user positions [K, 2] (metres).")
      .def_readonly("uavs", &Snapshot::uavs)
      .def_readonly("users", &Snapshot::users);

  py::class_<Network>(m, "Network",
                      "Every non-empty cluster of a snapshot, the cross channels and the spectrum model "
                      "(channel.spectrum): cross[i] is [K_s, L] complex, row r = h^H from cluster i's UAV to served user r.")
      .def_property_readonly("spectrum", [](const Network& n) { return std::string(name_of(n.spectrum)); })
      .def_readonly("uavs", &Network::uavs)
      .def_readonly("clusters", &Network::clusters)
      .def_readonly("served", &Network::served)
      .def_readonly("offset", &Network::offset)
      .def_readonly("cross", &Network::cross)
      .def("__repr__", [](const Network& n) {
        return "<Network " + std::string(name_of(n.spectrum)) + ", " + std::to_string(n.clusters.size()) + " clusters, " +
               std::to_string(n.served_count()) + " served users>";
      });

  py::class_<SystemModel>(m, "SystemModel", "The paper's Section III model: LoS channels, association, clusters.")
      .def(py::init<const Config&>(), py::arg("config"))
      .def("random_snapshot", &SystemModel::random_snapshot, py::arg("uavs"), py::arg("users"), py::arg("seed"))
      .def("snapshot", [](const SystemModel&, const Config& cfg, const Array<double>& uavs, const Array<double>& users) {
             return Snapshot{positions_from(uavs, cfg, "uavs", true), positions_from(users, cfg, "users")};
           }, py::arg("config"), py::arg("uavs"), py::arg("users"))
      .def("associate", [](const SystemModel& model, const Snapshot& s) { return model.associate(s).serving; }, py::arg("snapshot"),
           "serving UAV of every user, -1 where no UAV covers it")
      .def("clusters", py::overload_cast<const Snapshot&>(&SystemModel::clusters, py::const_), py::arg("snapshot"))
      .def("network", py::overload_cast<const Snapshot&>(&SystemModel::network, py::const_), py::arg("snapshot"),
           "the whole network of a snapshot under channel.spectrum")
      .def("channel", [](const SystemModel& self, double ux, double uy, double x, double y, int slot, std::optional<double> uz) {
             const double z = uz.value_or(self.altitude());
             check_link(ux, uy, z, x, y);
             return self.channel_model().channel_at(ux, uy, z, x, y, slot);
           },
           py::arg("ux"), py::arg("uy"), py::arg("x"), py::arg("y"), py::arg("slot") = 0, py::arg("uz") = py::none(),
           "h of the link from a UAV at (ux, uy) and altitude uz (default scenario.altitude_m) to the user at (x, y) in "
           "fast slot `slot` (0 <= slot < fast_slots)")
      .def_property_readonly("fast_slots", &SystemModel::fast_slots)
      .def("link", [](const SystemModel& self, double ux, double uy, double x, double y, std::optional<double> uz) {
             const double z = uz.value_or(self.altitude());
             check_link(ux, uy, z, x, y);
             return link_dict(self.channel_model(), ux, uy, z, x, y);
           },
           py::arg("ux"), py::arg("uy"), py::arg("x"), py::arg("y"), py::arg("uz") = py::none(),
           "the link's large-scale state from a UAV at altitude uz (default scenario.altitude_m): p_los, los, path_loss_db, "
           "shadowing_db, k_factor_db, gain, distance_m, elevation_deg");
}

/// The beamformers by spec string, and the rates of any precoder.
void bind_beamformers(py::module_& m) {
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

  // Benchmark helpers: the same work in C++ alone, timed in the same process (python/bench).
  m.def("_bench_cpp_batch", [](const Beamformer& b, const std::vector<Cluster>& cs, int repeats) {
    py::gil_scoped_release nogil;
    const auto t0 = std::chrono::steady_clock::now();
    for (int r = 0; r < repeats; ++r) (void)b.design_batch(cs, 1);
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count() / repeats;
  });
}

/// Planners, policies on held-out layouts, and the tables every entry point shares.
void bind_planning(py::module_& m) {
#ifdef SKYLOOP_HAS_TORCH
  m.def("policy_config", &policy_config, py::arg("path"), "the training configuration a policy (a run directory or its policy.pt) holds");
  m.def("evaluate_layouts", &evaluate_layouts_py, py::arg("config"), py::arg("policies"), py::arg("planners"),
        py::arg("layouts"), py::arg("split"), py::arg("first"), py::arg("unsafe"), py::arg("rollout"), py::arg("cache"),
        py::arg("threads"));
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

#ifdef SKYLOOP_HAS_TORCH
/// The benchmark (skyloop/experiments/bench.hpp): tasks, runs, summaries and their files.
void bind_bench(py::module_& m) {
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

  bind_config(m);
  bind_channel(m);
  bind_beamformers(m);
  bind_vec_env(m);
  bind_planning(m);
#ifdef SKYLOOP_HAS_TORCH
  bind_bench(m);
#endif
}
