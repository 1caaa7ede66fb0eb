#pragma once
// What a run may allocate. An input that asks for more memory than the process may use (a rollout
// of marl.envs x marl.rollout steps, a replay buffer of marl.buffer_episodes episodes) is refused
// before anything is allocated, in one line naming the fields, instead of failing inside an
// allocator (std::bad_alloc, LibTorch's "DefaultCPUAllocator: can't allocate memory" with its
// stack) or being killed by the kernel halfway through a run. Torch-free.
#include <string>

namespace skyloop {

/// The memory this process may use, in bytes: the least of the machine's physical memory, the
/// cgroup's limit (cgroup v2 memory.max, v1 memory.limit_in_bytes: what Slurm and containers set)
/// and RLIMIT_AS (ulimit -v), read once per process. 0 when none of them is known.
double memory_limit_bytes();

/// Throws InputError "<what> needs <X> GiB, more than the <Y> GiB of memory this process may use:
/// <allowed>" when `bytes` exceeds memory_limit_bytes() (nothing when the limit is unknown).
/// `what` names the fields and their values; `allowed` says what fits.
void require_memory(double bytes, const std::string& what, const std::string& allowed);

/// A byte count as the messages write it: "12.3 GiB" (or MiB below 1 GiB).
std::string format_bytes(double bytes);

}  // namespace skyloop
