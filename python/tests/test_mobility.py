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
                                       ({"trajectory.mobility": "continuous"}, "allowed one of grid, headings"),
                                       ({"trajectory.speeds_mps": "fast"}, "trajectory.speeds_mps")])
def test_bad_mobility_settings_raise_input_error(bad, match):
    with pytest.raises(sl.InputError, match=match):
        sl.VecEnv(dict(HEADINGS, **bad), num_envs=1, seed=1)
