#!/usr/bin/python3
"""Figures (PNG and PDF) and report.html for a `skyloop reproduce` run directory.

    /usr/bin/python3 scripts/plot_figures.py RUN_DIR

Reads RUN_DIR/manifest.json and the per-figure CSVs it lists, writes RUN_DIR/figures/*.png|pdf
and RUN_DIR/report.html. Needs only the standard library and matplotlib (Debian:
python3-matplotlib). Exits non-zero with one line on stderr if the run directory is incomplete.
"""
import csv
import html
import json
import math
import os
import sys
import tomllib
from collections import defaultdict

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

STYLE = {  # label, colour, marker, line style
    "ga": ("GA (paper's heuristic)", "#1f77b4", "o", "-"),
    "gnn": ("GNN (paper)", "#d62728", "s", "-"),
    "deepsets": ("DeepSets", "#2ca02c", "^", "-"),
    "mspointnet": ("MS-PointNet", "#9467bd", "v", "-"),
    "gnn_structured": ("GNN, structured readout (skyloop)", "#ff7f0e", "D", "--"),
    "wmmse": ("WMMSE (skyloop reference)", "#000000", "x", "--"),
    "zf": ("ZF", "#7f7f7f", "+", ":"),
    "zfsel": ("ZF with user selection", "#bcbd22", "1", ":"),
    "zfgain": ("ZF, users in order of gain", "#aec7e8", "2", ":"),
    "nwmmse": ("Coordinated WMMSE (network, skyloop)", "#17becf", "P", "-"),
    "crzf": ("Coordinated RZF", "#e377c2", "*", "-."),
    "czf": ("Coordinated ZF", "#7f7f7f", "X", "-."),
    "czfsel": ("Network ZF with user selection", "#393b79", "d", "-."),
    "ignn": ("Interference-aware GNN (skyloop)", "#d62728", "p", "-"),
    "ignn_structured": ("Interference-aware GNN, structured readout (skyloop)", "#ff7f0e", "h", "-"),
    "mrt": ("MRT", "#8c564b", ".", ":"),
    "mappo": ("MAPPO", "#d62728", "s", "-"),
    "ippo": ("IPPO", "#1f77b4", "o", "-"),
    "vdn": ("VDN", "#2ca02c", "^", "-"),
    "qmix": ("QMIX", "#9467bd", "v", "-"),
    "greedy": ("Greedy", "#7f7f7f", "+", "--"),
    "seqgreedy": ("Sequential greedy", "#bcbd22", "1", "--"),
    "rollout": ("Rollout over sequential greedy", "#17becf", "*", "--"),
    "random": ("Random", "#8c564b", ".", ":"),
    "optimal": ("Optimum (skyloop, DP)", "#000000", "x", "--"),
}
AXIS = {
    "channel.p_max_dbm": "maximum transmit power P_max (dBm)",
    "channel.noise_dbm": "noise power (dBm)",
    "scenario.uavs": "number of UAVs N",
    "scenario.users": "number of users K",
}


def style(key):
    return STYLE.get(key, (key, None, "o", "-"))


