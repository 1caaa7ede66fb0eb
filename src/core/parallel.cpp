#include "skyloop/core/parallel.hpp"

#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <exception>
#include <mutex>
#include <thread>
#include <vector>

#if defined(__SSE__) || defined(__x86_64__)
#include <pmmintrin.h>
#include <xmmintrin.h>
#endif

namespace skyloop {

void flush_denormals() {
#if defined(__SSE__) || defined(__x86_64__)
  _MM_SET_FLUSH_ZERO_MODE(_MM_FLUSH_ZERO_ON);
  _MM_SET_DENORMALS_ZERO_MODE(_MM_DENORMALS_ZERO_ON);
#elif defined(__aarch64__)
  std::uint64_t fpcr = 0;
  asm volatile("mrs %0, fpcr" : "=r"(fpcr));
  asm volatile("msr fpcr, %0" : : "r"(fpcr | (std::uint64_t{1} << 24)));  // FZ
#endif
}

int resolve_threads(int requested) {
  if (requested > 0) return requested;
  const unsigned hw = std::thread::hardware_concurrency();
  return hw == 0 ? 1 : static_cast<int>(hw);
}

namespace {

thread_local int parallel_depth = 0;  // > 0 inside fn(i) of a parallel_for on several threads

/// Calls fn(i) for i = next++ < n until the indices run out; the first exception stops the rest.
void drain(std::size_t n, std::atomic<std::size_t>& next, const std::function<void(std::size_t)>& fn,
           std::exception_ptr& error, std::mutex& error_mutex) {
  struct Depth {
    Depth() { ++parallel_depth; }
    ~Depth() { --parallel_depth; }
  } inside;
  for (std::size_t i = next++; i < n; i = next++) {
    try {
      fn(i);
    } catch (...) {
      std::lock_guard<std::mutex> lock(error_mutex);
      if (!error) error = std::current_exception();
      next = n;
    }
  }
}

/// Threads started per call: what a nested or concurrent parallel_for uses while the pool is busy.
void run_spawned(std::size_t n, std::size_t workers, const std::function<void(std::size_t)>& fn) {
  std::atomic<std::size_t> next{0};
  std::exception_ptr error;
  std::mutex error_mutex;
  std::vector<std::thread> pool;
  for (std::size_t w = 1; w < workers; ++w) pool.emplace_back([&] { drain(n, next, fn, error, error_mutex); });
  drain(n, next, fn, error, error_mutex);
  for (auto& t : pool) t.join();
  if (error) std::rethrow_exception(error);
}

/// Waits for `done()` without sleeping for a while: spinning on the CPU's pause instruction for
/// the first kSpinPause, then giving the core away (sched_yield, so that another thread or
/// process sharing it runs) between looks until kSpinYield. True when done() came within that
/// time; false (the caller then sleeps on its condition variable) otherwise. The learners'
/// parallel sections follow one another within microseconds, and a thread woken from sleep comes
/// back tens of microseconds later (BENCHMARKS.md, "Waiting without sleeping").
constexpr auto kSpinPause = std::chrono::microseconds(50);
constexpr auto kSpinYield = std::chrono::microseconds(1000);
template <typename Done>
bool spin_until(Done done) {
  using clock = std::chrono::steady_clock;
  const auto start = clock::now();
  for (;;) {
    for (int i = 0; i < 32; ++i) {
      if (done()) return true;
#if defined(__x86_64__) || defined(__i386__)
      __builtin_ia32_pause();
#endif
    }
    const auto waited = clock::now() - start;
    if (waited >= kSpinYield) return done();
    if (waited >= kSpinPause) std::this_thread::yield();
  }
}

/// Worker threads kept for the life of the process, so that the learners' many short parallel
/// sections (two halves of every minibatch) do not pay for starting threads each time: about 3 us
/// per call instead of 30. One job at a time; a call that finds the pool busy (nested inside a
/// job, or from another thread) starts its own threads instead. Helpers wait for the next job,
/// and the caller for its helpers, in spin_until before they sleep.
class Pool {
 public:
  /// The process's pool; a child after fork() gets a new one (the parent's threads are not there).
  static Pool& instance() {
    static std::atomic<Pool*> pool{nullptr};
    static std::mutex make;
    Pool* p = pool.load(std::memory_order_acquire);
    if (p && p->pid_ == getpid()) return *p;
    std::lock_guard<std::mutex> lock(make);
    p = pool.load(std::memory_order_relaxed);
    if (!p || p->pid_ != getpid()) {
      p = new Pool();  // never destroyed: its threads live as long as the process
      pool.store(p, std::memory_order_release);
    }
    return *p;
  }

