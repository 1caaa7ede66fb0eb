"""The environment's spec is the one layout: every Python array is sized and sliced by it, equals
the environment's own per-agent arrays, and each named field holds what its name says, for both
state kinds and both encoders at N = 1, 2, 3, 8, 9, 16 and 64 UAVs."""
import threading

import numpy as np
import pytest

import skyloop as sl

SIZES = [1, 2, 3, 8, 9, 16, 64]


def scenario(N, state, encoder, K=20):
    side = 200 if N <= 3 else 1000 if N <= 16 else 2000
    return {"env.oracle": "zf", "scenario.uavs": N, "scenario.users": K, "scenario.area_x_m": side,
            "scenario.area_y_m": side, "trajectory.layout": "generated", "trajectory.t_max": 30,
            "env.state": state, "marl.encoder": encoder}


def check_against_reference(env, o):
    spec = env.spec
    M, N = env.num_envs, env.num_agents
    assert o.obs.shape == (M, *spec["obs"]["shape"]) and o.obs.dtype == np.float32
    assert o.state.shape == (M, *spec["state"]["shape"])
    assert o.agent_state.shape == (M, *spec["agent_state"]["shape"])
    assert o.action_mask.shape == (M, N, spec["num_actions"]) and o.action_mask.dtype == np.int8
    for i in range(M):
        ref = env._env._reference(i)
        assert np.array_equal(o.state[i], ref["state"])
        assert np.array_equal(o.obs[i], np.array(ref["obs"], np.float32))
        assert np.array_equal(o.agent_state[i], np.array(ref["agent_state"], np.float32))


def check_fields(env, o):
    """Each named field holds what its name says, and every value lies in its field's bounds."""
    spec, pos = env.spec, env.positions()
    assert pos["uavs"].shape[-1] == 3 and np.all(pos["uavs"][..., 2] == env.config["scenario.altitude_m"])
    pos = {k: v[..., :2] if k != "t" else v for k, v in pos.items()}  # the fields below are horizontal
    side = float(env.config["scenario.area_x_m"])
    for name, arr in (("obs", o.obs), ("state", o.state), ("agent_state", o.agent_state)):
        fields = spec[name]["fields"]
        assert sum(f["size"] for f in fields) == spec[name]["size"]
        assert [f["offset"] for f in fields] == list(np.cumsum([0] + [f["size"] for f in fields])[:-1])
        for f in fields:
            part = arr[..., f["offset"]:f["offset"] + f["size"]]
            assert np.all(part >= f["low"] - 1e-6) and np.all(part <= f["high"] + 1e-6), (name, f["name"])
    own = env.field(o.obs, "obs", "own_position")
    assert np.allclose(own, pos["uavs"] / side, atol=1e-6)
    assert np.allclose(env.field(o.agent_state, "agent_state", "obs.own_position"), pos["uavs"] / side, atol=1e-6)
    assert np.allclose(env.field(o.obs, "obs", "destination_displacement"), (pos["destinations"] - pos["uavs"]) / side,
                       atol=1e-6)
    if spec["state_kind"] == "paper":
        M, N = o.obs.shape[:2]
        assert np.allclose(env.field(o.state, "state", "uav_positions"), pos["uavs"].reshape(M, -1) / side, atol=1e-6)
        ids = env.field(o.agent_state, "agent_state", "context.agent_id")
        assert np.array_equal(ids, np.broadcast_to(np.eye(N, dtype=np.float32), ids.shape))
    else:
        assert np.allclose(env.field(o.state, "state", "uav_density").sum(-1), 1.0, atol=1e-5)
        near = env.field(o.agent_state, "agent_state", "context.neighbour_displacements")
        assert near.shape[-1] == 2 * 4
        if o.obs.shape[1] == 1:
            assert np.all(near == 0)


@pytest.mark.parametrize("N", SIZES)
@pytest.mark.parametrize("state,encoder", [("paper", "mlp"), ("compact", "mlp"), ("compact", "set"), ("paper", "set")])
def test_every_array_is_the_environments_own(N, state, encoder):
    env = sl.VecEnv(scenario(N, state, encoder), num_envs=2, seed=N)
    spec = env.spec
    assert spec["agents"] == N and spec["observation_kind"] == encoder  # marl.encoder's own name
    expected_state = 4 * N + 2 * 20 if state == "paper" else 3 * 64 + 2
    assert spec["state"]["size"] == expected_state
    assert spec["agent_state"]["size"] == expected_state + spec["agent_context"]["size"] + spec["paper_obs"]["size"]
    o = env.reset()
    rng = np.random.default_rng(N)
    for t in range(4):
        check_against_reference(env, o)
        check_fields(env, o)
        a = (rng.random(o.action_mask.shape) * o.action_mask).argmax(-1)
        o = env.step(a)


