#include "skyloop/experiments/builtin.hpp"

#include <stdexcept>

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
#if defined(SKYLOOP_HAS_TORCH)
    register_learned_beamformers(r, "");  // data_dir()/models, looked up when a model is created
#elif defined(SKYLOOP_FRONT_END)
    // The command line's LibTorch-free front end knows the learned names (so that an unknown name
    // lists them all) but hands every command that asks for one to the LibTorch build before it
    // creates anything (apps/skyloop/common.hpp, continue_with_libtorch_if).
    for (const std::string& n : learned_beamformer_names())
      r.add(n, learned_beamformer_description(n), [n](const Config&, const std::string&) -> std::unique_ptr<Beamformer> {
        throw std::logic_error("the learned beamformer '" + n + "' reached the LibTorch-free front end");
      });
#endif
    return r;
  }();
  return reg;
}

}  // namespace skyloop