  /// Runs the job on the caller and workers - 1 helpers; false (nothing run) when busy.
  bool try_run(std::size_t n, std::size_t workers, const std::function<void(std::size_t)>& fn) {
    std::unique_lock<std::mutex> busy(busy_, std::try_to_lock);
    if (!busy.owns_lock()) return false;
    const std::size_t helpers = workers - 1;
    {
      std::lock_guard<std::mutex> lock(m_);
      while (threads_.size() < helpers) {
        const std::size_t index = threads_.size();
        const std::uint64_t seen = generation_.load(std::memory_order_relaxed);  // the job below is new to it
        threads_.emplace_back([this, index, seen] { loop(index, seen); });
        threads_.back().detach();
      }
      fn_ = &fn;
      n_ = n;
      helpers_ = helpers;
      next_ = 0;
      error_ = nullptr;
      running_.store(helpers, std::memory_order_relaxed);
      generation_.fetch_add(1, std::memory_order_release);
    }
    start_.notify_all();
    drain(n, next_, fn, error_, error_mutex_);
    spin_until([this] { return running_.load(std::memory_order_acquire) == 0; });
    {
      std::unique_lock<std::mutex> lock(m_);
      done_.wait(lock, [this] { return running_.load(std::memory_order_acquire) == 0; });
      fn_ = nullptr;
    }
    if (error_) std::rethrow_exception(error_);
    return true;
  }

 private:
  Pool() : pid_(getpid()) {}

  void loop(std::size_t index, std::uint64_t seen) {
    for (;;) {
      spin_until([&] { return generation_.load(std::memory_order_acquire) != seen; });
      std::unique_lock<std::mutex> lock(m_);
      start_.wait(lock, [&] { return generation_.load(std::memory_order_relaxed) != seen; });
      seen = generation_.load(std::memory_order_relaxed);
      if (index >= helpers_) continue;  // this job wants fewer helpers
      const std::function<void(std::size_t)>* fn = fn_;
      const std::size_t n = n_;
      lock.unlock();
      drain(n, next_, *fn, error_, error_mutex_);
      if (running_.fetch_sub(1, std::memory_order_acq_rel) == 1) {
        lock.lock();
        done_.notify_one();
      }
    }
  }

  const pid_t pid_;
  std::mutex busy_;  // held by the caller for the whole job
  std::mutex m_;     // guards the job's fields; the sleeping side of start_ and done_
  std::condition_variable start_, done_;
  std::vector<std::thread> threads_;
  std::atomic<std::uint64_t> generation_{0};
  const std::function<void(std::size_t)>* fn_ = nullptr;
  std::size_t n_ = 0, helpers_ = 0;
  std::atomic<std::size_t> running_{0};  // helpers still in the job
  std::atomic<std::size_t> next_{0};
  std::exception_ptr error_;
  std::mutex error_mutex_;
};

}  // namespace

bool in_parallel_for() { return parallel_depth > 0; }

void parallel_for(std::size_t n, int threads, const std::function<void(std::size_t)>& fn) {
  const std::size_t workers = std::min<std::size_t>(static_cast<std::size_t>(resolve_threads(threads)), n);
  if (workers <= 1) {
    for (std::size_t i = 0; i < n; ++i) fn(i);
    return;
  }
  if (!Pool::instance().try_run(n, workers, fn)) run_spawned(n, workers, fn);
}

}  // namespace skyloop
