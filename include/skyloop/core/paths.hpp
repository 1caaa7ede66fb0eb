#pragma once
// Where skyloop finds its shipped files (models/, configs/, scripts/): the source tree it was built
// from, unless SKYLOOP_DATA_DIR or set_data_dir() names another root (an installed Python package
// carries its own copy of models/ and configs/).
#include <string>

namespace skyloop {

/// The data root: set_data_dir()'s argument if called, else $SKYLOOP_DATA_DIR if set, else the
/// source directory compiled in.
std::string data_dir();

/// Sets the data root for this process (before the first beamformer is created).
void set_data_dir(const std::string& dir);

}  // namespace skyloop
