"""A golden command in Python: seeded rollouts of sl.VecEnv under several configurations, every
observation, state, mask, reward and info field written to CSV (scripts/golden runs it as
`python tests/golden/env_rollout.py OUT`)."""
import csv
import sys
from pathlib import Path

import numpy as np

import skyloop as sl

CASES = {
    "paper": {},
    "set-lookahead": {"marl.encoder": "set", "marl.lookahead": True, "marl.rate_map": 2},
    "headings-energy": {"trajectory.mobility": "headings", "env.objective": "energy-efficiency"},
    "shared-zf": {"channel.spectrum": "shared", "env.oracle": "zf"},
    "rician-uma": {"channel.pathloss": "3gpp-uma-av", "channel.fading": "rician", "env.oracle": "zfsel"},
}


def flat(a):
    return " ".join(repr(float(v)) for v in np.asarray(a, dtype=np.float64).ravel())


def write_info(w, name, step, prefix, value):
    if isinstance(value, dict):
        for k in sorted(value):
            write_info(w, name, step, f"{prefix}.{k}", value[k])
    else:
        w.writerow([name, step, prefix, flat(value)])


def main(out):
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    for name, overrides in CASES.items():
        cfg = sl.config(overrides=overrides)
        env = sl.VecEnv(cfg, num_envs=3, seed=7)
        rng = np.random.default_rng(11)
        o = env.reset()
        with open(out / f"{name}.csv", "w", newline="") as f:
            w = csv.writer(f)
            w.writerow(["case", "step", "field", "values"])
            for k in ("obs", "state", "agent_state", "action_mask"):
                w.writerow([name, 0, k, flat(getattr(o, k))])
            for step in range(1, 31):
                mask = np.asarray(o.action_mask, dtype=bool)
                # a seeded random allowed move per UAV
                choice = np.array([[rng.choice(np.flatnonzero(m)) for m in env_mask] for env_mask in mask])
                r = env.step(choice)
                o = r
                w.writerow([name, step, "actions", flat(choice)])
                for k in ("obs", "state", "agent_state", "action_mask", "reward", "terminated", "truncated"):
                    w.writerow([name, step, k, flat(getattr(r, k))])
                write_info(w, name, step, "info", r.info)
            pos = env.positions()  # x, y here; the altitudes in a file of their own
            write_info(w, name, 31, "positions", {k: v[..., :2] if k != "t" else v for k, v in pos.items()})
            for i in range(env.num_envs):
                write_info(w, name, 31, f"users{i}", env.users(i))
        with open(out / f"{name}-altitudes.csv", "w", newline="") as f:
            w = csv.writer(f)
            w.writerow(["case", "step", "field", "values"])
            write_info(w, name, 31, "altitudes", {k: pos[k][..., 2] for k in ("uavs", "destinations")})


if __name__ == "__main__":
    main(sys.argv[1])
