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
            if not (isinstance(obs[a], dict) and "action_mask" in obs[a]):  # sampled without a mask
                actions[a] = env.action_space(a).sample()
                assert env.action_space(a).contains(actions[a])
                continue
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
    # The continuous model: Box actions, observations without an action mask (a Box takes none).
    env = ParallelEnv(dict(CFG, **{"trajectory.mobility": "continuous"}), seed=1)
    parallel_api_test(env, num_cycles=100)
    assert set(env.observation_space("uav_0").spaces) == {"observation"}


def test_parallel_env_seeding_and_errors():
    a, b = ParallelEnv(CFG, seed=1), ParallelEnv(CFG, seed=1)
    oa, _ = a.reset(seed=5)
    ob, _ = b.reset(seed=5)
    assert all(np.array_equal(oa[k]["observation"], ob[k]["observation"]) for k in oa)
    with pytest.raises(sl.InputError, match="missing"):
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


# ---- the MAPPO reference implementation's shared SMAC-style runner, re-stated -------------------

def mappo_shared_runner(envs, episode_length, rng):
    """What onpolicy/runner/shared/smac_runner.py reads (warmup, collect, insert, log, eval)."""
    num_agents, M = envs.num_agents, envs.num_envs
    obs_space, share_space, act_space = envs.observation_space[0], envs.share_observation_space[0], envs.action_space[0]
    assert act_space.__class__.__name__ in ("Discrete", "Box") and obs_space.__class__.__name__ == "Box"
    discrete = act_space.__class__.__name__ == "Discrete"  # Box: a DiagGaussian head of act_space.shape[0]
    obs, share_obs, available_actions = envs.reset()  # warmup
    buf_obs = np.zeros((episode_length + 1, M, num_agents, *obs_space.shape), np.float32)
    buf_share = np.zeros((episode_length + 1, M, num_agents, *share_space.shape), np.float32)
    # The shared buffer keeps available actions for Discrete spaces only (None otherwise).
    buf_avail = np.ones((episode_length + 1, M, num_agents, act_space.n), np.float32) if discrete else None
    buf_obs[0], buf_share[0] = obs.copy(), share_obs.copy()
    if available_actions is not None:
        buf_avail[0] = available_actions.copy()
    bad, won, finished = [], 0, 0
    for step in range(episode_length):
        if discrete:
            avail = np.concatenate(buf_avail[step])  # collect: [M * N, A]
            actions = np.array([rng.choice(np.flatnonzero(a)) for a in avail]).reshape(M, num_agents, 1)
        else:
            actions = np.clip(rng.normal(size=(M, num_agents, act_space.shape[0])), act_space.low, act_space.high)
        obs, share_obs, rewards, dones, infos, available_actions = envs.step(actions)
        # insert
        dones_env = np.all(dones, axis=1)
        masks = np.ones((M, num_agents, 1), dtype=np.float32)
        masks[dones_env == True] = np.zeros(((dones_env == True).sum(), num_agents, 1), dtype=np.float32)  # noqa: E712
        active_masks = np.ones((M, num_agents, 1), dtype=np.float32)
        active_masks[dones == True] = np.zeros(((dones == True).sum(), 1), dtype=np.float32)  # noqa: E712
        active_masks[dones_env == True] = np.ones(((dones_env == True).sum(), num_agents, 1), dtype=np.float32)  # noqa: E712
        bad_masks = np.array([[[0.0] if info[agent_id]["bad_transition"] else [1.0] for agent_id in range(num_agents)]
                              for info in infos])
        assert bad_masks.shape == (M, num_agents, 1) and rewards.shape == (M, num_agents, 1)
        buf_obs[step + 1], buf_share[step + 1] = obs, share_obs
        if available_actions is not None:
            buf_avail[step + 1] = available_actions
        for i, info in enumerate(infos):  # log (StarCraft2 names) and eval
            "battles_won" in info[0].keys()
            if dones_env[i]:
                finished += 1
                won += bool(info[0]["won"])
                bad.append(bool(info[0]["bad_transition"]))
            else:
                assert not info[0]["bad_transition"]
    return finished, won, bad


