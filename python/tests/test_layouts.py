"""skyloop.evaluate_layouts: planners on held-out layouts, each against its own exact optimum."""
import os

import numpy as np
import pytest

import skyloop as sl

SMALL = {"env.oracle": "zf", "scenario.area_x_m": 120, "scenario.area_y_m": 120, "scenario.users": 6,
         "trajectory.starts": [[0, 0], [120, 120]], "trajectory.destinations": [[120, 40], [0, 80]],
         "trajectory.t_max": 12}


def test_rows_summary_and_the_optimum_cache(tmp_path):
    cache = str(tmp_path / "optimum")
    out = sl.evaluate_layouts(SMALL, planners=["greedy", "random"], layouts=4, cache=cache, threads=1)
    rows, summary = out["rows"], out["summary"]
    assert [r["planner"] for r in rows[:3]] == ["greedy", "random", "optimal"] and len(rows) == 12
    assert [s["planner"] for s in summary] == ["greedy", "random", "optimal"]
    for r in rows:
        assert r["split"] == "test" and r["users_seed"] >= 2 ** 63 and r["seed"] == 1
        assert r["fraction"] <= 1 + 1e-9 and r["reference_objective"] > 0 and r["reference"] == "optimal"
        assert r["fraction"] == pytest.approx(r["objective"] / r["reference_objective"])
    opt = summary[2]
    assert opt["complete_rate"] == 1 and opt["fraction_mean"] == pytest.approx(1) and opt["fraction_worst"] == pytest.approx(1)
    fr = [r["fraction"] for r in rows if r["planner"] == "random"]
    assert summary[1]["fraction_worst"] == pytest.approx(min(fr))
    assert summary[1]["fraction_p5"] == pytest.approx(float(np.percentile(fr, 5)))
    assert len(os.listdir(cache)) == 4
    # Same layouts, same numbers; the optimum now comes from the cache.
    again = sl.evaluate_layouts(SMALL, planners=["greedy", "random"], layouts=4, cache=cache, threads=2)
    for a, b in zip(rows, again["rows"]):
        assert {k: v for k, v in a.items() if k != "seconds"} == {k: v for k, v in b.items() if k != "seconds"}
    # Validation layouts are others.
    val = sl.evaluate_layouts(SMALL, planners=["greedy"], layouts=2, split="validation", threads=1)["rows"]
    assert all(2 ** 62 <= r["users_seed"] < 2 ** 63 for r in val)


def test_the_rollout_never_falls_below_its_base():
    # "rollout" (multiagent rollout over seqgreedy) is a registered planner; its missions are never
    # worse than seqgreedy's (complete first, then the objective) and never above the optimum.
    rows = sl.evaluate_layouts(SMALL, planners=["seqgreedy", "rollout"], layouts=6, threads=1)["rows"]
    assert [r["planner"] for r in rows[:3]] == ["seqgreedy", "rollout", "optimal"]
    for base, roll in zip(rows[0::3], rows[1::3]):
        assert roll["complete"] >= base["complete"]
        if roll["complete"] == base["complete"]:
            assert roll["objective"] >= base["objective"]
        assert roll["fraction"] <= 1 + 1e-9


def test_bad_arguments_raise_input_errors():
    with pytest.raises(sl.InputError, match="split"):
        sl.evaluate_layouts(SMALL, planners=["greedy"], layouts=1, split="holdout")
    with pytest.raises(sl.InputError, match="planner"):
        sl.evaluate_layouts(SMALL, planners=["teleport"], layouts=1)
    with pytest.raises(sl.InputError, match="layouts"):
        sl.evaluate_layouts(SMALL, planners=["greedy"], layouts=0)


def test_the_action_mask_brings_every_uav_home():
    # Random play inside the environment's action mask (the reachability mask) always arrives.
    env = sl.VecEnv(dict(SMALL, **{"env.resample_users": True}), num_envs=4, seed=2)
    o = env.reset()
    rng = np.random.default_rng(0)
    finished = 0
    for _ in range(200):
        u = rng.random(o.action_mask.shape) * o.action_mask
        o = env.step(u.argmax(-1))
        done = o.terminated | o.truncated
        assert not o.truncated.any(), "a UAV flying inside the mask missed its destination"
        finished += int(done.sum())
    assert finished >= 40
