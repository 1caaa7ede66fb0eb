#include "skyloop/core/io.hpp"

#include <atomic>
#include <cerrno>
#include <cmath>
#include <csignal>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <stdexcept>
#include <fcntl.h>
#include <sys/file.h>
#include <sys/stat.h>
#include <unistd.h>

#include "skyloop/core/error.hpp"

namespace skyloop {

namespace fs = std::filesystem;

namespace {

const char* kind_of(const fs::file_status& st) {
  switch (st.type()) {
    case fs::file_type::directory: return "a directory";
    case fs::file_type::fifo: return "a FIFO";
    case fs::file_type::character: return "a character device";
    case fs::file_type::block: return "a block device";
    case fs::file_type::socket: return "a socket";
    default: return "not a regular file";
  }
}

/// The file a write to `path` lands in: a symlink is followed (the link stays, its target is
/// replaced), and an existing target that is not a regular file is refused.
fs::path write_target(const std::string& path) {
  fs::path target(path);
  std::error_code ec;
  if (fs::is_symlink(fs::symlink_status(target, ec))) {
    const fs::path resolved = fs::weakly_canonical(target, ec);
    if (!ec) target = resolved;
  }
  const auto st = fs::status(target, ec);
  if (!ec && fs::exists(st) && !fs::is_regular_file(st))
    throw InputError("output '" + path + "' is " + kind_of(st) + ": allowed a regular file path (new or existing)");
  return target;
}

}  // namespace

void check_output_path(const std::string& path) { (void)write_target(path); }

void check_output_dir(const std::string& dir, const std::string& flag) {
  if (dir.empty()) throw InputError(flag + " is empty: allowed a directory path");
  // "a/b/" names the directory a/b: without the trailing separators a file a/b is seen as one.
  std::string path = dir;
  while (path.size() > 1 && path.back() == '/') path.pop_back();
  std::error_code ec;
  if (fs::exists(path, ec) && !fs::is_directory(path, ec))
    throw InputError(flag + " '" + dir + "' exists and is not a directory: allowed a directory (new or existing)");
  for (fs::path p = fs::path(path).parent_path(); !p.empty() && p != p.parent_path(); p = p.parent_path())
    if (fs::exists(p, ec) && !fs::is_directory(p, ec))
      throw InputError(flag + " '" + dir + "' lies under '" + p.string() + "', which is not a directory: allowed a directory path");
}

RunDirLock::RunDirLock(const std::string& dir, const std::string& flag) {
  check_output_dir(dir, flag);
  std::error_code ec;
  fs::create_directories(dir, ec);
  if (ec) throw std::runtime_error("cannot create directory " + dir + ": " + ec.message());
  const fs::path path = fs::path(dir) / kFile;
  fd_ = ::open(path.c_str(), O_RDWR | O_CREAT | O_CLOEXEC, 0644);
  if (fd_ < 0) throw std::runtime_error("cannot open the lock file " + path.string() + ": " + std::strerror(errno));
  if (::flock(fd_, LOCK_EX | LOCK_NB) != 0) {
    ::close(fd_);
    fd_ = -1;
    throw InputError(flag + " '" + dir + "' is in use by another skyloop run: allowed one run at a time per directory "
                     "(wait for it to finish, or choose another directory)");
  }
}

RunDirLock& RunDirLock::operator=(RunDirLock&& o) noexcept {
  if (this != &o) {
    if (fd_ >= 0) ::close(fd_);
    fd_ = o.fd_;
    o.fd_ = -1;
  }
  return *this;
}

RunDirLock::~RunDirLock() {
  if (fd_ >= 0) ::close(fd_);  // closing releases the lock
}

void check_resume_or_force(bool resume, bool force) {
  if (resume && force)
    throw InputError("--resume and --force together: allowed one of them (--resume continues the run in --out, --force replaces it)");
}

RunDirLock check_fresh_run_dir(const std::string& dir, const std::vector<std::string>& results, bool resume, bool force) {
  check_resume_or_force(resume, force);
  check_output_dir(dir);
  RunDirLock lock(dir);
  std::error_code ec;
  if (resume) return lock;
  for (const auto& f : results) {
    const fs::path p = fs::path(dir) / f;
    if (!fs::exists(p, ec)) continue;
    if (!force)
      throw InputError("--out '" + dir + "' already holds a run (" + f +
                       "): allowed --resume to continue it, --force to replace it, or a new directory");
  }
  if (force)
    for (const auto& f : results) fs::remove(fs::path(dir) / f, ec);
  return lock;
}

namespace {

/// "<pid>-<serial>": unique per write in this process, so threads that write the same file at once
/// (reproduce's evaluations share optima) never share a temporary. remove_stale_temporaries reads
/// the pid back.
std::string writer_tag() {
  static std::atomic<unsigned long> serial{0};
  return std::to_string(::getpid()) + "-" + std::to_string(serial.fetch_add(1, std::memory_order_relaxed));
}

fs::path temp_for(const fs::path& target) { return target.string() + ".tmp." + writer_tag(); }

/// Writes `content` to `tmp`, flushed to disk; removes `tmp` and throws on failure.
void write_temp(const fs::path& tmp, const std::string& content) {
  std::error_code ec;
  if (tmp.has_parent_path()) {
    fs::create_directories(tmp.parent_path(), ec);
    if (ec) throw std::runtime_error("cannot create directory " + tmp.parent_path().string() + ": " + ec.message());
  }
  std::FILE* f = std::fopen(tmp.c_str(), "wb");
  if (!f) throw std::runtime_error("cannot write " + tmp.string() + ": " + std::strerror(errno));
  bool ok = std::fwrite(content.data(), 1, content.size(), f) == content.size() && std::fflush(f) == 0 &&
            ::fsync(::fileno(f)) == 0;
  const int err = errno;
  ok = (std::fclose(f) == 0) && ok;
  if (!ok) {
    fs::remove(tmp, ec);
    throw std::runtime_error("cannot write " + tmp.string() + ": " + std::strerror(err ? err : EIO));
  }
}

}  // namespace

void write_file_atomic(const std::string& path, const std::string& content) {
  write_files_atomic({{path, content}});
}

void write_files_atomic(const std::vector<std::pair<std::string, std::string>>& files) {
  std::vector<fs::path> targets, temps;
  for (const auto& [path, content] : files) targets.push_back(write_target(path));
  std::error_code ec;
  auto remove_all_temps = [&] {
    for (const auto& t : temps) fs::remove(t, ec);
  };
  try {
    for (std::size_t i = 0; i < files.size(); ++i) {
      temps.push_back(temp_for(targets[i]));
      write_temp(temps.back(), files[i].second);
    }
  } catch (...) {
    remove_all_temps();
    throw;
  }
  // Every new file is on disk. Keep the old ones (hard links) until all renames succeed, so a
  // failure in the middle restores the earlier set: both or neither change.
  std::vector<fs::path> backups(files.size());
  for (std::size_t i = 0; i < files.size(); ++i) {
    if (!fs::exists(targets[i], ec)) continue;
    backups[i] = targets[i].string() + ".bak." + writer_tag();
    fs::remove(backups[i], ec);
    fs::create_hard_link(targets[i], backups[i], ec);
    if (ec) backups[i].clear();  // e.g. a file system without hard links: no rollback for this one
  }
  for (std::size_t i = 0; i < files.size(); ++i) {
    if (::rename(temps[i].c_str(), targets[i].c_str()) != 0) {
      const std::string why = std::strerror(errno);
      for (std::size_t j = 0; j < i; ++j) {
        if (!backups[j].empty()) fs::rename(backups[j], targets[j], ec);
        else fs::remove(targets[j], ec);
      }
      remove_all_temps();
      for (const auto& b : backups)
        if (!b.empty()) fs::remove(b, ec);
      throw std::runtime_error("cannot rename " + temps[i].string() + " into " + targets[i].string() + ": " + why);
    }
  }
  for (const auto& b : backups)
    if (!b.empty()) fs::remove(b, ec);
}

void remove_stale_temporaries(const std::string& dir, bool recursive) {
  std::error_code ec;
  if (!fs::is_directory(dir, ec)) return;
  std::vector<fs::path> entries;
  if (recursive) {
    for (auto it = fs::recursive_directory_iterator(dir, ec); !ec && it != fs::recursive_directory_iterator(); it.increment(ec))
      entries.push_back(it->path());
  } else {
    for (const auto& e : fs::directory_iterator(dir, ec)) entries.push_back(e.path());
  }
  for (const auto& path : entries) {
    const fs::directory_entry e(path, ec);
    const std::string name = e.path().filename().string();
    for (const char* tag : {".tmp.", ".bak."}) {
      const auto at = name.rfind(tag);
      if (at == std::string::npos) continue;
      // "<pid>" (older writers) or "<pid>-<serial>".
      std::string pid = name.substr(at + 5);
      if (const auto dash = pid.find('-'); dash != std::string::npos) {
        const std::string serial = pid.substr(dash + 1);
        if (serial.empty() || serial.find_first_not_of("0123456789") != std::string::npos) continue;
        pid.resize(dash);
      }
      if (pid.empty() || pid.size() > 10 || pid.find_first_not_of("0123456789") != std::string::npos) continue;
      const long p = std::strtol(pid.c_str(), nullptr, 10);
      // A temporary of a process that is gone (killed mid-write) is debris; a live writer's is not.
      if (p != ::getpid() && ::kill(static_cast<pid_t>(p), 0) != 0 && errno == ESRCH) {
        if (std::string(tag) == ".bak.") {
          // An interrupted pair write: the backup is the earlier file; put it back if the target is gone.
          const fs::path target = e.path().parent_path() / name.substr(0, at);
          if (!fs::exists(target, ec)) fs::rename(e.path(), target, ec);
          else fs::remove(e.path(), ec);
        } else {
          fs::remove(e.path(), ec);
        }
      }
    }
  }
}

std::string read_file(const std::string& path, const std::string& what) {
  std::error_code ec;
  const auto st = fs::status(path, ec);
  if (!ec && fs::exists(st) && !fs::is_regular_file(st))
    throw InputError(what + " '" + path + "' is " + kind_of(st) + ": allowed a regular file");
  std::ifstream in(path, std::ios::binary);
  if (!in) throw InputError(what + " '" + path + "' cannot be read: " + std::strerror(errno));
  std::ostringstream ss;
  ss << in.rdbuf();
  if (in.bad()) throw InputError(what + " '" + path + "' cannot be read: " + std::strerror(errno));
  return ss.str();
}

std::string format_double(double x) {
  if (std::isnan(x)) return "nan";
  if (std::isinf(x)) return x > 0 ? "inf" : "-inf";
  char buf[64];
  for (int prec = 6; prec <= 17; ++prec) {
    std::snprintf(buf, sizeof buf, "%.*g", prec, x);
    if (std::strtod(buf, nullptr) == x) break;
  }
  return buf;
}

}  // namespace skyloop
