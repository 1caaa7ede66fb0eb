#pragma once
// The environment's spec: every array the trajectory environment exposes, named field by field
// with its offset, size and bounds (in the spirit of EnvPool's StateSpec / ActionSpec). This is the
// one place a layout is written: UavEnv's writers fill exactly these rows, and VecEnv, the
// learners, the Python module and its adapters read sizes, fields and bounds from here.
//
// Arrays (one row each; "per agent" arrays have one row per UAV):
//   obs          per agent  float32  the agents' observation: the paper's 11 reals (marl.encoder =
//                                    "mlp") or the set observation (marl.encoder = "set")
//   state        per env    float32  the global state: paper (4N + 2K reals) or compact (3 G^2 + 2)
//   agent_context per agent float32  who agent n is: paper: one-hot id (N); compact: displacements
//                                    to its kNeighbours nearest UAVs
//   agent_state  per agent  float32  state, agent_context, then the paper observation (11)
//   action_mask  per agent  int8     1 = allowed, one entry per action
#include <array>
#include <memory>
#include <string>
#include <vector>

#include "skyloop/core/choices.hpp"

namespace skyloop {

struct Config;

// ObservationKind (marl.encoder) and StateKind (env.state): skyloop/core/choices.hpp.

/// One named field of a row: `size` consecutive values from `offset`, each in [low, high].
class UavEnv;
/// Writes a field's values for agent n (or, in an environment-wide array, for the environment)
/// into out[0 .. size - 1].
using FieldWriter = void (*)(const UavEnv& env, int n, float* out);

struct SpecField {
  std::string name;
  int offset = 0;
  int size = 1;
  float low = 0, high = 0;
  FieldWriter write = nullptr;  // the field's writer (observation_fields(), state_fields())
};

/// One array: its rows' fields, in order, without gaps.
struct ArraySpec {
  std::string name;     // obs | state | agent_context | agent_state | action_mask
  std::string kind;     // paper | set | compact | id | neighbours | mask
  std::string dtype;    // float32 | int8
  bool per_agent = true;
  std::vector<SpecField> fields;
  int size = 0;         // values in one row (sum of the fields' sizes)

