#pragma once
#include "skyloop/beamforming/registry.hpp"

namespace skyloop {

/// The process-wide registry with every built-in beamformer (mrt, zf, rzf, wmmse, and ga when
/// built with pagmo). Add your own to it before running an experiment.
BeamformerRegistry& builtin_beamformers();

}  // namespace skyloop
