"""The batch-first environment: shapes, bounds, seeding, auto-reset, errors that corrupt nothing."""
import numpy as np
import pytest

import skyloop as sl

SMALL = {"env.oracle": "zf"}


def random_actions(rng, mask):
    # Uniform over each agent's allowed actions.
    M, N, A = mask.shape
    u = rng.random((M, N, A)) * mask
    return u.argmax(-1)


def test_shapes_dtypes_and_bounds():
    env = sl.VecEnv(SMALL, num_envs=5, seed=1)
    o = env.reset()
    M, N, K = 5, 3, 12
    assert o.obs.shape == (M, N, 11) and o.obs.dtype == np.float32
    assert o.state.shape == (M, 4 * N + 2 * K) and o.state.dtype == np.float32
    assert o.agent_state.shape == (M, N, 4 * N + 2 * K + N + 11)
    assert o.action_mask.shape == (M, N, 5) and o.action_mask.dtype == np.int8
    assert np.all(o.action_mask == 1)
    rng = np.random.default_rng(0)
    seen_done = False
    for _ in range(60):
        r = env.step(random_actions(rng, o.action_mask))
        assert r.reward.shape == (M,) and r.terminated.dtype == np.bool_ and r.truncated.shape == (M,)
        assert np.all(np.abs(r.obs) <= 1) and np.all((r.state >= 0) & (r.state <= 1))
        for k in ("sum_rate", "objective", "collisions", "boundary", "arrivals", "home", "T", "success"):
            assert r.info[k].shape == (M,)
        assert np.all(r.info["sum_rate"] > 0)
        # Agent-specific state = state, one-hot id, obs.
        assert np.array_equal(r.agent_state[:, :, :r.state.shape[1]], np.repeat(r.state[:, None], N, axis=1))
        assert np.array_equal(r.agent_state[:, :, -11:], r.obs)
        assert r.info["final_obs"].shape == (M, N, 11) and r.info["final_state"].shape == r.state.shape
        done = r.terminated | r.truncated
        assert np.all(r.info["final_obs"][~done] == 0)
        if done.any():
            seen_done = True
            i = int(np.flatnonzero(done)[0])
            assert r.info["T"][i] >= 2 and np.any(r.info["final_obs"][i] != 0)
            assert np.all(r.action_mask[i] == 1)  # auto-reset: the new episode's first slot
        o = r
    assert seen_done


def test_arrived_uavs_keep_their_place_with_stay_mask():
    cfg = sl.config(overrides={"env.oracle": "zf", "trajectory.starts": [[20, 20], [180, 180]],
                               "trajectory.destinations": [[40, 20], [180, 100]]})
    env = sl.VecEnv(cfg, 1, 0)
    o = env.reset()
    r = env.step(np.array([[3, 4]]))  # UAV 0 moves RIGHT onto its destination
    assert r.action_mask[0, 0].tolist() == [0, 0, 0, 0, 1]
    assert r.action_mask[0, 1].tolist() == [1, 1, 1, 1, 1]
    assert r.obs.shape[1] == 2
    before = env.positions()["uavs"][0, 0].copy()
    env.step(np.array([[0, 4]]))  # an action for the arrived UAV is executed as STAY
    assert np.array_equal(env.positions()["uavs"][0, 0], before)


def test_same_seed_same_arrays_other_seed_other_users():
    def rollout(seed):
        env = sl.VecEnv(SMALL, 4, seed)
        o = env.reset()
        rng = np.random.default_rng(7)
        out = [o.obs.copy()]
        for _ in range(30):
            o = env.step(random_actions(rng, o.action_mask))
            out += [o.obs.copy(), o.reward.copy(), o.info["sum_rate"].copy()]
        return out, env.users(0)
    a, ua = rollout(3)
    b, ub = rollout(3)
    c, uc = rollout(4)
    assert all(np.array_equal(x, y) for x, y in zip(a, b))
    assert np.array_equal(ua, ub) and not np.array_equal(ua, uc)
    env = sl.VecEnv(SMALL, 2, 3)
    assert not np.array_equal(env.users(0), env.users(1))  # each environment its own users
    env.reset(seed=4)
    assert np.array_equal(env.users(0), uc)


@pytest.mark.parametrize("actions, message", [
    (np.zeros((2, 3)), "dtype float64"),
    (np.zeros((3, 3), dtype=np.int64), "shape [3, 3]"),
    (np.zeros((2, 2), dtype=np.int64), "shape [2, 2]"),
    (np.full((2, 3), 5, dtype=np.int64), "actions[0, 0] = 5 is invalid"),
    (np.full((2, 3), -1, dtype=np.int32), "= -1 is invalid"),
])
def test_bad_actions_raise_and_corrupt_nothing(actions, message):
    env = sl.VecEnv(SMALL, 2, 1)
    ref = sl.VecEnv(SMALL, 2, 1)
    env.reset(), ref.reset()
    good = np.array([[3, 1, 2], [0, 4, 3]])
    env.step(good), ref.step(good)
    with pytest.raises(sl.InputError) as e:
        env.step(actions)
    assert message in str(e.value)
    a, b = env.step(good), ref.step(good)
    assert np.array_equal(a.obs, b.obs) and np.array_equal(a.reward, b.reward)
    assert np.array_equal(env.positions()["uavs"], ref.positions()["uavs"])


