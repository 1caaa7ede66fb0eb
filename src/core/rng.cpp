#include "skyloop/core/rng.hpp"

#include <cmath>
#include <utility>

namespace skyloop {

std::uint64_t mix64(std::uint64_t x) {
  x += 0x9e3779b97f4a7c15ULL;
  x = (x ^ (x >> 30)) * 0xbf58476d1ce4e5b9ULL;
  x = (x ^ (x >> 27)) * 0x94d049bb133111ebULL;
  return x ^ (x >> 31);
}

std::uint64_t derive_seed(std::uint64_t seed, std::uint64_t stream) {
  return mix64(mix64(seed) ^ (stream * 0xd1342543de82ef95ULL + 0x632be59bd9b4e019ULL));
}

std::uint64_t derive_seed(std::uint64_t seed, std::uint64_t a, std::uint64_t b) {
  return derive_seed(derive_seed(seed, a), b);
}

std::uint64_t hash_bytes(const void* data, std::size_t n, std::uint64_t h) {
  const auto* p = static_cast<const unsigned char*>(data);
  for (std::size_t i = 0; i < n; ++i) {
    h ^= p[i];
    h *= 0x100000001b3ULL;
  }
  return mix64(h);
}

double Rng::normal() {
  double u1 = uniform();
  while (u1 <= 0.0) u1 = uniform();
  const double u2 = uniform();
  return std::sqrt(-2.0 * std::log(u1)) * std::cos(2.0 * M_PI * u2);
}

std::uint64_t Rng::below(std::uint64_t n) {
  // Rejection sampling: unbiased and portable.
  const std::uint64_t limit = n == 0 ? 0 : (~std::uint64_t{0} - (~std::uint64_t{0} % n));
  std::uint64_t x = engine_();
  while (x >= limit) x = engine_();
  return x % n;
}

void shuffle(std::vector<std::size_t>& v, Rng& rng) {
  __extension__ typedef unsigned __int128 u128;
  std::uint64_t state = rng.next();
  auto next = [&state] {
    const std::uint64_t x = mix64(state);  // SplitMix64: the finaliser of state + golden ratio
    state += 0x9e3779b97f4a7c15ULL;
    return x;
  };
  for (std::size_t i = v.size(); i > 1; --i) {
    const std::uint64_t n = i;
    u128 m = static_cast<u128>(next()) * n;
    auto low = static_cast<std::uint64_t>(m);
    if (low < n) {
      const std::uint64_t reject = (0 - n) % n;  // 2^64 mod n
      while (low < reject) {
        m = static_cast<u128>(next()) * n;
        low = static_cast<std::uint64_t>(m);
      }
    }
    std::swap(v[i - 1], v[static_cast<std::size_t>(m >> 64)]);
  }
}

}  // namespace skyloop
