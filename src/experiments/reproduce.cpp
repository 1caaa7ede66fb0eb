// `skyloop reproduce`: runs every experiment of configs/experiments/ for one profile.
//
// An experiment is made of pieces (reproduce/context.hpp): trained models, chunks of a sweep's
// snapshots, MARL runs, planner evaluations, each cached under the run directory by the hash of
// what decides it (reproduce/piece_cache.hpp). A run goes in three steps:
//   1. the models (phase 0: the other pieces' cache keys hold their bytes), then every process
//      loads them;
//   2. the other pieces (phase 1): over the ranks of an MPI job (farm.hpp), or one slice of them
//      (--shard i/n), or in this process (--jobs at a time: MARL runs as child processes, planner
//      and layout evaluations as threads);
//   3. the assembly: each experiment's CSVs from its pieces (computing any that is missing), the
//      manifest, then the figures and report. Rank 0 assembles; a shard does not.
#include "skyloop/experiments/reproduce.hpp"

#include <algorithm>
#include <cctype>
#include <cmath>
#include <condition_variable>
#include <exception>
#include <ctime>
#include <fmt/format.h>
#include <fstream>
#include <mutex>
#include <thread>
#include <unistd.h>
#include <unordered_map>

#include "reproduce/context.hpp"
#include "skyloop/core/config_io.hpp"
#include "skyloop/core/error.hpp"
#include "skyloop/core/io.hpp"
#include "skyloop/core/process.hpp"
#include "skyloop/experiments/farm.hpp"
#include "skyloop/nn/learned.hpp"

namespace skyloop {

namespace {
using namespace repro;

constexpr int kPendingTag = 10;  // rank 0 -> workers: which pieces of a phase still need work

/// A stream buffer that several threads write through: each write holds one lock.
class LockedBuf : public std::streambuf {
 public:
  explicit LockedBuf(std::streambuf* target) : target_(target) {}

 protected:
  int_type overflow(int_type c) override {
    std::lock_guard<std::mutex> lock(mutex_);
    return traits_type::eq_int_type(c, traits_type::eof()) ? traits_type::not_eof(c) : target_->sputc(traits_type::to_char_type(c));
  }
  std::streamsize xsputn(const char* s, std::streamsize n) override {
    std::lock_guard<std::mutex> lock(mutex_);
    return target_->sputn(s, n);
  }
  int sync() override {
    std::lock_guard<std::mutex> lock(mutex_);
    return target_->pubsync();
  }

 private:
  std::streambuf* target_;
  std::mutex mutex_;
};

class Runner {
 public:
  Runner(const ReproduceOptions& o, std::ostream& log, int threads, int jobs)
      : opt_(o), ctx_(o, log, threads), log_(log), jobs_(jobs), t_(o.transport),
        rank_(t_ ? t_->rank() : 0), ranks_(t_ ? t_->size() : 1), shard_(o.shard_count > 0) {
    ctx_.write_outputs = rank_ == 0 && !shard_;
  }

  int run(const std::vector<ExperimentSpec>& specs) {
    const auto t_all = Clock::now();
    const auto selected = select(specs);
    // Every experiment's kind and configuration resolve before any work starts: a typo fails at once.
    for (const auto* s : selected) (void)stage_kind(s->kind), (void)ctx_.base(*s);
    if (ctx_.write_outputs && !opt_.plan_out) {
      remove_stale_temporaries(ctx_.out.string(), true);  // debris of a run killed mid-write
      write_file_atomic((ctx_.out / "config.toml").string(), to_toml(ctx_.resolve(ExperimentSpec{})));
    }
    std::vector<const ExperimentSpec*> models, others;
    for (const auto* s : selected) (stage_kind(s->kind).phase == 0 ? models : others).push_back(s);
    if (opt_.plan_out) return print_plan(models, others);

    if (opt_.force && ctx_.write_outputs) forget(models);
    if (t_) t_->barrier();  // workers start once rank 0 has cleaned up
    try {
      run_phase(0, models);
      if (failed_) throw_failures();  // rank 0; under MPI the CLI then ends every rank
      for (const auto* s : models) stage_kind(s->kind).assemble(ctx_, *s);  // every process loads the models
      models_ready_ = true;
      if (opt_.force && ctx_.write_outputs) forget(others);
      if (t_) t_->barrier();
      run_phase(1, others);
      if (!time_left_.empty()) return stop_at_time_limit(models, others, time_left_);
      if (shard_) {
        log_ << fmt::format("shard {}/{} done in {:.1f} s; assemble with the same command without --shard\n", opt_.shard_index,
                            opt_.shard_count, since(t_all));
        return failed_ ? 1 : 0;
      }
      if (rank_ != 0) return 0;
      if (failed_) throw_failures();
      assemble(selected, since(t_all), t_all);
    } catch (const TimeLimitReached& e) {
      return stop_at_time_limit(models, others, e.what());
    }
    return 0;
  }

