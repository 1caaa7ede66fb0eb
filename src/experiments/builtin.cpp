#include "skyloop/experiments/builtin.hpp"

#ifdef SKYLOOP_HAS_GA
#include "skyloop/beamforming/ga.hpp"
#endif
#ifdef SKYLOOP_HAS_TORCH
#include "skyloop/nn/learned.hpp"
#endif

namespace skyloop {

BeamformerRegistry& builtin_beamformers() {
  static BeamformerRegistry reg = [] {
    BeamformerRegistry r;
    register_classical_beamformers(r);
#ifdef SKYLOOP_HAS_GA
    register_ga_beamformers(r);
#endif
#ifdef SKYLOOP_HAS_TORCH
    register_learned_beamformers(r, "");  // data_dir()/models, looked up when a model is created
#endif
    return r;
  }();
  return reg;
}

}  // namespace skyloop