  /// Appends a field at the current end of the row.
  ArraySpec& add(const std::string& field, int count, float low, float high, FieldWriter write = nullptr);
  /// Appends every field of `other`, each name prefixed with "<prefix>.".
  ArraySpec& append(const ArraySpec& other, const std::string& prefix);
  /// The field named so; throws InputError naming the fields there are.
  const SpecField& field(const std::string& field) const;
  /// Lowest / highest bound of any field.
  float low() const;
  float high() const;
};

/// The paper's grid moves (the grid mobility model's actions; every other reader takes the action
/// space of the environment's dynamics, skyloop/env/dynamics.hpp).
enum Action : int { kUp = 0, kDown = 1, kLeft = 2, kRight = 3, kStay = 4 };
constexpr int kGridActions = 5;

/// The action space. Discrete models: `names.size()` actions, index = action. The continuous model
/// (dims = 2): a command in [-1, 1]^dims, and `names` its primitives, the discrete actions of
/// planners that choose among a few (skyloop/env/dynamics.hpp).
struct ActionSpec {
  std::vector<std::string> names;
  int hover = kStay;  // the action that stays in place (grid: STAY; headings: HOVER, the last)
  int dims = 0;       // continuous: the command's size (2: velocity along x and y); 0: discrete
  bool continuous() const { return dims > 0; }
  int count() const { return static_cast<int>(names.size()); }
  /// names[a]; "?" outside 0..count()-1.
  const char* name(int a) const { return a >= 0 && a < count() ? names[static_cast<std::size_t>(a)].c_str() : "?"; }
  bool operator==(const ActionSpec& o) const { return names == o.names && hover == o.hover && dims == o.dims; }
};


struct EnvSpec {
  int agents = 0, users = 0;
  ObservationKind observation_kind = ObservationKind::Paper;
  StateKind state_kind = StateKind::Paper;
  ActionSpec action;
  ArraySpec obs, state, agent_context, agent_state, action_mask;
  /// The paper's observation (always the tail of agent_state) and the set observation: both
  /// layouts, whichever `obs` is.
  ArraySpec paper_obs, set_obs, compact_state;
};

/// What one step of an environment reports (UavEnv::step; its fields for Python in step_info_fields()).
struct StepInfo {
  double reward = 0;         // r[t] (eq:total_reward)
  double sum_rate = 0;       // R at the new slot
  double avg_rate = 0;       // R-bar at the new slot
  int arrivals = 0, boundary = 0, collisions = 0;
  int feasibility = 0;       // sum_n Phi_n
  bool done = false;
  bool success = false;      // every UAV arrived
  // Episode so far (final values when done): P2.2 objective, slots, UAVs home, totals.
  double objective = 0;
  int T = 0, home = 0, episode_collisions = 0, episode_boundary = 0;
  double episode_reward = 0;
  // Propulsion (skyloop/env/energy.hpp): this slot's energy over the fleet, the episode's so far,
  // its sum rate objective (P2.2, whatever env.objective is) and the UAVs past energy.budget_j.
  double energy_j = 0, episode_energy_j = 0, sum_rate_objective = 0, bits_per_joule = 0;
  int over_budget = 0;
};

/// One field of the step's info (what Python's `info` dict and every adapter's infos hold, and
/// `VecEnv.spec["info"]` lists): its name, its dtype (float64 | int32 | bool), one line of help,
/// and where it is in a StepInfo.
struct InfoField {
  const char* name;
  const char* dtype;
  const char* help;
  double (*get)(const StepInfo&);
};
/// The step's info fields, in the order the info dict lists them (one table: the Python module
/// builds its dicts from it).
const std::vector<InfoField>& step_info_fields();

// Layout constants the writers and the spec share.
constexpr int kStateGrid = 8;   // compact state: G x G cells over the area
constexpr int kNeighbours = 4;  // compact agent context: nearest other UAVs
constexpr int kWideGrid = 7;    // set observation: users and UAVs, spacing 2 D_fly
constexpr int kNearGrid = 5;    // set observation: UAVs one move away, spacing D_fly
constexpr double kGainScale = 10;  // set observation's move_gains: tanh(kGainScale (R_a - R) / R)
/// The set observation's rate_map cells: the lattice offsets (dx, dy), in steps of D_fly, with
/// 1 <= |dx| + |dy| <= radius (every cell a grid UAV reaches within `radius` slots), ring by ring,
/// each ring from +x counter-clockwise; 2 radius (radius + 1) of them.
/// Built once per radius (0..kMaxRateMap); the observation writer reads it every step.
const std::vector<std::array<int, 2>>& rate_map_offsets(int radius);

/// The action space of the paper's grid mobility: UP, DOWN, LEFT, RIGHT, STAY.
const ActionSpec& grid_actions();
/// The paper's observation layout (bounds for any scenario): 6 reals and the one-hot previous
/// action (11 reals under the grid model).

/// What an environment's spec depends on.
struct SpecParams {
  int agents = 0, users = 0;
  double area_x = 0, area_y = 0, d_fly = 0;
  int t_max = 0;
  StateKind state = StateKind::Paper;
  ObservationKind observation = ObservationKind::Paper;
  ActionSpec action = grid_actions();  // the mobility model's
  bool lookahead = false;              // marl.lookahead: the set observation's move_gains field
  int rate_map = 0;                    // marl.rate_map: the set observation's rate_map field (its radius)
  bool altitude = false;               // the dynamics choose the altitude: the observations' altitude field
};
SpecParams spec_params(const Config& cfg, int agents, int users);

/// The paper's observation: the fields of observation_fields() it carries under p (its 6 reals,
/// the previous action, then the optional ones).
ArraySpec paper_observation_spec(const SpecParams& p);

/// One field of the observations: its layout and its writer in one row, the one place a field is
/// laid out and written (src/env/observations.cpp; docs/extending/observation-field.md). Each
/// observation is the rows that join it and are on, in table order.
struct ObservationField {
  enum Arrays { kPaper = 1, kSet = 2 };
  const char* name;
  int arrays;                         // kPaper | kSet: the observations it joins
  bool (*on)(const SpecParams&);      // whether the configuration turns it on
  int (*size)(const SpecParams&);     // its values under p
  float low, high;                    // its bounds
  FieldWriter write;                  // UAV n's values into out[0 .. size - 1]
  /// Bounds that depend on the scenario (the slack's floor, the UAV count), else low and high.
  void (*bounds)(const SpecParams&, float& low, float& high) = nullptr;
};
/// Every observation field, in the order the observations hold them.
const std::vector<ObservationField>& observation_fields();

/// One field of the environment's states (the critics' and mixers' inputs): the paper's state,
/// the compact state, and the agent contexts that make them agent-specific.
struct StateField {
  enum Arrays { kPaperState = 1, kCompactState = 2, kIdContext = 4, kNeighbourContext = 8 };
  const char* name;
  int arrays;                      // the one array it belongs to
  int (*size)(const SpecParams&);  // its values under p
  float low, high;
  FieldWriter write;               // the environment's values (agent n's for a context)
};
/// Every state field, in the order its array holds them.
const std::vector<StateField>& state_fields();

/// The set observation (sizes independent of K and N); bounds from the scenario.
ArraySpec set_observation_spec(const SpecParams& p);
/// The compact state (3 G^2 + 2 reals).
const ArraySpec& compact_state_spec();

/// Every array of an environment with `agents` UAVs and `users` users under `cfg` (env.state,
/// marl.encoder, the area and horizon).
EnvSpec make_env_spec(const SpecParams& p);
EnvSpec make_env_spec(const Config& cfg, int agents, int users);
/// make_env_spec(p), shared by every parameter set that makes the same spec in this process
/// (environments of one VecEnv hold one spec between them); keyed by the spec's own contents.
std::shared_ptr<const EnvSpec> shared_env_spec(const SpecParams& p);


}  // namespace skyloop
