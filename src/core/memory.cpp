#include "skyloop/core/memory.hpp"

#include <sys/resource.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <string>

#include "skyloop/core/error.hpp"

namespace skyloop {

namespace {

/// A cgroup limit file's value in bytes; 0 for "max", a missing file or an unreadable one.
double cgroup_limit(const char* path) {
  std::ifstream in(path);
  std::string text;
  if (!(in >> text) || text == "max") return 0.0;
  try {
    const double v = std::stod(text);
    return v > 0 && v < 1e18 ? v : 0.0;  // v1 writes "no limit" as about 2^63
  } catch (...) {
    return 0.0;
  }
}

double read_memory_limit() {
  double limit = 0.0;
  auto take = [&](double v) {
    if (v > 0) limit = limit > 0 ? std::min(limit, v) : v;
  };
  const long pages = sysconf(_SC_PHYS_PAGES), page = sysconf(_SC_PAGE_SIZE);
  if (pages > 0 && page > 0) take(static_cast<double>(pages) * static_cast<double>(page));
  take(cgroup_limit("/sys/fs/cgroup/memory.max"));
  take(cgroup_limit("/sys/fs/cgroup/memory/memory.limit_in_bytes"));
  rlimit as{};
  if (getrlimit(RLIMIT_AS, &as) == 0 && as.rlim_cur != RLIM_INFINITY) take(static_cast<double>(as.rlim_cur));
  return limit;
}

}  // namespace

double memory_limit_bytes() {
  static const double limit = read_memory_limit();  // read once: callers may sit on hot paths
  return limit;
}

std::string format_bytes(double bytes) {
  char buf[64];
  if (bytes >= 1024.0 * 1024.0 * 1024.0) std::snprintf(buf, sizeof buf, "%.1f GiB", bytes / (1024.0 * 1024.0 * 1024.0));
  else std::snprintf(buf, sizeof buf, "%.1f MiB", bytes / (1024.0 * 1024.0));
  return buf;
}

void require_memory(double bytes, const std::string& what, const std::string& allowed) {
  const double limit = memory_limit_bytes();
  if (limit <= 0 || !(bytes > limit)) return;
  throw InputError(what + " needs " + format_bytes(bytes) + ", more than the " + format_bytes(limit) +
                   " of memory this process may use: " + allowed);
}

}  // namespace skyloop
