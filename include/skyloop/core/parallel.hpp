#pragma once
#include <cstddef>
#include <functional>

namespace skyloop {

/// Number of worker threads for a request: `requested` if > 0, else the hardware concurrency.
int resolve_threads(int requested);

/// Calls fn(i) for i in [0, n) on `threads` threads (dynamic chunks of one). fn must write only
/// to slot i of its outputs, so results do not depend on the thread count. The first exception
/// thrown by any call is rethrown after all threads stop.
void parallel_for(std::size_t n, int threads, const std::function<void(std::size_t)>& fn);

/// True while the calling thread runs fn(i) of a parallel_for on two or more threads: work that
/// could split itself over threads (the rate oracle's batches) stays on this one instead.
bool in_parallel_for();

/// Subnormal floats flushed to zero (results, FTZ, and inputs, DAZ) on the calling thread; the
/// threads it starts afterwards inherit the mode. They appear as training goes on and slow x86
/// arithmetic by 2x and more; and since they change the numbers, every thread that computes runs
/// in the same mode: the command line and the Python module set it before anything else, so a
/// run gives the same numbers in-process or in a process of its own. No effect where the CPU
/// has no such mode.
void flush_denormals();

}  // namespace skyloop