def test_mappo_reference_runner_reads_every_field():
    env = MappoEnv(CFG, num_envs=3, seed=2)
    spec = env.env.spec
    assert env.observation_space[0].shape == (spec["obs"]["size"],)
    assert env.share_observation_space[0].shape == (spec["agent_state"]["size"],)
    assert env.action_space[0].n == spec["num_actions"]
    finished, won, bad = mappo_shared_runner(env, 60, np.random.default_rng(0))
    assert finished >= 3 and len(bad) == finished
    # A finished episode is a time limit (bad transition) exactly when it was not won.
    assert sum(bad) == finished - won
    # Hovering never arrives: every episode ends at T_max, a bad transition for every agent.
    # The continuous model: a Box action space, available_actions None (what the reference's buffer expects).
    cont = MappoEnv(dict(CFG, **{"trajectory.mobility": "continuous"}), num_envs=2, seed=2)
    assert cont.action_space[0].__class__.__name__ == "Box" and cont.action_space[0].shape == (2,)
    finished, won, bad = mappo_shared_runner(cont, 40, np.random.default_rng(1))
    assert finished >= 2 and won == finished  # the safety layer brings every UAV home
    env = MappoEnv(CFG, num_envs=2, seed=2)
    env.reset()
    for _ in range(23):
        *_, dones, infos, _ = env.step(np.full((2, 3, 1), sl.ACTIONS.index("STAY")))
    assert dones.all() and all(info[n]["bad_transition"] and not info[n]["won"] for info in infos for n in range(3))


# ---- EPyMARL's current episode and parallel runners, re-stated ----------------------------------

def epymarl_episode(env, rng, common_reward=True):
    """One episode as src/runners/episode_runner.py runs it (EPyMARL with the 5-tuple step)."""
    episode_limit = env.episode_limit
    info = env.get_env_info()
    n_agents = info["n_agents"]
    state = np.zeros((episode_limit + 1, info["state_shape"]), np.float32)
    obs = np.zeros((episode_limit + 1, n_agents, info["obs_shape"]), np.float32)
    avail = np.zeros((episode_limit + 1, n_agents, info["n_actions"]), np.int64)
    env.reset()
    t, terminated, episode_return, stats = 0, False, 0 if common_reward else np.zeros(n_agents), {}
    while not terminated:
        state[t], avail[t], obs[t] = env.get_state(), env.get_avail_actions(), env.get_obs()
        actions = [rng.choice(np.flatnonzero(a)) for a in avail[t]]
        _, reward, terminated, truncated, env_info = env.step(actions)
        terminated = terminated or truncated
        episode_return += reward
        _ = [(terminated != env_info.get("episode_limit", False),)]
        _ = [(reward,)] if common_reward else [tuple(reward)]
        t += 1
        assert t <= episode_limit, "the episode outgrew the batch of episode_limit + 1 slots"
    state[t], avail[t], obs[t] = env.get_state(), env.get_avail_actions(), env.get_obs()
    assert all(any(a) for a in avail[t]), "the last slot needs an available action per agent"
    stats.update({k: stats.get(k, 0) + env_info.get(k, 0) for k in set(stats) | set(env_info)})
    return t, episode_return, env_info, state, obs


