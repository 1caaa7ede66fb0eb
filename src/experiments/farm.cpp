// The task farm's scheduling (see farm.hpp). Messages, rank 0 <-> worker:
//   worker -> 0, kResult: "-\n" (ready for a piece) or "<task>\n<ok 0|1>\n<seconds>\n<payload or error>"
//   0 -> worker, kTask:   "<task>\n<id>"        0 -> worker, kStop: ""
// A worker always reports ready once before its first piece and once after each, so when rank 0
// has seen every worker ready with nothing left to do, no message is in flight and kStop ends the
// round cleanly (the next farm_run starts from empty queues).
#include "skyloop/experiments/farm.hpp"

#include <algorithm>
#include <chrono>
#include <condition_variable>
#include <cstdlib>
#include <fmt/format.h>
#include <mutex>
#include <ostream>
#include <queue>
#include <sched.h>
#include <stdexcept>
#include <thread>

#include "skyloop/core/error.hpp"

namespace skyloop {

namespace {
using Clock = std::chrono::steady_clock;
constexpr int kResult = 1, kTask = 2, kStop = 3;
// Polling. MPI's blocking receive spins on its core, and rank 0's scheduler shares a core with
// rank 0's own worker, so an idle rank sleeps between polls: from kPollMin, doubling while nothing
// happens, up to kPollMax (each poll runs MPI's progress engine, which costs the worker on the
// same core far more than the poll's own time: at a fixed 0.5 ms rank 0's pieces ran 18% slower).
// The farm's latency per piece stays below 2 kPollMax.
constexpr auto kPollMin = std::chrono::microseconds(200);
constexpr auto kPollMax = std::chrono::milliseconds(10);

class Backoff {
 public:
  void reset() { wait_ = kPollMin; }
  void sleep() {
    std::this_thread::sleep_for(wait_);
    wait_ = std::min<std::chrono::microseconds>(wait_ * 2, kPollMax);
  }

 private:
  std::chrono::microseconds wait_ = kPollMin;
};

double seconds_since(Clock::time_point t0) { return std::chrono::duration<double>(Clock::now() - t0).count(); }

struct Outcome {
  bool ok = false;
  double seconds = 0;
  std::string payload;  // the result, or the error message
};

Outcome run_one(const std::function<std::string(std::size_t)>& work, std::size_t i) {
  Outcome o;
  const auto t0 = Clock::now();
  try {
    o.payload = work(i);
    o.ok = true;
  } catch (const std::exception& e) {
    o.payload = e.what();
  } catch (...) {
    o.payload = "unknown exception";
  }
  o.seconds = seconds_since(t0);
  return o;
}

/// Ready tasks, longest estimate first, then lowest index.
struct Ready {
  const std::vector<FarmTask>* tasks;
  bool operator()(std::size_t a, std::size_t b) const {
    const auto& x = (*tasks)[a];
    const auto& y = (*tasks)[b];
    if (x.cost != y.cost) return x.cost < y.cost;
    return a > b;
  }
};

/// Dependency bookkeeping shared by the sequential order, the shards and the farm.
class Graph {
 public:
  explicit Graph(const std::vector<FarmTask>& tasks) : tasks_(tasks), missing_(tasks.size(), 0), after_(tasks.size()),
                                                         ready_(Ready{&tasks}) {
    for (std::size_t i = 0; i < tasks.size(); ++i)
      for (std::size_t d : tasks[i].deps) {
        if (d >= tasks.size() || d == i) throw std::logic_error(fmt::format("farm: task {} depends on {}", i, d));
        ++missing_[i];
        after_[d].push_back(i);
      }
    for (std::size_t i = 0; i < tasks.size(); ++i)
      if (missing_[i] == 0) ready_.push(i);
  }
  bool has_ready() const { return !ready_.empty(); }
  std::size_t pop() {
    const std::size_t i = ready_.top();
    ready_.pop();
    return i;
  }
  /// Task i finished: its dependents may become ready.
  void done(std::size_t i) {
    for (std::size_t j : after_[i])
      if (--missing_[j] == 0) ready_.push(j);
  }
  /// Task i failed: every task that needs it, directly or not.
  std::vector<std::size_t> blocked_by(std::size_t i) const {
    std::vector<std::size_t> out, stack = after_[i];
    std::vector<bool> seen(tasks_.size(), false);
    while (!stack.empty()) {
      const std::size_t j = stack.back();
      stack.pop_back();
      if (seen[j]) continue;
      seen[j] = true;
      out.push_back(j);
      stack.insert(stack.end(), after_[j].begin(), after_[j].end());
    }
    return out;
  }

