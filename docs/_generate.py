"""Writes the generated pages of the documentation from the program itself, never by hand:

- reference/config.md: every configuration field (`skyloop config fields --json`: the one table,
  src/core/config_fields.cpp), grouped by section, with its type, default, allowed values and meaning;
- reference/cli.md: every command and option (each command's own `--help`, from the CLI's
  definitions), found by walking the subcommands;
- reference/cpp.md: one section per public header under include/skyloop (breathe, over the XML
  that doxygen writes here into <build>/docs/doxygen);
- benchmarks/index.md: today's figure per area, from bench/results/*.csv (scripts/bench-report).
- benchmarks/leaderboard.md (and its profile plots): the benchmark's baselines, from bench/leaderboard/ (scripts/bench_leaderboard.py).

Run by docs/conf.py when Sphinx starts; `python3 docs/_generate.py [build dir]` runs it alone.
The generated files are not committed (.gitignore); python/tests/test_docs.py checks that every
field and command that exists appears in them."""
import json
import os
import re
import subprocess
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
GENERATED = ["reference/config.md", "reference/cli.md", "reference/cpp.md", "benchmarks/index.md", "benchmarks/leaderboard.md"]


def _bin(build):
    return os.environ.get("SKYLOOP_BIN", os.path.join(build, "skyloop"))


def _write(rel, text):
    path = os.path.join(HERE, rel)
    os.makedirs(os.path.dirname(path), exist_ok=True)
    old = open(path).read() if os.path.exists(path) else None
    if old != text:  # unchanged pages keep their mtime (Sphinx rebuilds only what changed)
        with open(path, "w") as f:
            f.write(text)


def _cell(s):
    return str(s).replace("|", "\\|").replace("\n", " ")


def config_fields(build):
    out = subprocess.run([_bin(build), "config", "fields", "--json"], check=True, capture_output=True, text=True).stdout
    return json.loads(out)


def config_page(build):
    fields = config_fields(build)
    text = ["# Configuration fields", "",
            "Every field of a skyloop configuration, generated from the one table that loading, `--set`,",
            "validation and printing all read (`src/core/config_fields.cpp`). A configuration file is TOML with",
            "these sections; `--set section.name=value` overrides one field on any command;",
            "`skyloop config show` prints a resolved configuration, which is itself a valid file, and",
            "`skyloop config fields` prints this table. `configs/paper.toml` holds the paper's Section VI",
            "values, which are also the defaults below.", ""]
    section = None
    for f in fields:
        sec = f["key"].split(".")[0]
        if sec != section:
            section = sec
            text += ["", f"## [{sec}]", "", "| field | type | default | allowed | meaning |", "|---|---|---|---|---|"]
        text.append(f"| `{f['key']}` | {f['type']} | `{_cell(f['default'])}` | {_cell(f['allowed'])} | {_cell(f['help'])} |")
    return "\n".join(text) + "\n"


_SUB = re.compile(r"^  (\S+)\s{2,}(.*)$")


def cli_commands(build, path=()):
    """[(path tuple, help text)] for the program and every subcommand, depth first."""
    r = subprocess.run([_bin(build), *path, "--help"], capture_output=True, text=True)
    help_text = r.stdout.replace(_bin(build), "skyloop")
    out = [(path, help_text)]
    lines = help_text.splitlines()
    if "Subcommands:" in lines:
        for line in lines[lines.index("Subcommands:") + 1:]:
            m = _SUB.match(line)
            if not m:
                if line.strip():
                    break
                continue
            out += cli_commands(build, path + (m.group(1),))
    return out


def cli_page(build):
    text = ["# Command line", "",
            "Every command and option of `skyloop`, generated from each command's own `--help` (the CLI's",
            "definitions in `apps/skyloop/`). Options that set a configuration field say which",
            "(`sets scenario.users`); `--config F` and `--set key=value` reach every field",
            "([configuration fields](config.md)). A bad input prints one line naming the field, the",
            "value and what is allowed, and exits with code 2.", ""]
    for path, help_text in cli_commands(build):
        title = " ".join(("skyloop",) + path)
        text += [f"## `{title}`", "", "```text", help_text.rstrip(), "```", ""]
    return "\n".join(text)


def headers():
    inc = os.path.join(ROOT, "include")
    out = []
    for d, _, files in sorted(os.walk(inc)):
        for f in sorted(files):
            if f.endswith(".hpp"):
                out.append(os.path.relpath(os.path.join(d, f), inc))
    return out


def areas():
    """The header directories under include/skyloop (one doxygen project each: a header's name is
    unique within its area, which breathe's doxygenfile needs; beamforming/ and planning/ both
    have a registry.hpp)."""
    inc = os.path.join(ROOT, "include", "skyloop")
    return sorted(d for d in os.listdir(inc) if os.path.isdir(os.path.join(inc, d)))


def run_doxygen(build):
    for area in areas():
        out = os.path.join(build, "docs", "doxygen", area)
        os.makedirs(out, exist_ok=True)
        src = os.path.join(ROOT, "include", "skyloop", area)
        conf = "\n".join([
            f"PROJECT_NAME = skyloop-{area}", f"OUTPUT_DIRECTORY = {out}", f"INPUT = {src}",
            "FILE_PATTERNS = *.hpp", "GENERATE_XML = YES", "GENERATE_HTML = NO", "GENERATE_LATEX = NO",
            f"STRIP_FROM_PATH = {os.path.join(ROOT, 'include')}", f"STRIP_FROM_INC_PATH = {os.path.join(ROOT, 'include')}",
            "EXTRACT_ALL = YES", "JAVADOC_AUTOBRIEF = YES", "QUIET = YES", "WARNINGS = NO", "WARN_IF_UNDOCUMENTED = NO",
            "ENABLE_PREPROCESSING = YES", "MACRO_EXPANSION = YES", "PREDEFINED = SKYLOOP_HAS_TORCH=1", ""])
        subprocess.run(["doxygen", "-"], input=conf, text=True, check=True, capture_output=True)


def cpp_page():
    text = ["# C++ headers", "",
            "The public headers under `include/skyloop/`, one section each, generated by doxygen and",
            "breathe from the headers' own comments. Link against the CMake targets (`skyloop_core`,",
            "`skyloop_env`, `skyloop_experiments`, ...) and include `skyloop/<area>/<header>.hpp`; the",
            "[extending pages](../extending/index.md) show each extension point at work.", ""]
    for area in areas():
        text += [f"## `skyloop/{area}`", ""]
        for h in headers():
            if h.startswith(f"skyloop/{area}/"):
                text += [f"### `{h}`", "", "```{eval-rst}", f".. doxygenfile:: {os.path.basename(h)}",
                         f"   :project: skyloop-{area}", "```", ""]
    return "\n".join(text)


def main(build=None, doxygen=True):
    """Writes every generated page; doxygen's XML (what breathe renders the C++ page from) only
    with `doxygen` (the site's build; the link check reads the pages alone)."""
    build = build or os.path.join(ROOT, "build")
    _write("reference/config.md", config_page(build))
    _write("reference/cli.md", cli_page(build))
    if doxygen:
        run_doxygen(build)
    _write("reference/cpp.md", cpp_page())
    sys.path.insert(0, os.path.join(ROOT, "scripts"))
    import bench_report
    _write("benchmarks/index.md", bench_report.page())
    import bench_leaderboard
    _write("benchmarks/leaderboard.md", bench_leaderboard.page(plots=os.path.join(ROOT, "docs", "benchmarks", "leaderboard")))


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else None)