def read_csv(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def mean(xs):
    return sum(xs) / len(xs) if xs else float("nan")


def std(xs):
    if len(xs) < 2:
        return 0.0
    m = mean(xs)
    return math.sqrt(sum((x - m) ** 2 for x in xs) / (len(xs) - 1))


def save(fig, out_dir, name):
    os.makedirs(os.path.join(out_dir, "figures"), exist_ok=True)
    paths = []
    for ext in ("png", "pdf"):
        rel = f"figures/{name}.{ext}"
        tmp = os.path.join(out_dir, rel + ".tmp")
        fig.savefig(tmp, format=ext, dpi=150, bbox_inches="tight")
        os.replace(tmp, os.path.join(out_dir, rel))
        paths.append(rel)
    plt.close(fig)
    return paths


MANIFEST = {}


def experiment_spec(run, exp):
    """The experiment file as run (its [[reported]], [[reference]] and reading), {} if absent."""
    path = os.path.join(run, exp["name"], "experiment.toml")
    if not os.path.exists(path):
        return {}
    with open(path, "rb") as f:
        return tomllib.load(f)


def fnum(x, digits=2):
    try:
        return f"{float(x):.{digits}f}"
    except (TypeError, ValueError):
        return str(x)


# --- one function per experiment kind: (figures, tables) ------------------------------------------

def same_x(a, b):
    """One sweep value written two ways (50 and 50.0; or a name)."""
    try:
        return float(a) == float(b)
    except (TypeError, ValueError):
        return str(a) == str(b)


def sweep_axis(rows):
    """The sweep's x values: numbers (sorted, drawn at their value) or names such as a channel model
    (in the experiment's order, drawn at 0, 1, 2, ... and labelled)."""
    names = []
    for r in rows:
        if r["x"] not in names:
            names.append(r["x"])
    try:
        return {x: float(x) for x in sorted(names, key=float)}, True
    except ValueError:
        return {x: float(i) for i, x in enumerate(names)}, False


def beamform_sweep(run, exp):
    rows = read_csv(os.path.join(run, exp["files"][0]))
    latency = exp["name"] == "latency"
    at, numeric = sweep_axis(rows)
    # One curve per method, or per (method, series value) when the experiment has a series: the
    # series picks the colour, the method the marker and line.
    series = [v for v in dict.fromkeys(r.get("series", "") for r in rows) if v]
    palette = ["#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#8c564b", "#17becf", "#7f7f7f"]
    by = defaultdict(dict)
    for r in rows:
        by[(r["method"], r.get("series", ""))][at[r["x"]]] = r
    fig, ax = plt.subplots(figsize=(6, 4.2))
    for (method, sv), pts in by.items():
        xs = sorted(pts)
        lab, col, mk, ls = style(method)
        if sv:
            lab, col = f"{lab.split(' (')[0]}, {sv}", palette[series.index(sv) % len(palette)]
        if latency:
            ys = [float(pts[x]["median_latency_ms"]) for x in xs]
            ax.plot(xs, ys, marker=mk, ls=ls, color=col, label=lab)
        else:
            ys = [float(pts[x]["mean"]) for x in xs]
            es = [float(pts[x]["sem"]) for x in xs]
            ax.errorbar(xs, ys, yerr=es, marker=mk, ls=ls, color=col, label=lab, capsize=2)
    if not numeric:
        ax.set_xticks(list(at.values()))
        ax.set_xticklabels(list(at), rotation=20, fontsize=7)
    # Another experiment's curve, drawn grey and dashed for reference ([[reference]]).
    notes = []
    for i, ref in enumerate(experiment_spec(run, exp).get("reference", [])):
        other = next((e for e in MANIFEST.get("experiments", []) if e["name"] == ref["experiment"]), None)
        if other is None or not os.path.exists(os.path.join(run, other["files"][0])):
            notes.append(f"reference '{ref['experiment']}' is not in this run")
            continue
        pts = {at[r["x"]]: float(r["mean"]) for r in read_csv(os.path.join(run, other["files"][0]))
               if r["method"] == ref["method"] and r["x"] in at}
        xs = sorted(pts)
        ax.plot(xs, [pts[x] for x in xs], ls=("--", ":", "-.")[i % 3], color="#999999", marker="", lw=1.4,
                label=ref.get("label", f"{ref['method']} ({ref['experiment']})"))
    x_name = rows[0]["x_name"] if rows else ""
    ax.set_xlabel(AXIS.get(x_name, x_name))
    if latency:
        ax.set_yscale("log")
        ax.set_ylabel("time per decision (ms, median, one core)")
    else:
        ax.set_ylabel("network sum rate (bit/s/Hz)")
    ax.set_title(exp["title"], fontsize=9)
    ax.grid(alpha=0.3, which="both")
    if len(ax.get_legend_handles_labels()[0]) > 8:  # many curves: the legend beside the axes, not over them
        ax.legend(fontsize=7, bbox_to_anchor=(1.02, 1), loc="upper left")
    else:
        ax.legend(fontsize=7)
    figs = save(fig, run, exp["name"])
    # Table: methods x sweep values.
    xs = sorted(at.values())
    head = ["method"] + ([fnum(x, 0) for x in xs] if numeric else list(at))
    body = []
    for (method, sv), pts in by.items():
        key = "median_latency_ms" if latency else "mean"
        name = style(method)[0] + (f", {sv}" if sv else "")
        body.append([name] + [fnum(pts[x][key], 3 if latency else 2) if x in pts else "" for x in xs])
    samples = rows[0]["samples"] if rows else "0"
    what = "median ms per decision" if latency else "mean network sum rate, bit/s/Hz"
    cap = f"{what}; {samples} snapshots per point, seed {rows[0]['seed'] if rows else ''}; x = {AXIS.get(x_name, x_name)}"
    if notes:
        cap += "; " + "; ".join(notes)
    tables = [(cap, head, body)]
    if latency:
        # How many decisions fit in one channel coherence time: the fast timescale's budget.
        speed, carrier = 10.0, 2e9                    # m/s and Hz: a slow rotary-wing UAV at 2 GHz
        doppler = speed * carrier / 299792458.0        # f_D = V f_c / c = 66.7 Hz
        coherence_ms = 1e3 * 0.423 / doppler           # T_c = 0.423 / f_D (Rappaport's rule): 6.3 ms
        per = [[style(method)[0]] + [f"{coherence_ms / float(pts[x]['median_latency_ms']):.3g}"
                                     if x in pts and float(pts[x]["median_latency_ms"]) > 0 else "" for x in xs]
               for (method, _), pts in by.items()]
        tables.append((f"decisions per coherence time: T_c = 0.423 / f_D = {coherence_ms:.2f} ms at V = {speed:g} m/s, "
                       f"f_c = {carrier / 1e9:g} GHz (f_D = {doppler:.1f} Hz), divided by the median time per decision "
                       f"(one core); below 1 the beamformer cannot follow the fading; x = {AXIS.get(x_name, x_name)}",
                       head, per))
    return figs, tables


def curves(rows, metric):
    """Per algo: list of (steps, values per seed) on the steps of the shortest run."""
    per = defaultdict(lambda: defaultdict(list))
    for r in rows:
        v = r.get(metric, "")
        if v in ("", "nan"):
            continue
        per[r["algo"]][r["seed"]].append((int(r["env_steps"]), float(v)))
    out = {}
    for algo, seeds in per.items():
        series = [sorted(s) for s in seeds.values()]
        n = min(len(s) for s in series)
        steps = [series[0][i][0] for i in range(n)]
        vals = [[s[i][1] for s in series] for i in range(n)]
        out[algo] = (steps, vals, len(series))
    return out


def smooth(ys, w):
    out, acc = [], []
    for y in ys:
        acc.append(y)
        if len(acc) > w:
            acc.pop(0)
        out.append(mean(acc))
    return out


def stage_config(run, exp):
    """The configuration an experiment ran with (its resolved config.toml)."""
    with open(os.path.join(run, exp["name"], "config.toml"), "rb") as f:
        return tomllib.load(f)


def stage_uavs(run, exp):
    """The fleet size N of an experiment: scenario.uavs of the configuration it ran with."""
    return int(stage_config(run, exp)["scenario"]["uavs"])


def home_text(r, n):
    """'3/3': the UAVs home of a run's evaluation (the fleet's size from the row, else n)."""
    return f"{r['arrivals']}/{r.get('uavs') or n}"


def failed(r, n):
    """A run's evaluation is a failed mission: a UAV not home, a collision or a boundary event."""
    return int(r["arrivals"]) < int(r.get("uavs") or n) or int(r["collisions"]) > 0 or int(r["boundary_events"]) > 0


def mission_text(rs, n):
    """'complete', or 'FAILED on seed 2 (1/3 home)' naming every failed seed: never left to a reader."""
    bad = [r for r in rs if failed(r, n)]
    if not bad:
        return "complete" if len(rs) == 1 else f"complete on all {len(rs)}"
    what = [f"{home_text(r, n)} home, {r['collisions']} collisions, {r['boundary_events']} boundary events" for r in bad]
    if "train_seed" not in bad[0]:  # a planner's single episode
        return f"FAILED ({what[0]})"
    return "FAILED on " + "; ".join(f"seed {r['train_seed']} ({w})" for r, w in zip(bad, what))


def trained_text(rs):
    """How a learner row was trained: its environment steps (the same for every seed of a row)."""
    steps = sorted({int(r["train_steps"]) for r in rs if r.get("train_steps")})
    return ", ".join(f"{s:.0e} steps".replace("e+0", "e") for s in steps) or "(unknown)"


def marl_training(run, exp):
    rows = read_csv(os.path.join(run, exp["name"], "curves.csv"))
    finals = read_csv(os.path.join(run, exp["files"][0]))
    n = stage_uavs(run, exp)
    refs_path = os.path.join(run, exp["name"], "references.csv")
    refs = read_csv(refs_path) if os.path.exists(refs_path) else []
    figs = []
    for metric, ylabel, name in (("charts/episode_reward", "average episode reward", "marl_episode_reward"),
                                 ("charts/sum_rate", "average sum rate (bit/s/Hz)", "marl_sum_rate")):
        fig, ax = plt.subplots(figsize=(6, 4.2))
        for algo, (steps, vals, nseeds) in curves(rows, metric).items():
            lab, col, _, ls = style(algo)
            w = max(1, len(steps) // 50)
            m = smooth([mean(v) for v in vals], w)
            lo = smooth([min(v) for v in vals], w)
            hi = smooth([max(v) for v in vals], w)
            ax.plot(steps, m, color=col, ls=ls, label=f"{lab} ({nseeds} seed{'s' if nseeds > 1 else ''})")
            if nseeds > 1:
                ax.fill_between(steps, lo, hi, color=col, alpha=0.15)
        if metric == "charts/sum_rate":
            for r in refs:
                lab, col, _, ls = style(r["planner"])
                ax.axhline(float(r["objective"]), color=col, ls=ls, lw=1, label=f"{lab} (evaluation)")
        ax.set_xlabel("environment steps")
        ax.set_ylabel(ylabel)
        ax.set_title(exp["title"] + ("; mean, min-max band over seeds" if metric else ""), fontsize=9)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
        # The paper's experiment keeps its figure names; another MARL experiment is prefixed by its name.
        figs += save(fig, run, name if exp["name"] == "marl_training" else f"{exp['name']}_{name[5:]}")
    # Table: per algo, over seeds, the deterministic policy's evaluation.
    by = defaultdict(list)
    for r in finals:
        by[r["algo"]].append(r)
    head = ["learner", "trained", "seeds", "avg sum rate (mean)", "per seed", "UAVs home", "mission", "collisions",
            "boundary events", "train time per run (s)", "steps/s"]
    body = []
    for algo, rs in by.items():
        obj = [float(r["objective"]) for r in rs]
        body.append([style(algo)[0], trained_text(rs), str(len(rs)), fnum(mean(obj), 3), ", ".join(fnum(o, 3) for o in obj),
                     ", ".join(home_text(r, n) for r in rs), mission_text(rs, n), ", ".join(r["collisions"] for r in rs),
                     ", ".join(r["boundary_events"] for r in rs), fnum(mean([float(r["train_seconds"]) for r in rs]), 0),
                     fnum(mean([float(r["steps_per_second"]) for r in rs]), 0)])
    for r in refs:
        body.append([style(r["planner"])[0], "not trained", "-", fnum(r["objective"], 3), "", home_text(r, n), mission_text([r], n),
                     r["collisions"], r["boundary_events"], fnum(r["seconds"], 1), ""])
    ks = ", ".join(str(k) for k in sorted({int(r["users"]) for r in finals + refs}))
    cap = f"deterministic policies after training, on the training users (K = {ks}); references on the same users"
    return figs, [(cap, head, body)]


def planning_users(run, exp):
    rows = read_csv(os.path.join(run, exp["files"][0]))
    n = stage_uavs(run, exp)
    by = defaultdict(lambda: defaultdict(list))
    for r in rows:
        by[r["planner"]][int(r["users"])].append(r)
    fig, ax = plt.subplots(figsize=(6, 4.2))
    for planner, pts in by.items():
        ks = sorted(pts)
        lab, col, mk, ls = style(planner)
        ys = [mean([float(r["objective"]) for r in pts[k]]) for k in ks]
        es = [std([float(r["objective"]) for r in pts[k]]) for k in ks]
        ax.errorbar(ks, ys, yerr=es, marker=mk, color=col, ls=ls, label=lab, capsize=2)
    ax.set_xlabel("number of users K")
    ax.set_ylabel("average sum rate over the flight (bit/s/Hz)")
    ax.set_title(exp["title"], fontsize=9)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    figs = save(fig, run, exp["name"])
    ks = sorted({int(r["users"]) for r in rows})
    head = ["planner"] + [f"K = {k}" for k in ks]
    body = []
    for planner, pts in by.items():
        cells = []
        for k in ks:
            rs = pts.get(k, [])
            if not rs:
                cells.append("")
                continue
            home = sum(int(r["arrivals"]) for r in rs)
            viol = sum(int(r["collisions"]) + int(r["boundary_events"]) for r in rs)
            cells.append(f"{fnum(mean([float(r['objective']) for r in rs]), 3)} ({home}/{n * len(rs)} home"
                         + (f", {viol} violations" if viol else "") + ")")
        body.append([style(planner)[0]] + cells)
    cap = "average sum rate (P2.2 objective), mean over training seeds for learners; UAVs home and violations summed"
    return figs, [(cap, head, body)]


def trajectories(run, exp):
    traj = read_csv(os.path.join(run, exp["files"][0]))
    users = read_csv(os.path.join(run, exp["files"][1]))
    summary = read_csv(os.path.join(run, exp["files"][2]))
    ends = read_csv(os.path.join(run, exp["files"][3]))
    cfg = stage_config(run, exp)
    fleet = int(cfg["scenario"]["uavs"])
    area = (float(cfg["scenario"]["area_x_m"]), float(cfg["scenario"]["area_y_m"]))
    ks = sorted({int(r["users"]) for r in traj})
    fig, axes = plt.subplots(1, len(ks), figsize=(4.2 * len(ks), 4.4), squeeze=False)
    colours = ["#d62728", "#1f77b4", "#2ca02c", "#9467bd", "#ff7f0e", "#8c564b"]
    for ax, k in zip(axes[0], ks):
        us = [r for r in users if int(r["users"]) == k]
        ax.scatter([float(r["x"]) for r in us], [float(r["y"]) for r in us], s=14, c="#555555", marker="o", label="users")
        for planner, ls, alpha in (("optimal", "--", 0.8), ("mappo", "-", 1.0)):
            rs = [r for r in traj if int(r["users"]) == k and r["planner"] == planner]
            for n in sorted({int(r["uav"]) for r in rs}):
                pts = sorted((int(r["t"]), float(r["x"]), float(r["y"])) for r in rs if int(r["uav"]) == n)
                ax.plot([p[1] for p in pts], [p[2] for p in pts], ls=ls, color=colours[n % len(colours)], alpha=alpha,
                        marker="." if planner == "mappo" else None,
                        label=f"UAV {n + 1} ({'MAPPO' if planner == 'mappo' else 'optimum'})")
        for e in ends:
            n = int(e["uav"])
            c = colours[n % len(colours)]
            ax.annotate("S", (float(e["start_x"]), float(e["start_y"])), color=c, fontsize=11, weight="bold", ha="center",
                        va="center")
            ax.annotate("D", (float(e["dest_x"]), float(e["dest_y"])), color=c, fontsize=11, weight="bold", ha="center",
                        va="center")
        ax.set_xlim(0, area[0])
        ax.set_ylim(0, area[1])
        ax.set_aspect("equal")
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
        ax.set_title(f"K = {k}", fontsize=9)
        ax.grid(alpha=0.3)
    axes[0][0].legend(fontsize=6, loc="upper center")
    fig.suptitle(exp["title"] + " (solid: MAPPO, dashed: optimum)", fontsize=9)
    figs = save(fig, run, exp["name"])
    head = ["K", "planner", "avg sum rate", "T", "UAVs home", "collisions", "boundary events"]
    body = [[r["users"], style(r["planner"])[0], fnum(r["objective"], 3), r["T"], home_text(r, fleet), r["collisions"],
             r["boundary_events"]] for r in summary]
    return figs, [("the plotted episodes", head, body)]


def models(run, exp):
    rows = read_csv(os.path.join(run, exp["files"][0]))
    head = ["model", "source", "best validation sum rate", "epochs", "parameters"]
    body = [[style(r["model"])[0], r["source"], fnum(r["best_val_sum_rate"], 3), r["epoch"], r["parameters"]] for r in rows]
    return [], [("learned beamformers used by every experiment (trained at N = 3, K = 12)", head, body)]


def generalisation(run, exp):
    rows = read_csv(os.path.join(run, exp["files"][0]))
    # One group per evaluation (training layouts; test layouts at each K), one bar per planner:
    # the mean over training seeds of the mean % of each layout's optimum, with the seeds' 5th
    # percentile as a marker.
    groups = []
    for r in rows:
        g = (r["eval"], r["eval_users"])
        if g not in groups:
            groups.append(g)
    groups.sort(key=lambda g: (g[0] != "train", int(g[1]) if g[1].isdigit() else 0))
    planners = []
    for r in rows:
        if r["planner"] != "optimal" and r["planner"] not in planners:
            planners.append(r["planner"])
    fig, ax = plt.subplots(figsize=(max(6.0, 1.2 * len(groups) * len(planners) / 2), 4.2))
    width = 0.8 / max(1, len(planners))
    for j, pl in enumerate(planners):
        xs, ms, p5 = [], [], []
        for i, g in enumerate(groups):
            rs = [r for r in rows if (r["eval"], r["eval_users"]) == g and r["planner"] == pl]
            if not rs:
                continue
            xs.append(i + (j - (len(planners) - 1) / 2) * width)
            ms.append(100 * mean([float(r["fraction_mean"]) for r in rs]))
            p5.append(100 * min(float(r["fraction_p5"]) for r in rs))
        base = pl.split("/")[0].split("+")[0]
        label, colour, _, _ = style(base)
        raw, rolled = pl.endswith("/raw"), pl.endswith("+rollout")
        ax.bar(xs, ms, width, color=colour, alpha=0.35 if raw else 0.9, hatch="//" if raw else ".." if rolled else None,
               label=label + (" without mask and shield" if raw else " + rollout" if rolled else ""))
        ax.scatter(xs, p5, marker="_", color="#000000", s=60, zorder=3)
    ax.set_xticks(range(len(groups)))
    ax.set_xticklabels([("training layouts" if e == "train" else "held-out layouts") + f"\nK = {k}" for e, k in groups], fontsize=8)
    ax.set_ylabel("% of each layout's optimum")
    lo = min([100 * float(r["fraction_p5"]) for r in rows] + [90.0])
    ax.set_ylim(max(0.0, lo - 5), 101)
    ax.grid(axis="y", alpha=0.3)
    ax.legend(fontsize=6, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    ax.set_title(exp["title"] + " (bar: mean; tick: 5th percentile)", fontsize=9)
    fig.tight_layout()
    figs = save(fig, run, exp["name"])
    head = ["layouts", "K", "planner", "train seed", "complete", "collisions", "boundary events", "% optimum (mean)",
            "5th percentile", "worst"]
    body = [["training" if r["eval"] == "train" else "held-out", r["eval_users"], r["planner"], r["train_seed"] or "-",
             f"{100 * float(r['complete_rate']):.0f}%", r["collisions"], r["boundary_events"],
             fnum(100 * float(r["fraction_mean"])), fnum(100 * float(r["fraction_p5"])), fnum(100 * float(r["fraction_worst"]))]
            for r in rows if r["planner"] != "optimal"]
    return figs, [(f"each row over {rows[0]['layouts']} layouts", head, body)]


def rate_energy(run, exp):
    front = read_csv(os.path.join(run, exp["files"][0]))
    speeds = read_csv(os.path.join(run, exp["files"][1]))
    paths = read_csv(os.path.join(run, exp["files"][2]))
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.4))
    # The front: the optimum of R-bar - w P-bar at each w; the planners flying the experiment's objective.
    ax = axes[0]
    pts = sorted(((float(r["mean_power_w"]), float(r["sum_rate_objective"]), r["weight"]) for r in front if r["role"] == "front"))
    ax.plot([p[0] for p in pts], [p[1] for p in pts], "k--", marker="x", label="front: optimum of R-bar - w P-bar")
    for x, y, w in pts:
        ax.annotate(f"w={w}", (x, y), fontsize=6, textcoords="offset points", xytext=(3, -8))
    for r in front:
        if r["role"] != "placed":
            continue
        lab, col, mk, _ = style(r["planner"])
        if r["planner"] == "optimal":
            lab, mk = "optimum of bits/J", "*"
        ax.scatter([float(r["mean_power_w"])], [float(r["sum_rate_objective"])], color=col, marker=mk, s=60,
                   label=f"{lab} ({fnum(float(r['bits_per_joule']) / 1e3, 1)} kbit/J)")
    ax.set_xlabel("mean fleet propulsion power P-bar (W)")
    ax.set_ylabel("average sum rate R-bar (bit/s/Hz)")
    ax.set_title("rate-power front", fontsize=9)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=6)
    # The speeds the optimum flies at each weight.
    ax = axes[1]
    ws = sorted({r["weight"] for r in speeds}, key=float)
    vs = sorted({float(r["speed_mps"]) for r in speeds})
    width = 0.8 / max(1, len(ws))
    for i, w in enumerate(ws):
        count = {float(r["speed_mps"]): int(r["slots"]) for r in speeds if r["weight"] == w}
        total = max(1, sum(count.values()))
        ax.bar([j + i * width for j in range(len(vs))], [count.get(v, 0) / total for v in vs], width, label=f"w = {w}")
    ax.set_xticks([j + 0.4 - width / 2 for j in range(len(vs))])
    ax.set_xticklabels([fnum(v, 1) for v in vs])
    ax.set_xlabel("ground speed (m/s; 0 = hover)")
    ax.set_ylabel("share of UAV-slots")
    ax.set_title("speeds of the optimum", fontsize=9)
    ax.legend(fontsize=6)
    # Hover-and-serve (w = smallest) vs fly-through (w = largest).
    ax = axes[2]
    colours = ["#d62728", "#1f77b4", "#2ca02c", "#9467bd"]
    for w, ls in ((ws[0], "-"), (ws[-1], "--")):
        rs = [r for r in paths if r["weight"] == w]
        for n in sorted({int(r["uav"]) for r in rs}):
            p = sorted((int(r["t"]), float(r["x"]), float(r["y"])) for r in rs if int(r["uav"]) == n)
            ax.plot([q[1] for q in p], [q[2] for q in p], ls=ls, marker=".", color=colours[n % 4],
                    label=f"UAV {n + 1}, w = {w}")
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title("optimum's trajectories: solid w = min, dashed w = max", fontsize=9)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=6)
    fig.suptitle(exp["title"], fontsize=9)
    figs = save(fig, run, exp["name"])
    head = ["role", "weight", "planner", "train seed", "R-bar (bit/s/Hz)", "P-bar (W)", "energy (kJ)", "kbit/J", "T", "complete"]
    body = [[r["role"], r["weight"], style(r["planner"])[0], r["train_seed"], fnum(r["sum_rate_objective"], 3),
             fnum(r["mean_power_w"], 1), fnum(float(r["energy_j"]) / 1e3, 2), fnum(float(r["bits_per_joule"]) / 1e3, 1), r["T"],
             r["success"]] for r in front]
    return figs, [("front: the optimum at each weight; placed: flying the experiment's objective", head, body)]


