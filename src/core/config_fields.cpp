// The configuration's field table (skyloop/core/config.hpp): every key's type, range or allowed
// values, help line and where it lives in Config, section by section. Everything that reads a
// key (TOML, --set, validation, `config show`, the reference pages, Python) reads it here.
#include <algorithm>
#include <cmath>
#include <string>
#include <vector>

#include "skyloop/beamforming/registry.hpp"
#include "skyloop/channel/fading.hpp"
#include "skyloop/channel/path_loss.hpp"
#include "skyloop/core/config.hpp"
#include "skyloop/core/error.hpp"
#include "skyloop/core/io.hpp"
#include "skyloop/core/rng.hpp"
#include "skyloop/env/dynamics.hpp"
#include "skyloop/marl/learners.hpp"

namespace skyloop {

namespace {

using Type = Field::Type;

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

/// A closed choice: its allowed values and their help come from the enum's table
/// (skyloop/core/choices.hpp); `lead` says what the field decides.
template <class E, class Ref>
Field choice(std::string key, const std::string& lead, Ref ref) {
  Field f{key, Type::Text, lead + ": " + choice_help<E>(), 0, 0, choice_names<E>(), {}, {}};
  f.get = [ref](const Config& c) { return FieldValue(std::string(name_of(ref(const_cast<Config&>(c))))); };
  f.set = [ref, key](Config& c, const FieldValue& v) { ref(c) = parse_choice<E>(key, std::get<std::string>(v)); };
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

/// The fields of [run], [scenario], in the order `config show` writes them.
void add_run_and_scenario_fields(std::vector<Field>& f) {
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
  f.push_back(choice<UserLayout>("scenario.user_layout", "where users stand",
                                 [](Config& c) -> UserLayout& { return c.scenario.user_layout; }));
  f.push_back(integer("scenario.hotspots", "hotspot centres (uniform in the area) when user_layout = hotspot", 1, 1000,
                      [](Config& c) -> int& { return c.scenario.hotspots; }));
  f.push_back(real("scenario.hotspot_radius_m", "std of a hotspot user's offset from its centre, per axis (m)", 0.1, 1e5,
                   [](Config& c) -> double& { return c.scenario.hotspot_radius_m; }));
  f.push_back(real("scenario.hotspot_fraction", "share of users in hotspots (the rest uniform)", 0, 1,
                   [](Config& c) -> double& { return c.scenario.hotspot_fraction; }));
  f.push_back(real("scenario.user_height_m", "users' antenna height above ground (m; below the UAV altitude)", 0, 1e4,
                   [](Config& c) -> double& { return c.scenario.user_height_m; }));
}

/// The fields of [channel], in the order `config show` writes them.
void add_channel_fields(std::vector<Field>& f) {
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
  f.push_back(choice<Spectrum>("channel.spectrum", "how the UAVs share the spectrum",
                               [](Config& c) -> Spectrum& { return c.channel.spectrum; }));
  {
    std::vector<std::string> environments;
    for (const auto& e : kAlHouraniEnvironments) environments.emplace_back(e.name);
    f.push_back(text("channel.pathloss", "air-to-ground path loss and LoS model (docs/concepts/channels.md)", path_loss_models().names(),
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
  // The fading models' registry (skyloop/channel/fading.hpp): names and help.
  f.push_back(text("channel.fading", "small-scale fading (" + fading_models().help_text() + ")", fading_models().names(),
                   [](Config& c) -> std::string& { return c.channel.fading; }));
  f.push_back(choice<RicianK>("channel.rician_k", "Rician K of a LoS link", [](Config& c) -> RicianK& { return c.channel.rician_k; }));
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
}

/// The fields of [beamforming], [wmmse], [ga], in the order `config show` writes them.
void add_beamforming_fields(std::vector<Field>& f) {
  // [beamforming]
  f.push_back(choice<PowerScaling>("beamforming.power_scaling", "scaling onto the budget",
                                   [](Config& c) -> PowerScaling& { return c.beamforming.power_scaling; }));
  f.push_back(choice<PowerAllocation>("beamforming.zf_power_allocation", "ZF power over the users",
                                      [](Config& c) -> PowerAllocation& { return c.beamforming.zf_power_allocation; }));
  // [wmmse]
  f.push_back(real("wmmse.tolerance", "stop when an iteration raises the sum rate by less than this fraction", 0, 1,
                   [](Config& c) -> double& { return c.wmmse.tolerance; }));
  f.push_back(integer("wmmse.max_iterations", "iteration cap per WMMSE run", 1, 1e6,
                      [](Config& c) -> int& { return c.wmmse.max_iterations; }));
  f.push_back(integer("wmmse.restarts", "extra WMMSE runs from random starting points (best is kept)", 0, 1000,
                      [](Config& c) -> int& { return c.wmmse.restarts; }));
  f.push_back(choice<WmmseInit>("wmmse.init", "starting point of the first WMMSE run", [](Config& c) -> WmmseInit& { return c.wmmse.init; }));
  f.push_back(real("wmmse.bisection_tolerance", "relative tolerance on the power budget in the multiplier bisection",
                   1e-16, 1e-2, [](Config& c) -> double& { return c.wmmse.bisection_tolerance; }));
  // [ga]
  f.push_back(choice<GaAlgorithm>("ga.algorithm", "pagmo2 global optimiser behind the 'ga' beamformer",
                                  [](Config& c) -> GaAlgorithm& { return c.ga.algorithm; }));
  f.push_back(integer("ga.population", "population size", 8, 100000, [](Config& c) -> int& { return c.ga.population; }));
  f.push_back(integer("ga.generations", "generations per decision (the paper's 2000)", 1, 1e7,
                      [](Config& c) -> int& { return c.ga.generations; }));
}

/// The fields of [trajectory], [energy], in the order `config show` writes them.
void add_trajectory_and_energy_fields(std::vector<Field>& f) {
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
  f.push_back(choice<LayoutSource>("trajectory.layout", "where the starts and destinations come from",
                                   [](Config& c) -> LayoutSource& { return c.trajectory.layout; }));
  f.push_back(integer("trajectory.layout_seed", "seed of a generated layout", 0, 4611686018427387904.0,
                      [](Config& c) -> std::uint64_t& { return c.trajectory.layout_seed; }));
  // The models' own lines (skyloop/env/dynamics.hpp's registry).
  f.push_back(text("trajectory.mobility", dynamics_models().help_text() + " (docs/concepts/mobility-energy.md)", dynamics_models().names(),
                   [](Config& c) -> std::string& { return c.trajectory.mobility; }));
  f.push_back(reals("trajectory.speeds_mps",
                    "headings: speeds along the axes (m/s; 0 = hover; diagonals fly sqrt(2) x), each x slot_s a multiple of D_fly",
                    0, 200, [](Config& c) -> std::vector<double>& { return c.trajectory.speeds_mps; }));
  f.push_back(real("trajectory.slot_s", "slot duration delta_t (s); the grid model flies V = D_fly / delta_t", 0.01, 3600,
                   [](Config& c) -> double& { return c.trajectory.slot_s; }));
  f.push_back(real("trajectory.v_max_mps", "continuous: the largest ground speed (m/s); the velocity lies in its disc", 0.1, 200,
                   [](Config& c) -> double& { return c.trajectory.v_max_mps; }));
  f.push_back(real("trajectory.a_max_mps2", "continuous: the largest acceleration (m/s^2): |V[t] - V[t-1]| <= a_max slot_s", 0.01, 1000,
                   [](Config& c) -> double& { return c.trajectory.a_max_mps2; }));
  f.push_back(choice<Command>("trajectory.command", "continuous: what a command u in [-1, 1]^2 sets",
                              [](Config& c) -> Command& { return c.trajectory.command; }));
  f.push_back(real("trajectory.arrival_m", "continuous: a UAV this close to its destination at a slot's end has arrived (m)", 0.001,
                   1000, [](Config& c) -> double& { return c.trajectory.arrival_m; }));
  f.push_back(real("trajectory.climb_m", "grid-3d: the altitude one climb or descent changes in a slot (m)", 0.1, 1000,
                   [](Config& c) -> double& { return c.trajectory.climb_m; }));
  f.push_back(real("trajectory.altitude_min_m", "grid-3d: the lowest altitude a UAV may fly at (m); scenario.altitude_m, where missions start and end, on its levels",
                   1, 1e4, [](Config& c) -> double& { return c.trajectory.altitude_min_m; }));
  f.push_back(real("trajectory.altitude_max_m", "grid-3d: the highest altitude a UAV may fly at (m); levels of climb_m from altitude_min_m",
                   1, 1e4, [](Config& c) -> double& { return c.trajectory.altitude_max_m; }));
  // [energy]
  f.push_back(choice<Propulsion>("energy.model", "propulsion power", [](Config& c) -> Propulsion& { return c.energy.model; }));
  f.push_back(real("energy.p0_w", "blade profile power in hover P0 (W)", 0, 1e5, [](Config& c) -> double& { return c.energy.p0_w; }));
  f.push_back(real("energy.pi_w", "induced power in hover Pi (W)", 0, 1e5, [](Config& c) -> double& { return c.energy.pi_w; }));
  f.push_back(real("energy.u_tip_mps", "rotor blade tip speed U_tip (m/s)", 1, 1000, [](Config& c) -> double& { return c.energy.u_tip_mps; }));
  f.push_back(real("energy.v0_mps", "mean rotor induced velocity in hover v0 (m/s)", 0.01, 100,
                   [](Config& c) -> double& { return c.energy.v0_mps; }));
  f.push_back(real("energy.d0", "fuselage drag ratio d0", 0, 100, [](Config& c) -> double& { return c.energy.d0; }));
  f.push_back(real("energy.rho_kgm3", "air density rho (kg/m^3)", 0.01, 10, [](Config& c) -> double& { return c.energy.rho_kgm3; }));
  f.push_back(real("energy.solidity", "rotor solidity s", 0, 1, [](Config& c) -> double& { return c.energy.solidity; }));
  f.push_back(real("energy.rotor_area_m2", "rotor disc area A (m^2)", 0, 1000, [](Config& c) -> double& { return c.energy.rotor_area_m2; }));
  f.push_back(choice<Acceleration>("energy.acceleration", "acceleration term",
                                   [](Config& c) -> Acceleration& { return c.energy.acceleration; }));
  f.push_back(real("energy.mass_kg", "aircraft mass m for the kinetic term (kg)", 0, 1e5, [](Config& c) -> double& { return c.energy.mass_kg; }));
  f.push_back(real("energy.budget_j", "propulsion energy budget per UAV over a mission (J; 0 = none)", 0, 1e12,
                   [](Config& c) -> double& { return c.energy.budget_j; }));
  f.push_back(real("energy.weight", "env.objective = weighted: w in R-bar - w P-bar, (bit/s/Hz) per W of fleet power", 0, 1e6,
                   [](Config& c) -> double& { return c.energy.weight; }));
}

/// The fields of [nn], in the order `config show` writes them.
void add_nn_fields(std::vector<Field>& f) {
  // [nn]
  f.push_back(text("nn.model", "learned beamformer to train (ignn: the interference-aware network GNN)",
                   learned_beamformer_names(), [](Config& c) -> std::string& { return c.nn.model; }));
  f.push_back(integer("nn.hidden", "embedding size d_gnn (baselines use twice this width)", 4, 4096,
                      [](Config& c) -> int& { return c.nn.hidden; }));
  f.push_back(integer("nn.layers", "message-passing layers L_g (GNN)", 1, 16, [](Config& c) -> int& { return c.nn.layers; }));
  f.push_back(real("nn.learning_rate", "Adam learning rate", 1e-7, 1, [](Config& c) -> double& { return c.nn.learning_rate; }));
  f.push_back(choice<LrSchedule>("nn.lr_schedule", "learning rate over training", [](Config& c) -> LrSchedule& { return c.nn.lr_schedule; }));
  f.push_back(real("nn.weight_decay", "Adam weight decay (L2)", 0, 1, [](Config& c) -> double& { return c.nn.weight_decay; }));
  f.push_back(integer("nn.epochs", "training epochs E_gnn", 1, 100000, [](Config& c) -> int& { return c.nn.epochs; }));
  f.push_back(integer("nn.batch_samples", "snapshots per mini-batch (all their clusters form the batch)", 1, 1000000,
                      [](Config& c) -> int& { return c.nn.batch_samples; }));
  f.push_back(integer("nn.train_samples", "training snapshots", 1, 100000000, [](Config& c) -> int& { return c.nn.train_samples; }));
  f.push_back(integer("nn.val_samples", "validation snapshots", 1, 100000000, [](Config& c) -> int& { return c.nn.val_samples; }));
  f.push_back(integer("nn.test_samples", "held-out test snapshots", 1, 100000000, [](Config& c) -> int& { return c.nn.test_samples; }));
  f.push_back(integer("nn.data_seed", "seed of the train/validation/test sets (disjoint streams)", 0, 4611686018427387904.0,
                      [](Config& c) -> std::uint64_t& { return c.nn.data_seed; }));
  f.push_back(choice<ComputeDevice>("nn.device", "torch device for training and inference", [](Config& c) -> ComputeDevice& { return c.nn.device; }));
  f.push_back(real("nn.grad_clip", "max global gradient norm (0 = no clipping)", 0, 1e6,
                   [](Config& c) -> double& { return c.nn.grad_clip; }));
  f.push_back(choice<Readout>("nn.readout", "per-user output", [](Config& c) -> Readout& { return c.nn.readout; }));
  f.push_back(choice<Features>("nn.features", "what the encoders see of each channel",
                               [](Config& c) -> Features& { return c.nn.features; }));
  f.push_back(choice<Precision>("nn.precision", "arithmetic of a served model", [](Config& c) -> Precision& { return c.nn.precision; }));
  f.push_back(choice<Inference>("nn.inference", "serving path of a learned model",
                                [](Config& c) -> Inference& { return c.nn.inference; }));
  f.push_back(choice<Selection>("nn.selection", "what a served per-cluster model's beams become",
                                [](Config& c) -> Selection& { return c.nn.selection; }));
}

/// The fields of [marl], in the order `config show` writes them.
void add_marl_fields(std::vector<Field>& f) {
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
  f.push_back(choice<MinibatchLayout>("marl.minibatch", "what PPO's minibatches are drawn in",
                                [](Config& c) -> MinibatchLayout& { return c.marl.minibatch; }));
  f.push_back(integer("marl.epochs", "PPO epochs per update", 1, 1000, [](Config& c) -> int& { return c.marl.epochs; }));
  f.push_back(choice<CriticState>("marl.critic_state", "MAPPO critic input", [](Config& c) -> CriticState& { return c.marl.critic_state; }));
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
  f.push_back(choice<ObservationKind>("marl.encoder", "agent network input",
                                      [](Config& c) -> ObservationKind& { return c.marl.encoder; }));
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
  f.push_back(choice<StepSchedule>("marl.lr_schedule", "the learners' learning rate (from marl.learning_rate) over training",
                                   [](Config& c) -> StepSchedule& { return c.marl.lr_schedule; }));
  f.push_back(real("marl.average_decay",
                   "PPO: a Polyak average of the actor's weights, a <- d a + (1 - d) w after every optimiser step, is what "
                   "validation scores and policy.pt holds (training goes on with w; last.pt holds both); 0 = off, below 1",
                   0, 1, [](Config& c) -> double& { return c.marl.average_decay; }));
  f.push_back(choice<StepSchedule>("marl.entropy_schedule", "PPO's entropy bonus (from marl.entropy_coef) over training",
                                   [](Config& c) -> StepSchedule& { return c.marl.entropy_schedule; }));
  f.push_back(integer("marl.rate_map",
                      "the set observation also holds the radio map around the UAV: the sum rate R with the UAV at each lattice "
                      "point within this many D_fly steps, the others held in place (2 r (r + 1) cells, asked of the rate oracle "
                      "per agent and slot, memoised; 0 = none); needs marl.encoder = set",
                      0, kMaxRateMap, [](Config& c) -> int& { return c.marl.rate_map; }));
  f.push_back(integer("marl.slack_margin",
                      "slots of slack the reachability mask keeps in reserve; the collision shield may spend them to let a UAV "
                      "wait or step aside (0 = none)",
                      0, 1000, [](Config& c) -> int& { return c.marl.slack_margin; }));
  f.push_back(choice<Clearance>("marl.mask_clearance", "what the reachability mask counts the moves home around",
                                [](Config& c) -> Clearance& { return c.marl.mask_clearance; }));
  f.push_back(integer("marl.reserve_slack",
                      "a UAV with at most this much slack left reserves its way home in space and time, and the UAVs after it in "
                      "the shield's order plan around the ways reserved; an execution setting: validation, eval and deployment fly "
                      "it, training samples without it (lattice models; -1 = none)",
                      -1, 1000, [](Config& c) -> int& { return c.marl.reserve_slack; }));
  f.push_back(choice<PpoBackend>("marl.backend", "PPO learners' network library",
                                 [](Config& c) -> PpoBackend& { return c.marl.backend; }));
  f.push_back(integer("marl.val_layouts", "held-out validation layouts scored at every checkpoint; policy.pt = the best (0 = the last policy)",
                      0, 100000, [](Config& c) -> int& { return c.marl.val_layouts; }));
  f.push_back(integer("marl.checkpoint_every", "updates between checkpoints", 1, 1e7, [](Config& c) -> int& { return c.marl.checkpoint_every; }));
}

/// The fields of [env], in the order `config show` writes them.
void add_env_fields(std::vector<Field>& f) {
  // [env]
  f.push_back(text("env.oracle", "beamformer spec behind the environment's sum rate R[t] (gnn, wmmse, gnn=DIR, ...)",
                   {}, [](Config& c) -> std::string& { return c.env.oracle; }));
  f.push_back(real("env.w_rate", "reward weight of the cumulative average sum rate", 0, 1e6, [](Config& c) -> double& { return c.env.w_rate; }));
  f.push_back(real("env.w_arr", "reward per newly arrived UAV", 0, 1e6, [](Config& c) -> double& { return c.env.w_arr; }));
  f.push_back(real("env.w_bud", "penalty per boundary event", 0, 1e6, [](Config& c) -> double& { return c.env.w_bud; }));
  f.push_back(real("env.w_col", "penalty per UAV in a collision", 0, 1e6, [](Config& c) -> double& { return c.env.w_col; }));
  f.push_back(choice<Reward>("env.reward", "reward", [](Config& c) -> Reward& { return c.env.reward; }));
  f.push_back(choice<Objective>("env.objective", "what a mission is scored by (docs/concepts/mobility-energy.md)",
                                [](Config& c) -> Objective& { return c.env.objective; }));
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
    f.push_back(choice<StateKind>("env.state", "global state for critics and mixers",
                                  [](Config& c) -> StateKind& { return c.env.state; }));
    Field u{"env.users_file", Type::Text, "TOML file with users = [[x, y], ...] (empty: uniform users from the seed)", 0, 0, {}, {}, {}};
    u.get = [](const Config& c) { return FieldValue(c.env.users_file); };
    u.set = [](Config& c, const FieldValue& v) { c.env.users_file = std::get<std::string>(v); };
    f.push_back(std::move(u));
  }
}

std::vector<Field> make_fields() {
  std::vector<Field> f;
  add_run_and_scenario_fields(f);
  add_channel_fields(f);
  add_beamforming_fields(f);
  add_trajectory_and_energy_fields(f);
  add_nn_fields(f);
  add_marl_fields(f);
  add_env_fields(f);
  return f;
}

}  // namespace

const std::vector<Field>& config_fields() {
  static const std::vector<Field> fields = make_fields();
  return fields;
}

}  // namespace skyloop
