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
#include "skyloop/marl/learners.hpp"

namespace skyloop {

std::vector<std::string> learner_names() {
  std::vector<std::string> out;
  for (const auto& l : learners()) out.push_back(l.name);
  return out;
}

std::string learner_names_text() {
  std::string out;
  for (const auto& l : learners()) out += (out.empty() ? "" : ", ") + l.name;
  return out;
}

const LearnerInfo& find_learner(const std::string& name) {
  for (const auto& l : learners())
    if (l.name == name) return l;
  throw InputError("marl.algo = \"" + name + "\" is unknown: allowed " + learner_names_text());
}

std::string to_string(PowerScaling s) { return s == PowerScaling::Full ? "full" : "cap"; }

Spectrum parse_spectrum(const std::string& s) {
  if (s == "orthogonal") return Spectrum::Orthogonal;
  if (s == "orthogonal-split") return Spectrum::OrthogonalSplit;
  if (s == "shared") return Spectrum::Shared;
  throw InputError("channel.spectrum = \"" + s + "\" is not allowed: allowed one of orthogonal, orthogonal-split, shared");
}

std::string to_string(Spectrum s) {
  switch (s) {
    case Spectrum::Orthogonal: return "orthogonal";
    case Spectrum::OrthogonalSplit: return "orthogonal-split";
    case Spectrum::Shared: return "shared";
  }
  return "orthogonal";
}

namespace {

using Type = Field::Type;

std::string format_number(double x) { return format_double(x); }

template <class Ref>
Field real(std::string key, std::string help, double lo, double hi, Ref ref) {
  Field f{std::move(key), Type::Real, std::move(help), lo, hi, {}, {}, {}};
  f.get = [ref](const Config& c) { return FieldValue(ref(const_cast<Config&>(c))); };
  f.set = [ref](Config& c, const FieldValue& v) { ref(c) = std::get<double>(v); };
  return f;
}

template <class Ref>
Field integer(std::string key, std::string help, double lo, double hi, Ref ref) {
  Field f{std::move(key), Type::Integer, std::move(help), lo, hi, {}, {}, {}};
  f.get = [ref](const Config& c) { return FieldValue(static_cast<std::int64_t>(ref(const_cast<Config&>(c)))); };
  f.set = [ref](Config& c, const FieldValue& v) {
    using T = std::remove_reference_t<decltype(ref(c))>;
    ref(c) = static_cast<T>(std::get<std::int64_t>(v));
  };
  return f;
}

template <class Ref>
Field text(std::string key, std::string help, std::vector<std::string> choices, Ref ref) {
  Field f{std::move(key), Type::Text, std::move(help), 0, 0, std::move(choices), {}, {}};
  f.get = [ref](const Config& c) { return FieldValue(ref(const_cast<Config&>(c))); };
  f.set = [ref](Config& c, const FieldValue& v) { ref(c) = std::get<std::string>(v); };
  return f;
}

template <class Ref>
Field points(std::string key, std::string help, Ref ref) {
  Field f{std::move(key), Type::Points, std::move(help), 0, 0, {}, {}, {}};
  f.get = [ref](const Config& c) { return FieldValue(ref(const_cast<Config&>(c))); };
  f.set = [ref](Config& c, const FieldValue& v) { ref(c) = std::get<std::vector<Point2>>(v); };
  return f;
}

template <class Ref>
Field reals(std::string key, std::string help, double lo, double hi, Ref ref) {
  Field f{std::move(key), Type::Reals, std::move(help), lo, hi, {}, {}, {}};
  f.get = [ref](const Config& c) { return FieldValue(ref(const_cast<Config&>(c))); };
  f.set = [ref](Config& c, const FieldValue& v) { ref(c) = std::get<std::vector<double>>(v); };
  return f;
}

std::vector<Field> make_fields() {
  std::vector<Field> f;
  // [run]
  f.push_back(integer("run.seed", "base seed of every stochastic stage", 0, 4611686018427387904.0,
                      [](Config& c) -> std::uint64_t& { return c.run.seed; }));
  f.push_back(integer("run.threads", "worker threads for batch work (0 = all hardware threads)", 0, 1024,
                      [](Config& c) -> int& { return c.run.threads; }));
  // [scenario]
  f.push_back(real("scenario.area_x_m", "service area width, x in [0, area_x_m] (m)", 1, 1e5,
                   [](Config& c) -> double& { return c.scenario.area_x_m; }));
  f.push_back(real("scenario.area_y_m", "service area height, y in [0, area_y_m] (m)", 1, 1e5,
                   [](Config& c) -> double& { return c.scenario.area_y_m; }));
  f.push_back(real("scenario.altitude_m", "UAV altitude H (m)", 1, 1e4,
                   [](Config& c) -> double& { return c.scenario.altitude_m; }));
  f.push_back(integer("scenario.uavs", "number of UAVs N in random snapshots", 1, kMaxUavs,
                      [](Config& c) -> int& { return c.scenario.uavs; }));
  f.push_back(integer("scenario.users", "number of users K in random snapshots", 1, kMaxUsers,
                      [](Config& c) -> int& { return c.scenario.users; }));
  f.push_back(text("scenario.user_layout", "where users stand: uniform in the area (the paper), in hotspots, or mixed (each layout one of the two, even odds)",
                   {"uniform", "hotspot", "mixed"}, [](Config& c) -> std::string& { return c.scenario.user_layout; }));
  f.push_back(integer("scenario.hotspots", "hotspot centres (uniform in the area) when user_layout = hotspot", 1, 1000,
                      [](Config& c) -> int& { return c.scenario.hotspots; }));
  f.push_back(real("scenario.hotspot_radius_m", "std of a hotspot user's offset from its centre, per axis (m)", 0.1, 1e5,
                   [](Config& c) -> double& { return c.scenario.hotspot_radius_m; }));
  f.push_back(real("scenario.hotspot_fraction", "share of users in hotspots (the rest uniform)", 0, 1,
                   [](Config& c) -> double& { return c.scenario.hotspot_fraction; }));
  f.push_back(real("scenario.user_height_m", "users' antenna height above ground (m; below the UAV altitude)", 0, 1e4,
                   [](Config& c) -> double& { return c.scenario.user_height_m; }));
  // [channel]
  f.push_back(integer("channel.antennas", "ULA antennas per UAV, L", 1, 64,
                      [](Config& c) -> int& { return c.channel.antennas; }));
  f.push_back(real("channel.antenna_spacing_wavelengths", "antenna spacing d_a / lambda", 0.01, 10,
                   [](Config& c) -> double& { return c.channel.antenna_spacing_wavelengths; }));
  f.push_back(real("channel.p_max_dbm", "per-UAV transmit power budget P_max (dBm)", -30, 80,
                   [](Config& c) -> double& { return c.channel.p_max_dbm; }));
  f.push_back(real("channel.noise_dbm", "receiver noise power sigma_0^2 (dBm)", -200, 30,
                   [](Config& c) -> double& { return c.channel.noise_dbm; }));
  f.push_back(real("channel.beta0_db", "channel power gain at the reference distance (dB)", -100, 0,
                   [](Config& c) -> double& { return c.channel.beta0_db; }));
  f.push_back(real("channel.d0_m", "reference distance d_0 (m)", 0.01, 100,
                   [](Config& c) -> double& { return c.channel.d0_m; }));
  f.push_back(real("channel.coverage_radius_m", "coverage radius R_c on the 3-D UAV-user distance (m)", 1, 1e5,
                   [](Config& c) -> double& { return c.channel.coverage_radius_m; }));
  f.push_back(text("channel.spectrum",
                   "orthogonal: each UAV its own full band (the paper); orthogonal-split: N bands of 1/N; shared: one band, "
                   "inter-cluster interference",
                   {"orthogonal", "orthogonal-split", "shared"}, [](Config& c) -> std::string& { return c.channel.spectrum; }));
  {
    std::vector<std::string> models, environments;
    for (const auto& m : kPathLossModels) models.emplace_back(m.name);
    for (const auto& e : kAlHouraniEnvironments) environments.emplace_back(e.name);
    f.push_back(text("channel.pathloss", "air-to-ground path loss and LoS model (docs/concepts/channels.md)", models,
                     [](Config& c) -> std::string& { return c.channel.pathloss; }));
    f.push_back(text("channel.environment", "al-hourani's environment (its S-curve and excess losses)", environments,
                     [](Config& c) -> std::string& { return c.channel.environment; }));
  }
  f.push_back(real("channel.carrier_ghz", "carrier frequency f_c (GHz; 3GPP and al-hourani)", 0.5, 100,
                   [](Config& c) -> double& { return c.channel.carrier_ghz; }));
  {
    Field b{"channel.shadowing", Type::Boolean, "draw log-normal shadowing with the path-loss model's spread", 0, 0, {}, {}, {}};
    b.get = [](const Config& c) { return FieldValue(c.channel.shadowing); };
    b.set = [](Config& c, const FieldValue& v) { c.channel.shadowing = std::get<bool>(v); };
    f.push_back(std::move(b));
  }
  f.push_back(text("channel.fading", "small-scale fading: none (the paper) or rician (Rayleigh on NLoS links)", {"none", "rician"},
                   [](Config& c) -> std::string& { return c.channel.fading; }));
  f.push_back(text("channel.rician_k", "Rician K: fixed = rician_k_db; elevation = k_min_db at 0 deg rising linearly in dB to k_max_db at 90 deg",
                   {"fixed", "elevation"}, [](Config& c) -> std::string& { return c.channel.rician_k; }));
  f.push_back(real("channel.rician_k_db", "Rician K-factor of a LoS link (dB)", -50, 100,
                   [](Config& c) -> double& { return c.channel.rician_k_db; }));
  f.push_back(real("channel.rician_k_min_db", "Rician K at elevation 0 (dB)", -50, 100,
                   [](Config& c) -> double& { return c.channel.rician_k_min_db; }));
  f.push_back(real("channel.rician_k_max_db", "Rician K at elevation 90 deg (dB)", -50, 100,
                   [](Config& c) -> double& { return c.channel.rician_k_max_db; }));
  f.push_back(integer("channel.fast_slots", "small-scale realisations per trajectory slot (the beamformer designs each; R[t] is their mean)",
                      1, 256, [](Config& c) -> int& { return c.channel.fast_slots; }));
  f.push_back(real("channel.correlation_m", "decorrelation distance of the LoS-state and shadowing maps (m)", 0.1, 1e5,
                   [](Config& c) -> double& { return c.channel.correlation_m; }));
  f.push_back(integer("channel.seed", "seed of the city: the LoS, shadowing and fading maps", 0, 4611686018427387904.0,
                      [](Config& c) -> std::uint64_t& { return c.channel.seed; }));
  f.push_back(real("channel.bandwidth_hz", "bandwidth B turning the sum rate (bit/s/Hz) into bits for bits per joule (Hz)", 1, 1e12,
                   [](Config& c) -> double& { return c.channel.bandwidth_hz; }));
  // [beamforming]
  {
    Field s{"beamforming.power_scaling", Type::Text,
            "scaling onto the budget: full = sqrt(P/||W||^2), cap = the paper's min(1, sqrt(P/||W||^2))",
            0, 0, {"full", "cap"}, {}, {}};
    s.get = [](const Config& c) { return FieldValue(to_string(c.beamforming.power_scaling)); };
    s.set = [](Config& c, const FieldValue& v) {
      c.beamforming.power_scaling = std::get<std::string>(v) == "cap" ? PowerScaling::Cap : PowerScaling::Full;
    };
    f.push_back(std::move(s));
  }
  f.push_back(text("beamforming.zf_power_allocation", "ZF power over the users: waterfilling (optimal for ZF) or equal",
                   {"waterfilling", "equal"}, [](Config& c) -> std::string& { return c.beamforming.zf_power_allocation; }));
  // [wmmse]
  f.push_back(real("wmmse.tolerance", "stop when an iteration raises the sum rate by less than this fraction", 0, 1,
                   [](Config& c) -> double& { return c.wmmse.tolerance; }));
  f.push_back(integer("wmmse.max_iterations", "iteration cap per WMMSE run", 1, 1e6,
                      [](Config& c) -> int& { return c.wmmse.max_iterations; }));
  f.push_back(integer("wmmse.restarts", "extra WMMSE runs from random starting points (best is kept)", 0, 1000,
                      [](Config& c) -> int& { return c.wmmse.restarts; }));
  f.push_back(text("wmmse.init", "starting point of the first WMMSE run", {"zfsel", "rzf", "mrt", "random"},
                   [](Config& c) -> std::string& { return c.wmmse.init; }));
  f.push_back(real("wmmse.bisection_tolerance", "relative tolerance on the power budget in the multiplier bisection",
                   1e-16, 1e-2, [](Config& c) -> double& { return c.wmmse.bisection_tolerance; }));
  // [ga]
  f.push_back(text("ga.algorithm", "pagmo2 global optimiser behind the 'ga' beamformer",
                   {"sga", "de", "sade", "pso", "cmaes", "xnes", "gwo", "bee_colony"},
                   [](Config& c) -> std::string& { return c.ga.algorithm; }));
  f.push_back(integer("ga.population", "population size", 8, 100000, [](Config& c) -> int& { return c.ga.population; }));
  f.push_back(integer("ga.generations", "generations per decision (the paper's 2000)", 1, 1e7,
                      [](Config& c) -> int& { return c.ga.generations; }));
  // [trajectory]
  f.push_back(points("trajectory.starts", "UAV start points [[x, y], ...] (m)",
                     [](Config& c) -> std::vector<Point2>& { return c.trajectory.starts; }));
  f.push_back(points("trajectory.destinations", "UAV destinations [[x, y], ...] (m), one per start",
                     [](Config& c) -> std::vector<Point2>& { return c.trajectory.destinations; }));
  f.push_back(real("trajectory.d_fly_m", "distance flown per slot D_fly (m)", 0.1, 1e4,
                   [](Config& c) -> double& { return c.trajectory.d_fly_m; }));
  f.push_back(real("trajectory.d_min_m", "minimum UAV separation D_min (m)", 0, 1e4,
                   [](Config& c) -> double& { return c.trajectory.d_min_m; }));
  f.push_back(integer("trajectory.t_max", "mission horizon T_max (slots)", 1, 10000,
                      [](Config& c) -> int& { return c.trajectory.t_max; }));
  f.push_back(text("trajectory.layout",
                   "given: starts and destinations as listed; generated: scenario.uavs UAVs on the D_fly lattice from layout_seed",
                   {"given", "generated"}, [](Config& c) -> std::string& { return c.trajectory.layout; }));
  f.push_back(integer("trajectory.layout_seed", "seed of a generated layout", 0, 4611686018427387904.0,
                      [](Config& c) -> std::uint64_t& { return c.trajectory.layout_seed; }));
  f.push_back(text("trajectory.mobility",
                   "grid: the paper's five moves of D_fly; headings: 8 headings x trajectory.speeds_mps on the D_fly lattice; "
                   "continuous: a velocity in the disc of v_max_mps, its change bounded by a_max_mps2 (docs/concepts/mobility-energy.md)",
                   {"grid", "headings", "continuous"}, [](Config& c) -> std::string& { return c.trajectory.mobility; }));
  f.push_back(reals("trajectory.speeds_mps",
                    "headings: speeds along the axes (m/s; 0 = hover; diagonals fly sqrt(2) x), each x slot_s a multiple of D_fly",
                    0, 200, [](Config& c) -> std::vector<double>& { return c.trajectory.speeds_mps; }));
  f.push_back(real("trajectory.slot_s", "slot duration delta_t (s); the grid model flies V = D_fly / delta_t", 0.01, 3600,
                   [](Config& c) -> double& { return c.trajectory.slot_s; }));
  f.push_back(real("trajectory.v_max_mps", "continuous: the largest ground speed (m/s); the velocity lies in its disc", 0.1, 200,
                   [](Config& c) -> double& { return c.trajectory.v_max_mps; }));
  f.push_back(real("trajectory.a_max_mps2", "continuous: the largest acceleration (m/s^2): |V[t] - V[t-1]| <= a_max slot_s", 0.01, 1000,
                   [](Config& c) -> double& { return c.trajectory.a_max_mps2; }));
  f.push_back(text("trajectory.command",
                   "continuous: what a command u in [-1, 1]^2 sets: velocity (onto the disc of v_max_mps) or polar (a speed "
                   "v_max (u0 + 1) / 2 and a turn of u1 x the widest a_max allows from the last heading)",
                   {"velocity", "polar"}, [](Config& c) -> std::string& { return c.trajectory.command; }));
  f.push_back(real("trajectory.arrival_m", "continuous: a UAV this close to its destination at a slot's end has arrived (m)", 0.001,
                   1000, [](Config& c) -> double& { return c.trajectory.arrival_m; }));
  // [energy]
  f.push_back(text("energy.model", "propulsion power: rotary-wing (Zeng, Xu, Zhang, IEEE TWC 2019, eq. (12)) or none",
                   {"rotary-wing", "none"}, [](Config& c) -> std::string& { return c.energy.model; }));
  f.push_back(real("energy.p0_w", "blade profile power in hover P0 (W)", 0, 1e5, [](Config& c) -> double& { return c.energy.p0_w; }));
  f.push_back(real("energy.pi_w", "induced power in hover Pi (W)", 0, 1e5, [](Config& c) -> double& { return c.energy.pi_w; }));
  f.push_back(real("energy.u_tip_mps", "rotor blade tip speed U_tip (m/s)", 1, 1000, [](Config& c) -> double& { return c.energy.u_tip_mps; }));
  f.push_back(real("energy.v0_mps", "mean rotor induced velocity in hover v0 (m/s)", 0.01, 100,
                   [](Config& c) -> double& { return c.energy.v0_mps; }));
  f.push_back(real("energy.d0", "fuselage drag ratio d0", 0, 100, [](Config& c) -> double& { return c.energy.d0; }));
  f.push_back(real("energy.rho_kgm3", "air density rho (kg/m^3)", 0.01, 10, [](Config& c) -> double& { return c.energy.rho_kgm3; }));
  f.push_back(real("energy.solidity", "rotor solidity s", 0, 1, [](Config& c) -> double& { return c.energy.solidity; }));
  f.push_back(real("energy.rotor_area_m2", "rotor disc area A (m^2)", 0, 1000, [](Config& c) -> double& { return c.energy.rotor_area_m2; }));
  f.push_back(text("energy.acceleration", "acceleration term: none (Zeng's steady-flight model) or kinetic (+ m (V[t]^2 - V[t-1]^2) / 2 when speeding up)",
                   {"none", "kinetic"}, [](Config& c) -> std::string& { return c.energy.acceleration; }));
  f.push_back(real("energy.mass_kg", "aircraft mass m for the kinetic term (kg)", 0, 1e5, [](Config& c) -> double& { return c.energy.mass_kg; }));
  f.push_back(real("energy.budget_j", "propulsion energy budget per UAV over a mission (J; 0 = none)", 0, 1e12,
                   [](Config& c) -> double& { return c.energy.budget_j; }));
  f.push_back(real("energy.weight", "env.objective = weighted: w in R-bar - w P-bar, (bit/s/Hz) per W of fleet power", 0, 1e6,
                   [](Config& c) -> double& { return c.energy.weight; }));
  // [nn]
  f.push_back(text("nn.model", "learned beamformer to train (ignn: the interference-aware network GNN)",
                   learned_beamformer_names(), [](Config& c) -> std::string& { return c.nn.model; }));
  f.push_back(integer("nn.hidden", "embedding size d_gnn (baselines use twice this width)", 4, 4096,
                      [](Config& c) -> int& { return c.nn.hidden; }));
  f.push_back(integer("nn.layers", "message-passing layers L_g (GNN)", 1, 16, [](Config& c) -> int& { return c.nn.layers; }));
  f.push_back(real("nn.learning_rate", "Adam learning rate", 1e-7, 1, [](Config& c) -> double& { return c.nn.learning_rate; }));
  f.push_back(text("nn.lr_schedule",
                   "learning rate over training: constant (the paper) or cosine (from nn.learning_rate per step down to 1% of it at the last epoch)",
                   {"constant", "cosine"}, [](Config& c) -> std::string& { return c.nn.lr_schedule; }));
  f.push_back(real("nn.weight_decay", "Adam weight decay (L2)", 0, 1, [](Config& c) -> double& { return c.nn.weight_decay; }));
  f.push_back(integer("nn.epochs", "training epochs E_gnn", 1, 100000, [](Config& c) -> int& { return c.nn.epochs; }));
  f.push_back(integer("nn.batch_samples", "snapshots per mini-batch (all their clusters form the batch)", 1, 1000000,
                      [](Config& c) -> int& { return c.nn.batch_samples; }));
  f.push_back(integer("nn.train_samples", "training snapshots", 1, 100000000, [](Config& c) -> int& { return c.nn.train_samples; }));
  f.push_back(integer("nn.val_samples", "validation snapshots", 1, 100000000, [](Config& c) -> int& { return c.nn.val_samples; }));
  f.push_back(integer("nn.test_samples", "held-out test snapshots", 1, 100000000, [](Config& c) -> int& { return c.nn.test_samples; }));
  f.push_back(integer("nn.data_seed", "seed of the train/validation/test sets (disjoint streams)", 0, 4611686018427387904.0,
                      [](Config& c) -> std::uint64_t& { return c.nn.data_seed; }));
  f.push_back(text("nn.device", "torch device for training and inference", {"cpu", "cuda"},
                   [](Config& c) -> std::string& { return c.nn.device; }));
  f.push_back(real("nn.grad_clip", "max global gradient norm (0 = no clipping)", 0, 1e6,
                   [](Config& c) -> double& { return c.nn.grad_clip; }));
  f.push_back(text("nn.readout", "per-user output: direct = 2L reals (the paper), structured = (lambda, power) of the optimal structure",
                   {"direct", "structured"}, [](Config& c) -> std::string& { return c.nn.readout; }));
  f.push_back(text("nn.features",
                   "what the encoders see of each channel: linear = [Re h, Im h] scaled (the paper), log = its direction with the norm compressed logarithmically (for channels whose gains span decades: 3GPP, Al-Hourani)",
                   {"linear", "log"}, [](Config& c) -> std::string& { return c.nn.features; }));
  f.push_back(text("nn.precision",
                   "arithmetic of a served model: float32 (as trained) or float64 (same weights, a reference for numerical checks)",
                   {"float32", "float64"}, [](Config& c) -> std::string& { return c.nn.precision; }));
  f.push_back(text("nn.inference",
                   "serving path of a learned model: fast (fused float32 kernels, same weights; the ignn and float64 are served by "
                   "torch) or torch (LibTorch, the training path and the reference)",
                   {"fast", "torch"}, [](Config& c) -> std::string& { return c.nn.inference; }));
  f.push_back(text("nn.selection",
                   "what a served per-cluster model's beams become: soft = the network's beams (as trained); ranked = the "
                   "network chooses whom to serve, ZF how: in the order of the rates the network's beams give them, each user "
                   "joins while it raises the water-filled ZF sum rate (at most L); the result or the network's own beams, "
                   "whichever has the higher sum rate",
                   {"soft", "ranked"}, [](Config& c) -> std::string& { return c.nn.selection; }));
  // [marl]
  f.push_back(text("marl.algo", "multi-agent learner", learner_names(),
                   [](Config& c) -> std::string& { return c.marl.algo; }));
  f.push_back(integer("marl.total_steps", "environment steps of a training run", 1, 1e12,
                      [](Config& c) -> std::int64_t& { return c.marl.total_steps; }));
  f.push_back(integer("marl.envs", "parallel environments", 1, 4096, [](Config& c) -> int& { return c.marl.envs; }));
  f.push_back(integer("marl.users_seed", "seed of the scenario's users", 0, 4611686018427387904.0,
                      [](Config& c) -> std::uint64_t& { return c.marl.users_seed; }));
  f.push_back(integer("marl.hidden", "width of the actor, critic and Q networks", 4, 4096, [](Config& c) -> int& { return c.marl.hidden; }));
  f.push_back(real("marl.learning_rate", "Adam learning rate", 1e-8, 1, [](Config& c) -> double& { return c.marl.learning_rate; }));
  f.push_back(real("marl.gamma", "discount factor", 0, 1, [](Config& c) -> double& { return c.marl.gamma; }));
  f.push_back(real("marl.gae_lambda", "GAE lambda", 0, 1, [](Config& c) -> double& { return c.marl.gae_lambda; }));
  f.push_back(real("marl.clip", "PPO clip epsilon", 0, 1, [](Config& c) -> double& { return c.marl.clip; }));
  f.push_back(real("marl.value_coef", "value loss coefficient c1", 0, 1e3, [](Config& c) -> double& { return c.marl.value_coef; }));
  f.push_back(real("marl.entropy_coef", "entropy coefficient c2", 0, 1e3, [](Config& c) -> double& { return c.marl.entropy_coef; }));
  f.push_back(integer("marl.rollout", "steps per environment between PPO updates", 1, 1e6, [](Config& c) -> int& { return c.marl.rollout; }));
  f.push_back(integer("marl.minibatches", "PPO mini-batches per epoch", 1, 4096, [](Config& c) -> int& { return c.marl.minibatches; }));
  f.push_back(text("marl.minibatch",
                   "what PPO's minibatches are drawn in: samples = agent samples shuffled one by one (the paper's and the "
                   "MAPPO reference's); steps = whole steps, every agent of a step in the same minibatch (TorchRL's layout), "
                   "so that the critic's state columns the agents of a step share (the set encoder's compact state) are "
                   "multiplied once per step, forward and backward (the fast backend)",
                   {"samples", "steps"}, [](Config& c) -> std::string& { return c.marl.minibatch; }));
  f.push_back(integer("marl.epochs", "PPO epochs per update", 1, 1000, [](Config& c) -> int& { return c.marl.epochs; }));
  f.push_back(text("marl.critic_state", "MAPPO critic input: global state or agent-specific state", {"global", "agent"},
                   [](Config& c) -> std::string& { return c.marl.critic_state; }));
  {
    Field b{"marl.value_norm", Type::Boolean, "normalise value targets with running mean and variance", 0, 0, {}, {}, {}};
    b.get = [](const Config& c) { return FieldValue(c.marl.value_norm); };
    b.set = [](Config& c, const FieldValue& v) { c.marl.value_norm = std::get<bool>(v); };
    f.push_back(std::move(b));
  }
  f.push_back(real("marl.grad_clip", "max global gradient norm (0 = off)", 0, 1e6, [](Config& c) -> double& { return c.marl.grad_clip; }));
  f.push_back(integer("marl.buffer_episodes", "VDN/QMIX episode replay buffer size", 1, 1e7, [](Config& c) -> int& { return c.marl.buffer_episodes; }));
  f.push_back(integer("marl.batch_episodes", "VDN/QMIX episodes per gradient step", 1, 1e5, [](Config& c) -> int& { return c.marl.batch_episodes; }));
  f.push_back(real("marl.epsilon_start", "initial exploration rate", 0, 1, [](Config& c) -> double& { return c.marl.epsilon_start; }));
  f.push_back(real("marl.epsilon_end", "final exploration rate", 0, 1, [](Config& c) -> double& { return c.marl.epsilon_end; }));
  f.push_back(real("marl.epsilon_anneal", "fraction of total_steps to anneal epsilon over", 0, 1, [](Config& c) -> double& { return c.marl.epsilon_anneal; }));
  f.push_back(integer("marl.target_update", "gradient steps between target-network copies", 1, 1e7, [](Config& c) -> int& { return c.marl.target_update; }));
  f.push_back(integer("marl.mixer_embed", "QMIX mixing-network width", 1, 4096, [](Config& c) -> int& { return c.marl.mixer_embed; }));
  auto boolean = [](std::string key, std::string help, bool& (*ref)(Config&)) {
    Field b{std::move(key), Type::Boolean, std::move(help), 0, 0, {}, {}, {}};
    b.get = [ref](const Config& c) { return FieldValue(ref(const_cast<Config&>(c))); };
    b.set = [ref](Config& c, const FieldValue& v) { ref(c) = std::get<bool>(v); };
    return b;
  };
  f.push_back(boolean("marl.action_mask", "mask moves that leave the area or make the destination unreachable (training and execution)",
                      [](Config& c) -> bool& { return c.marl.action_mask; }));
  f.push_back(boolean("marl.shield", "collision shield: mask a move that brings two UAVs within D_min when another move avoids it",
                      [](Config& c) -> bool& { return c.marl.shield; }));
  f.push_back(text("marl.encoder",
                   "agent network input: mlp = the paper's 11-real observation; set = permutation-invariant encoder over "
                   "user and neighbour displacements (any K and N)",
                   {"mlp", "set"}, [](Config& c) -> std::string& { return c.marl.encoder; }));
  f.push_back(boolean("marl.lookahead",
                      "the set observation also holds each move's one-slot change of the sum rate R, the others held in place "
                      "(what Greedy ranks moves by; asks the rate oracle for A + 1 position sets per agent and slot, memoised); needs marl.encoder = set",
                      [](Config& c) -> bool& { return c.marl.lookahead; }));
  f.push_back(boolean("marl.sequential",
                      "PPO, grid and headings mobility: the UAVs choose one after another in the shield's order (least slack "
                      "first), each agent's set observation showing the landings the UAVs before it chose (their kernels, "
                      "and in the move gains and radio map the joint rate with them landed): an autoregressive joint policy, "
                      "in training and execution; needs marl.encoder = set",
                      [](Config& c) -> bool& { return c.marl.sequential; }));
  f.push_back(integer("marl.sequential_passes",
                      "with marl.sequential: the UAVs take their turns this many times each slot and fly the last pass's moves; "
                      "in every pass after the first a UAV's observation also shows the UAVs after it in the order at the moves "
                      "they chose in the pass before (their intentions), so the first to choose sees the others too (an actor "
                      "pass per UAV per pass; in training the earlier passes sample and only the last is trained on); 1 = one pass",
                      1, kMaxSequentialPasses, [](Config& c) -> int& { return c.marl.sequential_passes; }));
  f.push_back(text("marl.lr_schedule",
                   "the learners' learning rate over training: constant, or linear = from marl.learning_rate down to 0 "
                   "at total_steps (CleanRL's anneal_lr)",
                   {"constant", "linear"}, [](Config& c) -> std::string& { return c.marl.lr_schedule; }));
  f.push_back(real("marl.average_decay",
                   "PPO: a Polyak average of the actor's weights, a <- d a + (1 - d) w after every optimiser step, is what "
                   "validation scores and policy.pt holds (training goes on with w; last.pt holds both); 0 = off, below 1",
                   0, 1, [](Config& c) -> double& { return c.marl.average_decay; }));
  f.push_back(text("marl.entropy_schedule",
                   "PPO's entropy bonus over training: constant, or linear = from marl.entropy_coef down to 0 at total_steps",
                   {"constant", "linear"}, [](Config& c) -> std::string& { return c.marl.entropy_schedule; }));
  f.push_back(integer("marl.rate_map",
                      "the set observation also holds the radio map around the UAV: the sum rate R with the UAV at each lattice "
                      "point within this many D_fly steps, the others held in place (2 r (r + 1) cells, asked of the rate oracle "
                      "per agent and slot, memoised; 0 = none); needs marl.encoder = set",
                      0, kMaxRateMap, [](Config& c) -> int& { return c.marl.rate_map; }));
  f.push_back(integer("marl.slack_margin",
                      "slots of slack the reachability mask keeps in reserve; the collision shield may spend them to let a UAV "
                      "wait or step aside (0 = none)",
                      0, 1000, [](Config& c) -> int& { return c.marl.slack_margin; }));
  f.push_back(text("marl.mask_clearance",
                   "what the reachability mask counts the moves home around: none = nothing (through every UAV); parked = the "
                   "UAVs that have arrived (they hover at their destinations); destinations = every other UAV's destination, "
                   "then the parked UAVs, where the slots left allow it (lattice models)",
                   {"none", "parked", "destinations"}, [](Config& c) -> std::string& { return c.marl.mask_clearance; }));
  f.push_back(integer("marl.reserve_slack",
                      "a UAV with at most this much slack left reserves its way home in space and time, and the UAVs after it in "
                      "the shield's order plan around the ways reserved; an execution setting: validation, eval and deployment fly "
                      "it, training samples without it (lattice models; -1 = none)",
                      -1, 1000, [](Config& c) -> int& { return c.marl.reserve_slack; }));
  f.push_back(text("marl.backend",
                   "PPO learners' network library: fast = fused float32 passes on the CPU (the default); torch = LibTorch's "
                   "autograd (the reference; needed for nn.device = cuda)",
                   {"fast", "torch"}, [](Config& c) -> std::string& { return c.marl.backend; }));
  f.push_back(integer("marl.val_layouts", "held-out validation layouts scored at every checkpoint; policy.pt = the best (0 = the last policy)",
                      0, 100000, [](Config& c) -> int& { return c.marl.val_layouts; }));
  f.push_back(integer("marl.checkpoint_every", "updates between checkpoints", 1, 1e7, [](Config& c) -> int& { return c.marl.checkpoint_every; }));
  // [env]
  f.push_back(text("env.oracle", "beamformer spec behind the environment's sum rate R[t] (gnn, wmmse, gnn=DIR, ...)",
                   {}, [](Config& c) -> std::string& { return c.env.oracle; }));
  f.push_back(real("env.w_rate", "reward weight of the cumulative average sum rate", 0, 1e6, [](Config& c) -> double& { return c.env.w_rate; }));
  f.push_back(real("env.w_arr", "reward per newly arrived UAV", 0, 1e6, [](Config& c) -> double& { return c.env.w_arr; }));
  f.push_back(real("env.w_bud", "penalty per boundary event", 0, 1e6, [](Config& c) -> double& { return c.env.w_bud; }));
  f.push_back(real("env.w_col", "penalty per UAV in a collision", 0, 1e6, [](Config& c) -> double& { return c.env.w_col; }));
  f.push_back(text("env.reward",
                   "reward: paper = eq:total_reward; objective = R-bar[t+1] - R-bar[t] (sums to the P2.2 objective) "
                   "minus the boundary and collision penalties",
                   {"paper", "objective"}, [](Config& c) -> std::string& { return c.env.reward; }));
  f.push_back(text("env.objective",
                   "what a mission is scored by: sum-rate = P2.2's (1/T) sum R[t]; energy-efficiency = bits per joule (kbit/J); "
                   "weighted = R-bar - energy.weight x mean fleet propulsion power; energy = -kJ (the rate term off) "
                   "(docs/concepts/mobility-energy.md)",
                   {"sum-rate", "energy-efficiency", "weighted", "energy"}, [](Config& c) -> std::string& { return c.env.objective; }));
  f.push_back(real("env.w_fea", "weight of the reachability indicator Phi_n", 0, 1e6, [](Config& c) -> double& { return c.env.w_fea; }));
  {
    Field b{"env.resample_users", Type::Boolean, "draw new users at every reset", 0, 0, {}, {}, {}};
    b.get = [](const Config& c) { return FieldValue(c.env.resample_users); };
    b.set = [](Config& c, const FieldValue& v) { c.env.resample_users = std::get<bool>(v); };
    f.push_back(std::move(b));
  }
  f.push_back(integer("env.users_min", "fewest users of a sampled layout (0 = scenario.users)", 0, 4096,
                      [](Config& c) -> int& { return c.env.users_min; }));
  f.push_back(integer("env.users_max", "most users of a sampled layout (0 = scenario.users)", 0, 4096,
                      [](Config& c) -> int& { return c.env.users_max; }));
  {
    f.push_back(text("env.state",
                     "global state for critics and mixers: paper = every UAV, user and destination (4N + 2K reals); "
                     "compact = 8 x 8 density maps of users, UAVs and pending destinations (194 reals, any N and K)",
                     {"paper", "compact"}, [](Config& c) -> std::string& { return c.env.state; }));
    Field u{"env.users_file", Type::Text, "TOML file with users = [[x, y], ...] (empty: uniform users from the seed)", 0, 0, {}, {}, {}};
    u.get = [](const Config& c) { return FieldValue(c.env.users_file); };
    u.set = [](Config& c, const FieldValue& v) { c.env.users_file = std::get<std::string>(v); };
    f.push_back(std::move(u));
  }
  return f;
}

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

const std::vector<Field>& config_fields() {
  static const std::vector<Field> fields = make_fields();
  return fields;
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

void validate_mobility(const Config& c) {
  const auto& t = c.trajectory;
  if (t.mobility == "grid") {
    if (c.energy.model != "none" && t.d_fly_m / t.slot_s >= c.energy.u_tip_mps)
      throw InputError("trajectory.d_fly_m = " + format_double(t.d_fly_m) + " m per trajectory.slot_s = " + format_double(t.slot_s) +
                       " s flies " + format_double(t.d_fly_m / t.slot_s) + " m/s, at or above energy.u_tip_mps = " +
                       format_double(c.energy.u_tip_mps) + ": allowed a ground speed below the tip speed (the power model's range)");
    return;
  }
  if (t.mobility == "continuous") {
    if (c.marl.reserve_slack >= 0)
      throw InputError("marl.reserve_slack = " + std::to_string(c.marl.reserve_slack) +
                       " is not allowed with trajectory.mobility = continuous: allowed -1 (ways home are planned on the lattice of grid and headings)");
    if (c.energy.model != "none" && t.v_max_mps >= c.energy.u_tip_mps)
      throw InputError("trajectory.v_max_mps = " + format_double(t.v_max_mps) + " is at or above energy.u_tip_mps = " +
                       format_double(c.energy.u_tip_mps) + ": allowed a ground speed below the tip speed (the power model's range)");
    return;
  }
  if (t.mobility != "headings")
    throw InputError("trajectory.mobility = \"" + t.mobility + "\" is not allowed: allowed one of grid, headings, continuous");
  int moving = 0;
  for (std::size_t i = 0; i < t.speeds_mps.size(); ++i) {
    const double v = t.speeds_mps[i];
    if (v == 0) continue;
    const long k = lattice_steps(v, t.slot_s, t.d_fly_m);
    if (k < 1)
      throw InputError("trajectory.speeds_mps[" + std::to_string(i) + "] = " + format_double(v) + " m/s flies " +
                       format_double(v * t.slot_s) + " m per slot of trajectory.slot_s = " + format_double(t.slot_s) +
                       " s: allowed speeds whose step is a whole multiple of trajectory.d_fly_m = " + format_double(t.d_fly_m) +
                       " m (the lattice pitch), or 0 (hover)");
    for (std::size_t j = 0; j < i; ++j)
      if (t.speeds_mps[j] == v)
        throw InputError("trajectory.speeds_mps[" + std::to_string(i) + "] = " + format_double(v) + " repeats entry " +
                         std::to_string(j) + ": allowed distinct speeds");
    if (std::sqrt(2.0) * v >= c.energy.u_tip_mps && c.energy.model != "none")
      throw InputError("trajectory.speeds_mps[" + std::to_string(i) + "] = " + format_double(v) + " m/s flies " +
                       format_double(std::sqrt(2.0) * v) + " m/s on a diagonal, at or above energy.u_tip_mps = " +
                       format_double(c.energy.u_tip_mps) + ": allowed ground speeds below the tip speed (the power model's range)");
    ++moving;
  }
  if (moving == 0)
    throw InputError("trajectory.speeds_mps = " + format_value(FieldValue(t.speeds_mps)) +
                     " has no positive speed: allowed at least one speed above 0 (0 = hover)");
  if (8 * moving + 1 > kMaxActions)
    throw InputError("trajectory.speeds_mps has " + std::to_string(moving) + " positive speeds, " + std::to_string(8 * moving + 1) +
                     " actions: allowed at most " + std::to_string((kMaxActions - 1) / 8) + " positive speeds (" +
                     std::to_string(kMaxActions) + " actions)");
}

void finalise(Config& c) {
  if (c.trajectory.layout == "generated") generate_layout(c);
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
  if (kmin != kmax && c.env.state == "paper")
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
  validate_mobility(c);
  if (c.marl.rate_map > 0 && c.marl.encoder != "set")
    throw InputError("marl.rate_map = " + std::to_string(c.marl.rate_map) + " with marl.encoder = \"" + c.marl.encoder +
                     "\": allowed with marl.encoder = \"set\" (the paper's 11-real observation stays the paper's)");
  if (c.marl.lookahead && c.marl.encoder != "set")
    throw InputError("marl.lookahead = true with marl.encoder = \"" + c.marl.encoder +
                     "\": allowed with marl.encoder = \"set\" (the paper's 11-real observation stays the paper's)");
  if (c.marl.sequential && c.marl.encoder != "set")
    throw InputError("marl.sequential = true with marl.encoder = \"" + c.marl.encoder +
                     "\": allowed with marl.encoder = \"set\" (the paper's 11-real observation shows no other UAV)");
  if (c.marl.sequential && find_learner(c.marl.algo).core != LearnerInfo::Core::Ppo)
    throw InputError("marl.sequential = true with marl.algo = \"" + c.marl.algo +
                     "\": allowed with the PPO learners (mappo, ippo), whose policies sample one agent at a time");
  if (c.marl.sequential && c.trajectory.mobility == "continuous")
    throw InputError("marl.sequential = true with trajectory.mobility = \"continuous\": allowed with the grid and headings "
                     "mobility models (their moves land where the shield orders them)");
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
    const bool kinetic = e.acceleration == "kinetic" && e.mass_kg > 0;
    const bool zero = e.model == "none" || (e.p0_w == 0 && e.pi_w == 0 && e.d0 * e.rho_kgm3 * e.solidity * e.rotor_area_m2 == 0 && !kinetic);
    const std::string why = e.model == "none" ? "energy.model = \"none\"" : "energy.p0_w = 0, energy.pi_w = 0 and no parasite or kinetic term";
    if (zero && (c.env.objective == "energy-efficiency" || c.env.objective == "energy"))
      throw InputError("env.objective = \"" + c.env.objective + "\" with " + why +
                       ": no move costs energy, so every mission scores the same; allowed energy.model = \"rotary-wing\" "
                       "with a power above 0, or env.objective = \"sum-rate\"");
    if (zero && c.env.objective == "weighted" && e.weight > 0)
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
