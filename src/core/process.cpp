#include "skyloop/core/process.hpp"

#include <array>
#include <atomic>
#include <cerrno>
#include <csignal>
#include <cstring>
#include <fcntl.h>
#include <filesystem>
#include <fstream>
#include <stdexcept>
#include <string>
#include <thread>
#include <sys/prctl.h>
#include <sys/wait.h>
#include <unistd.h>

namespace skyloop {

std::string machine_label() {
  std::string model = "x86-64", flags;
  std::ifstream info("/proc/cpuinfo");
  for (std::string line; std::getline(info, line);) {
    const auto colon = line.find(':');
    if (colon == std::string::npos) continue;
    const auto start = line.find_first_not_of(" \t", colon + 1);
    const std::string value = start == std::string::npos ? "" : line.substr(start);
    if (line.rfind("model name", 0) == 0 && model == "x86-64") model = value;
    if (line.rfind("flags", 0) == 0 && flags.empty()) flags = " " + value + " ";
  }
  if (flags.find(" avx512f ") != std::string::npos) model += " (AVX-512)";
  else if (flags.find(" avx2 ") != std::string::npos) model += " (AVX2)";
  const unsigned hw = std::thread::hardware_concurrency();
  return std::to_string(hw == 0 ? 1u : hw) + "-core " + model;
}

namespace {

// What the interruption line tells the user to do next (set_interrupt_hint); a static string.
std::atomic<const char*> g_hint{"stopped; every file written is whole; rerun the same command to run it again"};

// Children being waited on; read by the signal handler, so lock-free slots instead of a container.
std::array<std::atomic<pid_t>, 256> g_children{};

void track(pid_t pid) {
  for (auto& slot : g_children) {
    pid_t empty = 0;
    if (slot.compare_exchange_strong(empty, pid)) return;
  }
}

void untrack(pid_t pid) {
  for (auto& slot : g_children) {
    pid_t mine = pid;
    if (slot.compare_exchange_strong(mine, 0)) return;
  }
}

void write_all(const char* s) {
  std::size_t n = std::strlen(s);
  while (n > 0) {
    const ssize_t w = ::write(STDERR_FILENO, s, n);
    if (w <= 0) return;
    s += w;
    n -= static_cast<std::size_t>(w);
  }
}

extern "C" void on_interrupt(int sig) {
  // Async-signal-safe only: kill, write, signal, raise.
  for (auto& slot : g_children) {
    const pid_t pid = slot.load();
    if (pid > 0) ::kill(pid, SIGTERM);
  }
  const char* name = sig == SIGINT ? "SIGINT" : sig == SIGTERM ? "SIGTERM" : "SIGHUP";
  write_all("skyloop: interrupted by ");
  write_all(name);
  write_all(": ");
  write_all(g_hint.load());
  write_all("\n");
  ::signal(sig, SIG_DFL);
  ::raise(sig);
}

}  // namespace

void set_interrupt_hint(const char* hint) { g_hint.store(hint); }

void install_interrupt_handlers() {
  for (int sig : {SIGINT, SIGTERM, SIGHUP}) {
    struct sigaction sa {};
    sa.sa_handler = on_interrupt;
    sigemptyset(&sa.sa_mask);
    sa.sa_flags = 0;
    ::sigaction(sig, &sa, nullptr);
  }
}

int run_process(const std::vector<std::string>& argv, const std::string& log_path) {
  if (argv.empty()) throw std::runtime_error("run_process: no program");
  std::vector<char*> args;
  for (const auto& a : argv) args.push_back(const_cast<char*>(a.c_str()));
  args.push_back(nullptr);
  const std::string exec_failed = "skyloop: cannot start " + argv[0] + " (exec failed, ";
  const pid_t parent = ::getpid();
  const pid_t pid = ::fork();
  if (pid < 0) throw std::runtime_error("cannot start " + argv[0] + ": " + std::strerror(errno));
  if (pid == 0) {
    // In the child: only async-signal-safe calls until exec.
    ::prctl(PR_SET_PDEATHSIG, SIGTERM);
    if (::getppid() != parent) ::_exit(127);  // the parent is already gone
    struct sigaction dfl {};
    dfl.sa_handler = SIG_DFL;
    for (int sig : {SIGINT, SIGTERM, SIGHUP}) ::sigaction(sig, &dfl, nullptr);
    if (!log_path.empty()) {
      const int fd = ::open(log_path.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
      if (fd < 0) ::_exit(126);
      ::dup2(fd, STDOUT_FILENO);
      ::dup2(fd, STDERR_FILENO);
    }
    ::execvp(args[0], args.data());
    // Said in the log (or on stderr), so a child that never started is not an empty log: only
    // write() from here, the message composed before the fork.
    const int err = errno;
    char digits[16];
    int n = 0;
    for (int e = err > 0 ? err : 0; n == 0 || e > 0; e /= 10) digits[n++] = static_cast<char>('0' + e % 10);
    char line[24] = "errno ";
    int at = 6;
    while (n > 0) line[at++] = digits[--n];
    line[at++] = ')';
    line[at++] = '\n';
    (void)!::write(STDERR_FILENO, exec_failed.data(), exec_failed.size());
    (void)!::write(STDERR_FILENO, line, static_cast<std::size_t>(at));
    ::_exit(127);
  }
  track(pid);
  int status = 0;
  pid_t r;
  do {
    r = ::waitpid(pid, &status, 0);
  } while (r < 0 && errno == EINTR);
  untrack(pid);
  if (r < 0) throw std::runtime_error("cannot wait for " + argv[0] + ": " + std::strerror(errno));
  if (WIFEXITED(status)) return WEXITSTATUS(status);
  if (WIFSIGNALED(status)) return 128 + WTERMSIG(status);
  return 1;
}

std::string self_path() {
  // Linux marks a running program whose file was since replaced (a rebuild) or removed with
  // " (deleted)"; /proc/self/exe still execs it, so a child runs the very program its parent is,
  // not whatever build now lies at that path (or nothing).
  const std::string path = std::filesystem::read_symlink("/proc/self/exe").string();
  const std::string mark = " (deleted)";
  if (path.size() > mark.size() && path.compare(path.size() - mark.size(), mark.size(), mark) == 0) return "/proc/self/exe";
  return path;
}

}  // namespace skyloop
