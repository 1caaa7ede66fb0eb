"""Thin adapters over ``skyloop.VecEnv`` for the APIs learners already use.

Every size, bound and action count is read from the environment's spec (``VecEnv.spec``).

- ``ParallelEnv``: PettingZoo's Parallel API (a subclass of ``pettingzoo.ParallelEnv`` when
  pettingzoo is importable, the same methods otherwise); agents "uav_0" .. "uav_{N-1}"; each
  observation is ``{"observation": float32[obs], "action_mask": int8[A]}`` (PettingZoo's
  documented action-mask convention; the continuous model's carries no mask); ``state()`` is s[t].
- ``MappoEnv``: what the MAPPO reference implementation's shared SMAC-style runner reads:
  ``reset() -> (obs, share_obs, available_actions)``, ``step(actions) -> (obs, share_obs, rewards,
  dones, infos, available_actions)``, arrays [M, N, ...], ``infos[env][agent]`` dicts with
  ``bad_transition`` and ``won``.
- Under ``trajectory.mobility = "continuous"`` the action spaces of ``ParallelEnv``, ``MappoEnv`` and
  ``GymVectorEnv`` are commands (``trajectory.command``), Box(-1, 1, (2,)) per agent (``spec["dims"]``), flown
  through the safety layer of ``marl.action_mask`` / ``marl.shield``; ``SmacEnv`` (EPyMARL is
  discrete) takes the model's primitives, ``spec["actions"]``, with their action mask.
- ``SmacEnv``: EPyMARL's current ``MultiAgentEnv`` (its episode and parallel runners):
  ``reset(seed, options) -> (obs, info)``, ``step(actions) -> (obs, reward, terminated, truncated,
  info)``, ``get_obs``, ``get_state``, ``get_avail_actions``, ``get_env_info``, ``get_stats``; built
  with EPyMARL's ``common_reward`` and ``reward_scalarisation`` arguments.
- ``GymEnv``: a Gymnasium environment over one skyloop environment (``gymnasium.make(GYM_ID)``), the
  N agents flattened as in ``GymVectorEnv``; what Gymnasium's ``check_env`` and wrappers take.
- ``GymVectorEnv``: a Gymnasium vector environment (``gymnasium.vector.VectorEnv`` when installed;
  ``gymnasium.make_vec(GYM_ID, num_envs=M, vectorization_mode="vector_entry_point")``) for single-policy learners: every
  environment's N agents flattened into one observation (N * obs) and a MultiDiscrete([A] * N)
  action (continuous model: a Box of N * 2 commands); same-step auto-reset with ``final_obs`` / ``final_info`` and episode statistics in
  ``infos["episode"]`` (what CleanRL's PPO and Gymnasium's RecordEpisodeStatistics give).

Spaces are Gymnasium's when gymnasium is importable, else the minimal ``Box`` / ``Discrete`` /
``MultiDiscrete`` below (same attributes: shape, dtype, low, high, n, nvec, sample, contains, seed).
"""
from __future__ import annotations

from typing import Optional

import numpy as np

from . import InputError
from ._check import as_actions, as_commands, as_int, as_seed
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


def _bounds(array_spec, repeat: int = 1):
    """Per-element low and high of one row of a spec array (repeated `repeat` times)."""
    low = np.empty(array_spec["size"], np.float32)
    high = np.empty(array_spec["size"], np.float32)
    for f in array_spec["fields"]:
        low[f["offset"]:f["offset"] + f["size"]] = f["low"]
        high[f["offset"]:f["offset"] + f["size"]] = f["high"]
    return np.tile(low, repeat), np.tile(high, repeat)


def _row_box(array_spec, repeat: int = 1):
    """The Box of one row of a spec array: shape (repeat * size,), the fields' bounds."""
    low, high = _bounds(array_spec, repeat)
    return Box(low, high, shape=low.shape, dtype=np.float32)


def _mask_box(num_actions):
    return Box(0, 1, shape=(num_actions,), dtype=np.int8)


