// Builds without MPI: one process; --mpi is refused, --shard i/n still fans out.
#include <cstdlib>

#include "skyloop/core/error.hpp"
#include "skyloop/experiments/farm.hpp"

namespace skyloop {

bool mpi_available() { return false; }

std::unique_ptr<Transport> open_transport(bool force) {
  if (launched_by_mpi())
    throw InputError("started by an MPI launcher, but this skyloop was built without MPI (every rank would run the whole "
                     "job): allowed a build with MPI (install libopenmpi-dev and rebuild), or --shard i/n without mpirun");
  if (force)
    throw InputError("--mpi: this skyloop was built without MPI: allowed only without --mpi (install libopenmpi-dev and "
                     "rebuild), or --shard i/n");
  return nullptr;
}

}  // namespace skyloop
