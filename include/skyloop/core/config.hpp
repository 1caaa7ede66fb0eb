#pragma once
// Typed configuration. Defaults are the paper's Section VI values (configs/paper.toml states the
// same values explicitly). Every field is described once, in the field table (config_fields()),
// which drives TOML loading, --set overrides, validation, and `skyloop config show`.
#include <cstdint>
#include <functional>
#include <string>
#include <variant>
#include <vector>

#include "skyloop/core/choices.hpp"
#include "skyloop/core/types.hpp"

namespace skyloop {

/// The most UAVs and users a snapshot, a scenario or an environment may hold (scenario.uavs,
/// scenario.users, trajectory.starts, explicit user arrays): every size is checked against these
/// before anything is allocated.
constexpr int kMaxUavs = 64;
constexpr int kMaxUsers = 4096;

struct RunConfig {            // [run]
  std::uint64_t seed = 1;     // base seed; every stochastic stage derives its streams from it
  int threads = 0;            // worker threads for batch work; 0 = all hardware threads
};

struct ScenarioConfig {       // [scenario]
  double area_x_m = 200.0;    // service area [0, area_x] x [0, area_y] (eq:range_x, eq:range_y)
  double area_y_m = 200.0;
  double altitude_m = 100.0;  // UAV flight altitude H
  int uavs = 3;               // N for random snapshots (and for a generated trajectory layout)
  int users = 12;             // K for random snapshots
  UserLayout user_layout = UserLayout::Uniform;  // uniform (the paper) | hotspot | mixed (per layout, even odds)
  int hotspots = 4;                     // hotspot centres, uniform in the area
  double hotspot_radius_m = 40.0;       // std of a hotspot user's offset from its centre (each axis)
  double hotspot_fraction = 0.8;        // share of users in hotspots; the rest uniform
  double user_height_m = 0.0;           // users' antenna height above ground (the paper: 0)
};

struct ChannelConfig {                     // [channel]
  int antennas = 4;                        // ULA size L
  double antenna_spacing_wavelengths = 0.5;  // d_a / lambda
  double p_max_dbm = 30.0;                 // per-UAV power budget P_max
  double noise_dbm = -90.0;                // sigma_0^2
  double beta0_db = -20.0;                 // channel gain at the reference distance
  double d0_m = 1.0;                       // reference distance d_0
  double coverage_radius_m = 150.0;        // R_c, on the 3-D UAV-user distance
  Spectrum spectrum = Spectrum::Orthogonal;  // orthogonal (the paper) | orthogonal-split | shared
  double bandwidth_hz = 1e6;               // B: turns R (bit/s/Hz) into bits for bits per joule (noise stays noise_dbm)
  // The air-to-ground channel (channel/channel_model.hpp; the models in channel/path_loss.hpp).
  std::string pathloss = "free-space";     // "free-space" (the paper) | "3gpp-uma-av" | "3gpp-umi-av" | "3gpp-rma-av" | "al-hourani"
  std::string environment = "urban";       // al-hourani: "suburban" | "urban" | "dense-urban" | "highrise-urban"
  double carrier_ghz = 2.0;                // carrier frequency f_c (3GPP and al-hourani)
  bool shadowing = true;                   // draw log-normal shadowing with the model's spread
  std::string fading = "none";             // "none" (the paper) | "rician"
  RicianK rician_k = RicianK::Fixed;       // fixed (rician_k_db) | elevation (k_min_db at 0 deg to k_max_db at 90 deg)
  double rician_k_db = 10.0;               // K of a LoS link under rician_k = "fixed"
  double rician_k_min_db = 5.0;            // K at elevation 0 under rician_k = "elevation"
  double rician_k_max_db = 15.0;           // K at elevation 90 deg under rician_k = "elevation"
  int fast_slots = 1;                      // small-scale realisations per trajectory slot; R[t] is their mean
  double correlation_m = 50.0;             // decorrelation distance of the LoS-state and shadowing maps
  std::uint64_t seed = 1;                  // the city: seeds the LoS, shadowing and fading maps

