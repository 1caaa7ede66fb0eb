"""The batch-first trajectory environment (EnvPool style).

``VecEnv(config, num_envs, seed)`` holds M copies of the paper's trajectory environment (N UAVs
flying from their starts to their destinations over K ground users, one move per slot of the
mobility model: the paper's UP, DOWN, LEFT, RIGHT, STAY, or ``trajectory.mobility = "headings"``;
``spec["actions"]`` names them; ``"continuous"``: velocity commands, ``spec["dims"]`` = 2), stepped as one batch in C++ with the GIL released; every environment's
sum rate R[t] comes from one batched beamformer call (``env.oracle``, default the paper's GNN).

Environment i draws its K users from ``derive_seed(seed, i)``; with ``env.resample_users`` each
reset draws new ones from that environment's own stream.

Auto-reset: an environment whose episode ends (every UAV home: ``terminated``; T_max reached
first: ``truncated``) is reset inside the same ``step``; the arrays returned are the new episode's
first slot, and ``info["final_obs"]`` / ``info["final_state"]`` hold the finished episode's last
observation (zeros elsewhere). ``info`` also carries the finished episode's ``objective``
(``env.objective``'s J; P2.2's average sum rate by default), ``sum_rate_objective``, ``T``, ``home``,
``success`` and ``episode_reward``, and the propulsion energy: ``energy_j`` (this step, the fleet),
``episode_energy_j`` and ``bits_per_joule``.

Arrived UAVs stay in the agent list: they keep serving users, their action mask is
hover only (``spec["hover"]``: STAY under the grid model) and any action given for them is executed as hover.
"""
from __future__ import annotations

from typing import NamedTuple, Optional

import numpy as np

from . import _skyloop


class Observation(NamedTuple):
    obs: np.ndarray          # float32 [M, N, spec["obs"]["size"]]: the agents' observation (marl.encoder: the paper's 11 reals, or the set observation)
    state: np.ndarray        # float32 [M, spec["state"]["size"]]: the global state (env.state: paper 4N + 2K, or compact)
    agent_state: np.ndarray  # float32 [M, N, spec["agent_state"]["size"]]: state, agent context, the paper observation
    action_mask: np.ndarray  # int8 [M, N, spec["num_actions"]]: 1 = allowed; an arrived UAV may only hover (spec["hover"]; STAY under the grid model)


class StepResult(NamedTuple):
    obs: np.ndarray
    state: np.ndarray
    agent_state: np.ndarray
    action_mask: np.ndarray
    reward: np.ndarray       # float32 [M]: the team reward r[t] (eq:total_reward)
    terminated: np.ndarray   # bool [M]: every UAV home (episode over)
    truncated: np.ndarray    # bool [M]: T_max reached before every UAV was home
    info: dict               # arrays [M]: sum_rate, objective, collisions, boundary, arrivals, home, T, success, episode_reward, episode_collisions, episode_boundary, energy; final_obs, final_state


class Turn(NamedTuple):
    agent: np.ndarray        # int32 [M]: whose turn it is in each environment (-1: every agent there has chosen)
    obs: np.ndarray          # float32 [M, spec["obs"]["size"]]: that agent's observation, written now (the landings chosen before it shown)
    action_mask: np.ndarray  # int8 [M, spec["num_actions"]]: its allowed moves (the mask, and the shield against the UAVs placed)
    last: np.ndarray         # bool [M]: its move is flown (the last pass; False where agent = -1)


