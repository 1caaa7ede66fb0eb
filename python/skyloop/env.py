"""The batch-first trajectory environment (EnvPool style).

``VecEnv(config, num_envs, seed)`` holds M copies of the paper's trajectory environment (N UAVs
flying from their starts to their destinations over K ground users, one move per slot from UP,
DOWN, LEFT, RIGHT, STAY), stepped as one batch in C++ with the GIL released; every environment's
sum rate R[t] comes from one batched beamformer call (``env.oracle``, default the paper's GNN).

Environment i draws its K users from ``derive_seed(seed, i)``; with ``env.resample_users`` each
reset draws new ones from that environment's own stream.

Auto-reset: an environment whose episode ends (every UAV home: ``terminated``; T_max reached
first: ``truncated``) is reset inside the same ``step``; the arrays returned are the new episode's
first slot, and ``info["final_obs"]`` / ``info["final_state"]`` hold the finished episode's last
observation (zeros elsewhere). ``info`` also carries the finished episode's ``objective`` (P2.2's
average sum rate), ``T``, ``home``, ``success`` and ``episode_reward``.

Arrived UAVs stay in the agent list: they keep serving users, their action mask is
[0, 0, 0, 0, 1] and any action given for them is executed as STAY.
"""
from __future__ import annotations

from typing import NamedTuple, Optional

import numpy as np

from . import _skyloop


class Observation(NamedTuple):
    obs: np.ndarray          # float32 [M, N, 11]: own position, mean displacement to the users, to the destination (/ area side), previous action one-hot
    state: np.ndarray        # float32 [M, 4N + 2K]: all UAV positions, all user positions, all destinations (/ area side)
    agent_state: np.ndarray  # float32 [M, N, S + N + 11]: state, one-hot agent id, obs
    action_mask: np.ndarray  # int8 [M, N, 5]: 1 = allowed; an arrived UAV may only STAY


class StepResult(NamedTuple):
    obs: np.ndarray
    state: np.ndarray
    agent_state: np.ndarray
    action_mask: np.ndarray
    reward: np.ndarray       # float32 [M]: the team reward r[t] (eq:total_reward)
    terminated: np.ndarray   # bool [M]: every UAV home (episode over)
    truncated: np.ndarray    # bool [M]: T_max reached before every UAV was home
    info: dict               # arrays [M]: sum_rate, objective, collisions, boundary, arrivals, home, T, success, episode_reward; final_obs, final_state


OBS_FIELDS = ("own_x", "own_y", "users_dx", "users_dy", "dest_dx", "dest_dy",
              "prev_up", "prev_down", "prev_left", "prev_right", "prev_stay")


class VecEnv:
    """M trajectory environments stepped as one batch. ``config``: a skyloop.Config, a dict of
    overrides or a TOML path; ``oracle``: the beamformer spec behind R[t] (default env.oracle)."""

    def __init__(self, config=None, num_envs: int = 1, seed: int = 0, oracle: str = ""):
        from . import _as_config
        self._env = _skyloop.VecEnv(_as_config(config), int(num_envs), int(seed), str(oracle))
        self.num_envs = self._env.num_envs
        self.num_agents = self._env.agents
        self.obs_size = self._env.obs_size
        self.state_size = self._env.state_size
        self.agent_state_size = self._env.agent_state_size
        self.num_actions = 5
        self.config = self._env.config

    def reset(self, seed: Optional[int] = None) -> Observation:
        """Starts a new episode in every environment; ``seed`` redraws every environment's users
        from it (None: the same users, or new ones with env.resample_users)."""
        d = self._env.reset(None if seed is None else int(seed))
        return Observation(d["obs"], d["state"], d["agent_state"], d["action_mask"])

    def step(self, actions) -> StepResult:
        """``actions``: integer array [M, N] with values 0..4 (UP, DOWN, LEFT, RIGHT, STAY)."""
        a = np.asarray(actions)
        d = self._env.step(a)
        return StepResult(d["obs"], d["state"], d["agent_state"], d["action_mask"], d["reward"], d["terminated"],
                          d["truncated"], d["info"])

    def positions(self) -> dict:
        """Current UAV positions and destinations [M, N, 2] (metres) and slots t [M]."""
        return self._env.positions()

    def users(self, env: int = 0) -> np.ndarray:
        """The users [K, 2] (metres) of environment ``env``."""
        return self._env.users(int(env))
