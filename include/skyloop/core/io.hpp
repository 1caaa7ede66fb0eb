#pragma once
#include <string>
#include <utility>
#include <vector>

namespace skyloop {

/// Writes `content` to `path` atomically: a temporary file beside it, flushed, then renamed over
/// the target, so a reader never sees a half-written file and an old file survives a failure.
/// Creates missing parent directories. A symlink is written through (the link stays). An existing
/// path that is not a regular file (a directory, FIFO, device, socket) is refused with InputError;
/// other failures throw std::runtime_error naming the path, and leave the old file untouched.
void write_file_atomic(const std::string& path, const std::string& content);

/// Writes several files as one: all temporaries first, then the renames, with the earlier files
/// kept aside until every rename succeeded, so either all of `files` change or none does (e.g. a
/// CSV and the resolved config beside it).
void write_files_atomic(const std::vector<std::pair<std::string, std::string>>& files);

/// Throws the InputError write_file_atomic would throw for `path` (a directory, FIFO, device or
/// socket where a file is to go), before any work is done.
void check_output_path(const std::string& path);

/// An output directory (`--out DIR`): refused with InputError when it, or a folder above it, exists
/// and is not a directory.
void check_output_dir(const std::string& dir, const std::string& flag = "--out");

/// An exclusive lock on a run directory (flock on DIR/.skyloop.lock), held while the object lives:
/// two runs into one `--out` at once would overwrite each other's files. The kernel drops the lock
/// of a process that dies, so a killed run never blocks the next.
class RunDirLock {
 public:
  /// The lock file's name in the directory: bookkeeping, never part of a run's results.
  static constexpr const char* kFile = ".skyloop.lock";
  RunDirLock() = default;
  /// Creates `dir` if needed and takes its lock, or throws InputError naming `flag` and the
  /// directory when another process (or another run in this one) holds it.
  explicit RunDirLock(const std::string& dir, const std::string& flag = "--out");
  RunDirLock(RunDirLock&& o) noexcept : fd_(o.fd_) { o.fd_ = -1; }
  RunDirLock& operator=(RunDirLock&& o) noexcept;
  RunDirLock(const RunDirLock&) = delete;
  RunDirLock& operator=(const RunDirLock&) = delete;
  ~RunDirLock();

 private:
  int fd_ = -1;
};

/// `--resume` and `--force` together are refused (InputError), before anything else is checked.
void check_resume_or_force(bool resume, bool force);

/// A run directory about to receive a run: takes its lock (RunDirLock), then, for a fresh (not
/// resumed) run, if any of `results` is already in `dir`, throws InputError ("already holds a run:
/// allowed --resume, --force or a new directory") unless `force`, which removes them first.
/// `resume` and `force` together are refused. The lock is the caller's to hold for the run.
[[nodiscard]] RunDirLock check_fresh_run_dir(const std::string& dir, const std::vector<std::string>& results, bool resume, bool force);

/// Removes the temporaries (NAME.tmp.PID) that killed processes left in `dir`, and restores the
/// earlier file from an interrupted pair write (NAME.bak.PID) when NAME is missing. A live
/// process's temporaries are left alone. Run directories call this when a run starts or resumes;
/// `reproduce` over its whole output tree (`recursive`).
void remove_stale_temporaries(const std::string& dir, bool recursive = false);

/// Reads a whole file; throws InputError naming the path if it cannot be read.
std::string read_file(const std::string& path, const std::string& what = "file");

/// Shortest decimal text that reads back to exactly `x` (for CSV, TOML and JSON output).
std::string format_double(double x);

}  // namespace skyloop