class VecEnv:
    """M trajectory environments stepped as one batch. ``config``: a skyloop.Config, a dict of
    overrides or a TOML path; ``oracle``: the beamformer spec behind R[t] (default env.oracle).

    ``spec`` describes every array (the environment's own spec, skyloop/env/spec.hpp): for each of
    ``obs``, ``state``, ``agent_context``, ``agent_state``, ``action_mask`` (and both observation
    layouts, ``paper_obs`` and ``set_obs``) its kind, dtype, shape per environment, bounds and
    fields (name, offset, size, low, high); ``num_actions`` and ``actions`` (names). Sizes below
    are read from it. ``field(array, name)`` slices one named field out of an array.

    Threads: the calls of one VecEnv from several Python threads are serialised (a lock taken with
    the GIL released), so sharing one is safe but not parallel; use one VecEnv per thread for that."""

    def __init__(self, config=None, num_envs: int = 1, seed: int = 0, oracle: str = "", layouts=None):
        """``layouts``: one users seed per environment (skyloop/env/layouts.hpp; e.g. a benchmark
        task's test layouts): environment i flies layout ``layouts[i]`` in every episode, and
        ``num_envs`` is their count."""
        from . import InputError, _as_config, _as_int, _as_seed, _as_str
        if layouts is None:
            seeds = []
        else:
            if isinstance(layouts, (str, bytes)) or not hasattr(layouts, "__len__"):
                raise InputError(f"layouts = {layouts!r} has the wrong type: allowed a list of users seeds")
            seeds = [_as_int(x, f"layouts[{i}]", 0, 3 * 2**62 - 1) for i, x in enumerate(layouts)]
            if not seeds:
                raise InputError("layouts is empty: allowed at least one users seed")
            if num_envs not in (1, len(seeds)):
                raise InputError(f"num_envs = {num_envs!r} with {len(seeds)} layouts: allowed one environment per layout")
            num_envs = len(seeds)
        self._args = (_as_int(num_envs, "num_envs", 1, 65536), _as_seed(seed, "seed"), _as_str(oracle, "oracle"), seeds)
        self._env = _skyloop.VecEnv(_as_config(config), *self._args)
        self.spec = self._env.spec
        self.num_envs = self._env.num_envs
        self.num_agents = self._env.agents
        self.obs_size = self.spec["obs"]["size"]
        self.state_size = self.spec["state"]["size"]
        self.agent_state_size = self.spec["agent_state"]["size"]
        self.num_actions = self.spec["num_actions"]
        self.action_dims = self.spec["dims"]  # continuous commands' size (0: discrete)
        self.config = self._env.config

    def __reduce__(self):
        # Pickled as its arguments: it unpickles as a VecEnv made afresh with the same
        # configuration, size, seed and oracle, at the start of its first episode.
        return (VecEnv, (self.config, *self._args[:3], self._args[3] or None))

    def close(self):
        """Releases the environments; any later call raises InputError. Closing twice is allowed."""
        self._env = _Closed()

    def field(self, array: np.ndarray, array_name: str, field: str) -> np.ndarray:
        """The named field of ``array`` (an array of kind ``array_name``: "obs", "state", ...), the
        last axis sliced by the spec: ``env.field(o.obs, "obs", "own_position")`` -> [M, N, 2]."""
        from . import InputError, _as_array, _as_str
        kinds = ", ".join(k for k, v in self.spec.items() if isinstance(v, dict) and "fields" in v)
        array_name, field = _as_str(array_name, "array_name"), _as_str(field, "field")
        array = _as_array(array, "array", f"a numeric array of kind {array_name!r}", dtype=None)
        if array_name not in self.spec or not isinstance(self.spec[array_name], dict):
            raise InputError(f"array {array_name!r} is unknown: allowed {kinds}")
        for f in self.spec[array_name]["fields"]:
            if f["name"] == field:
                return np.asarray(array)[..., f["offset"]:f["offset"] + f["size"]]
        names = ", ".join(f["name"] for f in self.spec[array_name]["fields"])
        raise InputError(f"{array_name} has no field {field!r}: allowed {names}")

    def reset(self, seed: Optional[int] = None) -> Observation:
        """Starts a new episode in every environment; ``seed`` redraws every environment's users
        from it (None: the same users, or new ones with env.resample_users)."""
        from . import _as_seed
        d = self._env.reset(None if seed is None else _as_seed(seed, "seed"))
        return Observation(d["obs"], d["state"], d["agent_state"], d["action_mask"])

    def step(self, actions) -> StepResult:
        """``actions``: integer array [M, N] with values 0..num_actions-1 (``spec["actions"]``); under
        ``trajectory.mobility = "continuous"`` (``spec["dims"]`` = 2) also a float array [M, N, 2] of
        commands in [-1, 1] (a velocity, a change of velocity or a speed and a turn, as
        ``trajectory.command`` says; projected onto what each UAV can fly, then through the safety
        layer of marl.action_mask and marl.shield)."""
        M, N = self.num_envs, self.num_agents
        if type(actions) is np.ndarray and actions.dtype.kind in "iu" and actions.shape == (M, N):
            return self._stepped(self._env.step(actions))  # the core checks each value itself (one line naming the entry)
        from ._check import as_actions, as_commands
        if self.action_dims and np.ndim(actions) == 3:
            a = as_commands(actions, "actions", (M, N, self.action_dims))
        else:
            a = as_actions(actions, "actions", (M, N), self.num_actions)
        return self._stepped(self._env.step(a))

    @staticmethod
    def _stepped(d) -> StepResult:
        return StepResult(d["obs"], d["state"], d["agent_state"], d["action_mask"], d["reward"], d["terminated"],
                          d["truncated"], d["info"])

    def begin_turns(self, passes: Optional[int] = None) -> Turn:
        """Starts the slot's turns (``marl.sequential``'s protocol, with the collision shield): in
        every environment the UAVs not yet home choose one after another, least slack first. Each
        turn's ``action_mask`` is the configuration's mask (``marl.action_mask``, ``slack_margin``,
        ``mask_clearance``) with the shield (``marl.shield``) against the UAVs placed so far: the
        arrived ones and those that chose before. ``obs`` is the turn's agent's observation written
        just before it chooses: with the set observation (``marl.encoder = "set"``) the landings
        chosen before it stand in place of where those UAVs are (their kernels, and the joint rate
        in ``marl.lookahead``'s move gains and ``marl.rate_map``). Grid and headings moves only.

        ``passes`` (1 .. ``skyloop.MAX_SEQUENTIAL_PASSES``; default the configuration's
        ``marl.sequential_passes``): the turns are taken that many times and the last pass is flown
        (``turn.last``). In every pass after the first each agent also sees the agents after it
        at their moves of the pass before (their intentions), and itself where it is: the protocol
        ``skyloop train`` trains and flies with ``marl.sequential_passes``. A learner that trains as
        it does keeps the last pass's rows and samples the earlier ones without training on them::

            turn = env.begin_turns()
            while (turn.agent >= 0).any():
                turn = env.take_turn(choose(turn.obs, turn.action_mask))  # int [M]; ignored where agent = -1
            result = env.step_turns()                                    # as step(): the joint moves chosen
        """
        from . import _as_int
        d = self._env.begin_turns(None if passes is None else _as_int(passes, "passes", 1, _skyloop.MAX_SEQUENTIAL_PASSES))
        return Turn(d["agent"], d["obs"], d["action_mask"], d["last"])

    def take_turn(self, actions) -> Turn:
        """``actions``: integer array [M], each environment's move for the agent whose turn it is (one
        its ``action_mask`` allows; ignored where ``agent`` is -1). Returns the next turn."""
        from ._check import as_actions
        d = self._env.take_turn(as_actions(actions, "actions", (self.num_envs,), None))
        return Turn(d["agent"], d["obs"], d["action_mask"], d["last"])

    def step_turns(self) -> StepResult:
        """Steps every environment with the moves its turns chose in the last pass (``step``'s result)."""
        return self._stepped(self._env.step_turns())

    def positions(self) -> dict:
        """Current UAV positions and destinations [M, N, 3] (x, y and altitude z, metres) and slots t [M]."""
        return self._env.positions()

    def users(self, env: int = 0) -> np.ndarray:
        """The users [K, 2] (metres) of environment ``env``."""
        from . import _as_int
        return self._env.users(_as_int(env, "env", 0, self.num_envs - 1))


class _Closed:
    """What a closed VecEnv holds instead of its environments: every use says so in one line."""

    def __getattr__(self, name):
        from . import InputError
        raise InputError(f"VecEnv.{name}: the VecEnv is closed: allowed calls before close(), or a new VecEnv")
