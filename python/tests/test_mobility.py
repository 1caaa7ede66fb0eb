"""Mobility models and propulsion energy from Python: the action space comes from the environment's
spec (names, count, mask width), every adapter's space reads it, and the energy bookkeeping of a
planned mission adds up (per-slot power x delta_t = each UAV's energy; their sum = the total)."""
import numpy as np
import pytest

import skyloop as sl
from skyloop import adapters

HEADINGS = {"env.oracle": "zf", "trajectory.mobility": "headings", "trajectory.speeds_mps": [0, 10, 20]}


def test_headings_action_space_reaches_every_reader():
    env = sl.VecEnv(HEADINGS, num_envs=2, seed=1)
    spec = env.spec
    assert spec["num_actions"] == 17
    assert spec["actions"][0] == "E@10" and spec["actions"][-1] == "HOVER"
    o = env.reset()
    assert o.action_mask.shape == (2, 3, 17)
    assert o.obs.shape == (2, 3, 6 + 17)  # the one-hot previous action is as wide as the action space
    assert spec["hover"] == 16
    pz = adapters.ParallelEnv(HEADINGS, seed=1)
    assert pz.action_space("uav_0").n == 17
    assert adapters.SmacEnv(HEADINGS, seed=1).get_total_actions() == 17
    rng = np.random.default_rng(0)
    energy = np.zeros(2)
    for _ in range(30):
        u = rng.random(o.action_mask.shape) * o.action_mask
        r = env.step(u.argmax(-1))
        assert np.all(r.info["energy_j"] > 0)  # every UAV spends at least hover power
        energy += r.info["energy_j"]
        done = r.terminated | r.truncated
        assert np.allclose(r.info["episode_energy_j"][~done], energy[~done])
        energy[done] = 0
        o = r
    with pytest.raises(sl.InputError, match="0..16"):
        env.step(np.full((2, 3), 17))


def test_planned_energy_adds_up_and_grid_is_the_default():
    cfg = sl.config(overrides=dict(HEADINGS, **{"env.objective": "energy-efficiency"}))
    p = sl.plan(cfg, planner="greedy", users_seed=3)
    assert p["speed_mps"].shape == p["power_w"].shape == (p["T"] - 1, 3)
    slot = float(cfg["trajectory.slot_s"])
    per_uav = p["power_w"].sum(0) * slot
    assert np.allclose(per_uav, p["energy_j"]) and np.isclose(p["energy_j"].sum(), p["total_energy_j"])
    bits = float(cfg["channel.bandwidth_hz"]) * slot * p["rates"].sum()
    assert np.isclose(p["bits_per_joule"], bits / p["total_energy_j"])
    assert np.isclose(p["objective"], p["bits_per_joule"] / 1e3)
    assert set(p["action_names"]) >= {"HOVER", "NE@20"}
    grid = sl.plan(sl.config(overrides={"env.oracle": "zf"}), planner="greedy", users_seed=3)
    assert grid["action_names"] == sl.ACTIONS


@pytest.mark.parametrize("bad,match", [({"trajectory.speeds_mps": [0, 15]}, "multiple of trajectory.d_fly_m"),
                                       ({"trajectory.mobility": "smooth"}, "allowed one of grid, headings, continuous"),
                                       ({"trajectory.mobility": "continuous", "trajectory.v_max_mps": 150}, "tip speed"),
                                       ({"trajectory.speeds_mps": "fast"}, "trajectory.speeds_mps")])
def test_bad_mobility_settings_raise_input_error(bad, match):
    with pytest.raises(sl.InputError, match=match):
        sl.VecEnv(dict(HEADINGS, **bad), num_envs=1, seed=1)


CONTINUOUS = {"env.oracle": "zf", "trajectory.mobility": "continuous", "trajectory.v_max_mps": 20,
              "trajectory.a_max_mps2": 5}


def test_continuous_commands_are_flown_safely_and_every_mission_completes():
    env = sl.VecEnv(CONTINUOUS, num_envs=3, seed=4)
    spec = env.spec
    assert spec["dims"] == env.action_dims == 2 and spec["actions"][-2:] == ("HOME", "HOVER")
    o = env.reset()
    assert o.obs.shape == (3, 3, 6 + 2)  # the previous action is the last velocity / v_max
    assert [f["name"] for f in spec["obs"]["fields"]][-1] == "previous_velocity"
    rng = np.random.default_rng(1)
    episodes = 0
    for _ in range(80):
        r = env.step(rng.uniform(-1, 1, (3, 3, 2)))
        v = env.field(r.obs, "obs", "previous_velocity")
        assert np.all(np.linalg.norm(v, axis=-1) <= 1 + 1e-6)
        assert np.all(r.info["boundary"] == 0)
        done = r.terminated | r.truncated
        assert np.all(r.info["success"][done])  # the mask brings every UAV home under any commands
        episodes += done.sum()
    assert episodes >= 3
    env.step(np.full((3, 3), spec["hover"]))  # the primitives stay discrete actions
    for bad, match in [(np.full((3, 3, 2), 1.5), r"in \[-1, 1\]"), (np.zeros((3, 3, 3)), "shape"),
                       (np.full((3, 3, 2), np.nan), "invalid")]:
        with pytest.raises(sl.InputError, match=match):
            env.step(bad)


def test_polar_commands_cruise_at_half_the_top_speed():
    """trajectory.command = polar: u = 0 flies straight on at v_max / 2 from the bearing to the
    destination (README, mobility models)."""
    polar = sl.VecEnv(dict(CONTINUOUS, **{"trajectory.command": "polar"}), num_envs=2, seed=4)
    polar.reset()
    for _ in range(3):
        r = polar.step(np.zeros((2, 3, 2)))
        v = polar.field(r.obs, "obs", "previous_velocity")
        assert np.allclose(np.linalg.norm(v, axis=-1), 0.5, atol=1e-6)  # 10 m/s of v_max = 20
    with pytest.raises(sl.InputError, match="trajectory.command"):
        sl.VecEnv(dict(CONTINUOUS, **{"trajectory.command": "jerk"}), num_envs=1, seed=1)


def test_continuous_action_spaces_in_every_adapter():
    pz = adapters.ParallelEnv(CONTINUOUS, seed=1)
    space = pz.action_space("uav_0")
    assert space.__class__.__name__ == "Box" and space.shape == (2,)
    obs, _ = pz.reset(seed=3)
    while pz.agents:
        obs, rew, term, trunc, info = pz.step({a: space.sample() for a in pz.agents})
    assert all(i["success"] for i in info.values())
    gym = adapters.GymVectorEnv(CONTINUOUS, num_envs=2, seed=1)
    assert gym.single_action_space.shape == (6,) and gym.action_space.shape == (2, 6)
    gym.reset(seed=1)
    gym.step(gym.action_space.sample())
    assert adapters.SmacEnv(CONTINUOUS, seed=1).get_total_actions() == 18  # EPyMARL: the primitives
    with pytest.raises(sl.InputError, match="command"):
        pz.reset()
        pz.step({})


def test_continuous_plan_energy_adds_up():
    cfg = sl.config(overrides=dict(CONTINUOUS, **{"env.objective": "energy-efficiency"}))
    p = sl.plan(cfg, planner="seqgreedy", users_seed=3)
    assert p["success"]
    assert np.all(p["speed_mps"] <= 20 + 1e-9)
    assert np.allclose(p["power_w"].sum(0) * float(cfg["trajectory.slot_s"]), p["energy_j"])
    with pytest.raises(sl.InputError, match="continuous"):
        sl.plan(cfg, planner="optimal", users_seed=3)
