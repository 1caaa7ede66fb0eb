#!/usr/bin/env python3
"""The paper's GNN beamformer written as plain eager PyTorch, the way a researcher would, timed
beside skyloop's serving paths in the same process: the peer of BM_GnnDecision.

    PYTHONPATH=build/python /usr/bin/python3 bench/gnn_eager.py [--model models/gnn] [--repeats 7]

One decision = one snapshot of the paper scenario (N = 3 UAVs, K = 12 users): its clusters in one
batched forward pass, scaled onto each UAV's budget. The eager network reads the same weights and
input normalisation from the same checkpoint (model.pt) and must give the same beamformers as
skyloop (checked first, to float32 tolerance). One thread everywhere. Prints the median time per
decision of: eager PyTorch, skyloop's LibTorch path and skyloop's fused path (nn.inference =
"fast", the default), the latter two timed in C++ (no binding overhead) on the same snapshots.
"""
from __future__ import annotations

import argparse
import json
import statistics
import time

import numpy as np
import torch
import torch.nn as nn

import skyloop as sl
from skyloop import _skyloop


class GraphNorm(nn.Module):
    """GraphNorm over each cluster's users (Cai et al. 2021)."""

    def __init__(self, d):
        super().__init__()
        self.gamma = nn.Parameter(torch.ones(d))
        self.beta = nn.Parameter(torch.zeros(d))
        self.alpha = nn.Parameter(torch.ones(d))

    def forward(self, x, seg, count):
        mean = torch.zeros(count.shape[0], x.shape[1]).index_add(0, seg, x) / count
        centred = x - self.alpha * mean[seg]
        var = torch.zeros(count.shape[0], x.shape[1]).index_add(0, seg, centred * centred) / count
        return self.gamma * centred / torch.sqrt(var[seg] + 1e-5) + self.beta


class Mlp(nn.Module):
    def __init__(self, din, dh, dout, norm, final=False):
        super().__init__()
        self.l1, self.l2, self.norm, self.final = nn.Linear(din, dh), nn.Linear(dh, dout), norm, final
        make = (lambda d: GraphNorm(d)) if norm == "graph" else (lambda d: nn.LayerNorm(d))
        self.n1 = make(dh)
        if not final:
            self.n2 = make(dout)

    def _norm(self, n, h, seg, count):
        return n(h, seg, count) if self.norm == "graph" else n(h)

    def forward(self, x, seg=None, count=None):
        h = torch.relu(self._norm(self.n1, self.l1(x), seg, count))
        h = self.l2(h)
        return h if self.final else torch.relu(self._norm(self.n2, h, seg, count))


class Gnn(nn.Module):
    """Section IV: user and UAV encoders, L_g message-passing layers, readout to 2L reals."""

    def __init__(self, L, d, layers):
        super().__init__()
        self.user_enc, self.uav_enc = Mlp(2 * L, d, d, "graph"), Mlp(d, d, d, "layer")
        self.user_msg = nn.ModuleList([Mlp(d, d, d, "graph") for _ in range(layers)])
        self.uav_msg = nn.ModuleList([Mlp(d, d, d, "layer") for _ in range(layers)])
        self.user_upd = nn.ModuleList([Mlp(3 * d, d, d, "graph") for _ in range(layers)])
        self.uav_upd = nn.ModuleList([Mlp(2 * d, d, d, "layer") for _ in range(layers)])
        self.out = Mlp(d, d, 2 * L, "graph", final=True)

    def forward(self, x, seg, pos, count, kmax):
        C = count.shape[0]

        def seg_mean(v):
            return torch.zeros(C, v.shape[1]).index_add(0, seg, v) / count

        def max_over_others(v):  # max over the other users j != k of k's cluster; 0 if none
            if kmax < 2:
                return torch.zeros_like(v)
            padded = torch.full((C, kmax, v.shape[1]), -float("inf")).index_put((seg, pos), v)
            top, idx = padded.topk(2, dim=1)
            other = torch.where(idx[:, 0][seg] == pos[:, None], top[:, 1][seg], top[:, 0][seg])
            return torch.where(torch.isinf(other), torch.zeros_like(other), other)

        u = self.user_enc(x, seg, count)
        a = self.uav_enc(seg_mean(u))
        for l in range(len(self.user_msg)):
            mu = self.user_msg[l](u, seg, count)
            ma = self.uav_msg[l](a)
            u = self.user_upd[l](torch.cat([u, ma[seg], max_over_others(mu)], 1), seg, count)
            a = self.uav_upd[l](torch.cat([a, seg_mean(mu)], 1))
        return self.out(u, seg, count)


