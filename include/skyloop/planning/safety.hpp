#pragma once
// Safety by construction for learned planners (beyond the paper): the reachability mask that the
// Random and Greedy baselines already fly with, and a collision shield over the joint action.
//
//  - reachability mask: UAV n may take action a only if a keeps it in the area and its
//    destination reachable in the slots left (UavEnv::feasible). An arrived UAV may only hover.
//    Flown from the start, the mask brings every UAV home by T_max: a UAV with no slack left can
//    only move towards its destination. With marl.mask_clearance the moves still needed are
//    counted, strictest first while the slots left allow it, around the other UAVs' destinations
//    ("destinations"), around the UAVs parked so far ("parked"), then through them ("none", the
//    only count without it; UavEnv::min_moves_around). An arrived UAV hovers at its destination
//    until the mission ends, closing the lattice points within D_min of it to the others;
//    counting around it keeps the slack for the detour, where counting through it lets a UAV with
//    no slack left meet it on its only way home (the 64-UAV fleet's collisions).
//  - collision shield: the UAVs choose one after another, least slack first (ties by index); a
//    move that brings a UAV within D_min of a UAV already placed (arrived UAVs are placed first)
//    is masked whenever one of its other allowed moves avoids that.
//  - slack margin (marl.slack_margin = m): the mask keeps m slots of slack in reserve (a UAV
//    plans to be home by T_max - m, and once the shield has spent some, keeps what is left);
//    the shield may spend it, widening a UAV's moves to the plain reachability mask when none of
//    its margin-keeping moves avoids a collision. Two UAVs
//    with no slack left on one line cannot pass each other; with a margin one of them can wait.
//
//  - continuous model (safe_velocities): the UAVs choose in shield order; a UAV keeps its velocity
//    command if, projected and flown, it leaves the area untouched and the destination reachable
//    (the HOME simulation, UavEnv::min_moves) and, with the shield, lands D_min clear of the UAVs
//    placed; a command that would leave the area slides along the boundary: the command turned by
//    15, 30, 45, 60, 90, 120 and 180 degrees, each side, smallest turn first, where the turned
//    command keeps the destination reachable; else it flies the allowed primitive (HOME, HOVER, the
//    headings) whose flown velocity is nearest to the one it asked for (the shielded primitives
//    first). HOME is always allowed from a state the mask led to, so the mask brings every UAV
//    home by T_max under any commands.
//
// Training samples through sequential_safe_actions (each UAV's allowed set is its action mask in
// the PPO / Q-learning update); execution uses shielded_argmax, which searches the joint action
// depth first so that a collision is never chosen when any joint action of allowed moves avoids one.
#include <cstdint>
#include <functional>
#include <memory>
#include <vector>

#include "skyloop/env/uav_env.hpp"

namespace skyloop {

// Clearance (marl.mask_clearance, skyloop/core/choices.hpp): what the reachability mask counts the
// moves home around: nothing; the parked UAVs; the other UAVs' destinations, then the parked UAVs
// (where the slots left allow).

struct SafetyOptions {
  bool mask = true;    // reachability mask
  bool shield = true;  // collision shield
  int margin = 0;      // slots of slack the mask keeps for the shield (marl.slack_margin)
  Clearance clearance = Clearance::None;  // marl.mask_clearance
  int reserve = -1;  // marl.reserve_slack: UAVs with at most this slack reserve their ways home (-1: none; ways_home.hpp)
};
/// The safety settings of a configuration: marl.action_mask, shield, slack_margin, mask_clearance,
/// reserve_slack.
SafetyOptions safety_options(const Config& cfg);
/// The safety the learners sample under in training: safety_options without reserve_slack, an
/// execution setting (the ways reserved are the deployed policy's, carried from slot to slot;
/// validation and deployment fly them).
SafetyOptions training_safety_options(const Config& cfg);

/// A set of actions, bit a = action a (the mobility models have at most 64 actions).
using ActionSet = std::uint64_t;
constexpr ActionSet action_bit(int a) { return ActionSet{1} << a; }
/// Every action of the environment's mobility model.
ActionSet all_actions(const UavEnv& env);

/// Bit a set if UAV n may take action a under the reachability mask: a keeps it in the area and its
/// destination reachable, with a slack (slots left after the move less the moves still needed)
/// of at least `margin`, or of all the slack it has if that is less (with no such move, the
/// margin-0 set). Never empty: if no move keeps the destination reachable (a state the mask itself never
/// leads to), the moves that stay in the area; an arrived UAV: hover only.
ActionSet reachable_moves(const UavEnv& env, int n, int margin = 0, Clearance clearance = Clearance::None);
/// Moves of UAV n allowed before the shield: reachable_moves (with safety.margin) with the mask,
/// else every action (hover only once arrived).
ActionSet allowed_moves(const UavEnv& env, int n, const SafetyOptions& safety);
/// The order in which not-yet-arrived UAVs choose: least slack (moves left minus moves needed)
/// first, ties by index.
std::vector<int> shield_order(const UavEnv& env, Clearance clearance = Clearance::None);

/// A point of a way home reserved (ways_home.hpp): UAV `uav` at (x, y) in slot tau.
struct ReservedPoint {
  int uav, tau;
  double x, y, z;
};
/// The ways home reserved in one slot (marl.reserve_slack), carried to the next by a caller that
/// plans a whole episode (a deployed policy): a UAV that followed its way keeps it, and the UAVs
/// planned around it keep theirs, so that two reserved UAVs never meet. Memory from another slot,
/// or a UAV that left its way, is dropped: a stale memory costs only the carrying.
struct WaysMemory {
  int t = -1;  // the slot it was planned in
  std::vector<ReservedPoint> points;
};

/// Joint action chosen one UAV at a time in shield order: choose(n, allowed) returns UAV n's
/// action given its allowed set (the shield applied against the UAVs placed so far).
/// `allowed_out[n]`, when given, receives each UAV's allowed set (arrived UAVs: hover only).
std::vector<int> sequential_safe_actions(const UavEnv& env, const SafetyOptions& safety,
                                         const std::function<int(int n, ActionSet allowed)>& choose,
                                         std::vector<ActionSet>* allowed_out = nullptr, WaysMemory* memory = nullptr);

/// The turns of sequential_safe_actions one at a time, for a caller that acts between them (the
/// Python VecEnv's begin_turns / take_turn: a learner writes each agent's observation just before
/// it chooses). sequential_safe_actions is a loop over it: the same order, allowed sets and ways.
/// The environment must not change while the turns run (UavEnv::show_decided excepted).
class SafeTurns {
 public:
  SafeTurns(const UavEnv& env, const SafetyOptions& safety, WaysMemory* memory = nullptr);
  ~SafeTurns();
  SafeTurns(SafeTurns&&) noexcept;
  SafeTurns& operator=(SafeTurns&&) noexcept;

