#pragma once
// Beamformers by name, so the CLI, experiments and the environment can be handed any of them, and
// a user can add their own:
//
//   auto& reg = skyloop::builtin_beamformers();          // experiments/builtin.hpp
//   reg.add("mine", "my precoder", [](const Config& cfg, const std::string& arg) {
//     return std::make_unique<MyBeamformer>(cfg, arg);
//   });
//   auto bf = reg.create("mine=path/to/model", cfg);
//
// A spec is "name" or "name=arg" (e.g. "ga=pso", later "gnn=models/gnn/model.pt").
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "skyloop/beamforming/beamformer.hpp"
#include "skyloop/core/config.hpp"
#include "skyloop/core/registry.hpp"

namespace skyloop {

using BeamformerFactory = std::function<std::unique_ptr<Beamformer>(const Config& cfg, const std::string& arg)>;

/// The beamformers by name, sorted (skyloop/core/registry.hpp); a spec is "name" or "name=arg".
class BeamformerRegistry : public Registry<BeamformerFactory> {
 public:
  BeamformerRegistry() : Registry("method '{}'", {}, Order::Name) {}
  /// Builds "name" or "name=arg"; throws InputError naming the spec and the known names.
  std::unique_ptr<Beamformer> create(const std::string& spec, const Config& cfg) const;
};

/// Registers the Eigen-only beamformers: mrt, zf, zfsel, rzf, wmmse (per cluster) and nwmmse, crzf,
/// czf (coordinated over the network).
void register_classical_beamformers(BeamformerRegistry& reg);

/// The learned beamformers' names ("gnn", "deepsets", "mspointnet", "ignn"), registered by
/// `register_learned_beamformers` (nn/learned.hpp) in a LibTorch build. Listed here, LibTorch-free,
/// so that the configuration, the command line's front end and the registry read one list.
const std::vector<std::string>& learned_beamformer_names();

/// The registry's description of the learned beamformer `name`.
std::string learned_beamformer_description(const std::string& name);

/// Whether the spec ("name" or "name=arg") names a learned beamformer (one that needs LibTorch).
bool is_learned_beamformer(const std::string& spec);

/// Splits a comma-separated list ("mrt,zf,gnn=a/b.pt"), rejecting empty and repeated items;
/// `flag` names the option in errors.
std::vector<std::string> split_methods(const std::string& list, const std::string& flag = "--methods");

}  // namespace skyloop
