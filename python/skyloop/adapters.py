"""Thin adapters over ``skyloop.VecEnv`` for the APIs learners already use.

- ``ParallelEnv``: PettingZoo's Parallel API (a subclass of ``pettingzoo.ParallelEnv`` when
  pettingzoo is importable, the same methods otherwise); agents "uav_0" .. "uav_{N-1}"; each
  observation is ``{"observation": float32[11], "action_mask": int8[5]}`` (PettingZoo's documented
  action-mask convention); ``state()`` is s[t].
- ``MappoEnv``: the MAPPO reference repository's vectorised interface
  (``obs, share_obs, rewards, dones, infos, available_actions``, arrays [M, N, ...]).
- ``SmacEnv``: EPyMARL/SMAC's single-environment interface (``get_obs``, ``get_state``,
  ``get_avail_actions``, ``get_env_info``, ``step(actions) -> (reward, terminated, info)``).
- ``GymVectorEnv``: a Gymnasium-style vector environment for single-policy learners: every
  environment's N agents flattened into one observation (N * 11) and a MultiDiscrete([5] * N) action.

Spaces are Gymnasium's when gymnasium is importable, else the minimal ``Box`` / ``Discrete`` /
``MultiDiscrete`` below (same attributes: shape, dtype, low, high, n, nvec, sample, contains, seed).
"""
from __future__ import annotations

from typing import Optional

import numpy as np

from .env import VecEnv

# ---- spaces -----------------------------------------------------------------------------------

try:  # pragma: no cover - gymnasium is not packaged in Debian
    from gymnasium.spaces import Box, Dict, Discrete, MultiDiscrete  # type: ignore
except ImportError:
    class _Space:
        def __init__(self, shape, dtype, seed=None):
            self.shape = tuple(shape)
            self.dtype = np.dtype(dtype)
            self._rng = np.random.default_rng(seed)

        def seed(self, seed=None):
            self._rng = np.random.default_rng(seed)
            return [seed]

    class Box(_Space):
        def __init__(self, low, high, shape=None, dtype=np.float32, seed=None):
            shape = shape if shape is not None else np.shape(low)
            super().__init__(shape, dtype, seed)
            self.low = np.full(self.shape, low, dtype=self.dtype)
            self.high = np.full(self.shape, high, dtype=self.dtype)

        def sample(self):
            lo = np.where(np.isfinite(self.low), self.low, -1.0)
            hi = np.where(np.isfinite(self.high), self.high, 1.0)
            return self._rng.uniform(lo, hi).astype(self.dtype)

        def contains(self, x):
            x = np.asarray(x)
            return x.shape == self.shape and bool(np.all(x >= self.low) and np.all(x <= self.high))

        def __repr__(self):
            return f"Box({self.low.min()}, {self.high.max()}, {self.shape}, {self.dtype})"

    class Discrete(_Space):
        def __init__(self, n, seed=None):
            super().__init__((), np.int64, seed)
            self.n = int(n)
            self.start = 0

        def sample(self, mask=None):
            if mask is not None:
                allowed = np.flatnonzero(np.asarray(mask))
                return int(self._rng.choice(allowed)) if len(allowed) else 0
            return int(self._rng.integers(self.n))

        def contains(self, x):
            return isinstance(x, (int, np.integer)) and 0 <= int(x) < self.n

        def __repr__(self):
            return f"Discrete({self.n})"

    class MultiDiscrete(_Space):
        def __init__(self, nvec, seed=None):
            super().__init__(np.shape(nvec), np.int64, seed)
            self.nvec = np.asarray(nvec, dtype=np.int64)

        def sample(self):
            return self._rng.integers(self.nvec)

        def contains(self, x):
            x = np.asarray(x)
            return x.shape == self.shape and bool(np.all(x >= 0) and np.all(x < self.nvec))

        def __repr__(self):
            return f"MultiDiscrete({self.nvec.tolist()})"

    class Dict(_Space):
        def __init__(self, spaces, seed=None):
            super().__init__((), object, seed)
            self.spaces = dict(spaces)

        def __getitem__(self, key):
            return self.spaces[key]

        def sample(self):
            return {k: s.sample() for k, s in self.spaces.items()}

        def contains(self, x):
            return isinstance(x, dict) and x.keys() == self.spaces.keys() and all(
                self.spaces[k].contains(v) for k, v in x.items())

        def seed(self, seed=None):
            for i, s in enumerate(self.spaces.values()):
                s.seed(None if seed is None else seed + i)
            return [seed]