 private:
  const ReproduceOptions& opt_;
  StageContext ctx_;
  std::ostream& log_;
  int jobs_;
  Transport* t_;
  int rank_, ranks_;
  bool shard_;
  std::size_t failed_ = 0;
  std::string first_failure_;
  bool models_ready_ = false;  // phase 1's pieces can be planned (their keys hold the models' bytes)
  std::string time_left_;      // the first piece --time-limit kept the pool from starting

  /// --time-limit left pieces: one line (how many, their estimated core-seconds, the next one)
  /// and kTimeLimitExit. Nothing is assembled; every finished piece is cached.
  int stop_at_time_limit(const std::vector<const ExperimentSpec*>& models, const std::vector<const ExperimentSpec*>& others,
                         const std::string& next) {
    if (rank_ != 0 && !shard_) return kTimeLimitExit;
    std::size_t left = 0;
    double cost = 0;
    for (const auto& p : plan(models_ready_ ? others : models))
      if (!p.done()) ++left, cost += p.cost;
    log_ << fmt::format("time limit: stopped after {:.0f} s of --time-limit {:.0f} s with {} pieces{} left (about {:.0f} "
                        "core-s by their estimates), the next being {}; the finished ones are cached: run the same command "
                        "again to go on\n",
                        ctx_.elapsed(), opt_.time_limit, left, models_ready_ ? "" : " of the models stage and the figures'",
                        cost, next)
         << std::flush;
    return kTimeLimitExit;
  }
  nlohmann::json farm_ = nlohmann::json::array();

  std::vector<const ExperimentSpec*> select(const std::vector<ExperimentSpec>& specs) const {
    std::vector<const ExperimentSpec*> selected;
    for (const auto& s : specs)
      if (s.kind == "models" || opt_.only.empty() || std::find(opt_.only.begin(), opt_.only.end(), s.name) != opt_.only.end())
        selected.push_back(&s);
    for (const auto& name : opt_.only) {
      bool found = false;
      for (const auto& s : specs) found = found || s.name == name;
      if (!found) {
        std::string all;
        for (const auto& s : specs) all += (all.empty() ? "" : ", ") + s.name;
        throw InputError("--only '" + name + "' is not an experiment: allowed " + all);
      }
    }
    return selected;
  }

  /// --force: the experiments' directories and pieces go (MARL runs and evaluations only where
  /// the experiment names them; other experiments' pieces stay).
  void forget(const std::vector<const ExperimentSpec*>& specs) {
    std::error_code ec;
    for (const auto* s : specs) {
      for (const auto& p : stage_kind(s->kind).pieces(ctx_, *s)) fs::remove_all(ctx_.out / p.id, ec);
      fs::remove_all(ctx_.out / s->name, ec);
    }
  }

  /// The pieces of `specs`, each once (experiments share MARL runs and evaluations).
  std::vector<Piece> plan(const std::vector<const ExperimentSpec*>& specs) {
    std::vector<Piece> all;
    std::unordered_map<std::string, std::size_t> at;
    for (const auto* s : specs)
      for (auto& p : stage_kind(s->kind).pieces(ctx_, *s))
        if (at.emplace(p.id, all.size()).second) all.push_back(std::move(p));
    return all;
  }

  /// Rank 0 (or a shard, or one process) decides which pieces still need work; the workers of
  /// an MPI job receive that list, so every rank holds the same tasks.
  std::vector<std::size_t> pending(const std::vector<Piece>& pieces) {
    std::vector<std::size_t> idx;
    if (rank_ == 0) {
      for (std::size_t i = 0; i < pieces.size(); ++i)
        if (!pieces[i].done()) idx.push_back(i);
      if (t_) {
        std::string msg;
        for (auto i : idx) msg += std::to_string(i) + ",";
        for (int r = 1; r < ranks_; ++r) t_->send(r, kPendingTag, msg);
      }
      return idx;
    }
    int from = 0, tag = 0;
    std::string msg;
    while (!t_->try_receive(from, tag, msg)) std::this_thread::sleep_for(std::chrono::milliseconds(1));
    if (tag != kPendingTag) throw std::runtime_error(fmt::format("rank {}: expected the list of pieces, got tag {}", rank_, tag));
    std::size_t start = 0;
    for (std::size_t comma; (comma = msg.find(',', start)) != std::string::npos; start = comma + 1)
      idx.push_back(std::stoul(msg.substr(start, comma - start)));
    return idx;
  }