def altitude_profile(run, exp):
    profile = read_csv(os.path.join(run, exp["files"][0]))
    summary = read_csv(os.path.join(run, exp["files"][1]))
    channels = list(dict.fromkeys(r["pathloss"] for r in summary))
    fig, axes = plt.subplots(1, len(channels), figsize=(5.5 * len(channels), 3.8), squeeze=False)
    colours = ["#d62728", "#1f77b4", "#2ca02c", "#9467bd"]
    objective = {(r["pathloss"], r["mobility"], r["planner"]): float(r["objective"]) for r in summary}
    for ax, ch in zip(axes[0], channels):
        for mobility, ls in (("grid-3d", "-"), ("grid", "--")):
            rs = [r for r in profile if r["pathloss"] == ch and r["mobility"] == mobility and r["planner"] == "optimal"]
            for n in sorted({int(r["uav"]) for r in rs}):
                p = sorted((int(r["t"]), float(r["z"])) for r in rs if int(r["uav"]) == n)
                ax.plot([q[0] for q in p], [q[1] for q in p], ls=ls, marker="." if mobility == "grid-3d" else None,
                        color=colours[n % 4], label=f"UAV {n + 1}, {'chosen' if mobility == 'grid-3d' else 'fixed'} altitude")
        j3, j2 = objective.get((ch, "grid-3d", "optimal")), objective.get((ch, "grid", "optimal"))
        gain = f": {fnum(j3, 2)} vs {fnum(j2, 2)} bit/s/Hz ({100 * (j3 / j2 - 1):+.1f}%)" if j3 and j2 else ""
        ax.set_title(f"{ch}{gain}", fontsize=8)
        ax.set_xlabel("slot t")
        ax.set_ylabel("altitude z (m)")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=6)
    fig.suptitle(exp["title"] + " (solid: optimum choosing its altitude; dashed: optimum at H)", fontsize=9)
    figs = save(fig, run, exp["name"])
    head = ["channel", "altitude", "planner", "objective (bit/s/Hz)", "T", "complete", "energy (kJ)"]
    body = [[r["pathloss"], "chosen (grid-3d)" if r["mobility"] == "grid-3d" else "fixed at H (grid)", style(r["planner"])[0],
             fnum(r["objective"], 3), r["T"], r["success"], fnum(float(r["energy_j"]) / 1e3, 2)] for r in summary]
    return figs, [("the exact optimum of the sum rate with each UAV's altitude chosen or fixed", head, body)]


