#pragma once
// The paper's GA baseline (Section VI-B) and pagmo2's other global optimisers.
//
// Decision vector: x in [-1, 1]^(2 L K_n), W = sqrt(P) (X_re + j X_im) with X the [L x K_n]
// reshape (column-major, real parts first). The power budget is enforced inside the fitness:
// W is scaled onto the budget (beamforming.power_scaling: full -> ||W||^2 = P, cap -> the paper's
// min(1, .)), and the fitness is minus the cluster sum rate. The returned W is the champion,
// scaled the same way, so it always meets eq:power_constraint.
//
// The default "sga" mirrors the paper's PYMOO GA: simulated binary crossover (p 0.9, eta 15),
// polynomial mutation (eta 20, p 1 / dimension), tournament selection of size 2, population 100,
// 2000 generations. Seeds: pagmo's 32-bit seeds are derived from run.seed and the cluster's
// numbers, so a decision is reproducible and independent of call order.
#include <cstdint>
#include <string>
#include <vector>

#include "skyloop/beamforming/beamformer.hpp"
#include "skyloop/beamforming/registry.hpp"

namespace skyloop {

struct GaOptions {
  GaAlgorithm algorithm = GaAlgorithm::Sga;  // ga.algorithm (its table: skyloop/core/choices.hpp)
  int population = 100;
  int generations = 2000;
  std::uint64_t seed = 1;
  PowerScaling scaling = PowerScaling::Full;
};

class GaBeamformer final : public Beamformer {
 public:
  explicit GaBeamformer(GaOptions opt);  // throws InputError for a population below 8 or no generations
  std::string name() const override {
    return opt_.algorithm == GaAlgorithm::Sga ? "ga" : "ga:" + std::string(name_of(opt_.algorithm));
  }
  MatrixXcd design(const Cluster& c) const override;

 private:
  GaOptions opt_;
};

/// Registers "ga" ("ga" uses ga.algorithm; "ga=pso" picks another pagmo optimiser).
void register_ga_beamformers(BeamformerRegistry& reg);

}  // namespace skyloop