  /// Every UAV that had a turn has chosen (arrived UAVs have none).
  bool done() const;
  /// Whose turn it is (not done).
  int uav() const;
  /// Its allowed moves: its mask, with the shield against the UAVs placed so far.
  ActionSet allowed() const;
  /// Records the move a of the UAV whose turn it is, places its landing, and begins the next turn.
  /// As with sequential_safe_actions' choose, a should be in allowed() (not checked here: a
  /// caller that takes moves from outside checks them; std::out_of_range for no such move).
  void choose(int a);
  /// Each UAV's move: hover for the arrived ones and for those still to choose.
  const std::vector<int>& actions() const;
  /// Each UAV's allowed set as its turn saw it (arrived UAVs and those still to choose: hover).
  const std::vector<ActionSet>& allowed_sets() const;

 private:
  struct State;
  std::unique_ptr<State> s_;
  void begin_turn();
};

/// take_turns (below) one turn at a time, for a caller that acts between them (the Python VecEnv's
/// begin_turns(passes) / take_turn). In every pass after the first, the turn's own UAV is shown
/// where it is as its turn begins (its landing of the pass before is no intention of its own);
/// choose(a) shows the landing of a. take_turns is a loop over it.
class TurnPasses {
 public:
  TurnPasses(UavEnv& env, const SafetyOptions& safety, int passes, WaysMemory* memory = nullptr);
  ~TurnPasses();
  TurnPasses(TurnPasses&&) noexcept;
  TurnPasses& operator=(TurnPasses&&) noexcept;

  /// Every pass is taken (no UAV flying: at once).
  bool done() const;
  /// Whose turn it is (not done).
  int uav() const;
  /// The pass of the turn in progress, from 0 (passes - 1 once done).
  int pass() const;
  /// The turn in progress is in the last pass: its move is flown.
  bool last() const;
  /// Its allowed moves (SafeTurns::allowed; 0 once done).
  ActionSet allowed() const;
  /// Records the move a of the UAV whose turn it is, shows its landing, and begins the next turn
  /// (after a pass's last turn, the next pass's first).
  void choose(int a);
  /// The last pass's joint move once done (before: the pass in progress's, hover for those still to choose).
  const std::vector<int>& actions() const;

 private:
  struct State;
  std::unique_ptr<State> s_;
  void settle();
};

/// marl.sequential's turns (sequential_safe_actions), taken `passes` times (marl.sequential_passes):
/// choose(n, allowed, last) returns UAV n's move on its turn, with the landings of the UAVs before
/// it in this pass shown to its observation and, after the first pass, those of the UAVs after it
/// at their moves of the pass before (UavEnv::show_decided); `last` marks the pass that is flown.
/// Each pass plans from a copy of *memory (the reserved ways), the last pass's memory is kept. The
/// last pass's joint action is returned with its landings still shown (the caller clears them).
std::vector<int> take_turns(UavEnv& env, const SafetyOptions& safety, int passes,
                            const std::function<int(int n, ActionSet allowed, bool last)>& choose, WaysMemory* memory = nullptr);

/// Continuous model: the velocity commands (m/s; row n = UAV n) that replace `wanted` where the
/// mask or the shield refuses it (above). Arrived UAVs' rows are 0.
Positions safe_velocities(const UavEnv& env, const SafetyOptions& safety, const Positions& wanted);

/// The deployed joint action of a learned planner from per-UAV action scores (scores[n][a], one
/// per action of the environment's mobility model; higher is better):
/// each UAV its best allowed move, and with the shield the first joint action, depth first over
/// the UAVs in shield order and each UAV's allowed moves best first, in which no two UAVs end
/// within D_min; if none exists (or the search passes its node budget), the sequential choice.
/// `memory`: the ways reserved, carried from slot to slot (WaysMemory; nullptr: planned afresh
/// each slot).
std::vector<int> shielded_argmax(const UavEnv& env, const SafetyOptions& safety,
                                 const std::vector<std::vector<float>>& scores, WaysMemory* memory = nullptr);

}  // namespace skyloop
