"""The benchmark page: today's figure per area, from data, never by hand.

bench/results/current.csv holds one row per measured quantity: area, quantity, value, unit, runs,
statistic, date, machine, command, and how the figure is read, which every row names once:

- `gbench`: the Google Benchmark it comes from (`binary:name`). `scripts/bench --record FILTER`
  runs the suite and refreshes these rows from the CSVs that run wrote (results/bench/<binary>.csv).
- `reads`: for a figure a command prints (a training run, a planner, a Python benchmark), a regular
  expression whose first group, searched in the command's output (stdout and stderr, line by
  line), is the figure in the row's unit; `wall` reads the command's wall time in seconds.
  `scripts/bench --measure [--runs N] [PATTERN]` runs the command of every row whose quantity
  matches PATTERN N times (3 unless given), from the repository's root with build/ first on PATH
  and $DIR a fresh empty directory, and records the median.

Either way the row gets today's date and this machine. No figure is typed in by hand; history lives
in git.

  python3 scripts/bench_report.py                        prints the page (docs/_generate.py writes it)
  python3 scripts/bench_report.py --record               refreshes the gbench rows from results/bench/*.csv
  python3 scripts/bench_report.py --measure [--runs N] [PATTERN]   measures the command rows
"""
import csv
import datetime
import io
import os
import platform
import re
import shutil
import statistics
import subprocess
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
CURRENT = os.path.join(ROOT, "bench", "results", "current.csv")
COLUMNS = ["area", "quantity", "value", "unit", "runs", "statistic", "date", "machine", "command", "gbench", "reads"]
_SCALE = {"ns": 1e-9, "us": 1e-6, "ms": 1e-3, "s": 1.0}


def rows():
    with open(CURRENT, newline="") as f:
        out = list(csv.DictReader(f))
    seen = {}
    for i, r in enumerate(out, start=2):
        if list(r) != COLUMNS:
            raise SystemExit(f"bench_report: {CURRENT} has columns {list(r)}: allowed {COLUMNS}")
        if r["quantity"] in seen:
            raise SystemExit(f"bench_report: {CURRENT}:{i} ({r['quantity']}): the same quantity as line {seen[r['quantity']]}: "
                             "allowed one row per quantity (today's figure)")
        seen[r["quantity"]] = i
        if bool(r["gbench"]) == bool(r["reads"]):
            raise SystemExit(f"bench_report: {CURRENT}:{i} ({r['quantity']}): gbench = {r['gbench']!r}, reads = "
                             f"{r['reads']!r}: allowed exactly one of the two (how the figure is measured)")
        if r["reads"] and r["reads"] != "wall":
            try:
                groups = re.compile(r["reads"]).groups
            except re.error:
                groups = 0
            if groups < 1:
                raise SystemExit(f"bench_report: {CURRENT}:{i} ({r['quantity']}): reads = {r['reads']!r}: allowed "
                                 "`wall` or a regular expression with a group (the figure)")
    return out


def _fmt(v):
    x = float(v)
    if x >= 1e4:
        return f"{x:,.0f}"
    return f"{x:g}"


def page():
    data = rows()
    text = ["# Benchmarks", "",
            "Today's figure for each area: the latest measurement of each quantity, with its command, the",
            "number of runs its statistic is taken over, the date and the machine. The page is made from",
            "`bench/results/current.csv` by `scripts/bench_report.py`, and every figure in that file is written",
            "by a script on the machine it names: `scripts/bench --record FILTER` for the Google Benchmark",
            "rows, `scripts/bench --measure PATTERN` for the rows whose command prints its figure (it runs",
            "the command three times and keeps the median). Earlier figures are in the file's git history.", "",
            "Every machine here is a 2-core x86-64 VM (Debian bookworm, g++ 12 `-O3`, LibTorch 1.13 CPU",
            "with OpenBLAS); they differ in their CPU and its vector units, and drift 10-25% from hour to",
            "hour, so compare figures taken in one run (the ratios) before figures taken on different days.", ""]
    areas = []
    for r in data:
        if r["area"] not in areas:
            areas.append(r["area"])
    for area in areas:
        text += [f"## {area}", "", "| quantity | figure | statistic | date | machine | command |", "|---|---:|---|---|---|---|"]
        for r in (r for r in data if r["area"] == area):
            runs = int(r["runs"])
            stat = f"{r['statistic']} ({runs})"
            cmd = r["command"].replace("|", "\\|")
            text.append(f"| {r['quantity']} | **{_fmt(r['value'])}** {r['unit']} | {stat} | {r['date']} | {r['machine']} | `{cmd}` |")
        text.append("")
    return "\n".join(text)


def _machine():
    model = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as f:
            info = f.read()
        model = next(l.split(":", 1)[1].strip() for l in info.splitlines() if l.startswith("model name"))
        flags = next(l for l in info.splitlines() if l.startswith("flags"))
        model += " (AVX-512)" if "avx512f" in flags else " (AVX2)" if "avx2" in flags else ""
    except (OSError, StopIteration):
        pass
    return f"{os.cpu_count()}-core {model}"


