"""The benchmark page: today's figure per area, from data, never by hand.

bench/results/current.csv holds one row per measured quantity (area, quantity, value, unit, runs,
statistic, date, machine, command, and the Google Benchmark it comes from, if any). `scripts/bench
--record` refreshes the rows that name a Google Benchmark from the CSVs that run wrote
(results/bench/<binary>.csv), with today's date and this machine; a figure measured another way
(a training run, the quick profile) is replaced in the CSV by whoever re-measures it, with its
command, runs and machine. History lives in git.

  python3 scripts/bench_report.py            prints the page (docs/_generate.py writes it)
  python3 scripts/bench_report.py --record   refreshes current.csv from results/bench/*.csv
"""
import csv
import datetime
import io
import os
import platform
import re
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
CURRENT = os.path.join(ROOT, "bench", "results", "current.csv")
COLUMNS = ["area", "quantity", "value", "unit", "runs", "statistic", "date", "machine", "command", "gbench"]
_SCALE = {"ns": 1e-9, "us": 1e-6, "ms": 1e-3, "s": 1.0}


def rows():
    with open(CURRENT, newline="") as f:
        out = list(csv.DictReader(f))
    for r in out:
        if list(r) != COLUMNS:
            raise SystemExit(f"bench_report: {CURRENT} has columns {list(r)}: allowed {COLUMNS}")
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
            "`bench/results/current.csv` by `scripts/bench_report.py`; `scripts/bench --record` refreshes the",
            "Google Benchmark rows on the machine it runs on. Earlier figures are in the file's git history.",
            "A row over fewer than three runs says so: it is due for re-measurement.", "",
            "Figures that the concept pages cite from *the benchmark record*, with a section name in quotes,",
            "come from the dated measurement log kept until 2026-12-01, which git holds:",
            "`git show 1920028:BENCHMARKS.md`.", "",
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
            stat = f"{r['statistic']} ({runs})" if runs >= 3 else f"{r['statistic']} (fewer than 3 runs)"
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


def record(reps):
    """Refreshes every row naming a Google Benchmark whose median results/bench/<binary>.csv holds."""
    data, today, machine, changed = rows(), datetime.date.today().isoformat(), _machine(), 0
    for r in data:
        if not r["gbench"]:
            continue
        binary, name = r["gbench"].split(":", 1)
        path = os.path.join(ROOT, "results", "bench", binary + ".csv")
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
    with open(CURRENT + ".tmp", "w", newline="") as f:
        w = csv.DictWriter(f, COLUMNS, lineterminator="\n")
        w.writeheader()
        w.writerows(data)
    os.replace(CURRENT + ".tmp", CURRENT)
    print(f"bench_report: refreshed {changed} rows of {CURRENT}")


if __name__ == "__main__":
    if sys.argv[1:2] == ["--record"]:
        record(int(os.environ.get("REPS", "5")))
    else:
        print(page())
