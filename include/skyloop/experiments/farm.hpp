#pragma once
// The task farm: independent, cached pieces of work (a trained model, a chunk of a sweep's
// snapshots, a MARL run, a planner evaluation) handed out over ranks. Rank 0 schedules (longest
// estimated piece first among those whose dependencies are done) and computes too, on a second
// thread; every other rank asks for a piece, computes it and reports back. The transport is
// MPI under mpirun (src/experiments/mpi_transport.cpp, built when Open MPI is found) and nothing
// for one process; the farm itself knows only messages.
//
// Without any transport, shard_slice() cuts the same pieces into n deterministic slices, so a
// Slurm job array or GNU parallel can fan them out (`skyloop reproduce --shard i/n`).
#include <cstddef>
#include <functional>
#include <iosfwd>
#include <memory>
#include <string>
#include <vector>

namespace skyloop {

/// Point-to-point messages between the ranks of one job.
class Transport {
 public:
  virtual ~Transport() = default;
  virtual int rank() const = 0;
  virtual int size() const = 0;
  virtual void send(int to, int tag, const std::string& data) = 0;
  /// A waiting message from any rank, if there is one (never blocks).
  virtual bool try_receive(int& from, int& tag, std::string& data) = 0;
  virtual void barrier() = 0;
  /// Ends every rank of the job at once with `code` (a rank failed outside any piece).
  [[noreturn]] virtual void abort(int code) = 0;
};

struct FarmTask {
  std::string id;                  // unique; a worker checks it against its own plan
  std::string kind, label;         // for the log
  double cost = 1.0;               // estimated seconds on one core: longest first
  std::vector<std::size_t> deps;   // indices of tasks that must finish first
};

/// What happened to one task (rank 0's view; times in seconds since the farm started).
struct FarmRecord {
  std::size_t task = 0;
  int rank = -1;                   // -1: never ran (a dependency failed)
  double assigned = 0, received = 0;
  double seconds = 0;              // the worker's own time for it
  bool ok = false;
  std::string error;
  /// Time the farm added to the piece: assignment to result minus the work itself.
  double overhead() const { return received - assigned - seconds; }
};

/// Runs every task once over the transport's ranks (collective: every rank calls it with the
/// same tasks). work(i) computes task i on whichever rank gets it and returns a payload, which
/// reaches collect(i, payload) on rank 0 (collect runs on rank 0's main thread). A task that
/// throws is recorded as failed with its message; the tasks depending on it do not run; the
/// others go on. Returns the records on rank 0 (empty elsewhere). `transport` may be null: one
/// process, tasks in order of priority on this thread.
std::vector<FarmRecord> farm_run(Transport* transport, const std::vector<FarmTask>& tasks,
                                 const std::function<std::string(std::size_t)>& work,
                                 const std::function<void(std::size_t, const std::string&)>& collect,
                                 std::ostream* log);

/// The tasks of slice `i` (1-based) of `n`: longest-processing-time-first over n bins by the
/// estimated costs, a task in the bin of its first dependency when it has one. Deterministic:
/// it depends only on the tasks. Returned in an order where dependencies come first.
std::vector<std::size_t> shard_slice(const std::vector<FarmTask>& tasks, int i, int n);

/// The order one process runs the tasks in: dependencies first, longest estimated first.
std::vector<std::size_t> priority_order(const std::vector<FarmTask>& tasks);

/// Worker threads for one rank: `requested` if > 0, else the cores this process may run on (its
/// affinity mask, which Slurm and mpirun set), shared with the other ranks on this machine when
/// the launcher did not bind each rank to its own cores.
int threads_per_rank(int requested, const Transport* transport);

/// The transport for this process: MPI when this binary has it and was started by an MPI
/// launcher (or `force` is set), else null. `force` without MPI support throws InputError.
/// Defined in mpi_transport.cpp (builds with MPI) or no_mpi_transport.cpp (builds without).
std::unique_ptr<Transport> open_transport(bool force);
/// True when started by an MPI launcher (OMPI_COMM_WORLD_SIZE, PMI_SIZE or PMIX_RANK set).
bool launched_by_mpi();
/// Whether this build has MPI.
bool mpi_available();

}  // namespace skyloop
