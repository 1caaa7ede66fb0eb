#include "piece_cache.hpp"

#include <algorithm>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <fcntl.h>
#include <fmt/format.h>
#include <ostream>
#include <stdexcept>
#include <sys/file.h>
#include <unistd.h>
#include <vector>

#include <nlohmann/json.hpp>

#include "skyloop/core/config_io.hpp"
#include "skyloop/core/io.hpp"
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

namespace {
/// A run directory's lock file: bookkeeping, not a result. A seal neither lists one nor checks one
/// an earlier version listed, so a piece copied without its lock files (a clone, an rsync that
/// leaves them out) still holds.
bool is_run_lock(const fs::path& p) { return p.filename() == RunDirLock::kFile; }

/// Every regular file under `at` (itself, when a file), as paths relative to `at`, sorted; the
/// temporaries of atomic writes (NAME.tmp.PID, NAME.bak.PID) and the run directories' lock files
/// left out.
std::vector<std::string> files_under(const fs::path& at) {
  std::vector<std::string> out;
  std::error_code ec;
  auto keep = [](const fs::path& p) {
    const std::string n = p.filename().string();
    return n.find(".tmp.") == std::string::npos && n.find(".bak.") == std::string::npos && !is_run_lock(p);
  };
  if (fs::is_regular_file(at, ec)) {
    if (keep(at)) out.push_back("");
    return out;
  }
  if (!fs::is_directory(at, ec)) return out;
  for (auto it = fs::recursive_directory_iterator(at, ec); !ec && it != fs::recursive_directory_iterator(); it.increment(ec))
    if (it->is_regular_file(ec) && keep(it->path())) out.push_back(it->path().lexically_relative(at).generic_string());
  std::sort(out.begin(), out.end());
  return out;
}

fs::path seal_path_of(const fs::path& root, const std::string& id) { return root / "seals" / (hex(hash_text(id)) + ".json"); }

/// {"bytes": size, "fnv": hash} of a file, or null when it cannot be read.
nlohmann::json file_stamp(const fs::path& p) {
  std::error_code ec;
  if (!fs::is_regular_file(p, ec)) return nullptr;
  std::FILE* f = std::fopen(p.c_str(), "rb");
  if (!f) return nullptr;
  std::uint64_t h = 0xcbf29ce484222325ULL, bytes = 0;
  char buf[1 << 16];
  for (std::size_t n; (n = std::fread(buf, 1, sizeof buf, f)) > 0;) h = hash_bytes(buf, n, h), bytes += n;
  std::fclose(f);
  return {{"bytes", bytes}, {"fnv", hex(h)}};
}
}  // namespace

bool PieceCache::sealed(const std::string& id) const {
  const fs::path seal_path = seal_path_of(root_, id);
  std::error_code ec;
  if (!fs::exists(seal_path, ec)) return false;
  nlohmann::json j;
  try {
    j = nlohmann::json::parse(read_file(seal_path.string(), "seal"));
    if (j.value("id", std::string()) != id || !j.contains("files") || !j.at("files").is_object()) return false;
    const fs::path at = root_ / id;
    for (const auto& [rel, stamp] : j.at("files").items())
      if (!is_run_lock(rel) && file_stamp(rel.empty() ? at : at / rel) != stamp) return false;
  } catch (const std::exception&) {
    return false;  // an unreadable seal: the piece is computed again
  }
  return true;
}

void PieceCache::seal(const std::string& id) const {
  const fs::path at = root_ / id;
  nlohmann::json files = nlohmann::json::object();
  for (const auto& rel : files_under(at)) files[rel] = file_stamp(rel.empty() ? at : at / rel);
  const nlohmann::json j = {{"id", id}, {"files", files}};
  write_file_atomic(seal_path_of(root_, id).string(), j.dump(1) + "\n");
}

bool PieceCache::ensure(const std::string& id, const std::function<bool()>& done, const std::function<void()>& compute,
                        std::ostream* log) const {
  if (done() && sealed(id)) return false;
  FileLock lock(root_ / "locks" / (hex(hash_text(id)) + ".lock"), id, log);
  const bool finished = done();
  std::error_code ec;
  const bool has_seal = fs::exists(seal_path_of(root_, id), ec), holds = has_seal && sealed(id);
  if (finished && holds) return false;
  // None of what is on disk is reused when its seal no longer holds (a file truncated or edited
  // since it was computed), or when a finished piece has none (written by another version). A
  // piece whose seal holds but which has more to do (a MARL run trained, not yet evaluated) keeps
  // what it has.
  if (has_seal ? !holds : finished) {
    if (has_seal && log) *log << fmt::format("  {} changed on disk since it was computed: computing it again\n", id) << std::flush;
    fs::remove_all(root_ / id, ec);
  }
  compute();
  seal(id);
  return true;
}

}  // namespace skyloop::repro
