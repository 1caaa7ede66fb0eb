// parallel_for: every index once on any thread count, exceptions, nesting, concurrent callers,
// and a child process after fork (the persistent worker pool, src/core/parallel.cpp).
#include <gtest/gtest.h>

#include <sys/wait.h>
#include <unistd.h>

#include <atomic>
#include <stdexcept>
#include <thread>
#include <vector>

#include "skyloop/core/parallel.hpp"

using namespace skyloop;

TEST(ParallelFor, RunsEveryIndexExactlyOnceOnAnyThreadCount) {
  for (int threads : {1, 2, 3, 8}) {
    for (std::size_t n : {0u, 1u, 2u, 5u, 1000u}) {
      std::vector<std::atomic<int>> hits(n);
      for (int repeat = 0; repeat < 50; ++repeat) parallel_for(n, threads, [&](std::size_t i) { ++hits[i]; });
      for (std::size_t i = 0; i < n; ++i) ASSERT_EQ(hits[i].load(), 50) << "threads " << threads << " n " << n << " i " << i;
    }
  }
}

TEST(ParallelFor, RethrowsTheFirstExceptionAndStaysUsable) {
  EXPECT_THROW(parallel_for(100, 2, [](std::size_t i) {
                 if (i == 7) throw std::runtime_error("index 7");
               }),
               std::runtime_error);
  std::atomic<int> sum{0};
  parallel_for(100, 2, [&](std::size_t i) { sum += static_cast<int>(i); });
  EXPECT_EQ(sum.load(), 4950);
}

TEST(ParallelFor, NestedCallsAndConcurrentCallersComplete) {
  std::atomic<int> count{0};
  parallel_for(4, 2, [&](std::size_t) { parallel_for(10, 2, [&](std::size_t) { ++count; }); });
  EXPECT_EQ(count.load(), 40);
  count = 0;
  std::vector<std::thread> callers;
  for (int c = 0; c < 3; ++c)
    callers.emplace_back([&] {
      for (int r = 0; r < 200; ++r) parallel_for(4, 2, [&](std::size_t) { ++count; });
    });
  for (auto& t : callers) t.join();
  EXPECT_EQ(count.load(), 3 * 200 * 4);
}

// The rate oracle splits its batches over threads only outside a parallel_for (in_parallel_for).
TEST(ParallelFor, InParallelForHoldsOnlyInsideAJobOnSeveralThreads) {
  EXPECT_FALSE(in_parallel_for());
  std::atomic<int> inside{0}, serial_inside{0};
  parallel_for(8, 2, [&](std::size_t) { inside += in_parallel_for(); });
  EXPECT_EQ(inside.load(), 8);
  parallel_for(8, 1, [&](std::size_t) { serial_inside += in_parallel_for(); });  // one thread: no job
  EXPECT_EQ(serial_inside.load(), 0);
  EXPECT_THROW(parallel_for(4, 2, [](std::size_t) { throw std::runtime_error("x"); }), std::runtime_error);
  EXPECT_FALSE(in_parallel_for());  // reset on every way out, exceptions included
}

TEST(ParallelFor, AChildProcessAfterForkRunsItsOwnWorkers) {
  std::atomic<int> warm{0};
  parallel_for(4, 2, [&](std::size_t) { ++warm; });  // the parent's pool exists now
  const pid_t child = fork();
  ASSERT_GE(child, 0);
  if (child == 0) {
    std::atomic<int> count{0};
    parallel_for(16, 2, [&](std::size_t) { ++count; });
    _exit(count.load() == 16 ? 0 : 1);
  }
  int status = 0;
  ASSERT_EQ(waitpid(child, &status, 0), child);
  EXPECT_TRUE(WIFEXITED(status) && WEXITSTATUS(status) == 0);
}
