#pragma once
// Where skyloop finds its shipped files (models/, configs/, scripts/): the source tree it was built
// from, unless SKYLOOP_DATA_DIR or set_data_dir() names another root (an installed Python package
// carries its own copy of models/ and configs/), or the programs run from an installed tree
// (`cmake --install build --component cli --prefix P`: P/bin/skyloop reads P/share/skyloop).
#include <string>

namespace skyloop {

/// The data root: set_data_dir()'s argument if called, else $SKYLOOP_DATA_DIR if set, else the
/// installed share/skyloop beside an installed `skyloop` / `skyloop-torch` (where it holds models/),
/// else the source directory compiled in.
std::string data_dir();

/// Sets the data root for this process (before the first beamformer is created).
void set_data_dir(const std::string& dir);

}  // namespace skyloop