  double p_max_w() const { return dbm_to_watt(p_max_dbm); }
  double noise_w() const { return dbm_to_watt(noise_dbm); }
};

struct BeamformingConfig {                  // [beamforming]
  PowerScaling power_scaling = PowerScaling::Full;
  PowerAllocation zf_power_allocation = PowerAllocation::WaterFilling;  // waterfilling | equal
};

struct WmmseConfig {                // [wmmse]
  double tolerance = 1e-6;          // stop when the relative sum-rate gain of an iteration is below
  int max_iterations = 1000;        // iteration cap per run
  int restarts = 0;                 // extra runs from random points; the best sum rate is kept
  WmmseInit init = WmmseInit::ZfSel;  // first run's starting point: zfsel | rzf | mrt | random
  double bisection_tolerance = 1e-10;  // relative tolerance of the power constraint in the mu bisection
};

struct GaConfig {                   // [ga]
  GaAlgorithm algorithm = GaAlgorithm::Sga;  // pagmo optimiser: sga | de | sade | pso | cmaes | xnes | gwo | bee_colony
  int population = 100;             // individuals
  int generations = 2000;           // generations (the paper's 2000)
};

struct TrajectoryConfig {           // [trajectory] (used by the environment)
  std::vector<Point2> starts{{20, 20}, {20, 180}, {180, 180}};
  std::vector<Point2> destinations{{180, 100}, {180, 20}, {20, 100}};
  double d_fly_m = 20.0;            // distance flown per slot
  double d_min_m = 25.0;            // minimum UAV separation (eq:collision_constraint)
  int t_max = 24;                   // mission horizon in slots
  LayoutSource layout = LayoutSource::Given;  // given (starts, destinations above) | generated (scenario.uavs UAVs from layout_seed)
  std::uint64_t layout_seed = 1;    // seed of a generated layout
  // Mobility (skyloop/env/dynamics.hpp; beyond the paper but the grid model, which is the paper's).
  std::string mobility = "grid";    // grid (the paper's five moves of D_fly) | headings (8 headings x speeds_mps) | continuous
  std::vector<double> speeds_mps{0.0, 10.0, 20.0};  // headings: axis speeds (0 = hover); speed x slot_s a multiple of D_fly
  double slot_s = 2.0;              // slot duration delta_t (s); the grid model flies V = D_fly / delta_t
  double v_max_mps = 20.0;          // continuous: the velocity lies in the disc of this radius (m/s)
  double a_max_mps2 = 5.0;          // continuous: |V[t] - V[t-1]| <= a_max slot_s (m/s^2)
  Command command = Command::Velocity;  // continuous: what u in [-1, 1]^2 commands: velocity | polar (speed, turn)
  double arrival_m = 1.0;           // continuous: a UAV within this distance of its destination has arrived (m)
  double climb_m = 20.0;            // grid-3d: the altitude a climb or descent changes in one slot (m)
  double altitude_min_m = 60.0;     // grid-3d: the lowest altitude a UAV may fly at (m)
  double altitude_max_m = 140.0;    // grid-3d: the highest (m)
};

struct EnergyConfig {               // [energy] propulsion (skyloop/env/energy.hpp; beyond the paper)
  // Rotary-wing power P(V) of Zeng, Xu and Zhang, IEEE TWC 2019, eq. (12), Table I values.
  Propulsion model = Propulsion::RotaryWing;  // rotary-wing | none (no propulsion energy)
  double p0_w = 79.86;              // blade profile power in hover P0 (W)
  double pi_w = 88.63;              // induced power in hover Pi (W)
  double u_tip_mps = 120.0;         // rotor blade tip speed U_tip (m/s)
  double v0_mps = 4.03;             // mean rotor induced velocity in hover v0 (m/s)
  double d0 = 0.6;                  // fuselage drag ratio d0
  double rho_kgm3 = 1.225;          // air density rho (kg/m^3)
  double solidity = 0.05;           // rotor solidity s
  double rotor_area_m2 = 0.503;     // rotor disc area A (m^2)
  Acceleration acceleration = Acceleration::None;  // none | kinetic: + max(0, m (V[t]^2 - V[t-1]^2) / 2) per slot
  double mass_kg = 2.04;            // aircraft mass m (Table I: weight W = 20 N)
  double budget_j = 0.0;            // energy budget per UAV over a mission (J; 0 = none)
  double weight = 0.0;              // env.objective = weighted: w in (bit/s/Hz) per W of fleet power
};

struct EnvConfig {                  // [env] the trajectory environment (Sections III-A, V-B)
  std::string oracle = "gnn";       // beamformer spec behind R[t] (gnn = the shipped paper GNN)
  // Not given in the paper; chosen so that MAPPO brings every UAV home (README, MARL status).
  double w_rate = 0.02;             // weight of the cumulative average sum rate R-bar[t]
  double w_arr = 30.0;              // per UAV newly arrived
  double w_bud = 5.0;               // per boundary event (a move out of the area, cancelled)
  double w_col = 2.0;               // per UAV closer than D_min to another
  double w_fea = 1.0;               // per UAV reachability indicator Phi_n[t] (+1 / -1)
  // Reward: paper (eq:total_reward with the weights above) | objective (beyond the paper): the
  // increment of R-bar, R-bar[t+1] - R-bar[t], whose sum over an episode is the P2.2 objective
  // less R[1], minus w_bud N_bud and w_col N_col; arrival comes from the action mask.
  Reward reward = Reward::Paper;
  bool resample_users = false;      // draw new users at every reset (else fixed per environment)
  std::string users_file;           // TOML with users = [[x, y], ...]; empty = uniform from the seed
  int users_min = 0;                // a sampled layout's K is uniform in [users_min, users_max] (0 = scenario.users)
  int users_max = 0;
  Objective objective = Objective::SumRate;  // sum-rate (P2.2) | energy-efficiency (kbit/J) | weighted (R-bar - w P-bar)
  StateKind state = StateKind::Paper;  // global state of the critics / mixers: paper (4N + 2K reals) | compact (independent of N and K)
};

constexpr int kMaxRateMap = 6;  // marl.rate_map's largest radius: 2 r (r + 1) = 84 cells of the radio map
constexpr int kMaxSequentialPasses = 4;  // marl.sequential_passes' largest value

struct MarlConfig {                 // [marl] trajectory learning (Section V, VI-C)
  std::string algo = "mappo";       // mappo | ippo | vdn | qmix
  std::int64_t total_steps = 2000000;  // environment steps (all environments together)
  int envs = 8;                     // parallel environments (VecEnv, one shared scenario)
  std::uint64_t users_seed = 3;     // the scenario's users (as `skyloop plan --seed`)
  int hidden = 64;                  // actor / critic / Q-network width (2 hidden layers)
  double learning_rate = 3e-4;      // Adam (PPO); the value-decomposition methods use it too
  double gamma = 0.99;
  double gae_lambda = 0.95;
  double clip = 0.2;                // PPO ratio clip epsilon (also the value clip)
  double value_coef = 0.5;          // c1
  double entropy_coef = 0.03;       // c2 (the paper uses 0.01; see README "Multi-agent trajectory learning")
  int rollout = 256;                // steps per environment between updates
  int minibatches = 4;
  MinibatchLayout minibatch = MinibatchLayout::Samples;  // PPO: samples (agent samples shuffled apart) | steps (whole steps: every agent of a step together)
  int epochs = 10;
  CriticState critic_state = CriticState::Agent;  // mappo critic input: global (s[t]) | agent (s[t] + id + o_n)
  bool value_norm = true;           // normalise value targets with running statistics
  double grad_clip = 10.0;          // max global gradient norm (0 = off)
  // value decomposition (VDN / QMIX)
  int buffer_episodes = 5000;       // episode replay buffer
  int batch_episodes = 32;
  double epsilon_start = 1.0;
  double epsilon_end = 0.05;
  double epsilon_anneal = 0.25;     // fraction of total_steps over which epsilon anneals linearly
  int target_update = 200;          // gradient steps between target-network copies
  int mixer_embed = 32;             // QMIX mixing-network width
  int checkpoint_every = 50;        // updates between checkpoints
  // Safety and generalisation (beyond the paper; README "Generalisation")
  bool action_mask = true;          // reachability mask (in the area, destination reachable in the slots left)
  bool shield = true;               // collision shield over the joint action
  int slack_margin = 0;             // slots of slack the mask keeps for the shield to spend (safety.hpp)
  Clearance mask_clearance = Clearance::None;  // what the mask counts the moves home around (safety.hpp)
  int reserve_slack = -1;           // UAVs with at most this slack reserve their ways home (ways_home.hpp; -1: none); execution only
  ObservationKind encoder = ObservationKind::Paper;  // mlp (the paper's 11-real observation) | set (users and neighbours as sets)
  bool lookahead = false;           // set observation: each move's one-slot change of R (UavEnv::write_move_gains)
  int rate_map = 0;                 // set observation: R around the UAV within this many lattice steps (UavEnv::write_rate_map; 0 = none, at most kMaxRateMap)
  bool sequential = false;          // the UAVs choose one after another in shield order, each seeing the landings chosen before it (UavEnv::show_decided)
  int sequential_passes = 1;        // with sequential: the turns taken this many times a slot, each pass showing the UAVs after a UAV at their last pass's moves
  StepSchedule lr_schedule = StepSchedule::Constant;       // constant | linear: the learning rate falls linearly to 0 over total_steps
  StepSchedule entropy_schedule = StepSchedule::Constant;  // constant | linear: PPO's entropy_coef falls linearly to 0 over total_steps
  PpoBackend backend = PpoBackend::Fast;  // PPO networks: fast (fused float32, CPU) | torch (LibTorch autograd)
  double average_decay = 0;         // PPO: Polyak average of the actor's weights, a <- d a + (1 - d) w per step; policy.pt and validation use it (0 = off)
  int val_layouts = 0;              // validation layouts scored at each checkpoint; policy.pt = the best (0 = last)
};

struct NnConfig {                   // [nn] learned beamformers (Section IV and its baselines)
  std::string model = "gnn";        // gnn | deepsets | mspointnet | ignn (network-level, interference-aware)
  int hidden = 128;                 // d_gnn (GNN embedding size); baselines use 2x, see README
  int layers = 3;                   // L_g message-passing layers (GNN)
  double learning_rate = 1e-3;      // Adam
  LrSchedule lr_schedule = LrSchedule::Constant;  // constant (the paper) | cosine (decays per step to 1% at the last epoch)
  double weight_decay = 1e-6;       // Adam L2 penalty
  int epochs = 25;                  // E_gnn
  int batch_samples = 64;           // snapshots per mini-batch (all their clusters)
  int train_samples = 10000;        // training snapshots (N = scenario.uavs, K = scenario.users)
  int val_samples = 1000;           // validation snapshots (model selection)
  int test_samples = 1000;          // held-out test snapshots (reported figures)
  std::uint64_t data_seed = 2024;   // seed of the data sets; train/val/test use disjoint streams
  ComputeDevice device = ComputeDevice::Cpu;       // cpu | cuda
  double grad_clip = 0.0;           // max global gradient norm; 0 = off
  Readout readout = Readout::Direct;  // direct (the paper: 2L reals per user) | structured (beyond the paper)
  Features features = Features::Linear;  // encoders' input: linear (the paper, eq:node_feature) | log (norm compressed)
  Precision precision = Precision::Float32;  // serving arithmetic: float32 (training's) | float64 (a reference for checks)
  Inference inference = Inference::Fast;     // serving path: fast (fused float32 kernels) | torch (LibTorch, the reference)
  Selection selection = Selection::Soft;     // what a served per-cluster model's beams become: soft (as trained) | ranked (nn.selection in config_fields.cpp)
};

struct Config {
  RunConfig run;
  ScenarioConfig scenario;
  ChannelConfig channel;
  BeamformingConfig beamforming;
  WmmseConfig wmmse;
  GaConfig ga;
  TrajectoryConfig trajectory;
  EnergyConfig energy;
  NnConfig nn;
  EnvConfig env;
  MarlConfig marl;
};

// ---- the field table -------------------------------------------------------------------------

using FieldValue = std::variant<bool, std::int64_t, double, std::string, std::vector<Point2>, std::vector<double>>;

struct Field {
  enum class Type { Boolean, Integer, Real, Text, Points, Reals };
  std::string key;   // "section.name"
  Type type;
  std::string help;  // one line: meaning and unit
  double lo = 0, hi = 0;             // inclusive range for Integer/Real and each entry of Reals
  std::vector<std::string> choices;  // allowed values for Text
  std::function<FieldValue(const Config&)> get;
  std::function<void(Config&, const FieldValue&)> set;  // assumes a checked value

