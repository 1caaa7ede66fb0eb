#!/usr/bin/env python3
"""Your own precoder, in numpy, against WMMSE and the paper's GNN on identical channels.

    /usr/bin/python3 examples/custom_precoder.py [--samples 200] [--seed 1]
    (PYTHONPATH=build/python from a build tree, or after scripts/install-python)

The precoder here is a regularised zero forcing with its regulariser scaled by a factor (a
classic knob); replace ``my_precoder`` with yours: it receives a cluster's channel G [K_n, L]
(row k = h_k^H), the power budget and the noise power, and returns W [L, K_n] (column k = w_k).
"""
from __future__ import annotations

import argparse

import numpy as np

import skyloop as sl


def my_precoder(G: np.ndarray, p_max: float, noise: float, factor: float = 0.1) -> np.ndarray:
    K = G.shape[0]
    H = G.conj().T                                            # [L, K], column k = h_k
    W = H @ np.linalg.inv(G @ H + factor * K * noise / p_max * np.eye(K))
    return W * np.sqrt(p_max) / np.linalg.norm(W)             # on the budget: ||W||_F^2 = P_max


def compare(samples: int = 200, seed: int = 1, methods=("wmmse", "gnn", "zf", "mrt")) -> dict:
    """Mean network sum rate (bit/s/Hz) of my_precoder and each method on the same snapshots
    (those of `skyloop beamform eval --seed SEED`)."""
    cfg = sl.config()
    model = sl.SystemModel(cfg)
    bfs = {m: sl.beamformer(m, cfg) for m in methods}
    totals = {"mine": 0.0, **{m: 0.0 for m in methods}}
    for i in range(samples):
        snap = model.random_snapshot(cfg["scenario.uavs"], cfg["scenario.users"], sl.derive_seed(seed, i))
        for c in model.clusters(snap):
            totals["mine"] += sl.sum_rate(c, my_precoder(c.G, c.p_max, c.noise))
            for m, bf in bfs.items():
                totals[m] += sl.sum_rate(c, bf.design(c))
    return {k: v / samples for k, v in totals.items()}


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--samples", type=int, default=200)
    p.add_argument("--seed", type=int, default=1)
    a = p.parse_args()
    means = compare(a.samples, a.seed)
    best = means["wmmse"]
    print(f"{'method':<8} {'sum rate':>10} {'% of WMMSE':>11}")
    for m, v in sorted(means.items(), key=lambda kv: -kv[1]):
        print(f"{m:<8} {v:10.3f} {100 * v / best:10.1f}%")


if __name__ == "__main__":
    main()