KINDS = {"generalisation": generalisation, "beamform_sweep": beamform_sweep, "marl_training": marl_training, "planning_users": planning_users,
         "trajectories": trajectories, "models": models, "rate_energy": rate_energy, "altitude_profile": altitude_profile}


# --- the paper's numbers beside skyloop's ------------------------------------------------------------

def reported(run, exp):
    spec = experiment_spec(run, exp)
    out = []
    for item in spec.get("reported", []):
        value = ""
        try:
            if exp["kind"] == "beamform_sweep":
                rows = read_csv(os.path.join(run, exp["files"][0]))
                at = {r["method"]: r for r in rows if same_x(r["x"], item["x"])}
                if item["method"] in at:
                    r = at[item["method"]]
                    if item.get("metric") == "latency":
                        value = f"{fnum(r['median_latency_ms'], 3)} ms"
                    else:
                        value = fnum(r["mean"])
                        other = item.get("versus")
                        if other in at:
                            d = float(r["mean"]) - float(at[other]["mean"])
                            value += f" vs {style(other)[0].split(' (')[0]} {fnum(at[other]['mean'])} ({d:+.2f})"
                        if "wmmse" in at and "wmmse" not in (item["method"], other):
                            value += f"; WMMSE {fnum(at['wmmse']['mean'])}"
                    value += f" [x = {item['x']}]"
            elif exp["kind"] == "marl_training":
                if item["metric"] == "objective":
                    rs = [r for r in read_csv(os.path.join(run, exp["files"][0])) if r["algo"] == item["algo"]]
                    value = ", ".join(fnum(r["objective"], 3) for r in rs) + " (per seed; "
                    n = stage_uavs(run, exp)
                    value += ", ".join(home_text(r, n) for r in rs) + " UAVs home; trained " + trained_text(rs) + ")"
                    if any(failed(r, n) for r in rs):
                        value += " MISSION " + mission_text(rs, n)
                else:
                    cs = curves(read_csv(os.path.join(run, exp["name"], "curves.csv")), "charts/episode_reward")
                    if item["algo"] in cs:
                        steps, vals, _ = cs[item["algo"]]
                        tail = vals[-max(1, len(vals) // 10):]
                        value = f"{fnum(mean([mean(v) for v in tail]))} (mean of the last 10% of training)"
            elif exp["kind"] == "planning_users":
                rows = read_csv(os.path.join(run, exp["files"][0]))
                wins = 0
                ks = sorted({int(r["users"]) for r in rows})
                for k in ks:
                    m = mean([float(r["objective"]) for r in rows if int(r["users"]) == k and r["planner"] == "mappo"])
                    others = [float(r["objective"]) for r in rows
                              if int(r["users"]) == k and r["planner"] in ("greedy", "random")]
                    wins += all(m > o for o in others)
                value = f"MAPPO above Greedy and Random at {wins} of {len(ks)} K values"
        except (KeyError, ValueError, OSError) as e:
            value = f"(not computed: {e})"
        out.append([exp["figure"], item.get("quantity", ""), item.get("paper", ""), value or "(not in this run's profile)"])
    return out


def runs_text(manifest):
    runs = manifest.get("runs") or [{"seconds": manifest.get("seconds", 0)}]
    return "; ".join(f"{fnum(r.get('seconds', 0), 1)} s" + (" (--force)" if r.get("force") else "")
                     + (f" on {r['ranks']} MPI ranks" if r.get("ranks", 1) > 1 else "")
                     + (f" ({', '.join(r['experiments'])})" if r.get("experiments") and len(r["experiments"]) < 9 else "")
                     for r in runs)


def table_html(cap, head, body):
    s = f"<table><caption>{html.escape(cap)}</caption><tr>" + "".join(f"<th>{html.escape(h)}</th>" for h in head) + "</tr>"
    for row in body:
        s += "<tr>" + "".join(f"<td>{html.escape(str(c))}</td>" for c in row) + "</tr>"
    return s + "</table>\n"


def link(run, rel, text=None):
    """A link to a file of the run; only files that exist are linked."""
    if not os.path.exists(os.path.join(run, rel)):
        return html.escape(text or rel) + " (missing)"
    return f'<a href="{html.escape(rel)}">{html.escape(text or rel)}</a>'


def main(argv):
    if len(argv) != 2:
        print("usage: plot_figures.py RUN_DIR", file=sys.stderr)
        return 2
    run = argv[1]
    try:
        with open(os.path.join(run, "manifest.json")) as f:
            manifest = json.load(f)
    except (OSError, ValueError) as e:
        print(f"plot_figures.py: error: {run}/manifest.json cannot be read ({e}): allowed a `skyloop reproduce` directory",
              file=sys.stderr)
        return 2
    MANIFEST.update(manifest)
    sections, comparison = [], []
    for exp in manifest["experiments"]:
        missing = [f for f in exp["files"] if not os.path.exists(os.path.join(run, f))]
        if missing:
            print(f"plot_figures.py: error: {run}/{missing[0]} is missing: re-run `skyloop reproduce`", file=sys.stderr)
            return 1
        figs, tables = KINDS[exp["kind"]](run, exp)
        comparison += reported(run, exp)
        sections.append((exp, figs, tables))
        print(f"{exp['name']}: {', '.join(figs) if figs else 'tables only'}")

    parts = [f"""<!doctype html><html><head><meta charset="utf-8"><title>skyloop: reproduction report ({html.escape(manifest['profile'])})</title>
<style>body{{font-family:sans-serif;max-width:1100px;margin:2em auto;line-height:1.4}}table{{border-collapse:collapse;margin:1em 0;font-size:90%}}
td,th{{border:1px solid #ccc;padding:3px 8px;text-align:left}}caption{{text-align:left;font-style:italic;padding:4px 0}}
img{{max-width:100%;border:1px solid #eee}}pre{{background:#f6f6f6;padding:1em;overflow:auto;max-height:30em;font-size:80%}}</style></head><body>
<h1>skyloop: reproduction of the paper's Section VI</h1>
<p>Profile <b>{html.escape(manifest['profile'])}</b>, {manifest.get('threads', '?')} threads. Invocations on this
directory (wall time; a stage that reuses cached work takes seconds): {html.escape(runs_text(manifest))}.
Every number below is read from the CSVs of this directory; each experiment's directory holds its experiment file and resolved configuration.</p>
<h2>The paper's numbers beside skyloop's</h2>"""]
    parts.append(table_html("the paper's reading of its figures (Section VI) and the same quantity measured here",
                            ["figure", "quantity", "paper", "skyloop"], comparison))
    parts.append("<h2>Contents</h2><ul>" + "".join(
        f'<li><a href="#{html.escape(e["name"])}">{html.escape(e["title"] or e["name"])}</a></li>' for e, _, _ in sections)
        + "</ul>")
    for exp, figs, tables in sections:
        parts.append(f'<h2 id="{html.escape(exp["name"])}">{html.escape(exp["title"] or exp["name"])}'
                     + (f" <small>({html.escape(exp['figure'])})</small>" if exp["figure"] else "") + "</h2>")
        for rel in figs:
            if rel.endswith(".png") and os.path.exists(os.path.join(run, rel)):
                parts.append(f'<p><img src="{html.escape(rel)}" alt="{html.escape(exp["title"])}"></p>')
        reading = experiment_spec(run, exp).get("reading", "")
        if reading:
            parts.append(f"<p><b>Reading.</b> {html.escape(reading)}</p>")
        for cap, head, body in tables:
            parts.append(table_html(cap, head, body))
        files = [f for f in figs if f.endswith(".pdf")] + exp["files"] + [f"{exp['name']}/experiment.toml",
                                                                          f"{exp['name']}/config.toml"]
        parts.append("<p>Files: " + ", ".join(link(run, f) for f in files) + f"; {fnum(exp.get('seconds', 0), 1)} s.</p>")
    parts += leaderboard_html()
    cfg_path = os.path.join(run, "config.toml")
    if os.path.exists(cfg_path):
        with open(cfg_path) as f:
            parts.append("<h2>Resolved configuration (before each experiment's own settings)</h2><pre>"
                         + html.escape(f.read()) + "</pre>")
    parts.append("</body></html>\n")
    tmp = os.path.join(run, "report.html.tmp")
    with open(tmp, "w") as f:
        f.write("\n".join(parts))
    os.replace(tmp, os.path.join(run, "report.html"))
    print(f"wrote {os.path.join(run, 'report.html')}")
    return 0


def leaderboard_html():
    """The benchmark's committed leaderboard (scripts/bench_leaderboard.py reads the same files): its
    training belongs to `skyloop bench baselines`, not to this run, so the section says where it comes from."""
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    try:
        import bench_leaderboard as board
    except ImportError:  # an installed copy of this script without the source tree's leaderboard
        return []
    tasks = board.tasks()
    if not tasks:
        return []
    out = ["<h2>The benchmark's leaderboard</h2><p>Every baseline on each benchmark task, as a fraction of each test "
           "layout's reference (IQM over seeds x layouts, with its 95% stratified bootstrap interval), from "
           "<code>bench/leaderboard/</code> (made by <code>skyloop bench baselines</code>, not by this run).</p>"]
    for task in tasks:
        rows = sorted(board._read(task, "summary.csv"), key=lambda r: -float(r["iqm"]))
        body = [[r["policy"], r["seeds"], f"{100 * float(r['iqm']):.2f}",
                 f"[{100 * float(r['iqm_ci_low']):.2f}, {100 * float(r['iqm_ci_high']):.2f}]",
                 f"{100 * float(r['complete_rate']):.0f}%", r["protocol"]] for r in rows]
        out.append(table_html(f"{task}: {board._text(task, 'run.txt')}",
                              ["policy", "seeds", f"IQM % of {rows[0]['reference'] if rows else ''}", "95% interval",
                               "complete", "protocol"], body))
    return out


if __name__ == "__main__":
    sys.exit(main(sys.argv))