  void run_phase(int phase, const std::vector<const ExperimentSpec*>& specs) {
    std::vector<Piece> pieces = plan(specs);
    const bool scale_out = t_ || shard_;
    if (rank_ == 0) announce(phase, pieces, scale_out ? std::max(1, ranks_) : std::max(1, jobs_), !scale_out);
    if (!scale_out) {
      // One process: MARL runs and evaluations go first, --jobs at a time; the assembly computes
      // the rest (a sweep's chunks, each on --threads cores) in turn.
      if (phase == 1 && jobs_ > 1) prefetch(pieces);
      return;
    }
    // A shard slices every piece, done or not, so the slices do not depend on when each shard
    // starts; it skips what is done. Under MPI rank 0 hands out what is left.
    std::vector<std::size_t> open_pieces;
    if (shard_)
      for (std::size_t i = 0; i < pieces.size(); ++i) open_pieces.push_back(i);
    else
      open_pieces = pending(pieces);
    std::vector<FarmTask> tasks;
    std::unordered_map<std::string, std::size_t> task_of;
    for (std::size_t t = 0; t < open_pieces.size(); ++t) task_of[pieces[open_pieces[t]].id] = t;
    for (std::size_t i : open_pieces) {
      const Piece& p = pieces[i];
      FarmTask f{p.id, p.kind, p.label, p.cost, {}};
      for (const auto& d : p.deps)
        if (auto it = task_of.find(d); it != task_of.end()) f.deps.push_back(it->second);
      tasks.push_back(std::move(f));
    }
    auto work = [&](std::size_t t) {
      ctx_.ensure(pieces[open_pieces[t]]);
      return std::string();
    };
    if (shard_) {
      const auto mine = shard_slice(tasks, opt_.shard_index, opt_.shard_count);
      log_ << fmt::format("phase {}: {} pieces; shard {}/{} takes {}\n", phase, pieces.size(), opt_.shard_index,
                          opt_.shard_count, mine.size())
           << std::flush;
      std::size_t n = 0;
      for (std::size_t t : mine) {
        if (!ctx_.fits(tasks[t].cost) && !pieces[open_pieces[t]].done()) {  // --time-limit: a later piece may fit
          if (time_left_.empty()) time_left_ = tasks[t].label;
          ++n;
          continue;
        }
        const auto t0 = Clock::now();
        try {
          work(t);
          log_ << fmt::format("  piece {}/{} done: {} {} ({:.1f} s)\n", ++n, mine.size(), tasks[t].kind, tasks[t].label, since(t0))
               << std::flush;
        } catch (const InputError&) {
          throw;
        } catch (const TimeLimitReached&) {
          throw;
        } catch (const std::exception& e) {
          note_failure(tasks[t].id, e.what());
          log_ << fmt::format("  piece {}/{} FAILED: {}: {}\n", ++n, mine.size(), tasks[t].id, e.what()) << std::flush;
        }
      }
      return;
    }
    if (rank_ == 0)
      log_ << fmt::format("phase {}: {} of {} pieces to compute on {} ranks (their logs: {})\n", phase, tasks.size(),
                          pieces.size(), ranks_, (ctx_.out / "farm" / "rank<r>.log").string())
           << std::flush;
    // Rank 0 prints one line per piece; the pieces it computes itself log to farm/rank0.log.
    std::ofstream own;
    std::streambuf* const shown = ctx_.log.rdbuf();
    if (rank_ == 0) {
      fs::create_directories(ctx_.out / "farm");
      own.open(ctx_.out / "farm" / "rank0.log", std::ios::app);
      ctx_.log.rdbuf(own.rdbuf());
    }
    const auto t0 = Clock::now();
    std::vector<FarmRecord> records;
    try {
      records = farm_run(t_, tasks, work, [](std::size_t, const std::string&) {}, rank_ == 0 ? &log_ : nullptr);
    } catch (...) {
      ctx_.log.rdbuf(shown);
      throw;
    }
    ctx_.log.rdbuf(shown);
    if (rank_ != 0) return;
    record_farm(phase, tasks, records, since(t0));
  }

  /// One line before a phase's work: how many pieces are left, their estimated core-seconds
  /// (`--plan`'s estimates) and the wall time and clock time that gives on `workers` cores. In one
  /// process (`in_turn`) only the MARL runs and evaluations share the workers; a sweep's chunks
  /// follow one after another in the assembly, each on --threads cores (prefetch).
  void announce(int phase, const std::vector<Piece>& pieces, int workers, bool in_turn) {
    double work = 0, shared = 0;
    std::size_t left = 0;
    for (const auto& p : pieces)
      if (!p.done()) {
        work += p.cost, ++left;
        if (!in_turn || p.kind == "marl" || p.kind == "eval") shared += p.cost;
      }
    if (left == 0) return;
    const double wall = shared / workers + (work - shared) / std::max(1, ctx_.threads);
    const std::time_t eta = std::time(nullptr) + static_cast<std::time_t>(wall);
    char at[16];
    std::strftime(at, sizeof at, "%H:%M", std::localtime(&eta));
    log_ << fmt::format("phase {}: {} of {} pieces to compute, estimated {:.0f} core-s: about {:.1f} min on {} workers, ETA {}\n",
                        phase, left, pieces.size(), work, wall / 60.0, workers, at)
         << std::flush;
  }