def _obs_box(size):
    # Positions / area are in [0, 1]; displacements in [-1, 1] (the mean displacement to the users
    # too); the one-hot previous action in {0, 1}.
    return Box(-1.0, 1.0, shape=(size,), dtype=np.float32)


try:  # pragma: no cover - pettingzoo is not packaged in Debian
    from pettingzoo import ParallelEnv as _ParallelBase  # type: ignore
except ImportError:
    _ParallelBase = object


# ---- PettingZoo ----------------------------------------------------------------------------------

class ParallelEnv(_ParallelBase):
    """PettingZoo Parallel API over one skyloop environment. Arrived UAVs stay in ``agents`` (they
    keep serving users) with action mask [0, 0, 0, 0, 1] until the episode ends; then ``agents``
    is empty until ``reset``. Rewards are the team reward, given to every agent."""

    metadata = {"name": "skyloop_uav_v0", "render_modes": [], "is_parallelizable": True}

    def __init__(self, config=None, seed: int = 0, oracle: str = ""):
        self._config, self._oracle, self._seed = config, oracle, int(seed)
        self._vec = VecEnv(config, 1, self._seed, oracle)
        n = self._vec.num_agents
        self.possible_agents = [f"uav_{i}" for i in range(n)]
        self.agents: list[str] = []
        self._obs_space = Dict({"observation": _obs_box(self._vec.obs_size),
                                "action_mask": Box(0, 1, shape=(5,), dtype=np.int8)})
        self._act_space = Discrete(5)
        self.state_space = Box(0.0, 1.0, shape=(self._vec.state_size,), dtype=np.float32)
        self.render_mode = None
        self._last: Optional[tuple] = None

    def observation_space(self, agent):
        return self._obs_space

    def action_space(self, agent):
        return self._act_space

    @property
    def num_agents(self):
        return len(self.agents)

    @property
    def max_num_agents(self):
        return len(self.possible_agents)

    def _per_agent(self, obs, mask):
        return {a: {"observation": obs[0, i].copy(), "action_mask": mask[0, i].copy()}
                for i, a in enumerate(self.possible_agents)}

    def reset(self, seed: Optional[int] = None, options: Optional[dict] = None):
        o = self._vec.reset(seed)
        self.agents = list(self.possible_agents)
        self._last = (o.obs, o.state, o.action_mask)
        return self._per_agent(o.obs, o.action_mask), {a: {} for a in self.agents}

    def step(self, actions: dict):
        if not self.agents:
            raise RuntimeError("step() after the episode ended: call reset() first")
        missing = [a for a in self.agents if a not in actions]
        if missing:
            raise ValueError(f"actions are missing for {missing}: allowed one action in 0..4 per live agent")
        joint = np.array([[int(actions[a]) for a in self.possible_agents]], dtype=np.int64)
        r = self._vec.step(joint)
        done = bool(r.terminated[0] or r.truncated[0])
        obs = r.info["final_obs"] if done else r.obs
        mask = r.action_mask
        if done:  # the finished episode's last view: every agent may only STAY
            mask = np.zeros_like(mask)
            mask[..., 4] = 1
        observations = self._per_agent(obs, mask)
        rewards = {a: float(r.reward[0]) for a in self.agents}
        terminations = {a: bool(r.terminated[0]) for a in self.agents}
        truncations = {a: bool(r.truncated[0]) for a in self.agents}
        info = {k: v[0].item() for k, v in r.info.items() if v.ndim == 1}
        infos = {a: dict(info) for a in self.agents}
        self._last = (obs, r.info["final_state"] if done else r.state, mask)
        if done:
            self.agents = []
        return observations, rewards, terminations, truncations, infos

    def state(self):
        if self._last is None:
            raise RuntimeError("state() before reset()")
        return self._last[1][0].copy()

    def render(self):
        return None

    def close(self):
        pass


# ---- MAPPO reference repository ------------------------------------------------------------------

