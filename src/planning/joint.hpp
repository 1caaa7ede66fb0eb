#pragma once
// Joint actions of the planners that enumerate them (Greedy, the DP, brute force): internal.
#include <vector>

namespace skyloop {

/// All joint actions of n UAVs with A actions each, index j -> digit n = (j / A^n) % A.
inline std::vector<int> joint_action(long j, int n, int A) {
  std::vector<int> a(static_cast<std::size_t>(n));
  for (int i = 0; i < n; ++i, j /= A) a[static_cast<std::size_t>(i)] = static_cast<int>(j % A);
  return a;
}
/// A^n, or -1 above 2^40.
inline long joint_count(int A, int n) {
  long p = 1;
  for (int i = 0; i < n; ++i) {
    if (p > (1L << 40) / A) return -1;
    p *= A;
  }
  return p;
}

}  // namespace skyloop
