#pragma once
// Ways home reserved in space and time (marl.reserve_slack; beyond the paper): prioritized
// planning for the UAVs whose slack is nearly spent, so that two of them never meet where
// neither can give way.
//
// The one-slot shield (safety.hpp) sees only the next positions. Two UAVs with no slack left
// whose shortest ways home cross at one lattice point walk into a dead end it cannot see: once
// both stand next to the crossing, whichever moves first lands within D_min of the other
// (D_min = 25 m > D_fly = 20 m), and neither can wait. The UAVs of the fleet recipe's 64-UAV
// missions met like this (BENCHMARKS, "Large fleets").
//
// WaysHome plans in space and time, one UAV after another in shield order (least slack first):
// UAV n's moves are those after which it has a way home by T_max (a move per slot, waiting
// included) that keeps every slot's position at least D_min from the parked UAVs and from the
// ways reserved before it; a way ends parked at its destination, where the UAV hovers until the
// mission ends, so the destination must stay clear from its arrival on. reserve(n, a) then
// reserves n's way beginning with a: each slot the move that keeps a way and needs the fewest
// moves after it. The UAVs later in the order plan around it; next slot everything is planned
// again from where the UAVs are, or, given the ways of the slot before (WaysMemory), around those
// of the UAVs that followed theirs: they keep a way, the others plan around them. A UAV whose slack is larger than marl.reserve_slack does not
// plan; it keeps clear of the reserved UAVs' next positions through the shield, and does not
// park while a reserved way still passes its destination (may_park).
//
// Lattice mobility models (grid, headings) only: the continuous model's positions are off the
// lattice. Exact over the lattice: breadth-first forward from where the UAV is, backward for the
// states from which a way exists, over (slot, lattice point) pairs within reach of both.
#include <vector>

#include "skyloop/env/dynamics.hpp"
#include "skyloop/env/uav_env.hpp"
#include "skyloop/planning/safety.hpp"

namespace skyloop {

class WaysHome {
 public:
  /// Nothing reserved yet; the parked UAVs are the arrived ones. Lattice models only
  /// (std::logic_error for the continuous model).
  explicit WaysHome(const UavEnv& env);
  /// The ways of the slot before (memory.t == env.t() - 1) of the UAVs that stand where their way
  /// put them and have not arrived; nothing from a memory of another slot.
  WaysHome(const UavEnv& env, const WaysMemory& memory);

  /// The moves of UAV n (not arrived) that keep it in the area and after which it has a way home
  /// by T_max clear of the parked UAVs and of every other UAV's way reserved so far; 0 if none.
  ActionSet moves(int n);
  /// Reserves UAV n's way home beginning with move a, in place of the one it had. Call right
  /// after moves(n), with a one of its moves (any other a reserves nothing).
  void reserve(int n, int a);
  /// False while a reserved way comes within D_min of UAV m's destination in a later slot:
  /// parked there, m would block it.
  bool may_park(int m) const;
  /// Whether UAV n holds a reserved way.
  bool holds(int n) const;
  /// The positions reserved for slot tau (for tests and diagnostics): one per reserved UAV.
  std::vector<std::pair<double, double>> reserved_at(int tau) const;
  /// Every way reserved, for the next slot.
  WaysMemory memory() const { return WaysMemory{env_.t(), ways_}; }

 private:
  const UavEnv& env_;
  std::vector<ReservedPoint> ways_;  // (slot, position) of every reserved way, parking included
  // moves(n)'s search, kept for reserve(n, a).
  int planned_ = -1;
  LatticeFrame frame_;
  int layers_ = 0, dest_ = -1;
};

}  // namespace skyloop