class MappoEnv:
    """The interface of the MAPPO reference implementation's vectorised envs: ``reset() -> (obs,
    share_obs, available_actions)``, ``step(actions) -> (obs, share_obs, rewards, dones, infos,
    available_actions)``, with obs [M, N, 11], share_obs [M, N, S + N + 11] (agent-specific global
    state), rewards [M, N, 1], dones bool [M, N], available_actions [M, N, 5]. Auto-reset as VecEnv."""

    def __init__(self, config=None, num_envs: int = 8, seed: int = 0, oracle: str = ""):
        self.env = VecEnv(config, num_envs, seed, oracle)
        self.num_envs, self.num_agents = self.env.num_envs, self.env.num_agents
        self.observation_space = [_obs_box(self.env.obs_size) for _ in range(self.num_agents)]
        self.share_observation_space = [Box(-1.0, 1.0, shape=(self.env.agent_state_size,)) for _ in range(self.num_agents)]
        self.action_space = [Discrete(5) for _ in range(self.num_agents)]

    def reset(self, seed: Optional[int] = None):
        o = self.env.reset(seed)
        return o.obs, o.agent_state, o.action_mask

    def step(self, actions):
        a = np.asarray(actions)
        if a.ndim == 3 and a.shape[-1] == 1:  # MAPPO passes [M, N, 1]
            a = a[..., 0]
        r = self.env.step(a)
        M, N = self.num_envs, self.num_agents
        done = r.terminated | r.truncated
        dones = np.repeat(done[:, None], N, axis=1)
        rewards = np.repeat(r.reward[:, None, None], N, axis=1).astype(np.float32)
        infos = [{k: v[i].item() for k, v in r.info.items() if v.ndim == 1} for i in range(M)]
        return r.obs, r.agent_state, rewards, dones, infos, r.action_mask

    def close(self):
        pass


# ---- EPyMARL / SMAC ------------------------------------------------------------------------------

class SmacEnv:
    """EPyMARL's MultiAgentEnv / SMAC interface over one environment."""

    def __init__(self, config=None, seed: int = 0, oracle: str = ""):
        self.env = VecEnv(config, 1, seed, oracle)
        self.n_agents = self.env.num_agents
        self.n_actions = 5
        self.episode_limit = int(self.env.config["trajectory.t_max"]) - 1
        self._o = self.env.reset()

    def reset(self, seed: Optional[int] = None):
        self._o = self.env.reset(seed)
        return self.get_obs(), self.get_state()

    def step(self, actions):
        r = self.env.step(np.asarray(actions, dtype=np.int64).reshape(1, -1))
        self._o = r
        info = {k: v[0].item() for k, v in r.info.items() if v.ndim == 1}
        info["episode_limit"] = bool(r.truncated[0])
        return float(r.reward[0]), bool(r.terminated[0] or r.truncated[0]), info

    def get_obs(self):
        return [self._o.obs[0, i].copy() for i in range(self.n_agents)]

    def get_obs_agent(self, agent_id):
        return self._o.obs[0, agent_id].copy()

    def get_obs_size(self):
        return self.env.obs_size

    def get_state(self):
        return self._o.state[0].copy()

    def get_state_size(self):
        return self.env.state_size

    def get_avail_actions(self):
        return [self._o.action_mask[0, i].astype(np.int64).tolist() for i in range(self.n_agents)]

    def get_avail_agent_actions(self, agent_id):
        return self._o.action_mask[0, agent_id].astype(np.int64).tolist()

    def get_total_actions(self):
        return self.n_actions

    def get_env_info(self):
        return {"state_shape": self.get_state_size(), "obs_shape": self.get_obs_size(), "n_actions": self.n_actions,
                "n_agents": self.n_agents, "episode_limit": self.episode_limit}

    def close(self):
        pass


# ---- Gymnasium-style vector env ------------------------------------------------------------------

class GymVectorEnv:
    """A Gymnasium-style vector environment for single-policy learners: observation [M, N * 11]
    (the N agents' observations concatenated), action MultiDiscrete([5] * N) per environment,
    ``reset(seed) -> (obs, infos)``, ``step(actions [M, N]) -> (obs, rewards, terminations,
    truncations, infos)``; infos holds the VecEnv info arrays and ``action_mask`` [M, N, 5].
    Auto-reset as VecEnv (final observation in ``infos["final_obs"]``)."""

    def __init__(self, config=None, num_envs: int = 8, seed: int = 0, oracle: str = ""):
        self.env = VecEnv(config, num_envs, seed, oracle)
        self.num_envs = self.env.num_envs
        n = self.env.num_agents
        self.single_observation_space = _obs_box(n * self.env.obs_size)
        self.single_action_space = MultiDiscrete([5] * n)
        self.observation_space = Box(-1.0, 1.0, shape=(self.num_envs, n * self.env.obs_size), dtype=np.float32)
        self.action_space = MultiDiscrete(np.full((self.num_envs, n), 5))

    def reset(self, seed: Optional[int] = None, options: Optional[dict] = None):
        o = self.env.reset(seed)
        return o.obs.reshape(self.num_envs, -1), {"action_mask": o.action_mask, "state": o.state}

    def step(self, actions):
        r = self.env.step(actions)
        infos = dict(r.info)
        infos["action_mask"] = r.action_mask
        infos["state"] = r.state
        return r.obs.reshape(self.num_envs, -1), r.reward, r.terminated, r.truncated, infos

    def close(self):
        pass
