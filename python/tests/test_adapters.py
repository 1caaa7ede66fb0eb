"""The adapters: a conformance test of the checks PettingZoo's parallel_api_test makes (it cannot
be installed here), and shape checks of the MAPPO, EPyMARL/SMAC and Gymnasium-style interfaces."""
import numpy as np
import pytest

import skyloop as sl
from skyloop.adapters import GymVectorEnv, MappoEnv, ParallelEnv, SmacEnv

CFG = {"env.oracle": "zf"}


def parallel_api_test(env, num_cycles=200):
    """What pettingzoo.test.parallel_api_test checks, re-stated (PettingZoo 1.24)."""
    assert isinstance(env.possible_agents, list) and env.possible_agents
    assert len(set(env.possible_agents)) == len(env.possible_agents)
    obs, infos = env.reset(seed=42)
    assert isinstance(obs, dict) and isinstance(infos, dict)
    assert set(obs) == set(env.agents) == set(infos)
    assert set(env.agents) <= set(env.possible_agents)
    has_finished = set()
    for _ in range(num_cycles):
        actions = {}
        for a in env.agents:
            mask = obs[a]["action_mask"]
            assert env.action_space(a).contains(int(np.flatnonzero(mask)[0]))
            actions[a] = env.action_space(a).sample(mask.astype(np.int8)) if _accepts_mask(env.action_space(a)) \
                else int(np.random.default_rng(len(has_finished)).choice(np.flatnonzero(mask)))
        live_before = set(env.agents)
        obs, rew, term, trunc, info = env.step(actions)
        for d in (obs, rew, term, trunc, info):
            assert isinstance(d, dict)
            assert set(d) == live_before, "every live agent appears in every step dict"
        for a, o in obs.items():
            assert env.observation_space(a).contains(o), f"observation of {a} outside its space"
            assert o["observation"].dtype == np.float32
        for a in live_before:
            assert isinstance(rew[a], float) and isinstance(term[a], bool) and isinstance(trunc[a], bool)
        for a in live_before:
            if term[a] or trunc[a]:
                has_finished.add(a)
                assert a not in env.agents, "a finished agent leaves env.agents"
        assert not (has_finished & set(env.agents))
        state = env.state()
        assert state.shape == env.state_space.shape and env.state_space.contains(state)
        if not env.agents:
            obs, infos = env.reset()
            has_finished.clear()
            assert set(obs) == set(env.agents) == set(env.possible_agents)
    assert env.num_agents == len(env.agents)


def _accepts_mask(space):
    try:
        space.sample(np.ones(space.n, np.int8))
        return True
    except TypeError:
        return False


def test_parallel_env_conformance():
    env = ParallelEnv(CFG, seed=1)
    parallel_api_test(env, num_cycles=300)


def test_parallel_env_seeding_and_errors():
    a, b = ParallelEnv(CFG, seed=1), ParallelEnv(CFG, seed=1)
    oa, _ = a.reset(seed=5)
    ob, _ = b.reset(seed=5)
    assert all(np.array_equal(oa[k]["observation"], ob[k]["observation"]) for k in oa)
    with pytest.raises(ValueError, match="missing"):
        a.step({"uav_0": 0})
    with pytest.raises(sl.InputError):
        a.step({"uav_0": 0, "uav_1": 9, "uav_2": 0})
    # A mission that ends: the agents leave and a further step is refused.
    env = ParallelEnv(CFG, seed=1)
    env.reset()
    for _ in range(30):
        if not env.agents:
            break
        env.step({a: 4 for a in env.agents})
    assert env.agents == []
    with pytest.raises(RuntimeError):
        env.step({})


def test_mappo_interface():
    env = MappoEnv(CFG, num_envs=3, seed=2)
    obs, share_obs, avail = env.reset()
    assert obs.shape == (3, 3, 11) and share_obs.shape == (3, 3, env.env.agent_state_size) and avail.shape == (3, 3, 5)
    obs, share_obs, rewards, dones, infos, avail = env.step(np.full((3, 3, 1), 4))
    assert rewards.shape == (3, 3, 1) and dones.shape == (3, 3) and dones.dtype == np.bool_ and len(infos) == 3
    assert len(env.observation_space) == len(env.action_space) == 3


def test_smac_interface():
    env = SmacEnv(CFG, seed=2)
    info = env.get_env_info()
    assert info == {"state_shape": env.get_state_size(), "obs_shape": 11, "n_actions": 5, "n_agents": 3,
                    "episode_limit": 23}
    env.reset()
    assert len(env.get_obs()) == 3 and env.get_state().shape == (info["state_shape"],)
    assert env.get_avail_actions() == [[1] * 5] * 3
    done, steps = False, 0
    while not done:
        reward, done, inf = env.step([4, 4, 4])
        steps += 1
    assert steps == 23 and inf["episode_limit"]  # hovering: T_max reached, mission failed


def test_gym_vector_interface():
    env = GymVectorEnv(CFG, num_envs=4, seed=2)
    obs, infos = env.reset(seed=1)
    assert obs.shape == (4, 33) and infos["action_mask"].shape == (4, 3, 5)
    assert env.single_action_space.contains(np.array([0, 1, 4]))
    obs, rew, term, trunc, infos = env.step(np.zeros((4, 3), dtype=np.int64))
    assert rew.shape == (4,) and term.shape == trunc.shape == (4,) and "sum_rate" in infos