def _action_space(spec, repeat: int = 1):
    """One agent's action space (``repeat`` agents flattened): Discrete over the mobility model's
    actions, or under ``trajectory.mobility = "continuous"`` (``spec["dims"]`` > 0) the velocity
    command Box(-1, 1, (dims,))."""
    if spec["dims"] > 0:
        return Box(-1.0, 1.0, shape=(repeat * spec["dims"],), dtype=np.float32)
    return Discrete(spec["num_actions"]) if repeat == 1 else MultiDiscrete([spec["num_actions"]] * repeat)


try:  # pragma: no cover - pettingzoo is not packaged in Debian
    from pettingzoo import ParallelEnv as _ParallelBase  # type: ignore
except ImportError:
    _ParallelBase = object


# ---- PettingZoo ----------------------------------------------------------------------------------

class ParallelEnv(_ParallelBase):
    """PettingZoo Parallel API over one skyloop environment. Arrived UAVs stay in ``agents`` (they
    keep serving users) with a hover-only action mask (STAY under the grid model) until the episode ends; then ``agents``
    is empty until ``reset``. Rewards are the team reward, given to every agent."""

    metadata = {"name": "skyloop_uav_v0", "render_modes": [], "is_parallelizable": True}

    def __init__(self, config=None, seed: int = 0, oracle: str = ""):
        self._config, self._oracle, self._seed = config, oracle, as_seed(seed, "seed")
        self._vec = VecEnv(config, 1, self._seed, oracle)
        n = self._vec.num_agents
        self.possible_agents = [f"uav_{i}" for i in range(n)]
        self.agents: list[str] = []
        spec = self._vec.spec
        self._act_space = _action_space(spec)
        self._dims = spec["dims"]
        # A Box action takes no mask: the continuous model's observations carry none (the safety layer acts).
        self._obs_space = Dict({"observation": _row_box(spec["obs"])} if self._dims else
                               {"observation": _row_box(spec["obs"]), "action_mask": _mask_box(spec["num_actions"])})
        self.state_space = _row_box(spec["state"])
        self._stay = spec["hover"]
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
        if self._dims:
            return {a: {"observation": obs[0, i].copy()} for i, a in enumerate(self.possible_agents)}
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
            allowed = (f"a command in [-1, 1]^{self._dims}" if self._dims else f"one action in 0..{self._act_space.n - 1}")
            raise InputError(f"actions are missing for {missing}: allowed {allowed} per live agent")
        if self._dims:
            joint = np.stack([as_commands(actions[a], f"actions[{a!r}]", (self._dims,)) for a in self.possible_agents])[None]
        else:
            joint = np.array([[as_actions(actions[a], f"actions[{a!r}]", (1,), self._act_space.n)[0]
                               for a in self.possible_agents]], dtype=np.int64)
        r = self._vec.step(joint)
        done = bool(r.terminated[0] or r.truncated[0])
        obs = r.info["final_obs"] if done else r.obs
        mask = r.action_mask
        if done:  # the finished episode's last view: every agent may only hover
            mask = np.zeros_like(mask)
            mask[..., self._stay] = 1
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


# ---- MAPPO reference implementation ---------------------------------------------------------------

