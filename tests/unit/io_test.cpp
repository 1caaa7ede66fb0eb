// Atomic writes: single files, pairs that change together, refusal of special files, and the
// clean-up of what killed processes leave behind.
#include <gtest/gtest.h>

#include <atomic>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <sys/stat.h>
#include <thread>
#include <vector>
#include <unistd.h>

#include "skyloop/core/error.hpp"
#include "skyloop/core/io.hpp"
#include "../scratch.hpp"

using namespace skyloop;
namespace fs = std::filesystem;

namespace {
fs::path fresh(const std::string& name) { return skyloop::test::scratch_dir(name); }
std::string slurp(const fs::path& p) {
  std::ifstream in(p);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}
std::size_t entries(const fs::path& d) {
  return static_cast<std::size_t>(std::distance(fs::directory_iterator(d), fs::directory_iterator()));
}
}  // namespace

TEST(Io, PairWritesBothOrNeither) {
  const auto d = fresh("pair");
  write_files_atomic({{(d / "a.csv").string(), "a1"}, {(d / "a.toml").string(), "t1"}});
  EXPECT_EQ(slurp(d / "a.csv"), "a1");
  EXPECT_EQ(slurp(d / "a.toml"), "t1");
  // The second file's directory cannot be created (a file holds its name): nothing changes and no
  // temporary is left (the same path as a full disk: the temporaries fail before any rename).
  std::ofstream(d / "blocker") << "x";
  EXPECT_THROW(write_files_atomic({{(d / "a.csv").string(), "a2"}, {(d / "blocker" / "a.toml").string(), "t2"}}),
               std::runtime_error);
  EXPECT_EQ(slurp(d / "a.csv"), "a1");
  EXPECT_EQ(entries(d), 3u);  // a.csv, a.toml, blocker
  write_files_atomic({{(d / "a.csv").string(), "a3"}, {(d / "a.toml").string(), "t3"}});
  EXPECT_EQ(slurp(d / "a.csv") + slurp(d / "a.toml"), "a3t3");
  EXPECT_EQ(entries(d), 3u);
}

TEST(Io, ThreadsWritingOneFileAtOnceAllSucceed) {
  // reproduce evaluates on several threads, and two evaluations may cache the same optimum: each
  // write must land whole, and no temporary may be left.
  const auto d = fresh("threads");
  const std::string target = (d / "optimum.csv").string();
  std::vector<std::thread> pool;
  std::atomic<int> failures{0};
  for (int t = 0; t < 8; ++t)
    pool.emplace_back([&, t] {
      for (int i = 0; i < 25; ++i) {
        try {
          write_file_atomic(target, "writer " + std::to_string(t) + "\n");
        } catch (const std::exception&) {
          ++failures;
        }
      }
    });
  for (auto& th : pool) th.join();
  EXPECT_EQ(failures.load(), 0);
  const std::string got = slurp(target);
  EXPECT_EQ(got.rfind("writer ", 0), 0u) << got;
  EXPECT_EQ(entries(d), 1u);
}

TEST(Io, SpecialFilesAreRefusedAndSymlinksWrittenThrough) {
  const auto d = fresh("special");
  fs::create_directories(d / "dir");
  EXPECT_THROW(write_file_atomic((d / "dir").string(), "x"), InputError);
  ASSERT_EQ(::mkfifo((d / "fifo").c_str(), 0644), 0);
  EXPECT_THROW(write_file_atomic((d / "fifo").string(), "x"), InputError);
  EXPECT_TRUE(fs::is_fifo(d / "fifo"));
  EXPECT_THROW(write_file_atomic("/dev/null", "x"), InputError);
  std::ofstream(d / "target") << "old";
  fs::create_symlink(d / "target", d / "link");
  write_file_atomic((d / "link").string(), "new");
  EXPECT_TRUE(fs::is_symlink(d / "link"));
  EXPECT_EQ(slurp(d / "target"), "new");
  EXPECT_THROW(read_file((d / "dir").string()), InputError);
}

TEST(Io, StaleTemporariesOfDeadProcessesAreRemoved) {
  const auto d = fresh("stale");
  fs::create_directories(d / "sub");
  // PID 2147483646 is above any Linux pid_max (at most 2^22): never alive. Our own PID is.
  const std::string dead = ".tmp.2147483646", live = ".tmp." + std::to_string(::getpid());
  std::ofstream(d / ("model.pt" + dead)) << "debris";
  std::ofstream(d / ("model.pt" + live)) << "being written";
  std::ofstream(d / "sub" / ("x.csv" + dead)) << "debris";
  std::ofstream(d / "metrics.csv.bak.2147483646") << "earlier";  // interrupted pair write, target gone
  std::ofstream(d / ("summary.csv" + dead + "-7")) << "debris";  // a writer's "<pid>-<serial>" tag
  std::ofstream(d / ("summary.csv" + live + "-7")) << "being written";
  remove_stale_temporaries(d.string());
  EXPECT_FALSE(fs::exists(d / ("summary.csv" + dead + "-7")));
  EXPECT_TRUE(fs::exists(d / ("summary.csv" + live + "-7")));
  EXPECT_FALSE(fs::exists(d / ("model.pt" + dead)));
  EXPECT_TRUE(fs::exists(d / ("model.pt" + live)));
  EXPECT_TRUE(fs::exists(d / "sub" / ("x.csv" + dead)));  // not recursive
  EXPECT_EQ(slurp(d / "metrics.csv"), "earlier");          // restored
  remove_stale_temporaries(d.string(), true);
  EXPECT_FALSE(fs::exists(d / "sub" / ("x.csv" + dead)));
}
