"""The benchmark's leaderboard: one table and one performance profile per task, from the outputs
of `skyloop bench baselines` committed under bench/leaderboard/<task>/, never by hand.

Each task's folder holds what `skyloop bench baselines TASK --out bench/leaderboard/TASK` wrote
(summary.csv, profile.csv, rows.csv, marl_eval.json, config.toml, not_run.txt, trainings.csv: a row per
training run with its seconds and machine) and run.txt: the command, its wall time, the date and the
machine.

  python3 scripts/bench_leaderboard.py              prints the page (docs/_generate.py writes it)
  python3 scripts/bench_leaderboard.py --plots DIR  also draws DIR/<task>.png (the profiles)
"""
import csv
import os
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
BOARD = os.path.join(ROOT, "bench", "leaderboard")


def tasks():
    if not os.path.isdir(BOARD):
        return []
    return sorted(t for t in os.listdir(BOARD) if os.path.exists(os.path.join(BOARD, t, "summary.csv")))


def _read(task, name):
    with open(os.path.join(BOARD, task, name), newline="") as f:
        return list(csv.DictReader(f))


def _text(task, name):
    p = os.path.join(BOARD, task, name)
    return open(p).read().strip() if os.path.exists(p) else ""


def trainings(task):
    """What trainings.csv (written by `bench baselines`) says of the board's training runs: per
    learner the runs and their seconds, how many ran at a time, the machines and the dates."""
    if not os.path.exists(os.path.join(BOARD, task, "trainings.csv")):
        return ""
    rows = _read(task, "trainings.csv")
    parts = []
    for algo in dict.fromkeys(r["algo"] for r in rows):
        rs = [r for r in rows if r["algo"] == algo]
        sec = sorted(float(r["seconds"]) for r in rs)
        jobs = "/".join(sorted({r["jobs"] for r in rs}, key=int))
        resumed = sum(r["resumed"] == "1" for r in rs)
        parts.append(f"{algo} {len(rs)} runs of {rs[0]['steps']} steps, {sec[0]:,.0f}-{sec[-1]:,.0f} s each ({jobs} at a time"
                     + (f"; {resumed} resumed" if resumed else "") + ")")
    machines = "; ".join(dict.fromkeys(r["machine"] for r in rows))
    days = sorted({r["finished_utc"][:10] for r in rows})
    when = days[0] if len(days) == 1 else f"{days[0]} to {days[-1]}"
    return f"Trainings (trainings.csv): {'; '.join(parts)}; on {machines}, {when}."


def plot(task, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    rows = _read(task, "profile.csv")
    fig, ax = plt.subplots(figsize=(5.5, 3.4))
    for policy in dict.fromkeys(r["policy"] for r in rows):
        pts = [(float(r["tau"]), float(r["fraction_of_runs"])) for r in rows if r["policy"] == policy]
        ax.plot([100 * p[0] for p in pts], [p[1] for p in pts], label=policy)
    ax.set_xlabel("score tau (% of the reference)")
    ax.set_ylabel("fraction of runs >= tau")
    ax.set_xlim(0, 105)
    ax.set_title(task)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def page(plots=None):
    out = ["# Leaderboard", "",
           "Every baseline on every [benchmark task](../concepts/benchmark.md), scored against each test layout's",
           "reference under the task's protocol. Made by `scripts/bench_leaderboard.py` from the outputs of",
           "`skyloop bench baselines` committed under `bench/leaderboard/`; each table names the command that made it,",
           "its wall time, date and machine. IQM: the interquartile mean of the fraction of the reference over seeds x",
           "layouts, with its 95% stratified bootstrap interval; a row off the protocol says why.", ""]
    for task in tasks():
        summary = sorted(_read(task, "summary.csv"), key=lambda r: -float(r["iqm"]))
        ref = summary[0]["reference"] if summary else ""
        made = trainings(task)
        out += [f"## {task}", "", _text(task, "run.txt"), ""] + ([made, ""] if made else []) + [
                f"| policy | seeds | layouts | IQM % of {ref} | 95% interval | mean % | p5 % | complete | protocol |",
                "|---|---:|---:|---:|---|---:|---:|---:|---|"]
        for r in summary:
            out.append(f"| {r['policy']} | {r['seeds']} | {r['layouts']} | **{100 * float(r['iqm']):.2f}** | "
                       f"[{100 * float(r['iqm_ci_low']):.2f}, {100 * float(r['iqm_ci_high']):.2f}] | "
                       f"{100 * float(r['mean']):.2f} | {100 * float(r['p5']):.2f} | "
                       f"{100 * float(r['complete_rate']):.0f}% | {r['protocol']} |")
        for line in _text(task, "not_run.txt").splitlines():  # "name: not run (why)"
            name, _, why = line.partition(": ")
            out.append(f"| {name} | - | - | - | - | - | - | - | {why} |")
        if plots:
            os.makedirs(plots, exist_ok=True)
            plot(task, os.path.join(plots, f"{task}.png"))
            out += ["", f"![Performance profile of {task}](leaderboard/{task}.png)"]
        out.append("")
    if not tasks():
        out.append("No leaderboard has been committed yet (`skyloop bench baselines TASK --out bench/leaderboard/TASK`).")
    return "\n".join(out) + "\n"


if __name__ == "__main__":
    plots = sys.argv[sys.argv.index("--plots") + 1] if "--plots" in sys.argv else None
    sys.stdout.write(page(plots))
