#pragma once
// Configuration choices. Every closed set of values a configuration field takes is an enum here
// with one table of rows (name, value, help) right below it, under its subsystem's heading. The
// field table (allowed values and help), TOML reading and writing, every error and every branch
// read the enum and its table; no code compares a choice's name.
//
// Open sets, the ones a user extends (beamformers, planners, learners, mobility, path-loss and
// fading models, experiment kinds), are registries instead (skyloop/core/registry.hpp).
//
// Adding a value: the enumerator and its row here, one file (docs/extending/config-field.md).
#include <string>
#include <vector>

#include "skyloop/core/error.hpp"

namespace skyloop {

template <class E>
struct Choice {
  const char* name;  // as written in TOML and --set
  E value;
  const char* help;  // one line
};

/// The table of enum E, its rows in display order.
template <class E>
const std::vector<Choice<E>>& choices();

// Defines choices<E>(): SKYLOOP_CHOICES(E, {"name", E::Value, "help"}, ...).
#define SKYLOOP_CHOICES(E, ...)                                \
  template <>                                                  \
  inline const std::vector<Choice<E>>& choices<E>() {          \
    static const std::vector<Choice<E>> table = {__VA_ARGS__}; \
    return table;                                              \
  }

// ---- [scenario] ------------------------------------------------------------------------------
enum class UserLayout { Uniform, Hotspot, Mixed };  // scenario.user_layout
SKYLOOP_CHOICES(UserLayout,
                {"uniform", UserLayout::Uniform, "uniform in the area (the paper)"},
                {"hotspot", UserLayout::Hotspot, "in scenario.hotspots hotspots"},
                {"mixed", UserLayout::Mixed, "each layout one of the two, even odds"})

// ---- [channel] -------------------------------------------------------------------------------
/// Spectrum model (channel.spectrum; equations in skyloop/channel/network.hpp).
enum class Spectrum {
  Orthogonal,       // the paper: each UAV its own band of the full bandwidth
  OrthogonalSplit,  // N bands of 1/N of the bandwidth each (equal total bandwidth)
  Shared,           // every UAV on the same band: inter-cluster interference
};
SKYLOOP_CHOICES(Spectrum,
                {"orthogonal", Spectrum::Orthogonal, "each UAV its own full band (the paper)"},
                {"orthogonal-split", Spectrum::OrthogonalSplit, "N bands of 1/N of the bandwidth"},
                {"shared", Spectrum::Shared, "one band, inter-cluster interference"})
enum class RicianK { Fixed, Elevation };  // channel.rician_k
SKYLOOP_CHOICES(RicianK,
                {"fixed", RicianK::Fixed, "channel.rician_k_db"},
                {"elevation", RicianK::Elevation, "k_min_db at 0 deg rising linearly in dB to k_max_db at 90 deg"})

// ---- [beamforming], [wmmse], [ga] ------------------------------------------------------------
/// How a beamformer's raw output is scaled onto the power budget (eq:power_constraint).
enum class PowerScaling {
  /// alpha = sqrt(P / ||W||_F^2): always transmit at full power. The default, because in the
  /// paper's model (orthogonal bands) scaling W up by c > 1 multiplies every signal and
  /// interference term by c^2 and so raises every SINR; the optimum of P2.1 therefore always uses
  /// the full budget. Under the shared spectrum that no longer holds (a UAV's power is other
  /// clusters' interference); coordinated beamformers then choose their power below the budget.
  Full,
  /// alpha = min(1, sqrt(P / ||W||_F^2)): the paper's scaling (Section IV); never scales up.
  Cap,
};
SKYLOOP_CHOICES(PowerScaling,
                {"full", PowerScaling::Full, "sqrt(P/||W||^2)"},
                {"cap", PowerScaling::Cap, "the paper's min(1, sqrt(P/||W||^2))"})
enum class PowerAllocation { WaterFilling, Equal };     // beamforming.zf_power_allocation
SKYLOOP_CHOICES(PowerAllocation,
                {"waterfilling", PowerAllocation::WaterFilling, "water-filling (optimal for ZF)"},
                {"equal", PowerAllocation::Equal, "equal power per served user"})
enum class WmmseInit { ZfSel, Rzf, Mrt, Random };       // wmmse.init
SKYLOOP_CHOICES(WmmseInit,
                {"zfsel", WmmseInit::ZfSel, "ZF over the selected users"},
                {"rzf", WmmseInit::Rzf, "regularised ZF"},
                {"mrt", WmmseInit::Mrt, "maximum ratio transmission"},
                {"random", WmmseInit::Random, "a random point"})
enum class GaAlgorithm { Sga, De, Sade, Pso, Cmaes, Xnes, Gwo, BeeColony };  // ga.algorithm (and "ga=NAME")
SKYLOOP_CHOICES(GaAlgorithm,
                {"sga", GaAlgorithm::Sga, "simple genetic algorithm (the paper)"},
                {"de", GaAlgorithm::De, "differential evolution"},
                {"sade", GaAlgorithm::Sade, "self-adaptive differential evolution"},
                {"pso", GaAlgorithm::Pso, "particle swarm"},
                {"cmaes", GaAlgorithm::Cmaes, "covariance matrix adaptation"},
                {"xnes", GaAlgorithm::Xnes, "exponential natural evolution strategies"},
                {"gwo", GaAlgorithm::Gwo, "grey wolf optimiser"},
                {"bee_colony", GaAlgorithm::BeeColony, "artificial bee colony"})

// ---- [trajectory], [energy] ------------------------------------------------------------------
enum class LayoutSource { Given, Generated };  // trajectory.layout
SKYLOOP_CHOICES(LayoutSource,
                {"given", LayoutSource::Given, "starts and destinations as listed"},
                {"generated", LayoutSource::Generated, "scenario.uavs UAVs on the D_fly lattice from layout_seed"})
enum class Command { Velocity, Polar };        // trajectory.command (continuous mobility)
SKYLOOP_CHOICES(Command,
                {"velocity", Command::Velocity, "the velocity, onto the disc of v_max_mps"},
                {"polar", Command::Polar,
                 "a speed v_max (u0 + 1) / 2 and a turn of u1 x the widest a_max allows from the last heading"})
enum class Propulsion { RotaryWing, None };    // energy.model
SKYLOOP_CHOICES(Propulsion,
                {"rotary-wing", Propulsion::RotaryWing, "Zeng, Xu, Zhang, IEEE TWC 2019, eq. (12)"},
                {"none", Propulsion::None, "no propulsion energy"})
enum class Acceleration { None, Kinetic };     // energy.acceleration
SKYLOOP_CHOICES(Acceleration,
                {"none", Acceleration::None, "Zeng's steady-flight model"},
                {"kinetic", Acceleration::Kinetic, "+ m (V[t]^2 - V[t-1]^2) / 2 when speeding up"})

// ---- [env] -----------------------------------------------------------------------------------
enum class Reward { Paper, Objective };                           // env.reward
SKYLOOP_CHOICES(Reward,
                {"paper", Reward::Paper, "eq:total_reward"},
                {"objective", Reward::Objective,
                 "R-bar[t+1] - R-bar[t] (sums to the P2.2 objective) minus the boundary and collision penalties"})
enum class Objective { SumRate, EnergyEfficiency, Weighted, Energy };  // env.objective
SKYLOOP_CHOICES(Objective,
                {"sum-rate", Objective::SumRate, "P2.2's (1/T) sum R[t]"},
                {"energy-efficiency", Objective::EnergyEfficiency, "bits per joule (kbit/J)"},
                {"weighted", Objective::Weighted, "R-bar - energy.weight x mean fleet propulsion power"},
                {"energy", Objective::Energy, "-kJ (the rate term off)"})
enum class StateKind { Paper, Compact };                          // env.state
SKYLOOP_CHOICES(StateKind,
                {"paper", StateKind::Paper, "every UAV, user and destination (4N + 2K reals)"},
                {"compact", StateKind::Compact,
                 "8 x 8 density maps of users, UAVs and pending destinations (194 reals, any N and K)"})

// ---- [marl] ----------------------------------------------------------------------------------
enum class ObservationKind { Paper, Set };             // marl.encoder: mlp | set
SKYLOOP_CHOICES(ObservationKind,
                {"mlp", ObservationKind::Paper, "the paper's 11-real observation"},
                {"set", ObservationKind::Set,
                 "permutation-invariant encoder over user and neighbour displacements (any K and N)"})
enum class MinibatchLayout { Samples, Steps };         // marl.minibatch
SKYLOOP_CHOICES(MinibatchLayout,
                {"samples", MinibatchLayout::Samples, "agent samples shuffled one by one (the paper's and the MAPPO reference's)"},
                {"steps", MinibatchLayout::Steps,
                 "whole steps, every agent of a step in the same minibatch (TorchRL's layout), so that the critic's "
                 "state columns the agents of a step share (the set encoder's compact state) are multiplied once per "
                 "step, forward and backward (the fast backend)"})
enum class CriticState { Global, Agent };              // marl.critic_state
SKYLOOP_CHOICES(CriticState,
                {"global", CriticState::Global, "the global state s[t]"},
                {"agent", CriticState::Agent, "the agent-specific state s[t] + id + o_n"})
enum class Clearance { None, Parked, Destinations };   // marl.mask_clearance (skyloop/planning/safety.hpp)
SKYLOOP_CHOICES(Clearance,
                {"none", Clearance::None, "nothing (through every UAV)"},
                {"parked", Clearance::Parked, "the UAVs that have arrived (they hover at their destinations)"},
                {"destinations", Clearance::Destinations,
                 "every other UAV's destination, then the parked UAVs, where the slots left allow it (lattice models)"})
enum class StepSchedule { Constant, Linear };          // marl.lr_schedule, marl.entropy_schedule
SKYLOOP_CHOICES(StepSchedule,
                {"constant", StepSchedule::Constant, "held over training"},
                {"linear", StepSchedule::Linear, "falls linearly to 0 at total_steps (CleanRL's anneal_lr)"})
enum class PpoBackend { Fast, Torch };                 // marl.backend
SKYLOOP_CHOICES(PpoBackend,
                {"fast", PpoBackend::Fast, "fused float32 passes on the CPU (the default)"},
                {"torch", PpoBackend::Torch, "LibTorch's autograd (the reference; needed for nn.device = cuda)"})

// ---- [nn] ------------------------------------------------------------------------------------
enum class LrSchedule { Constant, Cosine };            // nn.lr_schedule
SKYLOOP_CHOICES(LrSchedule,
                {"constant", LrSchedule::Constant, "the paper"},
                {"cosine", LrSchedule::Cosine, "from nn.learning_rate per step down to 1% of it at the last epoch"})
enum class ComputeDevice { Cpu, Cuda };                // nn.device
SKYLOOP_CHOICES(ComputeDevice,
                {"cpu", ComputeDevice::Cpu, "the CPU"},
                {"cuda", ComputeDevice::Cuda, "the first CUDA device"})
enum class Readout { Direct, Structured };             // nn.readout
SKYLOOP_CHOICES(Readout,
                {"direct", Readout::Direct, "2L reals per user (the paper)"},
                {"structured", Readout::Structured, "(lambda, power) of the optimal structure"})
enum class Features { Linear, Log };                   // nn.features
SKYLOOP_CHOICES(Features,
                {"linear", Features::Linear, "[Re h, Im h] scaled (the paper, eq:node_feature)"},
                {"log", Features::Log,
                 "its direction with the norm compressed logarithmically (for channels whose gains span decades: "
                 "3GPP, Al-Hourani)"})
enum class Precision { Float32, Float64 };             // nn.precision
SKYLOOP_CHOICES(Precision,
                {"float32", Precision::Float32, "as trained"},
                {"float64", Precision::Float64, "same weights, a reference for numerical checks"})
enum class Inference { Fast, Torch };                  // nn.inference
SKYLOOP_CHOICES(Inference,
                {"fast", Inference::Fast, "fused float32 kernels, same weights; float64 is served by torch"},
                {"torch", Inference::Torch, "LibTorch, the training path and the reference"})
enum class Selection { Soft, Ranked };                 // nn.selection
SKYLOOP_CHOICES(Selection,
                {"soft", Selection::Soft, "the network's beams (as trained)"},
                {"ranked", Selection::Ranked,
                 "the network chooses whom to serve, ZF how: in the order of the rates the network's beams give them, "
                 "each user joins while it raises the water-filled ZF sum rate (at most L); the result or the network's "
                 "own beams, whichever has the higher sum rate"})

/// The names of E's values, in table order.
template <class E>
std::vector<std::string> choice_names() {
  std::vector<std::string> out;
  for (const auto& c : choices<E>()) out.emplace_back(c.name);
  return out;
}

/// "a, b, c": E's names for errors and help.
template <class E>
std::string choice_names_text() {
  std::string out;
  for (const auto& c : choices<E>()) out += (out.empty() ? "" : ", ") + std::string(c.name);
  return out;
}

/// "a = help; b = help": E's rows for a field's help line.
template <class E>
std::string choice_help() {
  std::string out;
  for (const auto& c : choices<E>()) out += (out.empty() ? "" : "; ") + std::string(c.name) + " = " + c.help;
  return out;
}

/// The name of value v (as TOML writes it).
template <class E>
const char* name_of(E v) {
  for (const auto& c : choices<E>())
    if (c.value == v) return c.name;
  return "?";  // an enumerator without a row of its table: add the row
}

/// The value named s; InputError "<field> = "s" is not allowed: allowed one of a, b" otherwise.
template <class E>
E parse_choice(const std::string& field, const std::string& s) {
  for (const auto& c : choices<E>())
    if (s == c.name) return c.value;
  throw InputError(field + " = \"" + s + "\" is not allowed: allowed one of " + choice_names_text<E>());
}

#undef SKYLOOP_CHOICES

}  // namespace skyloop