def load(model_dir):
    archive = torch.jit.load(f"{model_dir}/model.pt")
    meta = json.loads(archive._c.getattr("skyloop_meta"))
    net = Gnn(meta["antennas"], meta["hidden"], meta["layers"])
    state = {k[len("model."):]: v for k, v in archive.named_parameters()}
    net.load_state_dict(state)
    return net.eval(), meta


def batch_of(clusters, scale):
    """Features x = [Re h, Im h] * scale (h = conj of G's rows), segment ids, positions, counts."""
    rows = np.concatenate([c.G for c in clusters])
    h = np.conj(rows)
    x = torch.tensor(np.concatenate([h.real, h.imag], 1) * scale, dtype=torch.float32)
    sizes = [c.size for c in clusters]
    seg = torch.repeat_interleave(torch.arange(len(sizes)), torch.tensor(sizes))
    pos = torch.cat([torch.arange(k) for k in sizes])
    count = torch.tensor(sizes, dtype=torch.float32)[:, None]
    return x, seg, pos, count, max(sizes)


def decide(net, clusters, scale):
    """Beamformers on each cluster's budget (full power), one complex [L, K_n] array per cluster."""
    x, seg, pos, count, kmax = batch_of(clusters, scale)
    raw = net(x, seg, pos, count, kmax)
    L = raw.shape[1] // 2
    power = torch.zeros(count.shape[0]).index_add(0, seg, (raw * raw).sum(1))
    p_max = torch.tensor([c.p_max for c in clusters], dtype=torch.float32)
    w = raw * torch.sqrt(p_max / (power + 1e-12))[seg][:, None]
    w = w.double().numpy()
    out, row = [], 0
    for c in clusters:
        out.append((w[row:row + c.size, :L] + 1j * w[row:row + c.size, L:]).T)
        row += c.size
    return out


def main():
    p = argparse.ArgumentParser()
    p.add_argument("--model", default=f"{sl.data_dir() if hasattr(sl, 'data_dir') else _skyloop.data_dir()}/models/gnn")
    p.add_argument("--repeats", type=int, default=7)
    p.add_argument("--decisions", type=int, default=64)
    p.add_argument("--passes", type=int, default=10, help="passes over the decisions per repeat")
    a = p.parse_args()
    torch.set_num_threads(1)

    net, meta = load(a.model)
    cfg = sl.config()
    model = sl.SystemModel(cfg)
    decisions = [model.clusters(model.random_snapshot(3, 12, s)) for s in range(a.decisions)]
    decisions = [[c for c in d if c.size > 0] for d in decisions]
    fast = sl.beamformer(f"gnn={a.model}", cfg)
    ref = sl.beamformer(f"gnn={a.model}", sl.config(nn={"inference": "torch"}))

    # Same network, same weights: the eager beamformers equal skyloop's (float32 tolerance).
    worst = 0.0
    with torch.inference_mode():
        for d in decisions:
            for W, Wf, Wt in zip(decide(net, d, meta["feature_scale"]), fast.design_batch(d, 1), ref.design_batch(d, 1)):
                scale = np.sqrt(d[0].p_max)
                worst = max(worst, np.abs(W - Wt).max() / scale, np.abs(W - Wf).max() / scale)
    print(f"max |W_eager - W_skyloop| / sqrt(P_max) over {len(decisions)} decisions: {worst:.2e}")
    if worst > 1e-3:
        raise SystemExit("the eager network does not reproduce skyloop's beamformers")

    def eager_once():
        t0 = time.perf_counter()
        with torch.inference_mode():
            for _ in range(a.passes):
                for d in decisions:
                    decide(net, d, meta["feature_scale"])
        return (time.perf_counter() - t0) / (a.passes * len(decisions))

    def cpp_once(bf):
        return statistics.mean(_skyloop._bench_cpp_batch(bf, d, a.passes) for d in decisions)

    # Interleaved, so that a slow stretch of the machine falls on all three alike.
    times = {"eager": [], "libtorch": [], "fused": []}
    for _ in range(a.repeats):
        times["eager"].append(eager_once())
        times["libtorch"].append(cpp_once(ref))
        times["fused"].append(cpp_once(fast))
    eager, libtorch, fused = (statistics.median(times[k]) for k in ("eager", "libtorch", "fused"))
    print(f"per decision (N = 3, K = 12, one thread, median of {a.repeats}):")
    print(f"  eager PyTorch (Python)   {eager * 1e6:9.1f} us")
    print(f"  skyloop, LibTorch path   {libtorch * 1e6:9.1f} us   ({eager / libtorch:.1f}x faster than eager)")
    print(f"  skyloop, fused path      {fused * 1e6:9.1f} us   ({eager / fused:.1f}x faster than eager)")


if __name__ == "__main__":
    main()