@pytest.mark.parametrize("N", [1, 3, 9])
def test_the_look_ahead_is_one_field_of_the_set_observation(N):
    """marl.lookahead adds move_gains (one per action) at the end of the set observation; STAY
    changes nothing (0), and the arrays stay the environment's own."""
    cfg = dict(scenario(N, "compact", "set"), **{"marl.lookahead": True})
    env = sl.VecEnv(cfg, num_envs=2, seed=N)
    plain = sl.VecEnv(scenario(N, "compact", "set"), num_envs=2, seed=N)
    spec = env.spec
    assert spec["obs"]["size"] == plain.spec["obs"]["size"] + env.num_actions
    assert spec["obs"]["fields"][-1]["name"] == "move_gains"
    o, p = env.reset(), plain.reset()
    rng = np.random.default_rng(N)
    moved = False
    for t in range(4):
        check_against_reference(env, o)
        check_fields(env, o)
        assert np.array_equal(o.obs[..., :plain.spec["obs"]["size"]], p.obs)
        gains = env.field(o.obs, "obs", "move_gains")
        assert np.all(gains[..., sl.ACTIONS.index("STAY")] == 0)
        moved |= bool(np.any(gains != 0))
        a = (rng.random(o.action_mask.shape) * o.action_mask).argmax(-1)
        o, p = env.step(a), plain.step(a)
    assert moved
    with pytest.raises(sl.InputError, match="marl.lookahead"):
        sl.VecEnv(dict(scenario(N, "compact", "mlp"), **{"marl.lookahead": True}), num_envs=1, seed=0)


def test_the_rate_map_is_the_last_field_of_the_set_observation():
    """marl.rate_map = r adds the radio map around each UAV (2 r (r + 1) cells) after the move
    gains; with r = 1 its cells are the four moves' gains (cells 0..3 = RIGHT, UP, LEFT, DOWN)."""
    base = dict(scenario(3, "compact", "set"), **{"marl.lookahead": True})
    for r in (1, 3):
        env = sl.VecEnv(dict(base, **{"marl.rate_map": r}), num_envs=2, seed=r)
        plain = sl.VecEnv(base, num_envs=2, seed=r)
        assert env.spec["obs"]["fields"][-1]["name"] == "rate_map"
        assert env.spec["obs"]["size"] == plain.spec["obs"]["size"] + 2 * r * (r + 1)
        o, p = env.reset(), plain.reset()
        rng = np.random.default_rng(r)
        for t in range(4):
            check_against_reference(env, o)
            check_fields(env, o)
            assert np.array_equal(o.obs[..., :plain.spec["obs"]["size"]], p.obs)
            cells = env.field(o.obs, "obs", "rate_map")
            assert np.all((cells >= -1) & (cells <= 1)) and np.any((cells != 0) & (cells != -1))
            if r == 1:
                gains = env.field(o.obs, "obs", "move_gains")
                for a, c in (("RIGHT", 0), ("UP", 1), ("LEFT", 2), ("DOWN", 3)):
                    inside = cells[..., c] > -1
                    assert np.array_equal(gains[..., sl.ACTIONS.index(a)][inside], cells[..., c][inside])
            a = (rng.random(o.action_mask.shape) * o.action_mask).argmax(-1)
            o, p = env.step(a), plain.step(a)
    for bad, pattern in (({"marl.rate_map": 7}, "marl.rate_map"), ({"marl.encoder": "mlp", "marl.lookahead": False, "marl.rate_map": 2}, "marl.rate_map")):
        with pytest.raises(sl.InputError, match=pattern):
            sl.VecEnv(dict(base, **bad), num_envs=1, seed=0)


def test_spec_names_the_actions_once():
    env = sl.VecEnv({"env.oracle": "zf"}, 1, 0)
    assert env.spec["actions"] == sl.ACTIONS and env.num_actions == len(sl.ACTIONS)
    assert [f["name"] for f in env.spec["action_mask"]["fields"]] == list(sl.ACTIONS)
    assert env.spec == sl._skyloop.env_spec(env.config, 12)
    with pytest.raises(sl.InputError, match="allowed own_position"):
        env.field(env.reset().obs, "obs", "nope")


def test_one_env_from_two_threads_is_serialised():
    """step in one thread, reset in another, at once: never a crash, every array consistent."""
    env = sl.VecEnv(scenario(9, "compact", "mlp"), num_envs=4, seed=1)
    o = env.reset()
    errors = []

    def stepper():
        rng = np.random.default_rng(0)
        try:
            for _ in range(150):
                r = env.step(np.full(o.action_mask.shape[:2], sl.ACTIONS.index("STAY")))
                assert r.obs.shape == o.obs.shape and np.all(np.isfinite(r.agent_state))
        except Exception as e:  # noqa: BLE001
            errors.append(e)

    def resetter():
        try:
            for k in range(150):
                r = env.reset(seed=k % 3 if k % 2 else None)
                assert np.all(np.isfinite(r.agent_state))
        except Exception as e:  # noqa: BLE001
            errors.append(e)

    threads = [threading.Thread(target=stepper), threading.Thread(target=resetter)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors, errors


def test_the_step_info_is_the_specs():
    """Every info field the step reports is listed by the spec, with its dtype, and nothing else is
    (the final observation and state of an auto-reset aside)."""
    env = sl.VecEnv(sl.config(overrides={"env.oracle": "zf"}), num_envs=2, seed=3)
    env.reset()
    r = env.step(np.full((2, env.spec["agents"]), env.spec["hover"]))
    fields = env.spec["info"]
    assert [f["name"] for f in fields][:3] == ["sum_rate", "objective", "collisions"] and all(f["help"] for f in fields)
    assert set(r.info) - {"final_obs", "final_state"} == {f["name"] for f in fields}
    for f in fields:
        got = np.asarray(r.info[f["name"]])
        assert got.shape == (2,) and got.dtype == np.dtype(f["dtype"]), f["name"]
    assert np.all(r.info["T"] == 2) and np.all(r.info["home"] == 0)
