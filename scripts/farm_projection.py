#!/usr/bin/env python3
"""Expected wall time of `skyloop reproduce` on P ranks, from its pieces.

    build/skyloop reproduce --profile paper --plan > plan.csv
    scripts/farm_projection.py plan.csv --measured results/paper/farm/pieces.csv --ranks 1 2 8 32 128

plan.csv (from --plan) lists every piece with its estimated seconds on one core and its
dependencies; --measured (farm/pieces.csv files of earlier runs) replaces an estimate by the time
measured for the same piece; --scale multiplies the estimates of one kind (e.g. marl=1.1) to
calibrate them. The farm is simulated as it schedules: phase 0 (the models) first, then phase 1;
a free rank takes the ready piece with the longest time; each piece costs --overhead-ms more.
Printed per P: the simulated wall time, the two bounds no schedule beats (total work / P, and the
longest chain of dependent pieces, which is at least the longest piece) and the efficiency."""
import argparse
import csv
import heapq
import sys


def load(plan, measured, scale):
    pieces = {}
    with open(plan) as f:
        for r in csv.DictReader(f):
            t = float(r["cost_estimate"]) * scale.get(r["kind"], 1.0)
            pieces[(int(r["phase"]), r["piece"])] = {"kind": r["kind"], "label": r["label"], "t": t, "measured": False,
                                                     "deps": [d for d in r["deps"].split(";") if d]}
    for m in measured:
        with open(m) as f:
            for r in csv.DictReader(f):
                key = (int(r["phase"]), r["piece"])
                if key in pieces and r["status"] == "done":
                    pieces[key]["t"] = float(r["seconds"])
                    pieces[key]["measured"] = True
    return pieces


def simulate(pieces, ranks, overhead):
    wall = 0.0
    for phase in sorted({p for p, _ in pieces}):
        ps = {k[1]: v for k, v in pieces.items() if k[0] == phase}
        missing = {i: sum(d in ps for d in v["deps"]) for i, v in ps.items()}
        after = {i: [] for i in ps}
        for i, v in ps.items():
            for d in v["deps"]:
                if d in ps:
                    after[d].append(i)
        ready = [(-v["t"], i) for i, v in ps.items() if missing[i] == 0]
        heapq.heapify(ready)
        running = []  # (end, piece)
        free, now = ranks, wall
        while ready or running:
            while free and ready:
                _, i = heapq.heappop(ready)
                heapq.heappush(running, (now + ps[i]["t"] + overhead, i))
                free -= 1
            now, i = heapq.heappop(running)
            free += 1
            for j in after[i]:
                missing[j] -= 1
                if missing[j] == 0:
                    heapq.heappush(ready, (-ps[j]["t"], j))
        wall = now
    return wall


def chain(pieces):
    """Longest chain of dependent pieces, phases in sequence."""
    total = 0.0
    for phase in sorted({p for p, _ in pieces}):
        ps = {k[1]: v for k, v in pieces.items() if k[0] == phase}
        memo = {}

        def longest(i):
            if i not in memo:
                memo[i] = ps[i]["t"] + max([longest(d) for d in ps[i]["deps"] if d in ps], default=0.0)
            return memo[i]

        total += max((longest(i) for i in ps), default=0.0)
    return total


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("plan")
    ap.add_argument("--measured", nargs="*", default=[])
    ap.add_argument("--ranks", nargs="+", type=int, default=[1, 2, 8, 32, 128])
    ap.add_argument("--overhead-ms", type=float, default=5.0)
    ap.add_argument("--scale", nargs="*", default=[], help="KIND=FACTOR applied to the estimates of that kind")
    a = ap.parse_args()
    scale = {k: float(v) for k, v in (s.split("=") for s in a.scale)}
    pieces = load(a.plan, a.measured, scale)
    if not pieces:
        sys.exit("no pieces in " + a.plan)
    work = sum(v["t"] for v in pieces.values())
    longest = max(pieces.items(), key=lambda kv: kv[1]["t"])
    cp = chain(pieces)
    kinds = {}
    for v in pieces.values():
        k = kinds.setdefault(v["kind"], [0, 0.0, 0])
        k[0] += 1
        k[1] += v["t"]
        k[2] += v["measured"]
    print(f"{len(pieces)} pieces, {work / 60:.1f} min of work on one core; longest piece {longest[1]['t'] / 60:.1f} min "
          f"({longest[0][1]}); longest dependency chain {cp / 60:.1f} min")
    for kind, (n, t, m) in sorted(kinds.items()):
        print(f"  {kind:6s} {n:4d} pieces {t / 60:8.1f} min ({m} measured, {n - m} estimated)")
    print(f"{'ranks':>6} {'wall (min)':>11} {'work/P (min)':>13} {'chain (min)':>12} {'efficiency':>11}")
    for p in a.ranks:
        w = simulate(pieces, p, a.overhead_ms / 1e3)
        print(f"{p:6d} {w / 60:11.1f} {work / p / 60:13.1f} {cp / 60:12.1f} {work / (p * w):11.0%}")


if __name__ == "__main__":
    main()