  /// --plan: every piece with its estimate, done or not; phase 1 needs the models to exist.
  int print_plan(const std::vector<const ExperimentSpec*>& models, const std::vector<const ExperimentSpec*>& others) {
    std::ostream& out = *opt_.plan_out;
    out << "phase,piece,kind,label,cost_estimate,done,deps\n";
    auto print = [&](int phase, const std::vector<Piece>& pieces) {
      std::size_t missing = 0;
      for (const auto& p : pieces) {
        std::string deps, label = p.label;
        for (const auto& d : p.deps) deps += (deps.empty() ? "" : ";") + d;
        std::replace(label.begin(), label.end(), ',', ';');
        const bool done = p.done();
        missing += done ? 0 : 1;
        out << fmt::format("{},{},{},{},{},{},{}\n", phase, p.id, p.kind, label, format_double(p.cost), done ? 1 : 0, deps);
      }
      return missing;
    };
    if (print(0, plan(models)) > 0) {
      log_ << "--plan: phase 1 is planned once the models exist (its cache keys hold their bytes); run the models stage "
              "first (e.g. --only models)\n";
      return 0;
    }
    ctx_.write_outputs = false;
    for (const auto* s : models) stage_kind(s->kind).assemble(ctx_, *s);
    print(1, plan(others));
    return 0;
  }

  [[noreturn]] void throw_failures() const {
    throw std::runtime_error(fmt::format("{} piece{} failed (see {}); the first: {}", failed_, failed_ == 1 ? "" : "s",
                                         (ctx_.out / "farm" / "pieces.csv").string(), first_failure_));
  }

  void note_failure(const std::string& id, const std::string& what) {
    if (failed_++ == 0) first_failure_ = id + ": " + what;
  }

  /// farm/pieces.csv (one row per piece and phase) and a summary line: where each piece ran, its
  /// time, and what the farm added to it.
  void record_farm(int phase, const std::vector<FarmTask>& tasks, const std::vector<FarmRecord>& records, double wall) {
    std::string csv;
    const fs::path file = ctx_.out / "farm" / "pieces.csv";
    if (phase > 0 && fs::exists(file)) csv = read_file(file.string());
    if (csv.empty()) csv = "phase,ranks,piece,kind,label,rank,cost_estimate,assigned_s,received_s,seconds,overhead_ms,status,deps\n";
    double busy = 0;
    std::vector<double> overhead;
    for (const auto& r : records) {
      const FarmTask& t = tasks[r.task];
      std::string deps, error = r.error;
      for (auto d : t.deps) deps += (deps.empty() ? "" : ";") + tasks[d].id;
      std::string label = t.label;
      std::replace(error.begin(), error.end(), ',', ';');
      std::replace(label.begin(), label.end(), ',', ';');
      std::replace(error.begin(), error.end(), '\n', ' ');
      const std::string status = r.ok ? "done" : r.rank < 0 ? "not run" : "failed: " + error;
      if (!r.ok) note_failure(t.id, r.rank < 0 ? r.error : error);
      if (r.rank >= 0) busy += r.seconds, overhead.push_back(r.overhead());
      csv += fmt::format("{},{},{},{},{},{},{},{},{},{},{},{},{}\n", phase, ranks_, t.id, t.kind, label, r.rank,
                         format_double(t.cost), format_double(r.assigned), format_double(r.received), format_double(r.seconds),
                         format_double(r.rank >= 0 ? 1e3 * r.overhead() : 0.0), status, deps);
    }
    write_file_atomic(file.string(), csv);
    std::sort(overhead.begin(), overhead.end());
    const double med = overhead.empty() ? 0 : overhead[overhead.size() / 2], max = overhead.empty() ? 0 : overhead.back();
    log_ << fmt::format("phase {}: {} pieces on {} ranks in {:.1f} s; ranks busy {:.0f}%; farm overhead per piece median "
                        "{:.1f} ms, max {:.1f} ms ({})\n",
                        phase, tasks.size(), ranks_, wall, wall > 0 ? 100.0 * busy / (wall * ranks_) : 0.0, 1e3 * med, 1e3 * max,
                        file.string())
         << std::flush;
    farm_.push_back({{"phase", phase}, {"pieces", tasks.size()}, {"seconds", wall}, {"busy_seconds", busy},
                     {"overhead_median_ms", 1e3 * med}, {"overhead_max_ms", 1e3 * max}});
  }

