#!/usr/bin/env python3
"""Environment steps per second of `skyloop train` (MAPPO) beside a PyTorch MAPPO learner written
the way a researcher would (examples/ppo.py: CleanRL-style, torch.nn modules and autograd, driving
skyloop's Python VecEnv), at the same PPO settings, for the same number of steps, in one run.

    /usr/bin/python3 bench/ppo_speed.py [--steps 100000] [--out DIR]
    (PYTHONPATH=build/python from a build tree, or after scripts/install-python)

The MAPPO reference implementation's trainer is not packaged for this machine (no PyPI); the
PyTorch learner here does the same work per step: a 2 x 64 tanh actor and critic, the
agent-specific state as the critic's input, 8 environments x 256 steps per update, 10 epochs of 4
minibatches, Adam 3e-4, gradient clipping at 10, GAE(0.99, 0.95), on the paper's scenario with the
GNN rate oracle. Both run on the same number of threads (--threads, default every core: LibTorch's
intra-op threads for the PyTorch learner, run.threads for skyloop). Prints a table and writes
OUT/ppo_speed.csv (the seed and the thread count in every row).
"""
from __future__ import annotations

import argparse
import csv
import os
import pathlib
import re
import subprocess
import sys
import tempfile
import time

HERE = pathlib.Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "examples"))

import torch  # noqa: E402

import ppo  # noqa: E402  examples/ppo.py


def skyloop_binary() -> str:
    given = os.environ.get("SKYLOOP_BIN")
    if given:
        return given
    for c in (HERE.parent / "build" / "skyloop", pathlib.Path("/usr/local/bin/skyloop")):
        if c.exists():
            return str(c)
    sys.exit("ppo_speed: no skyloop binary (build/skyloop); run scripts/build first")


def run_skyloop(steps: int, seed: int, threads: int):
    with tempfile.TemporaryDirectory() as d:
        t0 = time.perf_counter()
        out = subprocess.run([skyloop_binary(), "train", "--algo", "mappo", "--steps", str(steps), "--seed", str(seed),
                              "--set", f"run.threads={threads}", "--out", os.path.join(d, "run")],
                             check=True, capture_output=True, text=True).stdout
        wall = time.perf_counter() - t0
    m = re.search(r"(\d+) environment steps in ([0-9.]+) s", out)
    if not m:
        sys.exit("ppo_speed: cannot read the training summary of skyloop train:\n" + out)
    return int(m.group(1)), float(m.group(2)), wall


def run_pytorch(steps: int, seed: int, threads: int):
    t0 = time.perf_counter()
    ppo.train(config={}, steps=steps, num_envs=8, num_steps=256, seed=seed, epochs=10, minibatches=4, ent_coef=0.03,
              max_grad=10.0, threads=threads)
    wall = time.perf_counter() - t0
    done = max(1, steps // (256 * 8)) * 256 * 8
    return done, wall, wall


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--steps", type=int, default=100_000, help="environment steps for each learner (default 100000)")
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--threads", type=int, default=0, help="threads for each learner (default 0: every core)")
    p.add_argument("--out", default="", help="directory for ppo_speed.csv (default: none)")
    a = p.parse_args()
    if a.steps < 2048:
        sys.exit(f"ppo_speed: --steps = {a.steps} is out of range: allowed at least 2048 (one update of 8 x 256 steps)")
    if a.threads < 0 or a.threads > 1024:
        sys.exit(f"ppo_speed: --threads = {a.threads} is out of range: allowed 0 (every core) to 1024")
    threads = a.threads or os.cpu_count() or 1
    torch.set_num_threads(threads)
    rows = []
    for name, fn in (("pytorch (examples/ppo.py)", run_pytorch), ("skyloop train", run_skyloop)):
        done, train_s, wall = fn(a.steps, a.seed, threads)
        rows.append({"seed": a.seed, "threads": threads, "learner": name, "env_steps": done, "seconds": round(train_s, 3),
                     "steps_per_s": round(done / train_s, 1)})
        print(f"{name:<28} {done:>9} steps {train_s:>9.1f} s {done / train_s:>10.0f} steps/s", flush=True)
    ratio = rows[1]["steps_per_s"] / rows[0]["steps_per_s"]
    print(f"skyloop train / pytorch: {ratio:.1f}x the environment steps per second")
    if a.out:
        os.makedirs(a.out, exist_ok=True)
        with open(os.path.join(a.out, "ppo_speed.csv"), "w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=list(rows[0]))
            w.writeheader()
            w.writerows(rows)


if __name__ == "__main__":
    main()
