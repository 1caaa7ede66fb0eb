#include "skyloop/experiments/builtin.hpp"

#ifdef SKYLOOP_HAS_GA
#include "skyloop/beamforming/ga.hpp"
#endif

namespace skyloop {

BeamformerRegistry& builtin_beamformers() {
  static BeamformerRegistry reg = [] {
    BeamformerRegistry r;
    register_classical_beamformers(r);
#ifdef SKYLOOP_HAS_GA
    register_ga_beamformers(r);
#endif
    return r;
  }();
  return reg;
}

}  // namespace skyloop
