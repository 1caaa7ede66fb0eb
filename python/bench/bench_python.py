#!/usr/bin/env python3
"""Python-binding overhead, measured against the same work in C++ in the same process.

    PYTHONPATH=build/python /usr/bin/python3 python/bench/bench_python.py [--repeats 5]

1. VecEnv.step from Python vs C++ VecEnv::step, paper scenario, warm cache (every position the
   random actions reach already in the oracle's cache), M = 64 and M = 1, one core.
2. A beamformer batch from Python vs the C++ call: 1024 clusters, WMMSE.
Prints medians over --repeats runs.
"""
from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

import skyloop as sl
from skyloop import _skyloop


def actions_for(steps, M, N, seed):
    return np.random.default_rng(seed).integers(0, 5, size=(steps, M, N), dtype=np.int64)


def python_steps(env, actions):
    t0 = time.perf_counter()
    for a in actions:
        env.step(a)
    return time.perf_counter() - t0


def main():
    p = argparse.ArgumentParser()
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--steps", type=int, default=2000)
    a = p.parse_args()
    cfg = sl.config()  # the paper scenario, the paper's GNN as the oracle
    N = 3
    print("machine: 1 thread; paper scenario (N = 3, K = 12), GNN oracle, random actions, warm cache")
    for M in (64, 1):
        steps = a.steps if M == 64 else 20 * a.steps
        acts = actions_for(steps, M, N, 1)
        env = sl.VecEnv(cfg, M, 7)
        env.reset()
        python_steps(env, acts)  # warm: the same actions again reach the same (cached) positions
        py_t, cpp_t = [], []
        for _ in range(a.repeats):
            env.reset(seed=7)  # users of seed 7 again: a new oracle, so warm it once more
            python_steps(env, acts)
            env.reset(seed=7)
            python_steps(env, acts)
            py_t.append(python_steps(env, acts))
            # C++: the same environments (seed 7), the same actions, three passes: the last is timed warm.
            three = np.concatenate([acts, acts, acts])
            full = _skyloop._bench_cpp_vecenv(cfg, M, 7, three)
            warm_part = _skyloop._bench_cpp_vecenv(cfg, M, 7, np.concatenate([acts, acts]))
            cpp_t.append(full - warm_part)
        py, cpp = statistics.median(py_t), statistics.median(cpp_t)
        print(f"M = {M:3d}: Python {steps * M / py:12,.0f} env steps/s ({steps * M * N / py:12,.0f} agent steps/s, "
              f"{1e6 * py / steps:7.2f} us per call); C++ {steps * M / cpp:12,.0f} env steps/s ({1e6 * cpp / steps:7.2f} us per call); "
              f"Python / C++ = {cpp / py:.2f}; overhead per call {1e6 * (py - cpp) / steps:+.2f} us")

    model = sl.SystemModel(cfg)
    clusters = []
    s = 0
    while len(clusters) < 1024:
        clusters += model.clusters(model.random_snapshot(3, 12, s))
        s += 1
    clusters = clusters[:1024]
    bf = sl.beamformer("wmmse", cfg)
    py_t, cpp_t = [], []
    for _ in range(a.repeats):
        t0 = time.perf_counter()
        bf.design_batch(clusters, threads=1)
        py_t.append(time.perf_counter() - t0)
        cpp_t.append(_skyloop._bench_cpp_batch(bf, clusters, 1))
    py, cpp = statistics.median(py_t), statistics.median(cpp_t)
    print(f"WMMSE batch of 1024 clusters: Python {1e3 * py:.2f} ms, C++ {1e3 * cpp:.2f} ms, Python / C++ = {py / cpp:.3f}")


if __name__ == "__main__":
    main()
