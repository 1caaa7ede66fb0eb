// The task farm's scheduling over an in-memory transport (ranks = threads): every piece runs
// exactly once, never before its dependencies, a failure stops only what needs it, payloads reach
// rank 0; shards cover every piece once, deterministically.
#include <gtest/gtest.h>

#include <atomic>
#include <condition_variable>
#include <deque>
#include <map>
#include <mutex>
#include <set>
#include <stdexcept>
#include <thread>

#include "skyloop/core/csv.hpp"
#include "skyloop/experiments/farm.hpp"

namespace skyloop {
namespace {

/// Mailboxes shared by the ranks of one in-process "job".
struct Post {
  struct Msg {
    int from, tag;
    std::string data;
  };
  explicit Post(int n) : boxes(static_cast<std::size_t>(n)) {}
  std::mutex mu;
  std::vector<std::deque<Msg>> boxes;
};

class MemoryTransport final : public Transport {
 public:
  MemoryTransport(Post& post, int rank) : post_(post), rank_(rank) {}
  int rank() const override { return rank_; }
  int size() const override { return static_cast<int>(post_.boxes.size()); }
  void send(int to, int tag, const std::string& data) override {
    std::lock_guard<std::mutex> lock(post_.mu);
    post_.boxes[static_cast<std::size_t>(to)].push_back({rank_, tag, data});
  }
  bool try_receive(int& from, int& tag, std::string& data) override {
    std::lock_guard<std::mutex> lock(post_.mu);
    auto& box = post_.boxes[static_cast<std::size_t>(rank_)];
    if (box.empty()) return false;
    from = box.front().from, tag = box.front().tag, data = box.front().data;
    box.pop_front();
    return true;
  }
  void barrier() override {}
  [[noreturn]] void abort(int) override { throw std::logic_error("abort"); }

