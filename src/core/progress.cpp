#include "skyloop/core/progress.hpp"

#include <cstdio>
#include <ostream>

namespace skyloop {

Progress::Progress(std::string label, std::size_t total, std::ostream& out, double interval_s, double delay_s)
    : label_(std::move(label)), total_(total), out_(out), interval_s_(interval_s), delay_s_(delay_s),
      start_(std::chrono::steady_clock::now()), last_(start_) {}

void Progress::advance(std::size_t n) {
  std::lock_guard<std::mutex> lock(mutex_);
  done_ += n;
  const auto now = std::chrono::steady_clock::now();
  const double since_start = std::chrono::duration<double>(now - start_).count();
  const double since_last = std::chrono::duration<double>(now - last_).count();
  if (since_start >= delay_s_ && (!shown_ || since_last >= interval_s_)) {
    last_ = now;
    print_locked(false);
  }
}

void Progress::finish() {
  std::lock_guard<std::mutex> lock(mutex_);
  if (shown_) print_locked(true);
}

void Progress::print_locked(bool final_line) {
  shown_ = true;
  const double elapsed = std::chrono::duration<double>(std::chrono::steady_clock::now() - start_).count();
  const double rate = elapsed > 0 ? static_cast<double>(done_) / elapsed : 0.0;
  const double eta = rate > 0 ? static_cast<double>(total_ - std::min(done_, total_)) / rate : 0.0;
  char buf[256];
  if (final_line) {
    std::snprintf(buf, sizeof buf, "%s  %zu/%zu done in %.1fs (%.2f it/s)", label_.c_str(), done_, total_, elapsed, rate);
  } else {
    std::snprintf(buf, sizeof buf, "%s  %zu/%zu (%.0f%%)  %.2f it/s  ETA %.0fs", label_.c_str(), done_, total_,
                  total_ ? 100.0 * static_cast<double>(done_) / static_cast<double>(total_) : 100.0, rate, eta);
  }
  out_ << buf << std::endl;
}

}  // namespace skyloop