def test_bad_construction():
    with pytest.raises(sl.InputError, match="num_envs = 0"):
        sl.VecEnv(SMALL, 0, 1)
    with pytest.raises(sl.InputError, match="unknown"):
        sl.VecEnv(SMALL, 1, 1, oracle="nosuch")


def test_planners_from_python_equal_the_cli(skyloop_bin, tmp_path):
    import csv
    from conftest import run_cli, SQUARE, SQUARE_SET
    r = run_cli("plan", "--planner", "random,greedy,optimal", "--seed", "3", *SQUARE_SET, "--out", str(tmp_path))
    assert r.returncode == 0, r.stderr
    rows = {row["planner"]: row for row in csv.DictReader(open(tmp_path / "summary.csv"))}
    cfg = sl.config(overrides=SQUARE)
    results = {p: sl.plan(cfg, p, users_seed=3) for p in ("random", "greedy", "optimal")}
    for p, res in results.items():
        assert res["objective"] == float(rows[p]["objective"]), p
        assert res["positions"].shape == (res["T"], 3, 3) and res["rates"].shape == (res["T"],)
        assert np.isclose(res["rates"].mean(), res["objective"], rtol=1e-12)
    assert results["optimal"]["objective"] >= max(results["random"]["objective"], results["greedy"]["objective"])
    users = sl.VecEnv(cfg, 1, 9).users(0)
    explicit = sl.plan(cfg, "optimal", users=users)
    assert explicit["success"] and explicit["collisions"] == 0
    with pytest.raises(sl.InputError, match="planner 'nosuch' is unknown"):
        sl.plan(cfg, "nosuch")


@pytest.mark.skipif(not sl._skyloop.HAS_TORCH, reason="trained policies need a LibTorch build")
def test_trained_policy_from_python(skyloop_bin, tmp_path):
    from conftest import run_cli, SQUARE, SQUARE_SET
    out = tmp_path / "pol"
    r = run_cli("train", "--algo", "mappo", "--steps", "512", "--out", str(out), *SQUARE_SET,
                "--set", "marl.envs=2", "--set", "marl.rollout=64", "--set", "run.threads=1")
    assert r.returncode == 0, r.stderr
    small = sl.config(overrides=SQUARE)
    res = sl.plan(small, str(out), users_seed=3)
    assert res["planner"] and res["positions"].shape[1:] == (3, 3)
    # The policy as a rollout's base: never below its own mission on any layout (failures first).
    ev = sl.evaluate_layouts(small, [str(out)], planners=[], layouts=2, threads=1, rollout=True)
    rows = ev["rows"]
    assert [r["planner"] for r in rows[:3]] == ["mappo", "mappo+rollout", "optimal"]
    for base, roll in zip(rows[0::3], rows[1::3]):
        assert roll["complete"] >= base["complete"]
        if roll["complete"] == base["complete"]:
            assert roll["objective"] >= base["objective"]
    # A policy carrying reserved ways from slot to slot cannot be a rollout's base: one line.
    with pytest.raises(sl.InputError, match="--rollout with marl.reserve_slack = 2: allowed -1"):
        sl.evaluate_layouts(sl.config(overrides={**SQUARE, "marl.reserve_slack": 2}), [str(out)], planners=[], layouts=1,
                            threads=1, rollout=True)


def test_registries_are_the_cores_lists():
    # One list each, read from the C++ registries: every planner runs, an unknown one is refused
    # with the list.
    assert sl.PLANNERS == ("random", "greedy", "seqgreedy", "rollout", "bestknown", "optimal")
    assert sl.LEARNERS == ("mappo", "ippo", "vdn", "qmix")
    with pytest.raises(sl.InputError, match="allowed random, greedy, seqgreedy, rollout, bestknown, optimal"):
        sl.plan(None, "astar")
    cfg = sl.config(env={"oracle": "zf"}, scenario={"area_x_m": 120.0, "area_y_m": 120.0, "users": 6},
                    trajectory={"starts": [[0.0, 0.0], [120.0, 120.0]], "destinations": [[120.0, 40.0], [0.0, 80.0]],
                                "t_max": 12})
    objective = {p: sl.plan(cfg, p, users_seed=3)["objective"] for p in sl.PLANNERS}
    assert objective["bestknown"] == pytest.approx(objective["optimal"], rel=1e-12)  # the DP fits: exact
    assert max(objective.values()) <= objective["optimal"] * (1 + 1e-12)
