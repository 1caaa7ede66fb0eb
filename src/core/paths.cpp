#include "skyloop/core/paths.hpp"

#include <cstdlib>
#include <filesystem>
#include <mutex>

namespace skyloop {

namespace {
std::mutex g_mutex;
std::string g_override;

/// <prefix>/share/skyloop when this process is an installed `skyloop` or `skyloop-torch`
/// (`cmake --install`: <prefix>/bin beside it) and the directory holds the shipped models; else "".
std::string installed_data_dir() {
  namespace fs = std::filesystem;
  std::error_code ec;
  const fs::path exe = fs::read_symlink("/proc/self/exe", ec);
  if (ec || exe.filename().string().rfind("skyloop", 0) != 0) return "";
  const fs::path root = (exe.parent_path() / SKYLOOP_INSTALL_DATA_FROM_BIN).lexically_normal();
  return fs::is_directory(root / "models", ec) ? root.string() : "";
}
}  // namespace

std::string data_dir() {
  std::lock_guard<std::mutex> lock(g_mutex);
  if (!g_override.empty()) return g_override;
  if (const char* env = std::getenv("SKYLOOP_DATA_DIR"); env && *env) return env;
  static const std::string installed = installed_data_dir();
  if (!installed.empty()) return installed;
  return SKYLOOP_SOURCE_DIR;
}

void set_data_dir(const std::string& dir) {
  std::lock_guard<std::mutex> lock(g_mutex);
  g_override = dir;
}

}  // namespace skyloop
