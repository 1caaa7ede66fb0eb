#include "skyloop/core/paths.hpp"

#include <cstdlib>
#include <mutex>

namespace skyloop {

namespace {
std::mutex g_mutex;
std::string g_override;
}  // namespace

std::string data_dir() {
  std::lock_guard<std::mutex> lock(g_mutex);
  if (!g_override.empty()) return g_override;
  if (const char* env = std::getenv("SKYLOOP_DATA_DIR"); env && *env) return env;
  return SKYLOOP_SOURCE_DIR;
}

void set_data_dir(const std::string& dir) {
  std::lock_guard<std::mutex> lock(g_mutex);
  g_override = dir;
}

}  // namespace skyloop