def record(reps, binaries, root=ROOT):
    """Refreshes every row naming a Google Benchmark of `binaries` (the ones this run of scripts/bench
    wrote results/bench/<binary>.csv for) whose median that file holds. A CSV left by an earlier
    run is never read: its rows would take today's date without being measured."""
    data, today, machine, changed = rows(), datetime.date.today().isoformat(), _machine(), 0
    for r in data:
        if not r["gbench"]:
            continue
        binary, name = r["gbench"].split(":", 1)
        if binary not in binaries:
            continue
        path = os.path.join(root, "results", "bench", binary + ".csv")
        if not os.path.exists(path):
            continue
        text = open(path).read()
        body = text[text.index("name,"):] if "name," in text else text  # Google Benchmark's context lines come first
        for b in csv.DictReader(io.StringIO(body)):
            if b["name"] == name + "_median":
                if r["unit"].endswith("/s"):  # a rate: the benchmark's items per second
                    r["value"] = f"{float(b['items_per_second']):.5g}"
                else:
                    seconds = float(b["real_time"]) * _SCALE[b["time_unit"]]
                    r["value"] = f"{seconds / _SCALE[r['unit']]:.4g}"
                r["date"], r["machine"], r["runs"] = today, machine, str(reps)
                r["command"] = re.sub(r"^REPS=\d+ ", f"REPS={reps} ", r["command"])
                r["statistic"] = "median of repetition means"
                changed += 1
    _save(data)
    print(f"bench_report: refreshed {changed} rows of {CURRENT}")


def _save(data):
    with open(CURRENT + ".tmp", "w", newline="") as f:
        w = csv.DictWriter(f, COLUMNS, lineterminator="\n")
        w.writeheader()
        w.writerows(data)
    os.replace(CURRENT + ".tmp", CURRENT)


def read_figure(reads, output):
    """The figure a command printed: the first group of `reads` on the first line it matches (the
    thousands separators of a printed number dropped)."""
    pattern = re.compile(reads)
    for line in output.splitlines():
        m = pattern.search(line)
        if m:
            return float(m.group(1).replace(",", ""))
    raise ValueError(f"no line of the output matches {reads!r}")


def run_command(command, root=ROOT):
    """Runs `command` in `root` (build/ first on PATH, $DIR a fresh directory); returns what it
    printed (stdout and stderr) and its wall time in seconds."""
    d = tempfile.mkdtemp(prefix="skyloop-bench-")
    env = dict(os.environ, DIR=os.path.join(d, "run"),
               PATH=os.path.join(root, "build") + os.pathsep + os.environ.get("PATH", ""))
    try:
        t0 = time.perf_counter()
        r = subprocess.run(["bash", "-o", "pipefail", "-c", command], cwd=root, env=env,
                           stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        wall = time.perf_counter() - t0
    finally:
        shutil.rmtree(d, ignore_errors=True)
    if r.returncode != 0:
        raise RuntimeError(f"`{command}` exited with {r.returncode}:\n{r.stdout[-2000:]}")
    return r.stdout, wall


def figure_of(row, output, wall):
    """A row's figure from one run of its command: what it printed, or its wall time for `reads = wall`."""
    return wall if row["reads"] == "wall" else read_figure(row["reads"], output)


def run_once(row, root=ROOT):
    """Runs one row's command and returns the figure it printed (or its wall time)."""
    return figure_of(row, *run_command(row["command"], root))


def measure(pattern, runs, root=ROOT):
    """Measures every command row whose quantity matches `pattern`: the median of `runs` runs. Rows
    that share a command share its runs: each run is read for all of them, so their figures (a
    ratio and a rate, say) come from the same runs."""
    data, today, machine = rows(), datetime.date.today().isoformat(), _machine()
    chosen = [r for r in data if r["reads"] and re.search(pattern, r["quantity"])]
    if not chosen:
        raise SystemExit(f"bench_report: no command row's quantity matches {pattern!r}")
    by_command = {}
    for r in chosen:
        by_command.setdefault(r["command"], []).append(r)
    for command, group in by_command.items():
        figures = [[] for _ in group]
        for i in range(runs):
            try:
                output, wall = run_command(command, root)
                for r, f in zip(group, figures):
                    f.append(figure_of(r, output, wall))
            except (RuntimeError, ValueError) as e:
                raise SystemExit(f"bench_report: {'; '.join(r['quantity'] for r in group)}: {e}")
            for r, f in zip(group, figures):
                print(f"bench_report: {r['quantity']}: run {i + 1}/{runs}: {f[-1]:g} {r['unit']}", flush=True)
        for r, f in zip(group, figures):
            r["value"] = f"{statistics.median(f):.4g}"
            r["runs"], r["statistic"], r["date"], r["machine"] = str(runs), "median of runs", today, machine
        _save(data)  # each command's rows as soon as they are measured: an interrupted measurement keeps those before
    print(f"bench_report: measured {len(chosen)} rows of {CURRENT} ({len(by_command)} command{'s' if len(by_command) != 1 else ''}, {runs} runs each)")


def main(argv):
    if argv[:1] == ["--record"]:
        record(int(os.environ.get("REPS", "5")), set(argv[1:]))
    elif argv[:1] == ["--measure"]:
        args, runs = argv[1:], 3
        if args[:1] == ["--runs"]:
            if len(args) < 2 or not args[1].isdigit() or not 1 <= int(args[1]) <= 100:
                raise SystemExit(f"bench_report: --runs = {args[1] if len(args) > 1 else ''!r}: allowed a whole number from 1 to 100")
            runs, args = int(args[1]), args[2:]
        if len(args) > 1:
            raise SystemExit(f"bench_report: --measure takes one PATTERN, got {args}")
        try:
            pattern = re.compile(args[0] if args else ".").pattern
        except re.error as e:
            raise SystemExit(f"bench_report: PATTERN = {args[0]!r} is not a regular expression: {e}")
        measure(pattern, runs)
    elif argv:
        raise SystemExit(f"bench_report: unknown arguments {argv}: allowed none, --record BINARY..., or --measure [--runs N] [PATTERN]")
    else:
        print(page())


if __name__ == "__main__":
    main(sys.argv[1:])