  /// One process, --jobs J > 1: J workers share the MARL runs (each a child `skyloop train`
  /// process on one thread, first) and the planner and layout evaluations (threads of this
  /// process, one core each, once the runs and pieces they read are done). The assembly then finds
  /// them done; a sweep's chunks stay in the assembly, where each uses --threads cores.
  void prefetch(const std::vector<Piece>& pieces) {
    Pool pool;
    for (const auto& p : pieces) {
      pool.by_id[p.id] = &p;
      if (p.kind == "marl" && !p.done()) pool.runs.push_back(&p);
      if (p.kind == "eval" && !p.done()) pool.evals.push_back(&p);
    }
    if (pool.runs.empty() && pool.evals.empty()) return;
    // The longest evaluations first, so that the last ones to start are short.
    std::stable_sort(pool.evals.begin(), pool.evals.end(), [](const Piece* a, const Piece* b) { return a->cost > b->cost; });
    std::size_t to_train = 0;
    for (const auto* r : pool.runs) to_train += !trained(*r);
    log_ << fmt::format("training {} MARL runs and computing {} evaluations, {} at a time (run logs: <run>/train.log)\n", to_train,
                        pool.evals.size(), jobs_)
         << std::flush;
    // Lines from the workers and from the pieces they run go through one lock.
    LockedBuf locked(ctx_.log.rdbuf());
    std::streambuf* const shown = ctx_.log.rdbuf(&locked);
    std::ostream out(&locked);
    pool.out = &out;
    pool.run_taken.assign(pool.runs.size(), kOpen);
    pool.taken.assign(pool.evals.size(), kOpen);
    pool.t0 = Clock::now();
    std::vector<std::thread> threads;
    for (int j = 0; j < jobs_; ++j) threads.emplace_back([this, &pool] { work(pool); });
    for (auto& t : threads) t.join();
    ctx_.log.rdbuf(shown);
    // --time-limit: the first piece the pool could not start (the run stops before the assembly).
    for (std::size_t r = 0; r < pool.runs.size() && time_left_.empty(); ++r)
      if (pool.run_taken[r] == kSkipped) time_left_ = pool.runs[r]->label;
    for (std::size_t e = 0; e < pool.evals.size() && time_left_.empty(); ++e)
      if (pool.taken[e] == kSkipped) time_left_ = pool.evals[e]->label;
    if (!pool.failed.empty())
      throw std::runtime_error(fmt::format("{} of {} MARL runs failed; see {}", pool.failed.size(), pool.runs.size(), pool.failed.front()));
    if (pool.error) std::rethrow_exception(pool.error);
  }

  enum : char { kOpen = 0, kTaken = 1, kSkipped = 2 };

  /// What prefetch's workers share; everything after `mu` is guarded by it.
  struct Pool {
    std::vector<const Piece*> runs, evals;
    std::unordered_map<std::string, const Piece*> by_id;
    std::ostream* out = nullptr;
    Clock::time_point t0;
    std::mutex mu;
    std::condition_variable changed;
    std::size_t running = 0, runs_done = 0, evals_done = 0;
    std::vector<char> run_taken, taken;              // per run and evaluation: kOpen, kTaken or kSkipped
    std::unordered_map<std::string, char> finished;  // ids of pieces this pool completed
    double busy = 0;
    std::vector<std::string> failed;
    std::exception_ptr error;
  };

  /// A dependency is met when its piece is done (a MARL run: trained; its own evaluation is run
  /// by whichever piece reads it) or is no piece of this phase (the models).
  bool met(const Pool& pool, const std::string& dep) const {
    if (pool.finished.count(dep)) return true;
    const auto it = pool.by_id.find(dep);
    if (it == pool.by_id.end()) return true;
    return it->second->kind == "marl" ? trained(*it->second) : it->second->done();
  }

  bool ready(const Pool& pool, std::size_t e) const {
    for (const auto& d : pool.evals[e]->deps)
      if (!met(pool, d)) return false;
    return true;
  }

  std::string eta(const Pool& pool, std::size_t done, std::size_t total) const {
    if (done >= total) return std::string();
    const double per = pool.busy / static_cast<double>(done) / static_cast<double>(jobs_);
    return fmt::format(", ETA {:.0f} s", per * static_cast<double>(total - done));
  }