 private:
  const std::vector<FarmTask>& tasks_;
  std::vector<std::size_t> missing_;
  std::vector<std::vector<std::size_t>> after_;
  std::priority_queue<std::size_t, std::vector<std::size_t>, Ready> ready_;
};

void worker_loop(Transport& t, const std::vector<FarmTask>& tasks, const std::function<std::string(std::size_t)>& work) {
  t.send(0, kResult, "-\n");
  for (;;) {
    int from = 0, tag = 0;
    std::string data;
    Backoff wait;
    while (!t.try_receive(from, tag, data)) wait.sleep();
    if (tag == kStop) return;
    if (tag != kTask) throw std::runtime_error(fmt::format("farm: rank {} got message tag {} from rank {}", t.rank(), tag, from));
    const auto nl = data.find('\n');
    const std::size_t i = std::stoul(data.substr(0, nl));
    const std::string id = data.substr(nl + 1);
    if (i >= tasks.size() || tasks[i].id != id)
      throw std::runtime_error(fmt::format("farm: rank {} plans other pieces than rank 0 (piece {} is '{}' there, '{}' here); "
                                           "every rank must see the same files and options",
                                           t.rank(), i, id, i < tasks.size() ? tasks[i].id : "none"));
    const Outcome o = run_one(work, i);
    t.send(0, kResult, fmt::format("{}\n{}\n{}\n{}", i, o.ok ? 1 : 0, o.seconds, o.payload));
  }
}

/// Rank 0's own worker: one thread computing the pieces rank 0 gives itself.
class LocalWorker {
 public:
  explicit LocalWorker(const std::function<std::string(std::size_t)>& work) : work_(work), thread_([this] { loop(); }) {}
  ~LocalWorker() {
    {
      std::lock_guard<std::mutex> lock(mu_);
      stop_ = true;
    }
    cv_.notify_all();
    thread_.join();
  }
  void give(std::size_t i) {
    {
      std::lock_guard<std::mutex> lock(mu_);
      job_ = i;
      has_job_ = true;
    }
    cv_.notify_all();
  }
  /// The finished piece, if any.
  bool take(std::size_t& i, Outcome& o) {
    std::lock_guard<std::mutex> lock(mu_);
    if (!has_result_) return false;
    i = job_, o = std::move(result_);
    has_result_ = false;
    return true;
  }

 private:
  const std::function<std::string(std::size_t)>& work_;
  std::mutex mu_;
  std::condition_variable cv_;
  std::size_t job_ = 0;
  bool has_job_ = false, has_result_ = false, stop_ = false;
  Outcome result_;
  std::thread thread_;

