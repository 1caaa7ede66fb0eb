"""The adapters against the real libraries' own test code: PettingZoo's parallel_api_test,
parallel_seed_test and (through parallel_to_aec) the AEC api_test; Gymnasium's check_env, its
registry (make / make_vec) and its vector wrappers. pettingzoo and gymnasium come from PyPI
(scripts/install-python-env, or `pip install ".[pettingzoo]"`); where they are not installed these
tests are skipped, and conftest.py says so in one line."""
import warnings

import numpy as np
import pytest

import skyloop as sl

CFG = {"env.oracle": "zf"}
CONTINUOUS = {"env.oracle": "zf", "trajectory.mobility": "continuous"}

pettingzoo = pytest.importorskip("pettingzoo", reason="pettingzoo is not installed (scripts/install-python-env)")


# ---- PettingZoo ----------------------------------------------------------------------------------

@pytest.mark.parametrize("config", [CFG, CONTINUOUS], ids=["grid", "continuous"])
def test_pettingzoo_parallel_api_test(config):
    from pettingzoo.test import parallel_api_test
    from skyloop.adapters import ParallelEnv
    env = ParallelEnv(config, seed=1)
    assert isinstance(env, pettingzoo.ParallelEnv)
    parallel_api_test(env, num_cycles=300)  # several episodes: T_max = 100 slots each at most


def test_pettingzoo_parallel_seed_test():
    from pettingzoo.test import parallel_seed_test
    from skyloop.adapters import ParallelEnv
    parallel_seed_test(lambda: ParallelEnv(CFG, seed=3), num_cycles=60)


def test_pettingzoo_aec_api_test_through_parallel_to_aec():
    from pettingzoo.test import api_test
    from pettingzoo.utils.conversions import parallel_to_aec
    from skyloop.adapters import ParallelEnv
    with warnings.catch_warnings():
        # PettingZoo's documented action-mask convention makes each observation a dict
        # ({"observation", "action_mask"}); api_test only warns that it is not a bare array.
        warnings.filterwarnings("ignore", message="Observation", category=UserWarning)
        api_test(parallel_to_aec(ParallelEnv(CFG, seed=2)), num_cycles=300)


def test_pettingzoo_spaces_are_the_real_ones_with_the_spec_dtypes():
    import gymnasium.spaces as gs
    from skyloop.adapters import ParallelEnv
    env = ParallelEnv(CFG, seed=1)
    obs_space = env.observation_space("uav_0")
    assert isinstance(obs_space, gs.Dict) and isinstance(env.action_space("uav_0"), gs.Discrete)
    assert obs_space["observation"].dtype == np.float32 and obs_space["action_mask"].dtype == np.int8
    assert obs_space["observation"].shape == (env._vec.spec["obs"]["size"],)
    assert env.action_space("uav_0").n == len(env._vec.spec["actions"])


# ---- Gymnasium -----------------------------------------------------------------------------------

@pytest.mark.parametrize("config", [CFG, CONTINUOUS], ids=["grid", "continuous"])
def test_gymnasium_check_env(config):
    gym = pytest.importorskip("gymnasium")
    from gymnasium.utils.env_checker import check_env
    from skyloop.adapters import GYM_ID
    env = gym.make(GYM_ID, config=config, seed=1)  # make's passive checker runs on the first calls
    env.reset(seed=0)
    env.step(env.action_space.sample())
    check_env(env.unwrapped, skip_render_check=True)


def test_gymnasium_make_vec_is_the_vector_adapter_and_its_wrappers_count_episodes():
    gym = pytest.importorskip("gymnasium")
    from gymnasium.wrappers.vector import RecordEpisodeStatistics
    from skyloop.adapters import GYM_ID, GymVectorEnv
    venv = gym.make_vec(GYM_ID, num_envs=4, vectorization_mode="vector_entry_point", config=CFG, seed=5)
    assert isinstance(venv.unwrapped, GymVectorEnv) and isinstance(venv.unwrapped, gym.vector.VectorEnv)
    env = RecordEpisodeStatistics(venv)
    obs, _ = env.reset(seed=7)
    assert obs.dtype == np.float32 and obs.shape == env.observation_space.shape
    assert obs in env.observation_space
    env.action_space.seed(7)
    finished, returns = 0, []
    for _ in range(120):  # T_max = 100: every environment ends at least once
        obs, rew, term, trunc, info = env.step(env.action_space.sample())
        assert obs in env.observation_space and rew.dtype == np.float32
        done = term | trunc
        if done.any():
            # Gymnasium's wrapper and the adapter's own statistics agree on the finished episodes.
            np.testing.assert_allclose(info["episode"]["r"][done], info["final_info"]["episode"]["r"][done]
                                       if isinstance(info["final_info"], dict) else
                                       [info["final_info"][i]["episode"]["r"] for i in np.flatnonzero(done)], rtol=1e-5)
            finished += int(done.sum())
            returns += list(info["episode"]["r"][done])
    assert finished >= 4 and len(env.return_queue) == finished
    env.close()
    assert venv.unwrapped.closed


def test_gymnasium_sync_vector_env_over_gym_env_steps_like_the_batched_adapter():
    """Gymnasium's own SyncVectorEnv over GymEnv, against GymVectorEnv: environment i of a VecEnv
    of seed s draws its users from derive_seed(s, i), and so does GymEnv(seed=s) for i = 0, so the
    first environments' trajectories agree step for step under the same actions."""
    gym = pytest.importorskip("gymnasium")
    from skyloop.adapters import GymEnv, GymVectorEnv
    ours = GymVectorEnv(CFG, num_envs=1, seed=11)
    theirs = gym.vector.SyncVectorEnv([lambda: GymEnv(CFG, seed=11)], autoreset_mode=gym.vector.AutoresetMode.SAME_STEP)
    o1, _ = ours.reset()
    o2, _ = theirs.reset()
    np.testing.assert_array_equal(o1, o2)
    rng, ended = np.random.default_rng(0), 0
    for _ in range(110):
        a = rng.integers(0, ours.env.num_actions, size=(1, ours.env.num_agents))
        r1, r2 = ours.step(a), theirs.step(a)
        for x, y in zip(r1[:4], r2[:4]):
            np.testing.assert_array_equal(x, y)
        if "_final_obs" in r2[4]:  # an episode ended: the same finished episode, in Gymnasium's layout
            ended += 1
            np.testing.assert_array_equal(r1[4]["_final_obs"], r2[4]["_final_obs"])
            mask = r2[4]["_final_obs"]
            np.testing.assert_array_equal(np.stack(r1[4]["final_obs"][mask]), np.stack(r2[4]["final_obs"][mask]))
            for key in ("objective", "home", "success"):
                np.testing.assert_array_equal(r1[4]["final_info"][key], r2[4]["final_info"][key])
    assert ended >= 1