class MappoEnv:
    """What the MAPPO reference implementation's shared SMAC-style runner reads from its
    vectorised envs: ``reset() -> (obs, share_obs, available_actions)``; ``step(actions) -> (obs,
    share_obs, rewards, dones, infos, available_actions)`` with obs [M, N, obs], share_obs
    [M, N, agent_state] (the agent-specific global state), rewards [M, N, 1] (the team reward),
    dones bool [M, N] (the episode's end, for every agent), available_actions [M, N, A] (None under
    the continuous model, whose action space is a Box as the reference's MPE runs use), and infos a
    list of M lists of N dicts: the environment's step statistics plus ``bad_transition`` (the
    episode hit T_max: a time limit, not a terminal state) and ``won`` (every UAV home).
    ``actions`` may be [M, N] or [M, N, 1]. Auto-reset as VecEnv."""

    def __init__(self, config=None, num_envs: int = 8, seed: int = 0, oracle: str = ""):
        self.env = VecEnv(config, num_envs, seed, oracle)
        self.num_envs, self.num_agents = self.env.num_envs, self.env.num_agents
        spec = self.env.spec
        self.observation_space = [_row_box(spec["obs"]) for _ in range(self.num_agents)]
        self.share_observation_space = [_row_box(spec["agent_state"]) for _ in range(self.num_agents)]
        self.action_space = [_action_space(spec) for _ in range(self.num_agents)]

    def seed(self, seed: int):
        self.env.reset(seed)

    def reset(self, seed: Optional[int] = None):
        o = self.env.reset(seed)
        return o.obs, o.agent_state, self._available(o.action_mask)

    def _available(self, mask):
        # The reference's buffer keeps available_actions for Discrete spaces only (None otherwise).
        return None if self.env.action_dims else mask

    def step(self, actions):
        M, N = self.num_envs, self.num_agents
        if self.env.action_dims:
            a = as_commands(actions, "actions", (M, N, self.env.action_dims))
        else:  # the runner passes [M, N, 1]
            a = as_actions(actions, "actions", (M, N), self.env.num_actions)
        r = self.env.step(a)
        M, N = self.num_envs, self.num_agents
        done = r.terminated | r.truncated
        dones = np.repeat(done[:, None], N, axis=1)
        rewards = np.repeat(r.reward[:, None, None], N, axis=1).astype(np.float32)
        infos = []
        for i in range(M):
            stats = {k: v[i].item() for k, v in r.info.items() if v.ndim == 1}
            stats["bad_transition"] = bool(r.truncated[i])
            stats["won"] = bool(r.terminated[i])
            infos.append([dict(stats) for _ in range(N)])
        return r.obs, r.agent_state, rewards, dones, infos, self._available(r.action_mask)

    def close(self):
        pass


# ---- EPyMARL -------------------------------------------------------------------------------------

class SmacEnv:
    """EPyMARL's ``MultiAgentEnv`` over one environment, as its current episode and parallel
    runners use it. ``reset(seed=None, options=None) -> (obs, info)``; ``step(actions) -> (obs,
    reward, terminated, truncated, info)`` with ``info["episode_limit"]`` = truncated (T_max hit),
    numeric values only (the runners sum them); after the last step ``get_obs``, ``get_state`` and
    ``get_avail_actions`` describe the finished episode's last slot (every agent may only hover)
    until ``reset``. ``common_reward`` (EPyMARL's argument): True gives the team reward as a float,
    False the same reward once per agent; ``reward_scalarisation`` is accepted and has no effect
    (the reward is already a team reward). Register it as ``REGISTRY["skyloop"] = SmacEnv``."""

    def __init__(self, config=None, seed: int = 0, oracle: str = "", common_reward: bool = True,
                 reward_scalarisation: str = "sum", **unused):
        if unused:
            raise InputError(f"SmacEnv got unknown arguments {sorted(unused)}: allowed config, seed, oracle, "
                             f"common_reward, reward_scalarisation")
        if not isinstance(common_reward, bool):
            raise InputError(f"common_reward = {common_reward!r}: allowed True or False")
        self.env = VecEnv(config, 1, seed, oracle)
        spec = self.env.spec
        self.n_agents = self.env.num_agents
        self.n_actions = spec["num_actions"]
        self.common_reward = common_reward
        self.reward_scalarisation = reward_scalarisation
        self.episode_limit = int(self.env.config["trajectory.t_max"]) - 1
        self._stay = spec["hover"]
        self._next = self.env.reset()  # the environment's current episode, first slot
        self._view = (self._next.obs[0], self._next.state[0], self._next.action_mask[0])
        self._pending = False  # a finished episode is shown; the next one's first slot waits in _next
        self._stats = {"episodes": 0, "won": 0, "collisions": 0, "boundary": 0, "objective": 0.0}

    def reset(self, seed: Optional[int] = None, options: Optional[dict] = None):
        # After the last step the environment has already started its next episode (auto-reset):
        # show it. Otherwise (mid-episode, a repeated reset, or a new seed) reset for real.
        o = self._next if (self._pending and seed is None) else self.env.reset(seed)
        self._view = (o.obs[0], o.state[0], o.action_mask[0])
        self._pending = False
        return self.get_obs(), {}

    def step(self, actions):
        a = as_actions(actions.cpu() if hasattr(actions, "cpu") else actions, "actions", (self.n_agents,), self.n_actions)[None]
        r = self.env.step(a)
        terminated, truncated = bool(r.terminated[0]), bool(r.truncated[0])
        info = {k: v[0].item() for k, v in r.info.items() if v.ndim == 1}
        info["episode_limit"] = truncated
        if terminated or truncated:  # the finished episode's last slot; the new one waits for reset()
            mask = np.zeros_like(r.action_mask[0])
            mask[:, self._stay] = 1
            self._view = (r.info["final_obs"][0], r.info["final_state"][0], mask)
            self._next, self._pending = r, True
            self._stats["episodes"] += 1
            self._stats["won"] += int(terminated)
            self._stats["objective"] += info["objective"]
        else:
            self._view = (r.obs[0], r.state[0], r.action_mask[0])
        self._stats["collisions"] += info["collisions"]
        self._stats["boundary"] += info["boundary"]
        reward = float(r.reward[0])
        return self.get_obs(), (reward if self.common_reward else [reward] * self.n_agents), terminated, truncated, info

    def get_obs(self):
        return [self._view[0][i].copy() for i in range(self.n_agents)]

    def get_obs_agent(self, agent_id):
        return self._view[0][as_int(agent_id, "agent_id", 0, self.n_agents - 1)].copy()

    def get_obs_size(self):
        return self.env.obs_size

    def get_state(self):
        return self._view[1].copy()

    def get_state_size(self):
        return self.env.state_size

    def get_avail_actions(self):
        return [self._view[2][i].astype(np.int64).tolist() for i in range(self.n_agents)]

    def get_avail_agent_actions(self, agent_id):
        return self._view[2][as_int(agent_id, "agent_id", 0, self.n_agents - 1)].astype(np.int64).tolist()

    def get_total_actions(self):
        return self.n_actions

    def get_env_info(self):
        return {"state_shape": self.get_state_size(), "obs_shape": self.get_obs_size(), "n_actions": self.n_actions,
                "n_agents": self.n_agents, "episode_limit": self.episode_limit}

    def get_stats(self):
        """Totals since construction: episodes, missions won, collisions, boundary events, and the
        mean P2.2 objective of the finished episodes."""
        s = dict(self._stats)
        s["objective"] = s["objective"] / s["episodes"] if s["episodes"] else 0.0
        return s

    def seed(self, seed=None):
        if seed is not None:
            self.reset(seed)

    def render(self):
        return None

    def save_replay(self):
        pass

    def close(self):
        pass


