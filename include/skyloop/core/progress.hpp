#pragma once
#include <chrono>
#include <cstddef>
#include <iosfwd>
#include <mutex>
#include <string>

namespace skyloop {

/// Periodic progress line for long work: "label  120/200 (60%)  4.2 it/s  ETA 19s".
/// Thread-safe. Prints at most once per `interval_s` and only once the work has run for
/// `delay_s`, so short runs stay quiet; finish() prints the final line if anything was shown.
class Progress {
 public:
  Progress(std::string label, std::size_t total, std::ostream& out, double interval_s = 2.0,
           double delay_s = 1.0);
  void advance(std::size_t n = 1);
  void finish();

 private:
  void print_locked(bool final_line);
  std::string label_;
  std::size_t total_;
  std::size_t done_ = 0;
  std::ostream& out_;
  double interval_s_, delay_s_;
  bool shown_ = false;
  std::chrono::steady_clock::time_point start_, last_;
  std::mutex mutex_;
};

}  // namespace skyloop
