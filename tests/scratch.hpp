#pragma once
// Scratch directories for the tests' files: one root per test process, removed when it ends well.
#include <unistd.h>

#include <filesystem>
#include <iostream>
#include <string>
#include <system_error>

#include <gtest/gtest.h>

namespace skyloop::test {

/// This process's scratch root, <TempDir>/skyloop_tests_<pid> (TempDir: $TEST_TMPDIR or /tmp).
/// Every test's files live under it. When the process exits with every test it ran passed, the
/// root is removed; after a failure it stays and its path is printed, so that the failed test's
/// files can be read. A forked child (the input sweep's probes) never removes it.
class ScratchRoot {
 public:
  static ScratchRoot& get() {
    static ScratchRoot root;  // constructed after gtest's UnitTest, so destroyed before it
    return root;
  }
  const std::filesystem::path& path() const { return path_; }
  ScratchRoot(const ScratchRoot&) = delete;
  ScratchRoot& operator=(const ScratchRoot&) = delete;
  ~ScratchRoot() {
    if (::getpid() != owner_) return;
    if (::testing::UnitTest::GetInstance()->Passed()) {
      std::error_code ignored;
      std::filesystem::remove_all(path_, ignored);
    } else {
      std::cerr << "the tests' files stay in " << path_.string() << "\n";
    }
  }

 private:
  ScratchRoot()
      : path_(std::filesystem::path(::testing::TempDir()) / ("skyloop_tests_" + std::to_string(::getpid()))),
        owner_(::getpid()) {
    std::filesystem::create_directories(path_);
  }
  std::filesystem::path path_;
  pid_t owner_;
};

/// An empty directory `name` under the scratch root (whatever was there before is removed).
inline std::filesystem::path scratch_dir(const std::string& name) {
  const auto d = ScratchRoot::get().path() / name;
  std::filesystem::remove_all(d);
  std::filesystem::create_directories(d);
  return d;
}

/// A path `name` under the scratch root where nothing exists yet (for a command that must create
/// its own output directory).
inline std::filesystem::path scratch_path(const std::string& name) {
  const auto d = ScratchRoot::get().path() / name;
  std::filesystem::remove_all(d);
  return d;
}

}  // namespace skyloop::test
