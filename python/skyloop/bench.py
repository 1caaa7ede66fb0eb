"""The benchmark from Python: score any policy on a task's test layouts against their exact optimum.

A task (``skyloop bench list``; docs/concepts/benchmark.md) is a frozen configuration, a fixed set of
test layouts and each layout's shipped reference objective (the exact optimum where the joint DP
fits, else the best-known planner). ``evaluate`` flies a policy on every test layout, for each of its
training seeds, through the same environment as ``skyloop bench run``, and returns one row per
(seed, layout) and the protocol's summary::

    import skyloop.bench as bench

    task = bench.task("paper-v1")
    def greedy_home(batch):                      # any callable: a batch of observations -> actions
        return my_policy(batch["obs"], batch["action_mask"])   # int [M, N] (or float [M, N, 2] commands)
    result = bench.evaluate(task, {1: greedy_home}, label="mine", steps=2_000_000)
    print(result.summary)                        # mean, IQM with its 95% interval, p5, completion
    result.write("bench_out")                    # rows.csv, summary.csv, profile.csv, marl_eval.json

``policy`` is a callable (one training seed, labelled 0), a dict {training seed: callable}, a
planner name (``skyloop.PLANNERS``) or a list of ``skyloop train`` run directories.
"""
from __future__ import annotations

import os
from typing import Callable, NamedTuple

import numpy as np

from . import InputError, _skyloop
from ._check import as_int, as_seed, as_str


class Task(NamedTuple):
    id: str                  # "paper-v1"
    name: str
    version: int
    title: str
    config: object           # skyloop.Config: train on it (env.resample_users draws training layouts)
    users_seeds: list        # the test layouts (skyloop/env/layouts.hpp), in order
    references: list         # one dict per test layout: layout, users_seed, users, reference, objective
    protocol: dict           # budget_steps, seeds, train_split
    reference_note: str
    dir: str


class Result(NamedTuple):
    rows: list               # one dict per (policy, seed, layout): objective, reference, fraction, complete, ...
    summary: list            # one dict per policy: seeds, layouts, mean, iqm, iqm_ci_low, iqm_ci_high, p5, complete_rate, protocol
    files: dict              # the output files' texts by name

    def write(self, out: str) -> None:
        """Writes the outputs under ``out`` (made if missing): each file whole or not at all."""
        out = as_str(out, "out")
        os.makedirs(out, exist_ok=True)
        for name, text in self.files.items():
            path = os.path.join(out, name)
            tmp = path + ".tmp"
            with open(tmp, "w") as f:
                f.write(text)
            os.replace(tmp, path)


def tasks() -> list:
    """Every task's id (``skyloop bench list``)."""
    return list(_skyloop.bench_tasks())


def task(name) -> Task:
    """A task by id ("paper-v1"), by name (its highest version) or by folder."""
    if isinstance(name, Task):
        return name
    d = _skyloop.bench_task(as_str(name, "task"))
    return Task(d["id"], d["name"], d["version"], d["title"], d["config"], [r["users_seed"] for r in d["references"]],
                list(d["references"]), dict(d["protocol"]), d["reference_note"], d["dir"])


def _policies(policy) -> dict:
    """{seed: callable} from a callable or a dict of them."""
    if callable(policy):
        return {0: policy}
    if isinstance(policy, dict) and policy:
        out = {}
        for k, v in policy.items():
            seed = as_seed(k, "policy's seed")
            if not callable(v):
                raise InputError(f"policy[{k!r}] = {v!r} is not callable: allowed a function of a batch of observations")
            out[seed] = v
        return out
    raise InputError(f"policy = {policy!r} has the wrong type: allowed a callable, a dict {{seed: callable}}, a planner "
                     f"name or a list of run directories")


def _protocol(t: Task, steps, layouts_on: str) -> str:
    reasons = []
    if steps is None:
        reasons.append("training budget not stated")
    elif as_int(steps, "steps", 0, 2**62) != t.protocol["budget_steps"]:
        reasons.append(f"trained {steps} steps, the budget is {t.protocol['budget_steps']}")
    if layouts_on != t.protocol["train_split"]:
        reasons.append(f"trained on {layouts_on} layouts, allowed {t.protocol['train_split']}")
    return "; ".join(reasons) if reasons else "ok"


