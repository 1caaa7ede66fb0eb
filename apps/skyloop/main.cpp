// skyloop: joint beamforming and trajectory optimisation for multi-UAV downlink networks.
// Exit codes: 0 success, 2 bad input (one line on stderr), 1 runtime failure.
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <iostream>
#include <unistd.h>

#include "common.hpp"
#include "skyloop/core/error.hpp"
#include "skyloop/core/parallel.hpp"
#include "skyloop/core/process.hpp"

namespace skyloop::cli {

Config ConfigOptions::resolve(const std::vector<std::string>& extra) const {
  std::vector<std::string> all = sets;
  all.insert(all.end(), extra.begin(), extra.end());
  return resolve_config(path.empty() ? std::nullopt : std::optional<std::string>(path), all);
}

void add_config_options(CLI::App* cmd, ConfigOptions& o) {
  cmd->add_option("--config", o.path, "TOML configuration file (defaults: the paper's Section VI values)");
  cmd->add_option("--set", o.sets, "override one field, e.g. --set channel.p_max_dbm=40 (repeatable)")
      ->type_name("KEY=VALUE");
}

int on_every_rank(Transport* transport, const std::function<int()>& body) {
  const int rank = transport ? transport->rank() : 0;
  try {
    return body();
  } catch (const InputError&) {
    if (rank != 0) return 2;
    throw;
  } catch (const std::exception& e) {
    if (!transport || transport->size() == 1) throw;
    std::cerr << "skyloop: failed on rank " << rank << ": " << e.what() << "\n" << std::flush;
    transport->abort(1);
    return 1;  // abort() does not return
  }
}

#ifdef SKYLOOP_FRONT_END
namespace {
char** g_argv = nullptr;
}  // namespace

void continue_with_libtorch_if(bool needed) {
  if (!needed) return;
  std::cout.flush();
  std::cerr.flush();
  std::fflush(nullptr);
  namespace fs = std::filesystem;
  std::error_code ec;
  const fs::path self = fs::read_symlink("/proc/self/exe", ec);  // the real file, through any symlink
  const fs::path full = (ec ? fs::path(g_argv[0]) : self).parent_path() / SKYLOOP_LIBTORCH_BUILD;
  ::execv(full.c_str(), g_argv);
  throw std::runtime_error("cannot start " + full.string() + " (the LibTorch build, installed beside skyloop): " +
                           std::strerror(errno));
}
#else
void continue_with_libtorch_if(bool) {}
#endif

/// The first word that names no subcommand where one is required: "unknown command 'x': allowed
/// a, b, c" (CLI11 alone says only that a subcommand is required). Empty if the words are fine.
std::string unknown_command(CLI::App& app, int argc, char** argv) {
  CLI::App* at = &app;
  for (int i = 1; i < argc; ++i) {
    const std::string word = argv[i];
    if (word.empty() || word[0] == '-') return {};
    const auto subs = at->get_subcommands([](CLI::App*) { return true; });
    if (subs.empty()) return {};
    CLI::App* next = nullptr;
    std::string names;
    for (auto* s : subs) {
      names += (names.empty() ? "" : ", ") + s->get_name();
      if (s->get_name() == word) next = s;
    }
    if (!next) return "unknown command '" + word + "'" + (at == &app ? "" : " for '" + at->get_name() + "'") + ": allowed " + names;
    at = next;
  }
  return {};
}

/// Every option that takes a value refuses an empty one ("--seed ''" is a mistake, not "use the
/// default"), on every subcommand.
void refuse_empty_values(CLI::App* app) {
  for (CLI::Option* o : app->get_options([](const CLI::Option*) { return true; })) {
    if (o->get_type_size_max() == 0) continue;  // a flag
    o->check(CLI::Validator(
        [](std::string& v) { return v.find_first_not_of(" \t") == std::string::npos ? std::string("an empty value is not allowed") : std::string(); },
        ""));
  }
  for (CLI::App* s : app->get_subcommands([](CLI::App*) { return true; })) refuse_empty_values(s);
}

}  // namespace skyloop::cli

int main(int argc, char** argv) {
  using namespace skyloop;
  flush_denormals();  // before any thread starts: every thread computes in the same mode
  install_interrupt_handlers();
  CLI::App app{"skyloop: joint beamforming and trajectory optimisation for multi-UAV downlink networks"};
  app.set_version_flag("--version", std::string("skyloop ") + SKYLOOP_VERSION + (mpi_available() ? " (MPI)" : " (no MPI)"));
  app.require_subcommand(1);
  cli::Action action;
  cli::add_beamform_command(app, action);
  cli::add_snapshot_command(app, action);
  cli::add_config_command(app, action);
  cli::add_plan_command(app, action);
#ifdef SKYLOOP_HAS_TORCH
  cli::add_marl_commands(app, action);
  cli::add_reproduce_command(app, action);
  cli::add_bench_command(app, action);
#endif
  cli::refuse_empty_values(&app);
#ifdef SKYLOOP_FRONT_END
  // Help (whose texts list what the LibTorch build adds), no command, and a command this front end
  // does not hold (train, eval, reproduce, beamform train; and unknown words, which the LibTorch
  // build refuses with the whole list) go to the LibTorch build as they are.
  cli::g_argv = argv;
  bool hand_over = argc < 2 || !cli::unknown_command(app, argc, argv).empty();
  for (int i = 1; i < argc && !hand_over; ++i) hand_over = !std::strcmp(argv[i], "--help") || !std::strcmp(argv[i], "-h");
  try {
    cli::continue_with_libtorch_if(hand_over);
  } catch (const std::exception& e) {
    std::cerr << "skyloop: failed: " << e.what() << "\n";
    return 1;
  }
#endif
  if (const std::string bad = cli::unknown_command(app, argc, argv); !bad.empty()) {
    std::cerr << "skyloop: error: " << bad << "\n";
    return 2;
  }
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    if (e.get_exit_code() == 0) return app.exit(e);  // --help, --version
    std::cerr << "skyloop: error: " << e.what() << "\n";
    return 2;
  }
  try {
    const int rc = action ? action() : 0;
    // A full disk or a closed pipe on stdout is a failure, not a silent success.
    std::cout.flush();
    if (!std::cout || std::fflush(stdout) != 0 || std::ferror(stdout))
      throw std::runtime_error(std::string("cannot write to standard output: ") + std::strerror(errno ? errno : EIO));
    return rc;
  } catch (const InputError& e) {
    std::cerr << "skyloop: error: " << e.what() << "\n";
    return 2;
  } catch (const std::exception& e) {
    std::cerr << "skyloop: failed: " << e.what() << "\n";
    return 1;
  }
}