 private:
  Post& post_;
  int rank_;
};

std::vector<FarmTask> chain_and_fan(std::size_t n) {
  // Task i > 0 depends on i / 2 (a binary tree), costs vary.
  std::vector<FarmTask> t(n);
  for (std::size_t i = 0; i < n; ++i) {
    t[i].id = "piece-" + std::to_string(i);
    t[i].kind = "test";
    t[i].cost = static_cast<double>((i * 7919) % 13);
    if (i > 0) t[i].deps = {i / 2};
  }
  return t;
}

/// Runs farm_run on `ranks` threads; returns rank 0's records and what collect() saw.
std::vector<FarmRecord> run_job(int ranks, const std::vector<FarmTask>& tasks, const std::function<std::string(int, std::size_t)>& work,
                                std::map<std::size_t, std::string>& collected) {
  Post post(ranks);
  std::vector<FarmRecord> rec;
  std::vector<std::thread> threads;
  std::mutex mu;
  for (int r = 0; r < ranks; ++r)
    threads.emplace_back([&, r] {
      MemoryTransport t(post, r);
      auto out = farm_run(&t, tasks, [&](std::size_t i) { return work(r, i); },
                          [&](std::size_t i, const std::string& p) {
                            std::lock_guard<std::mutex> lock(mu);
                            collected[i] = p;
                          },
                          nullptr);
      if (r == 0) rec = std::move(out);
    });
  for (auto& t : threads) t.join();
  for (const auto& box : post.boxes) EXPECT_TRUE(box.empty()) << "a message was left in flight";
  return rec;
}

TEST(Farm, EveryPieceRunsOnceAfterItsDependencies) {
  const auto tasks = chain_and_fan(40);
  for (int ranks : {1, 2, 3, 5}) {
    std::vector<std::atomic<int>> runs(tasks.size());
    std::vector<std::atomic<bool>> finished(tasks.size());
    std::atomic<int> order_violations{0};
    std::set<int> ranks_used;
    std::mutex mu;
    std::map<std::size_t, std::string> collected;
    const auto rec = run_job(ranks, tasks,
                             [&](int rank, std::size_t i) {
                               for (auto d : tasks[i].deps)
                                 if (!finished[d]) ++order_violations;
                               ++runs[i];
                               // Milliseconds of work: long beside a thread's wake-up even on a loaded machine,
                               // so that every rank asks for work before the job ends.
                               std::this_thread::sleep_for(std::chrono::microseconds(1000 * (1 + i % 3)));
                               finished[i] = true;
                               std::lock_guard<std::mutex> lock(mu);
                               ranks_used.insert(rank);
                               return "payload of " + std::to_string(i);
                             },
                             collected);
    ASSERT_EQ(rec.size(), tasks.size()) << ranks;
    for (std::size_t i = 0; i < tasks.size(); ++i) {
      EXPECT_EQ(runs[i], 1) << "piece " << i << " on " << ranks << " ranks";
      EXPECT_TRUE(rec[i].ok);
      EXPECT_GE(rec[i].rank, 0);
      EXPECT_LT(rec[i].rank, ranks);
      EXPECT_GE(rec[i].received, rec[i].assigned);
      EXPECT_EQ(collected.at(i), "payload of " + std::to_string(i));
    }
    EXPECT_EQ(order_violations, 0) << ranks;
    EXPECT_EQ(static_cast<int>(ranks_used.size()), ranks) << "every rank computes (rank 0 too)";
  }
}

TEST(Farm, AFailedPieceStopsOnlyWhatNeedsIt) {
  const auto tasks = chain_and_fan(31);  // 3 fails: 6, 7, 12..15, 24..31 need it
  std::map<std::size_t, std::string> collected;
  std::vector<std::atomic<int>> runs(tasks.size());
  const auto rec = run_job(3, tasks,
                           [&](int, std::size_t i) -> std::string {
                             ++runs[i];
                             if (i == 3) throw std::runtime_error("piece 3 broke");
                             return {};
                           },
                           collected);
  const std::set<std::size_t> blocked = {6, 7, 12, 13, 14, 15, 24, 25, 26, 27, 28, 29, 30};
  for (std::size_t i = 0; i < tasks.size(); ++i) {
    if (i == 3) {
      EXPECT_FALSE(rec[i].ok);
      EXPECT_EQ(rec[i].error, "piece 3 broke");
    } else if (blocked.count(i)) {
      EXPECT_FALSE(rec[i].ok) << i;
      EXPECT_EQ(rec[i].rank, -1) << i;
      EXPECT_EQ(runs[i], 0) << i;
      EXPECT_NE(rec[i].error.find("piece-3"), std::string::npos) << rec[i].error;
    } else {
      EXPECT_TRUE(rec[i].ok) << i;
      EXPECT_EQ(runs[i], 1) << i;
    }
  }
}

TEST(Farm, ShardsCoverEveryPieceOnceAndKeepDependenciesTogether) {
  std::vector<FarmTask> independent(50);
  for (std::size_t i = 0; i < independent.size(); ++i) independent[i] = {"p" + std::to_string(i), "t", "", double(i % 7 + 1), {}};
  for (const auto& set : {chain_and_fan(40), independent})
    for (int n : {1, 2, 3, 8}) {
      std::vector<int> seen(set.size(), 0);
      std::vector<double> load;
      for (int i = 1; i <= n; ++i) {
        const auto slice = shard_slice(set, i, n);
        EXPECT_EQ(slice, shard_slice(set, i, n)) << "deterministic";
        double l = 0;
        std::set<std::size_t> mine(slice.begin(), slice.end());
        for (std::size_t pos = 0; pos < slice.size(); ++pos) {
          ++seen[slice[pos]];
          l += set[slice[pos]].cost;
          for (auto d : set[slice[pos]].deps) {
            EXPECT_TRUE(mine.count(d)) << "a piece's first dependency is in its shard";
            EXPECT_LT(std::find(slice.begin(), slice.end(), d) - slice.begin(), static_cast<long>(pos)) << "dependencies first";
          }
        }
        load.push_back(l);
      }
      for (std::size_t t = 0; t < set.size(); ++t) EXPECT_EQ(seen[t], 1) << "piece " << t << ", " << n << " shards";
      if (set[1].deps.empty()) {
        // Longest first over independent pieces: no shard above the mean by more than the longest piece.
        double total = 0;
        for (double l : load) total += l;
        for (double l : load) EXPECT_LE(l, total / n + 7.0 + 1e-9) << n;
      }
    }
  EXPECT_THROW(shard_slice(independent, 0, 2), std::exception);
  EXPECT_THROW(shard_slice(independent, 3, 2), std::exception);
}

TEST(Farm, OneProcessRunsLongestFirstAfterDependencies) {
  std::vector<FarmTask> t = {{"a", "", "", 1, {}}, {"b", "", "", 5, {}}, {"c", "", "", 9, {0}}, {"d", "", "", 3, {}}};
  // b (5) and d (3) and a (1) are ready; a unlocks c (9), which then goes first.
  EXPECT_EQ(priority_order(t), (std::vector<std::size_t>{1, 3, 0, 2}));
  t[0].deps = {2};
  EXPECT_THROW(priority_order(t), std::logic_error);  // a cycle
}

TEST(Csv, ColumnsAreFoundByName) {
  const auto t = CsvTable::parse("seed,planner,objective\n3,random,1.5\n3,greedy,2\n", "x.csv");
  ASSERT_EQ(t.size(), 2u);
  EXPECT_EQ(t.at(1, "planner"), "greedy");
  EXPECT_EQ(t.number(0, "objective"), 1.5);
  EXPECT_THROW(t.at(0, "reward"), std::runtime_error);
  EXPECT_THROW(t.number(0, "planner"), std::runtime_error);
  EXPECT_THROW(CsvTable::parse("a,b\n1\n", "bad.csv"), std::runtime_error);
  try {
    t.at(0, "reward");
  } catch (const std::exception& e) {
    EXPECT_NE(std::string(e.what()).find("x.csv"), std::string::npos);
    EXPECT_NE(std::string(e.what()).find("objective"), std::string::npos) << "names the columns it has";
  }
}

}  // namespace
}  // namespace skyloop
