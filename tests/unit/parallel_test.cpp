// parallel_for: every index once on any thread count, exceptions, nesting, concurrent callers,
// and a child process after fork (the persistent worker pool, src/core/parallel.cpp); run_process
// and self_path (src/core/process.cpp).
#include <gtest/gtest.h>

#include <sys/wait.h>
#include <unistd.h>

#include <atomic>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

#include "skyloop/core/parallel.hpp"
#include "skyloop/core/process.hpp"
#include "../scratch.hpp"

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

// run_process: a program that cannot start says so in its log (exit status 127), and a child of
// a program whose file was replaced while it ran (a rebuild under a long `bench baselines`) runs
// the very program its parent is (self_path()), not an empty log from an exec that failed.
namespace {
std::string read_all(const std::filesystem::path& p) {
  std::ifstream in(p);
  return std::string(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
}
}  // namespace

TEST(Process, AProgramThatCannotStartSaysSoInItsLog) {
  const auto log = test::scratch_path("no_such_program.log");
  EXPECT_EQ(run_process({"/nonexistent/skyloop-no-such-program", "x"}, log.string()), 127);
  EXPECT_EQ(read_all(log), "skyloop: cannot start /nonexistent/skyloop-no-such-program (exec failed, errno 2)\n");
}

TEST(Process, ChildrenRunTheParentsProgramAfterItsFileIsReplaced) {
  if (std::getenv("SKYLOOP_TEST_SELF_PATH_COPY")) {  // in the copy: delete it, then start a child of itself
    std::filesystem::remove(std::filesystem::read_symlink("/proc/self/exe").string());
    EXPECT_EQ(self_path(), "/proc/self/exe");
    const int rc = run_process({self_path(), "--gtest_list_tests", "--gtest_filter=Process.*"}, std::getenv("SKYLOOP_TEST_SELF_PATH_COPY"));
    EXPECT_EQ(rc, 0);
    return;
  }
  EXPECT_EQ(self_path(), std::filesystem::canonical("/proc/self/exe").string());
  const auto dir = test::scratch_dir("self_path");
  const auto copy = dir / "copy", grandchild = dir / "grandchild.log", child = dir / "child.log";
  std::filesystem::copy_file("/proc/self/exe", copy);
  ::setenv("SKYLOOP_TEST_SELF_PATH_COPY", grandchild.c_str(), 1);
  const int rc = run_process({copy.string(), "--gtest_filter=Process.ChildrenRunTheParentsProgramAfterItsFileIsReplaced"}, child.string());
  ::unsetenv("SKYLOOP_TEST_SELF_PATH_COPY");
  EXPECT_EQ(rc, 0) << read_all(child);
  EXPECT_FALSE(std::filesystem::exists(copy));
  EXPECT_NE(read_all(grandchild).find("ChildrenRunTheParentsProgramAfterItsFileIsReplaced"), std::string::npos) << read_all(grandchild);
}
