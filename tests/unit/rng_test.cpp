#include <gtest/gtest.h>

#include <algorithm>
#include <numeric>
#include <set>

#include "skyloop/core/rng.hpp"

using namespace skyloop;

TEST(Rng, SameSeedSameStream) {
  Rng a(42), b(42);
  for (int i = 0; i < 100; ++i) EXPECT_EQ(a.next(), b.next());
}

TEST(Rng, DifferentSeedsDiffer) {
  Rng a(1), b(2);
  int equal = 0;
  for (int i = 0; i < 100; ++i) equal += a.next() == b.next();
  EXPECT_EQ(equal, 0);
}

TEST(Rng, UniformInRangeWithRightMean) {
  Rng r(7);
  double sum = 0;
  const int n = 100000;
  for (int i = 0; i < n; ++i) {
    const double u = r.uniform(-2.0, 3.0);
    ASSERT_GE(u, -2.0);
    ASSERT_LT(u, 3.0);
    sum += u;
  }
  EXPECT_NEAR(sum / n, 0.5, 0.02);
}

TEST(Rng, NormalMoments) {
  Rng r(9);
  double s = 0, s2 = 0;
  const int n = 200000;
  for (int i = 0; i < n; ++i) {
    const double x = r.normal();
    s += x;
    s2 += x * x;
  }
  EXPECT_NEAR(s / n, 0.0, 0.01);
  EXPECT_NEAR(s2 / n, 1.0, 0.02);
}

TEST(Rng, DerivedStreamsAreDistinctAndStable) {
  std::set<std::uint64_t> seen;
  for (std::uint64_t i = 0; i < 1000; ++i) seen.insert(derive_seed(5, i));
  EXPECT_EQ(seen.size(), 1000u);
  EXPECT_EQ(derive_seed(5, 17), derive_seed(5, 17));
  EXPECT_NE(derive_seed(5, 17), derive_seed(6, 17));
}

TEST(Rng, BelowIsInRange) {
  Rng r(3);
  std::vector<int> counts(7, 0);
  for (int i = 0; i < 70000; ++i) counts[r.below(7)]++;
  for (int c : counts) EXPECT_NEAR(c, 10000, 500);
}

// shuffle: a permutation, the same for the same seed, and every ordering of 4 items equally
// likely (24 orderings x 24,000 shuffles: each count within 5 standard deviations, sqrt(1000 x
// 23/24) = 31, of 1,000), and the last item lands in every position of a long vector.
TEST(Rng, ShuffleIsAUniformPermutation) {
  Rng r(13);
  std::vector<int> counts(24, 0);
  for (int i = 0; i < 24000; ++i) {
    std::vector<std::size_t> v{0, 1, 2, 3};
    shuffle(v, r);
    std::vector<std::size_t> sorted = v;
    std::sort(sorted.begin(), sorted.end());
    ASSERT_EQ(sorted, (std::vector<std::size_t>{0, 1, 2, 3}));
    // Lehmer code of the ordering: 0 .. 23.
    int code = 0;
    for (std::size_t a = 0; a < 4; ++a) {
      int smaller = 0;
      for (std::size_t b = a + 1; b < 4; ++b) smaller += v[b] < v[a];
      code = code * static_cast<int>(4 - a) + smaller;
    }
    counts[static_cast<std::size_t>(code)]++;
  }
  for (int c : counts) EXPECT_NEAR(c, 1000, 5 * 31);
  std::vector<std::size_t> a(1000), b(1000);
  std::iota(a.begin(), a.end(), std::size_t{0});
  b = a;
  Rng x(5), y(5);
  shuffle(a, x);
  shuffle(b, y);
  EXPECT_EQ(a, b);
  std::vector<int> where(10, 0);
  for (int i = 0; i < 10000; ++i) {
    std::vector<std::size_t> v(10);
    std::iota(v.begin(), v.end(), std::size_t{0});
    shuffle(v, r);
    where[static_cast<std::size_t>(std::find(v.begin(), v.end(), std::size_t{9}) - v.begin())]++;
  }
  for (int c : where) EXPECT_NEAR(c, 1000, 5 * 30);
}
