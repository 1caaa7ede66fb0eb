#!/usr/bin/env python3
"""Python-binding overhead, measured against the same work in C++ in the same process.

    PYTHONPATH=build/python /usr/bin/python3 python/bench/bench_python.py [--repeats 5]

1. VecEnv.step from Python vs the same work in C++ (VecEnv::step, then the observation, state,
   agent-state and mask arrays written as the Python step writes them), on the same environments:
   paper scenario, warm cache (a random action sequence replayed from reset(), so every position
   is already cached), M = 64 and M = 1, one core. The difference is the binding's own cost.
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
        env = sl.VecEnv(cfg, M, 7)
        # Warm cache: the environments are deterministic given their users and the actions, so a
        # sequence replayed from reset() visits exactly the positions of its first pass (all cached).
        acts = actions_for(steps, M, N, 10)
        env.reset()
        python_steps(env, acts)
        py_t, cpp_t = [], []
        for r in range(a.repeats):
            env.reset()
            py_t.append(python_steps(env, acts))
            env.reset()
            cpp_t.append(env._env._bench_cpp_steps(acts))  # the same environments and caches, C++ alone
        py, cpp = statistics.median(py_t), statistics.median(cpp_t)
        print(f"M = {M:3d} (hit rate {env._env.hit_rate():.4f}): Python {steps * M / py:12,.0f} env steps/s "
              f"({steps * M * N / py:12,.0f} agent steps/s, {1e6 * py / steps:8.2f} us per call); "
              f"C++ {steps * M / cpp:12,.0f} env steps/s ({1e6 * cpp / steps:8.2f} us per call); "
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
