#pragma once
// Portable, seeded randomness. std::mt19937_64's output sequence is fixed by the C++ standard,
// but the std distributions are not, so skyloop draws uniforms and normals itself: the same seed
// gives the same numbers with every standard library.
#include <cstdint>
#include <random>
#include <vector>

namespace skyloop {

/// SplitMix64 finaliser: a bijective 64-bit mix used to derive independent stream seeds.
std::uint64_t mix64(std::uint64_t x);

/// Seed of stream `stream` under base seed `seed` (e.g. sample i of a run seeded s). Order- and
/// thread-independent: sample i gets the same numbers however the work is split.
std::uint64_t derive_seed(std::uint64_t seed, std::uint64_t stream);

/// Seed of stream (a, b) under `seed`.
std::uint64_t derive_seed(std::uint64_t seed, std::uint64_t a, std::uint64_t b);

/// Hash of a byte range (FNV-1a folded through mix64). Used to make stochastic beamformers pure
/// functions of (their seed, the cluster they are given).
std::uint64_t hash_bytes(const void* data, std::size_t n, std::uint64_t h = 0xcbf29ce484222325ULL);

class Rng;

/// A uniform random permutation of `v` in place (Fisher-Yates), from one draw of `rng`: the
/// indices come from a SplitMix64 stream seeded by that draw, each bounded by Lemire's
/// multiply-shift with its rejection step (unbiased; a division only in the rare rejection zone).
/// Three to seven times as fast as below() per index (BENCHMARKS.md); the PPO update shuffles its rollout with it
/// every epoch (some 60 million indices over a 2e6-step run of the paper scenario).
void shuffle(std::vector<std::size_t>& v, Rng& rng);

class Rng {
 public:
  explicit Rng(std::uint64_t seed) : engine_(mix64(seed)) {}
  /// Uniform in [0, 1) with 53 random bits.
  double uniform() { return static_cast<double>(engine_() >> 11) * 0x1.0p-53; }
  /// Uniform in [a, b).
  double uniform(double a, double b) { return a + (b - a) * uniform(); }
  /// Standard normal (Box-Muller, no caching so the stream is position-independent per call).
  double normal();
  /// Uniform integer in [0, n).
  std::uint64_t below(std::uint64_t n);
  std::uint64_t next() { return engine_(); }

 private:
  std::mt19937_64 engine_;
};

}  // namespace skyloop
