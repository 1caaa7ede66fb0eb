#include "piece_cache.hpp"

#include <cerrno>
#include <cstring>
#include <fcntl.h>
#include <fmt/format.h>
#include <ostream>
#include <stdexcept>
#include <sys/file.h>
#include <unistd.h>

#include "skyloop/core/config_io.hpp"
#include "skyloop/core/rng.hpp"

namespace skyloop::repro {

namespace fs = std::filesystem;

std::string hex(std::uint64_t h) { return fmt::format("{:016x}", h); }
std::uint64_t hash_text(const std::string& s, std::uint64_t h) { return hash_bytes(s.data(), s.size(), h); }

std::string config_key(Config c) {
  c.run.threads = 0;
  return to_toml(c);
}

std::string training_key(Config c) {
  const Config d;
  c.env = d.env;
  c.marl = d.marl;
  c.ga = d.ga;
  c.wmmse = d.wmmse;
  c.trajectory = d.trajectory;
  c.nn.device = d.nn.device;
  c.nn.precision = d.nn.precision;  // serving only
  return config_key(c);
}

namespace {
/// flock() held for the lifetime of the object.
class FileLock {
 public:
  FileLock(const fs::path& path, const std::string& id, std::ostream* log) {
    std::error_code ec;
    fs::create_directories(path.parent_path(), ec);
    fd_ = ::open(path.c_str(), O_RDWR | O_CREAT | O_CLOEXEC, 0644);
    if (fd_ < 0) throw std::runtime_error(fmt::format("cannot open the lock file {}: {}", path.string(), std::strerror(errno)));
    if (::flock(fd_, LOCK_EX | LOCK_NB) == 0) return;
    if (log) *log << fmt::format("  waiting for {} (another process is computing it)\n", id) << std::flush;
    while (::flock(fd_, LOCK_EX) != 0)
      if (errno != EINTR) {
        ::close(fd_);
        throw std::runtime_error(fmt::format("cannot lock {}: {}", path.string(), std::strerror(errno)));
      }
  }
  ~FileLock() { ::close(fd_); }  // closing releases the lock
  FileLock(const FileLock&) = delete;
  FileLock& operator=(const FileLock&) = delete;

 private:
  int fd_ = -1;
};
}  // namespace

bool PieceCache::ensure(const std::string& id, const std::function<bool()>& done, const std::function<void()>& compute,
                        std::ostream* log) const {
  if (done()) return false;
  FileLock lock(root_ / "locks" / (hex(hash_text(id)) + ".lock"), id, log);
  if (done()) return false;
  compute();
  return true;
}

}  // namespace skyloop::repro