def test_epymarl_episode_runner():
    env = SmacEnv(**{"config": CFG, "seed": 2}, common_reward=True, reward_scalarisation="sum")
    spec = env.env.spec
    assert env.get_env_info() == {"state_shape": spec["state"]["size"], "obs_shape": spec["obs"]["size"],
                                  "n_actions": spec["num_actions"], "n_agents": 3, "episode_limit": 23}
    rng = np.random.default_rng(1)
    seen_limit = False
    for _ in range(4):
        t, ret, info, state, obs = epymarl_episode(env, rng)
        assert isinstance(ret, float) and t == info["T"] - 1
        seen_limit |= info["episode_limit"]
        # The last slot is the finished episode's, not the next episode's first.
        assert not np.array_equal(state[t], state[0])
        pos = env.env.field(obs[t], "obs", "own_position")
        assert np.allclose(pos, env.env.field(obs[t - 1], "obs", "own_position"), atol=0.11)
    assert env.get_stats()["episodes"] == 4
    # Per-agent rewards (common_reward = False): one per agent.
    env = SmacEnv(CFG, seed=2, common_reward=False, reward_scalarisation="sum")
    _, ret, _, _, _ = epymarl_episode(env, rng, common_reward=False)
    assert ret.shape == (3,) and np.allclose(ret, ret[0])
    with pytest.raises(sl.InputError, match="unknown arguments"):
        SmacEnv(CFG, map_name="3m")


def test_epymarl_parallel_runner_worker_protocol():
    """The commands env_worker (src/runners/parallel_runner.py) sends, in its order."""
    env = SmacEnv(CFG, seed=3, common_reward=True, reward_scalarisation="sum")
    info = env.get_env_info()
    env.reset()
    data = {"state": env.get_state(), "avail_actions": env.get_avail_actions(), "obs": env.get_obs()}
    terminated = False
    while not terminated:
        actions = [int(np.flatnonzero(a)[-1]) for a in data["avail_actions"]]
        _, reward, terminated, truncated, env_info = env.step(actions)
        terminated = terminated or truncated
        data = {"state": env.get_state(), "avail_actions": env.get_avail_actions(), "obs": env.get_obs(),
                "reward": reward, "terminated": terminated, "info": env_info}
        assert len(data["obs"]) == info["n_agents"] and data["state"].shape == (info["state_shape"],)
    stats = env.get_stats()
    assert stats["episodes"] == 1 and all(isinstance(v, (int, float)) for v in stats.values())


# ---- Gymnasium vector API, as CleanRL's PPO reads it ------------------------------------------

def test_gym_vector_env_as_cleanrl_reads_it():
    envs = GymVectorEnv(CFG, num_envs=4, seed=2, episode_statistics=True)
    spec = envs.env.spec
    assert envs.single_observation_space.shape == (3 * spec["obs"]["size"],)
    assert list(envs.single_action_space.nvec) == [spec["num_actions"]] * 3
    next_obs, infos = envs.reset(seed=1)
    assert next_obs.shape == (4, 3 * spec["obs"]["size"]) and infos["action_mask"].shape == (4, 3, spec["num_actions"])
    rng = np.random.default_rng(0)
    ours = np.zeros(4)
    returns_v0, returns_v1 = [], []
    for _ in range(80):
        action = np.array([[rng.choice(np.flatnonzero(m)) for m in env_mask] for env_mask in infos["action_mask"]])
        next_obs, reward, terminations, truncations, infos = envs.step(action)
        ours += reward
        done = np.logical_or(terminations, truncations)
        assert envs.observation_space.contains(next_obs)
        if "final_info" in infos and not isinstance(infos["final_info"], dict):  # without gymnasium (0.29's layout)
            for i, info in enumerate(infos["final_info"]):
                if info and "episode" in info:
                    returns_v0.append(info["episode"]["r"])
                    assert abs(info["episode"]["r"] - ours[i]) < 1e-3 * max(1, abs(ours[i]))
                    assert infos["final_obs"][i].shape == next_obs[i].shape
        if "final_info" in infos and isinstance(infos["final_info"], dict):  # gymnasium 1.x's layout
            fin = infos["final_info"]
            returns_v0 += list(fin["episode"]["r"][fin["_episode"]])
            assert all(o.shape == next_obs[i].shape for i, o in enumerate(infos["final_obs"]) if infos["_final_obs"][i])
        if "episode" in infos:  # gymnasium 1.x (RecordEpisodeStatistics)
            returns_v1 += list(infos["episode"]["r"][infos["_episode"]])
        ours[done] = 0
    assert returns_v0 and np.allclose(returns_v0, returns_v1)