  void loop() {
    for (;;) {
      std::size_t i;
      {
        std::unique_lock<std::mutex> lock(mu_);
        cv_.wait(lock, [&] { return stop_ || has_job_; });
        if (stop_) return;
        i = job_;
        has_job_ = false;
      }
      Outcome o = run_one(work_, i);
      std::lock_guard<std::mutex> lock(mu_);
      result_ = std::move(o);
      has_result_ = true;
    }
  }
};

}  // namespace

int threads_per_rank(int requested, const Transport* transport) {
  if (requested > 0) return requested;
  int cores = 0;
  cpu_set_t set;
  if (sched_getaffinity(0, sizeof set, &set) == 0) cores = CPU_COUNT(&set);
  const int machine = std::max(1, static_cast<int>(std::thread::hardware_concurrency()));
  if (cores <= 0) cores = machine;
  const int ranks = transport ? transport->size() : 1;
  if (ranks > 1 && cores >= machine) {
    const char* local = std::getenv("OMPI_COMM_WORLD_LOCAL_SIZE");
    cores = std::max(1, cores / (local ? std::max(1, std::atoi(local)) : ranks));
  }
  return cores;
}

bool launched_by_mpi() {
  for (const char* v : {"OMPI_COMM_WORLD_SIZE", "PMI_SIZE", "PMIX_RANK"})
    if (std::getenv(v)) return true;
  return false;
}

std::vector<std::size_t> priority_order(const std::vector<FarmTask>& tasks) {
  Graph g(tasks);
  std::vector<std::size_t> order;
  while (g.has_ready()) {
    const std::size_t i = g.pop();
    order.push_back(i);
    g.done(i);
  }
  if (order.size() != tasks.size()) throw std::logic_error("farm: the pieces' dependencies form a cycle");
  return order;
}

std::vector<std::size_t> shard_slice(const std::vector<FarmTask>& tasks, int i, int n) {
  if (n < 1 || i < 1 || i > n) throw InputError(fmt::format("--shard {}/{} is invalid: allowed i/n with 1 <= i <= n", i, n));
  std::vector<std::size_t> free, bound;
  for (std::size_t t = 0; t < tasks.size(); ++t) (tasks[t].deps.empty() ? free : bound).push_back(t);
  std::stable_sort(free.begin(), free.end(), [&](std::size_t a, std::size_t b) { return tasks[a].cost > tasks[b].cost; });
  std::vector<int> bin(tasks.size(), 0);
  std::vector<double> load(static_cast<std::size_t>(n), 0.0);
  for (std::size_t t : free) {
    const auto b = static_cast<std::size_t>(std::min_element(load.begin(), load.end()) - load.begin());
    bin[t] = static_cast<int>(b);
    load[b] += tasks[t].cost;
  }
  // A task with dependencies goes where its first one went (its input is written there first).
  for (std::size_t t : priority_order(tasks))
    if (!tasks[t].deps.empty()) {
      bin[t] = bin[tasks[t].deps.front()];
      load[static_cast<std::size_t>(bin[t])] += tasks[t].cost;
    }
  std::vector<std::size_t> out;
  for (std::size_t t : priority_order(tasks))
    if (bin[t] == i - 1) out.push_back(t);
  return out;
}

std::vector<FarmRecord> farm_run(Transport* transport, const std::vector<FarmTask>& tasks,
                                 const std::function<std::string(std::size_t)>& work,
                                 const std::function<void(std::size_t, const std::string&)>& collect, std::ostream* log) {
  const int size = transport ? transport->size() : 1;
  if (transport && transport->rank() != 0) {
    worker_loop(*transport, tasks, work);
    return {};
  }
  const auto t0 = Clock::now();
  const std::size_t n = tasks.size();
  std::vector<FarmRecord> rec(n);
  for (std::size_t i = 0; i < n; ++i) rec[i].task = i;
  Graph g(tasks);
  std::size_t finished = 0;
  auto note = [&](const std::string& line) {
    if (log) *log << line << std::flush;
  };
  auto finish = [&](std::size_t i, int rank, Outcome&& o) {
    rec[i].received = seconds_since(t0);
    rec[i].seconds = o.seconds;
    rec[i].ok = o.ok;
    ++finished;
    if (o.ok) {
      collect(i, o.payload);
      g.done(i);
      note(fmt::format("  piece {}/{} done: {} {} on rank {} ({:.1f} s)\n", finished, n, tasks[i].kind, tasks[i].label, rank,
                       o.seconds));
      return;
    }
    rec[i].error = o.payload;
    note(fmt::format("  piece {}/{} FAILED: {} {} on rank {}: {}\n", finished, n, tasks[i].kind, tasks[i].label, rank, o.payload));
    for (std::size_t j : g.blocked_by(i)) {
      if (!rec[j].error.empty()) continue;
      rec[j].error = "not run: needs " + tasks[i].id + ", which failed";
      ++finished;
    }
  };

  if (size == 1) {
    while (g.has_ready()) {
      const std::size_t i = g.pop();
      rec[i].rank = 0;
      rec[i].assigned = seconds_since(t0);
      finish(i, 0, run_one(work, i));
    }
    return rec;
  }

  Transport& t = *transport;
  std::vector<int> idle;            // ranks waiting for a piece (0 = this rank's worker thread)
  std::size_t busy_remote = 0;
  bool local_busy = false;
  int remote_seen = 0;               // workers that have reported ready at least once
  std::vector<bool> started(static_cast<std::size_t>(size), false);
  LocalWorker local(work);
  idle.push_back(0);
  Backoff wait;
  for (;;) {
    while (!idle.empty() && g.has_ready()) {
      const int r = idle.back();
      idle.pop_back();
      const std::size_t i = g.pop();
      rec[i].rank = r;
      rec[i].assigned = seconds_since(t0);
      if (r == 0) {
        local.give(i);
        local_busy = true;
      } else {
        t.send(r, kTask, fmt::format("{}\n{}", i, tasks[i].id));
        ++busy_remote;
      }
    }
    if (finished == n && !local_busy && busy_remote == 0 && remote_seen == size - 1) break;
    bool progress = false;
    std::size_t i;
    Outcome o;
    if (local.take(i, o)) {
      local_busy = false;
      idle.push_back(0);
      finish(i, 0, std::move(o));
      progress = true;
    }
    int from = 0, tag = 0;
    std::string data;
    while (t.try_receive(from, tag, data)) {
      progress = true;
      if (tag != kResult) throw std::runtime_error(fmt::format("farm: rank 0 got message tag {} from rank {}", tag, from));
      if (!started[static_cast<std::size_t>(from)]) started[static_cast<std::size_t>(from)] = true, ++remote_seen;
      idle.push_back(from);
      if (data.rfind("-\n", 0) == 0) continue;
      std::size_t p1 = data.find('\n'), p2 = data.find('\n', p1 + 1), p3 = data.find('\n', p2 + 1);
      const std::size_t task = std::stoul(data.substr(0, p1));
      Outcome r;
      r.ok = data.substr(p1 + 1, p2 - p1 - 1) == "1";
      r.seconds = std::stod(data.substr(p2 + 1, p3 - p2 - 1));
      r.payload = data.substr(p3 + 1);
      --busy_remote;
      finish(task, from, std::move(r));
    }
    if (progress) wait.reset();
    else wait.sleep();
  }
  for (int r = 1; r < size; ++r) t.send(r, kStop, "");
  return rec;
}

}  // namespace skyloop
