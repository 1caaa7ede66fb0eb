#pragma once
// Child processes and interruption. skyloop's long jobs (reproduce's parallel MARL runs, the plot
// step) run children that must never outlive their parent or ignore its interruption:
//  * install_interrupt_handlers(): SIGINT, SIGTERM and SIGHUP stop every running child (SIGTERM),
//    print one line "skyloop: interrupted by SIGINT: ..." and end the process with that signal
//    (exit status 128 + signal), so Ctrl-C or `kill PID` stops the whole job at once. What was
//    finished is on disk (every output is written atomically) and a rerun resumes from it.
//  * run_process(): fork + exec with its own wait, never std::system (which ignores SIGINT and
//    SIGQUIT in the parent while the child runs); the child gets PR_SET_PDEATHSIG, so it is
//    stopped even when the parent is killed with SIGKILL.
#include <string>
#include <vector>

namespace skyloop {

/// This machine as the benchmark rows name it (the words of scripts/bench_report.py): its hardware
/// threads, the CPU's model name and its widest vector extension, e.g. "2-core AMD EPYC (AVX2)".
/// It goes beside a long run's time in the records that state it (bench baselines' trainings.csv).
std::string machine_label();

/// Installs the handlers described above (idempotent). The CLI calls it first thing.
void install_interrupt_handlers();

/// What the interruption line says after "interrupted by SIGINT: " (a string that lives as long as
/// the process): each command names how it continues, e.g. "... rerun the same command with
/// --resume to continue" for the train commands, whose rerun without --resume is refused.
void set_interrupt_hint(const char* hint);

/// Runs argv[0] (a path, or a name looked up in PATH) with `argv`; stdout and stderr go to `log_path` (truncated), or are
/// inherited when it is empty. Blocks until the child ends and returns its exit status, or 128 +
/// the signal that ended it; 127 when the program could not be started, said in one line of the
/// log ("skyloop: cannot start PROGRAM (exec failed, errno N)"). Throws std::runtime_error if the process cannot be started. Safe to
/// call from several threads at once.
int run_process(const std::vector<std::string>& argv, const std::string& log_path = "");

/// The running program's own path (/proc/self/exe): what a command runs to start a child of itself.
/// When the file was replaced (a rebuild) or removed since the program started, "/proc/self/exe"
/// itself, which still execs the running program: a child never runs another build.
std::string self_path();

}  // namespace skyloop