# ---- Gymnasium vector env ------------------------------------------------------------------------

try:  # pragma: no cover - gymnasium is not packaged in Debian
    import gymnasium as _gym  # type: ignore
    from gymnasium.vector import AutoresetMode as _AutoresetMode  # type: ignore
    _SAME_STEP = _AutoresetMode.SAME_STEP
    _EnvBase, _VectorBase = _gym.Env, _gym.vector.VectorEnv
except ImportError:
    _gym = None
    _SAME_STEP = "same-step"
    _EnvBase = _VectorBase = object

#: The id under which ``GymEnv`` (``gymnasium.make``) and ``GymVectorEnv`` (``gymnasium.make_vec``)
#: are registered with Gymnasium when it is installed.
GYM_ID = "skyloop/UavDownlink-v0"


def _flat_actions(actions, n, dims, num_actions, name="action"):
    """One environment's joint action, flattened as GymEnv takes it, as VecEnv.step's [1, N(, dims)]."""
    if dims:
        return as_commands(actions, name, (n * dims,)).reshape(1, n, dims)
    return as_actions(actions, name, (n,), num_actions)[None]


class GymEnv(_EnvBase):
    """A Gymnasium environment (``gymnasium.Env`` when gymnasium is installed) over one skyloop
    environment, for single-policy learners and Gymnasium's own tools (``check_env``, wrappers,
    ``SyncVectorEnv``): the N agents' observations concatenated (float32 [N * obs]), the joint action
    MultiDiscrete([A] * N) (continuous model: a Box of N * dims commands), the team reward.
    ``reset(seed)`` redraws the users from ``seed`` (None: the same users, or new ones with
    ``env.resample_users``); ``info`` holds ``action_mask`` [N, A] and ``state``, and after the last
    step the finished episode's statistics (``objective``, ``home``, ``success``, ...).
    ``gymnasium.make("skyloop/UavDownlink-v0", config=...)`` builds one."""

    metadata = {"render_modes": []}

    def __init__(self, config=None, seed: int = 0, oracle: str = "", render_mode=None):
        if render_mode is not None:
            raise InputError(f"render_mode = {render_mode!r}: allowed None (skyloop renders no frames)")
        self._vec = VecEnv(config, 1, seed, oracle)
        spec, self._n = self._vec.spec, self._vec.num_agents
        self._dims = spec["dims"]
        self.observation_space = _row_box(spec["obs"], self._n)
        self.action_space = _action_space(spec, self._n)
        self.render_mode = None

    def reset(self, *, seed: Optional[int] = None, options: Optional[dict] = None):
        seed = None if seed is None else as_seed(seed, "seed")
        if _gym is not None:
            super().reset(seed=seed)  # Gymnasium's np_random, seeded as its checker expects
        o = self._vec.reset(seed)
        return o.obs.reshape(-1), {"action_mask": o.action_mask[0], "state": o.state[0]}

    def step(self, action):
        r = self._vec.step(_flat_actions(action, self._n, self._dims, self._vec.num_actions))
        terminated, truncated = bool(r.terminated[0]), bool(r.truncated[0])
        done = terminated or truncated
        obs = (r.info["final_obs"] if done else r.obs)[0].reshape(-1)
        info = {k: v[0].item() for k, v in r.info.items() if v.ndim == 1}
        info["action_mask"] = r.action_mask[0]
        info["state"] = (r.info["final_state"] if done else r.state)[0]
        return obs, float(r.reward[0]), terminated, truncated, info

    def render(self):
        return None

    def close(self):
        self._vec.close()