  /// "[-30, 60]" or "one of: full, cap" etc.
  std::string allowed() const;
};

/// All fields, in display order.
const std::vector<Field>& config_fields();
/// The field with this key, or nullptr.
const Field* find_field(const std::string& key);

/// Checks `value` against the field's type and range, converts it (an integer is accepted for a
/// real) and stores it. Throws InputError: "<key> = <value> is out of range: allowed [lo, hi]".
void set_field(Config& cfg, const Field& field, const FieldValue& value);

/// Most actions a mobility model may have (action masks are 64-bit sets).
constexpr int kMaxActions = 64;
/// Lattice steps per slot at axis speed v (m/s), or -1 if v slot_s is not a whole multiple of pitch.
long lattice_steps(double speed, double slot_s, double pitch);

/// Cross-field rules (starts and destinations in the area, same count, R_c >= H, ...).
/// Throws InputError naming the fields.
void validate(const Config& cfg);
/// Completes a configuration after its fields are set, then validates it: a generated trajectory
/// layout (trajectory.layout = "generated") fills trajectory.starts and .destinations.
void finalise(Config& cfg);
/// Starts and destinations for scenario.uavs UAVs, from trajectory.layout_seed: distinct points
/// of the D_fly lattice inside the area (one D_fly from its edges), starts pairwise at least
/// D_min apart and so are the destinations, each destination 1 .. T_max - 1 moves from its start.
/// Throws InputError naming the settings when they cannot be placed.
void generate_layout(Config& cfg);

/// Human text of a value, TOML syntax ("3", "0.5", "\"full\"", "[[20, 20], [20, 180]]").
std::string format_value(const FieldValue& v);
/// A TOML basic string literal for `s` (quotes, backslashes and control characters escaped).
std::string toml_string(const std::string& s);

}  // namespace skyloop