def fly(t: Task, fn: Callable, seed: int = 0) -> list:
    """One episode of ``fn`` on every test layout at once (a VecEnv with one environment per layout);
    returns one dict per layout: objective, home, complete, collisions, boundary_events, energy_j.

    ``fn(batch)`` gets a dict of the spec's arrays for the layouts still flying: ``obs`` float32
    [M, N, O], ``state`` [M, S], ``agent_state`` [M, N, A], ``action_mask`` int8 [M, N, num_actions],
    and ``spec`` (the environment's spec: names, offsets, bounds); it returns int actions [M, N] or,
    under continuous mobility, float commands [M, N, 2] in [-1, 1]."""
    from .env import VecEnv
    env = VecEnv(t.config, len(t.users_seeds), seed=0, layouts=t.users_seeds)
    o = env.reset()
    M = env.num_envs
    done = np.zeros(M, dtype=bool)
    out = [None] * M
    arrays = {"obs": o.obs, "state": o.state, "agent_state": o.agent_state, "action_mask": o.action_mask}
    while not done.all():
        a = np.asarray(fn({**arrays, "spec": env.spec}))
        if a.shape[:1] == (M,):  # a finished layout restarts: its row is flown but not scored, so hover it
            a = np.where(done.reshape((M,) + (1,) * (a.ndim - 1)), 0.0 if a.ndim == 3 else env.spec["hover"], a)
        r = env.step(a)
        ended = (r.terminated | r.truncated) & ~done
        for i in np.flatnonzero(ended):
            info = r.info
            home = int(info["home"][i])
            collisions, boundary = int(info["episode_collisions"][i]), int(info["episode_boundary"][i])
            out[i] = {"objective": float(info["objective"][i]), "home": home, "collisions": collisions,
                      "boundary_events": boundary, "energy_j": float(info["episode_energy_j"][i]),
                      "complete": bool(info["success"][i]) and collisions == 0 and boundary == 0}
        done |= ended
        arrays = {"obs": r.obs, "state": r.state, "agent_state": r.agent_state, "action_mask": r.action_mask}
    env.close()
    return out


def evaluate(t, policy, label: str = "policy", steps=None, trained_on: str = "train", threads: int = 0) -> Result:
    """Scores ``policy`` on task ``t`` (a Task or its id) under the task's protocol.

    ``policy``: a callable ``fn(batch) -> actions`` (see ``fly``) or {training seed: callable};
    a planner name of ``skyloop.PLANNERS``; or a list of ``skyloop train`` run directories (one per
    training seed; their budget and training layouts are read from them). ``steps``: the environment
    steps the callables were trained for, and ``trained_on``: the layouts they trained on ("train"
    for the task's train split); a run that states neither, or differs from the protocol, is labelled
    so in every row and summary, never mixed in silently."""
    t = task(t)
    label = as_str(label, "label")
    if isinstance(policy, str) or (isinstance(policy, (list, tuple)) and policy and all(isinstance(p, str) for p in policy)):
        names = [policy] if isinstance(policy, str) else list(policy)
        planners = [p for p in names if p in _skyloop.PLANNERS]
        dirs = [p for p in names if p not in _skyloop.PLANNERS]
        rows = _skyloop.bench_run(t.id, planners, dirs, [], label if dirs and label != "policy" else "",
                                  as_int(threads, "threads", 0, 1024))
    else:
        protocol = _protocol(t, steps, as_str(trained_on, "trained_on"))
        rows = []
        for seed, fn in _policies(policy).items():
            for ref, got in zip(t.references, fly(t, fn)):
                frac = got["objective"] / ref["objective"] if ref["objective"] > 0 else 0.0
                rows.append({"task": t.name, "version": t.version, "policy": label, "seed": seed, "layout": ref["layout"],
                             "users_seed": ref["users_seed"], "users": ref["users"], "objective": got["objective"],
                             "reference": ref["reference"], "reference_objective": ref["objective"], "fraction": frac,
                             "complete": got["complete"], "home": got["home"], "collisions": got["collisions"],
                             "boundary_events": got["boundary_events"], "energy_j": got["energy_j"], "protocol": protocol})
    out = _skyloop.bench_outputs(t.id, rows)
    return Result(list(rows), list(out["summary"]), dict(out["files"]))


def interquartile_mean(scores) -> float:
    """The mean of the middle half of ``scores`` (scipy.stats.trim_mean(scores, 0.25)): the protocol's statistic."""
    return _skyloop.interquartile_mean([float(x) for x in np.ravel(scores)])