  /// A MARL run trained by a child `skyloop train` (unless another process holds or made it).
  void train_run(Pool& pool, const Piece& piece) {
    const Config& cfg = piece.train_config;
    const fs::path dir = ctx_.out / piece.id;
    int rc = 0;
    double sec = 0;
    const bool ran = ctx_.cache.ensure(
        piece.id, [&] { return trained(piece); },
        [&] {
          write_file_atomic((dir / "request.toml").string(), to_toml(cfg));
          std::vector<std::string> argv = {self_path(), "train", "--config", (dir / "request.toml").string(), "--out", dir.string()};
          if (fs::exists(dir / "last.pt")) *pool.out << restart_note(dir) << std::flush;
          argv.push_back("--force");
          const auto tr = Clock::now();
          rc = run_process(argv, (dir / "train.log").string());
          sec = since(tr);
          if (rc == 0) {
            ctx_.record_timing(piece.id, "marl-train", piece.cost, sec);
            nlohmann::json j = {{"seconds", sec},
                                {"steps_per_second", static_cast<double>(cfg.marl.total_steps) / sec},
                                {"env_steps", cfg.marl.total_steps},
                                {"process", true}};
            write_file_atomic((dir / "train.json").string(), j.dump(2) + "\n");
          }
        },
        pool.out);
    std::lock_guard<std::mutex> lock(pool.mu);
    if (rc != 0) {
      pool.failed.push_back(fmt::format("{} (exit status {})", (dir / "train.log").string(), rc));
      return;
    }
    pool.busy += sec;
    ++pool.runs_done;
    *pool.out << fmt::format("  {} K = {} seed {}: {:.0f} s{} ({}/{} runs, {:.0f} s elapsed{})\n", cfg.marl.algo,
                             cfg.scenario.users, cfg.run.seed, sec, ran ? "" : " (by another process)", pool.runs_done,
                             pool.runs.size(), since(pool.t0), eta(pool, pool.runs_done, pool.runs.size()))
              << std::flush;
  }

  void evaluate_piece(Pool& pool, const Piece& piece, bool counted) {
    const auto te = Clock::now();
    try {
      ctx_.ensure(piece, false);  // the pool admitted it under --time-limit
    } catch (...) {
      std::lock_guard<std::mutex> lock(pool.mu);
      if (!pool.error) pool.error = std::current_exception();
      return;
    }
    std::lock_guard<std::mutex> lock(pool.mu);
    pool.finished[piece.id] = 1;
    if (!counted) return;
    ++pool.evals_done;
    *pool.out << fmt::format("  {}: {:.1f} s ({}/{} evaluations, {:.0f} s elapsed)\n", piece.label, since(te), pool.evals_done,
                             pool.evals.size(), since(pool.t0))
              << std::flush;
  }

  /// One worker: the runs first, in order, then any evaluation whose inputs are ready. Under
  /// --time-limit a piece that no longer fits is skipped for good (the time left only shrinks).
  void work(Pool& pool) {
    set_torch_threads(1);  // one core per worker, denormals flushed as on the main thread
    std::unique_lock<std::mutex> lock(pool.mu);
    for (;;) {
      if (pool.error) return;
      const Piece* run = nullptr;
      const Piece* eval = nullptr;
      bool runs_open = false;
      for (std::size_t r = 0; r < pool.runs.size() && !run; ++r) {
        if (pool.run_taken[r] != kOpen) continue;
        if (!ctx_.fits(pool.runs[r]->cost) && !trained(*pool.runs[r])) {
          pool.run_taken[r] = kSkipped;
          continue;
        }
        pool.run_taken[r] = kTaken, run = pool.runs[r], runs_open = true;
      }
      if (!runs_open) {
        std::size_t open = 0;
        for (std::size_t e = 0; e < pool.evals.size() && !eval; ++e) {
          if (pool.taken[e] != kOpen) continue;
          if (ready(pool, e) && !ctx_.fits(pool.evals[e]->cost) && !pool.evals[e]->done()) {
            pool.taken[e] = kSkipped;
            continue;
          }
          ++open;
          if (ready(pool, e)) pool.taken[e] = kTaken, eval = pool.evals[e];
        }
        if (!eval) {
          // Nothing to start: done, or wait for a running piece that may make one ready.
          if (open == 0 || pool.running == 0) return;
          pool.changed.wait(lock);
          continue;
        }
      }
      ++pool.running;
      lock.unlock();
      if (run) {
        try {
          if (!trained(*run)) train_run(pool, *run);
        } catch (...) {  // the cache's lock or a file: stop the pool, report it after
          std::lock_guard<std::mutex> guard(pool.mu);
          if (!pool.error) pool.error = std::current_exception();
        }
        if (trained(*run)) evaluate_piece(pool, *run, false);  // its policy on its own users
      } else {
        evaluate_piece(pool, *eval, true);
      }
      lock.lock();
      --pool.running;
      pool.changed.notify_all();
    }
  }

