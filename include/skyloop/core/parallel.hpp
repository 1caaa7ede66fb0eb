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

}  // namespace skyloop