class GymVectorEnv(_VectorBase):
    """A Gymnasium vector environment for single-policy learners: observation [M, N * obs] (the N
    agents' observations concatenated), action MultiDiscrete([A] * N) per environment,
    ``reset(seed, options) -> (obs, infos)``, ``step(actions [M, N]) -> (obs, rewards,
    terminations, truncations, infos)``. Auto-reset in the same step (``metadata
    ["autoreset_mode"]``): a finished environment's returned observation is its new episode's
    first; ``infos["final_obs"]`` and ``infos["final_info"]`` (with its ``episode``: r, l, t) hold
    the finished episode, masked by ``infos["_final_obs"]`` / ``["_final_info"]``: in Gymnasium's own
    layout when gymnasium is installed (an array [M, N * obs] and a dict of arrays, as its
    SyncVectorEnv writes them), else object arrays with one entry per finished environment.
    Episode statistics ``infos["episode"]`` {r, l, t} with ``infos["_episode"]`` come from
    Gymnasium's ``RecordEpisodeStatistics`` wrapper, or from here with ``episode_statistics=True``.
    ``infos`` also holds the VecEnv info arrays, ``action_mask`` [M, N, A] and ``state``."""

    metadata = {"autoreset_mode": _SAME_STEP, "render_modes": []}
    render_mode = None

    def __init__(self, config=None, num_envs: int = 8, seed: int = 0, oracle: str = "", episode_statistics: bool = False):
        import time
        from ._check import as_bool
        # Gymnasium's convention: episode statistics are its RecordEpisodeStatistics wrapper's to add
        # (it refuses an "episode" key already there); True adds them here, for use without it.
        self._episode_statistics = as_bool(episode_statistics, "episode_statistics")
        self.env = VecEnv(config, num_envs, seed, oracle)
        self.num_envs = self.env.num_envs
        spec, n = self.env.spec, self.env.num_agents
        self.single_observation_space = _row_box(spec["obs"], n)
        self.single_action_space = _action_space(spec, n)
        self._dims = spec["dims"]
        low, high = _bounds(spec["obs"], n)
        self.observation_space = Box(np.tile(low, (self.num_envs, 1)), np.tile(high, (self.num_envs, 1)),
                                     shape=(self.num_envs, n * spec["obs"]["size"]), dtype=np.float32)
        if self._dims:
            self.action_space = Box(-1.0, 1.0, shape=(self.num_envs, n * self._dims), dtype=np.float32)
        else:
            self.action_space = MultiDiscrete(np.full((self.num_envs, n), spec["num_actions"]))
        self.closed = False
        self._return = np.zeros(self.num_envs)
        self._length = np.zeros(self.num_envs, dtype=np.int64)
        self._start = np.full(self.num_envs, time.perf_counter())

    @property
    def unwrapped(self):
        return self

    def reset(self, seed: Optional[int] = None, options: Optional[dict] = None):
        import time
        self._open("reset")
        if seed is not None and _gym is not None:  # Gymnasium's np_random, as its vector envs seed it
            from gymnasium.utils import seeding
            self._np_random, self._np_random_seed = seeding.np_random(as_seed(seed, "seed"))
        o = self.env.reset(seed)
        self._return[:] = 0
        self._length[:] = 0
        self._start[:] = time.perf_counter()
        return o.obs.reshape(self.num_envs, -1), {"action_mask": o.action_mask, "state": o.state}

    def _open(self, what):
        if self.closed:
            raise InputError(f"GymVectorEnv.{what}() after close(): allowed calls before close(), or a new GymVectorEnv")

    def step(self, actions):
        import time
        self._open("step")
        M, N = self.num_envs, self.env.num_agents
        if self._dims:  # [M, N * dims] flattened commands -> [M, N, dims]
            actions = as_commands(actions, "actions", (M, N * self._dims)).reshape(M, N, self._dims)
        else:
            actions = as_actions(actions, "actions", (M, N), self.env.num_actions)
        r = self.env.step(actions)
        M = self.num_envs
        done = r.terminated | r.truncated
        self._return += r.reward
        self._length += 1
        infos = {k: v for k, v in r.info.items() if k not in ("final_obs", "final_state")}
        infos["action_mask"] = r.action_mask
        infos["state"] = r.state
        now = time.perf_counter()
        episode = {"r": np.where(done, self._return, 0.0).astype(np.float32),
                   "l": np.where(done, self._length, 0).astype(np.int32),
                   "t": np.where(done, now - self._start, 0.0).astype(np.float32)}
        finished = {int(i): {"episode": {"r": float(episode["r"][i]), "l": int(episode["l"][i]), "t": float(episode["t"][i])},
                             **{k: v[i].item() for k, v in r.info.items() if v.ndim == 1}} for i in np.flatnonzero(done)}
        if done.any() and self._episode_statistics:
            infos["episode"], infos["_episode"] = episode, done.copy()
        if done.any() and _gym is not None:
            # Gymnasium's own layout of a same-step reset (as its SyncVectorEnv writes it):
            # infos["final_obs"] [M, N * obs] and infos["final_info"] a dict of arrays, each with its mask.
            for i, info in finished.items():
                infos = self._add_info(infos, {"final_obs": r.info["final_obs"][i].reshape(-1), "final_info": info}, i)
        elif done.any():  # without gymnasium: object arrays of the finished ones (CleanRL's gymnasium 0.29 reads)
            final_obs, final_info = np.empty(M, dtype=object), np.empty(M, dtype=object)
            for i, info in finished.items():
                final_obs[i], final_info[i] = r.info["final_obs"][i].reshape(-1), info
            infos["final_obs"], infos["_final_obs"] = final_obs, done.copy()
            infos["final_info"], infos["_final_info"] = final_info, done.copy()
        self._return[done] = 0
        self._length[done] = 0
        self._start[done] = now
        return r.obs.reshape(M, -1), r.reward, r.terminated, r.truncated, infos

    def close(self, **kwargs):
        if not self.closed:
            self.env.close()
        self.closed = True


def _register_gymnasium():
    """Registers GymEnv and GymVectorEnv under GYM_ID (once per process)."""
    if _gym is None or GYM_ID in _gym.registry:
        return
    _gym.register(id=GYM_ID, entry_point="skyloop.adapters:GymEnv", vector_entry_point="skyloop.adapters:GymVectorEnv",
                  nondeterministic=False)


_register_gymnasium()