  bool trained(const Piece& run) const {
    const fs::path dir = ctx_.out / run.id;
    return fs::exists(dir / "train.json") && fs::exists(dir / "policy.pt");
  }


  void assemble(const std::vector<const ExperimentSpec*>& selected, double compute_s, Clock::time_point t_all) {
    nlohmann::json manifest;
    manifest["profile"] = opt_.profile;
    manifest["threads"] = ctx_.threads;
    manifest["experiments"] = nlohmann::json::array();
    for (std::size_t i = 0; i < selected.size(); ++i) {
      const auto& s = *selected[i];
      log_ << fmt::format("[{}/{}] {} ({}{}{})\n", i + 1, selected.size(), s.name, s.kind, s.figure.empty() ? "" : ", ", s.figure)
           << std::flush;
      const auto t0 = Clock::now();
      nlohmann::json entry = {{"name", s.name}, {"kind", s.kind}, {"figure", s.figure}, {"title", s.title}};
      write_file_atomic((ctx_.out / s.name / "experiment.toml").string(), s.text);
      write_file_atomic((ctx_.out / s.name / "config.toml").string(), to_toml(ctx_.base(s)));
      entry["files"] = stage_kind(s.kind).assemble(ctx_, s);
      entry["seconds"] = since(t0);
      manifest["experiments"].push_back(entry);
      log_ << fmt::format("[{}/{}] {} done in {:.1f} s\n", i + 1, selected.size(), s.name, since(t0)) << std::flush;
    }
    manifest["seconds"] = since(t_all);
    // Earlier invocations on this directory stay listed: a cached re-run takes seconds, and the
    // report shows what the computing run took.
    nlohmann::json runs = nlohmann::json::array();
    if (fs::exists(ctx_.out / "manifest.json")) {
      try {
        const auto old = nlohmann::json::parse(read_file((ctx_.out / "manifest.json").string()));
        if (old.contains("runs")) runs = old["runs"];
      } catch (const std::exception&) {
      }
    }
    nlohmann::json names = nlohmann::json::array();
    for (const auto* s : selected) names.push_back(s->name);
    nlohmann::json run = {{"seconds", manifest["seconds"]}, {"threads", ctx_.threads}, {"jobs", jobs_}, {"ranks", ranks_},
                          {"force", opt_.force}, {"experiments", names}};
    if (!farm_.empty()) run["farm"] = farm_;
    runs.push_back(run);
    manifest["runs"] = runs;
    manifest["models"] = ctx_.shown_models;
    write_file_atomic((ctx_.out / "manifest.json").string(), manifest.dump(2) + "\n");
    log_ << fmt::format("all stages done in {:.1f} s ({:.1f} s before the assembly); wrote {}\n", since(t_all), compute_s,
                        (ctx_.out / "manifest.json").string());
  }
};

}  // namespace

int reproduce(const ReproduceOptions& o) {
  ReproduceOptions opt = o;
  if (opt.profile != "quick" && opt.profile != "paper" && opt.profile != "tiny")
    throw InputError("--profile '" + opt.profile + "' is unknown: allowed quick, paper, tiny");
  if (opt.threads < 0 || opt.threads > 1024)
    throw InputError("--threads = " + std::to_string(opt.threads) + " is out of range: allowed an integer in [0, 1024] (0 = all cores)");
  if (!std::isfinite(opt.piece_seconds) || opt.piece_seconds <= 0)
    throw InputError(fmt::format("--piece-seconds = {} is out of range: allowed a finite number of seconds above 0", opt.piece_seconds));
  if (opt.jobs < 0 || opt.jobs > 1024)
    throw InputError("--jobs = " + std::to_string(opt.jobs) + " is out of range: allowed an integer in [0, 1024] (0 = --threads)");
  if (opt.shard_count > 0 && (opt.shard_index < 1 || opt.shard_index > opt.shard_count))
    throw InputError(fmt::format("--shard {}/{} is invalid: allowed i/n with 1 <= i <= n", opt.shard_index, opt.shard_count));
  if (opt.shard_count > 0 && opt.transport && opt.transport->size() > 1)
    throw InputError("--shard under an MPI job of several ranks: allowed one or the other");
  if (opt.shard_count > 0 && opt.force)
    throw InputError("--force with --shard: allowed only in a run without --shard (shards would delete each other's work)");
  if (!std::isfinite(opt.time_limit) || opt.time_limit < 0)
    throw InputError(fmt::format("--time-limit = {} s is out of range: allowed a finite duration above 0", opt.time_limit));
  if (opt.time_limit > 0 && opt.transport)
    throw InputError("--time-limit under MPI: allowed in one process or with --shard (one rank cannot stop alone; a "
                     "Slurm array gives each task its own limit)");
  if (opt.out_dir.empty()) opt.out_dir = "results/" + opt.profile;
  check_output_dir(opt.out_dir);
  if (opt.experiments_dir.empty()) opt.experiments_dir = (fs::path(source_dir()) / "configs" / "experiments").string();
  const auto specs = load_experiments(opt.experiments_dir, opt.profile);

  const int ranks = opt.transport ? opt.transport->size() : 1, rank = opt.transport ? opt.transport->rank() : 0;
  const int threads = threads_per_rank(opt.threads, opt.transport);
  const int jobs = opt.jobs > 0 ? opt.jobs : threads;
  std::ostringstream null;
  std::ofstream rank_log;
  std::ostream* log = opt.progress ? opt.progress : &null;
  if (rank > 0) {
    // Workers log to a file each; rank 0 prints one line per piece.
    fs::create_directories(fs::path(opt.out_dir) / "farm");
    rank_log.open(fs::path(opt.out_dir) / "farm" / fmt::format("rank{}.log", rank));
    log = &rank_log;
    rank_log << fmt::format("rank {} of {}, pid {}\n", rank, ranks, static_cast<long>(::getpid())) << std::flush;
  }
  const int rc = Runner(opt, *log, threads, jobs).run(specs);
  if (rank != 0 || opt.shard_count > 0 || opt.plan_out || !opt.plots || rc != 0) return rc;
  const std::string script = (fs::path(source_dir()) / "scripts" / "plot_figures.py").string();
  const std::string cmd = fmt::format("'{}' '{}' '{}'", opt.python, script, opt.out_dir);
  if (opt.progress) *opt.progress << "plots and report: " << cmd << "\n" << std::flush;
  const int prc = run_process({opt.python, script, opt.out_dir});
  if (prc != 0) throw std::runtime_error("the plot step failed (" + cmd + "); the CSVs under " + opt.out_dir + " are complete");
  return 0;
}

double parse_time_limit(const std::string& text, const std::string& what) {
  const auto bad = [&] {
    return InputError(fmt::format("{} = '{}' is not a duration: allowed hours, minutes and seconds with their units (2h50m, "
                                  "45m, 600s, 1.5h) or [D-]HH:MM:SS / MM:SS, above 0 and at most 365 days",
                                  what, text));
  };
  // A non-negative decimal number at text[i...], advancing i; false if there is none.
  const auto number = [&](std::size_t& i, double& v, bool integer) {
    const std::size_t start = i;
    while (i < text.size() && (std::isdigit(static_cast<unsigned char>(text[i])) || (!integer && text[i] == '.'))) ++i;
    const std::string digits = text.substr(start, i - start);
    if (digits.empty() || digits.size() > 12 || std::count(digits.begin(), digits.end(), '.') > 1 || digits.front() == '.' ||
        digits.back() == '.')
      return false;
    v = std::stod(digits);
    return true;
  };
  double seconds = 0;
  std::size_t i = 0;
  if (text.find(':') != std::string::npos) {
    // Slurm's forms: [D-]HH:MM:SS, [D-]HH:MM, MM:SS (its bare minutes are not taken: units say which).
    double days = 0, v = 0;
    const auto dash = text.find('-');
    if (dash != std::string::npos) {
      if (!number(i, days, true) || i != dash) throw bad();
      ++i;
    }
    std::vector<double> fields;
    for (;;) {
      if (!number(i, v, true)) throw bad();
      fields.push_back(v);
      if (i == text.size()) break;
      if (text[i++] != ':') throw bad();
    }
    if (fields.size() < 2 || fields.size() > 3) throw bad();
    for (std::size_t f = 1; f < fields.size(); ++f)
      if (fields[f] >= 60) throw bad();
    if (dash != std::string::npos)  // D-HH:MM[:SS]
      seconds = days * 86400 + fields[0] * 3600 + fields[1] * 60 + (fields.size() == 3 ? fields[2] : 0);
    else if (fields.size() == 3)
      seconds = fields[0] * 3600 + fields[1] * 60 + fields[2];
    else
      seconds = fields[0] * 60 + fields[1];
  } else {
    const std::string units = "dhms";
    const double scale[] = {86400, 3600, 60, 1};
    std::size_t last_unit = 0;  // units in order, each at most once: 1d2h3m4s
    while (i < text.size()) {
      double v = 0;
      if (!number(i, v, false) || i == text.size()) throw bad();
      const auto u = units.find(text[i++]);
      if (u == std::string::npos || u + 1 <= last_unit) throw bad();
      last_unit = u + 1;
      seconds += v * scale[u];
    }
  }
  if (!(seconds > 0) || seconds > 365.0 * 86400) throw bad();
  return seconds;
}

}  // namespace skyloop
