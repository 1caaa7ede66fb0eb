"""skyloop from Python: the multi-UAV downlink model, every beamformer, the batched trajectory
environment, the planners, and the adapters the field's learners expect.

Shapes (numpy)::

  G  complex128 [K_n, L]   a cluster's channel, row k = h_k^H (so (G W)[k, j] = h_k^H w_j)
  W  complex128 [L, K_n]   a beamformer, column k = w_k
  VecEnv: obs float32 [M, N, O], state float32 [M, S], agent_state float32 [M, N, A], action_mask
          int8 [M, N, len(ACTIONS)] (an arrived UAV may only STAY), reward float32 [M]; the sizes,
          field names, offsets and bounds are the environment's spec (VecEnv.spec)

Errors in input (a config key, a value out of range, a bad action) raise ``skyloop.InputError``
(a ValueError) carrying the same one-line message as the CLI.
"""
from __future__ import annotations

import os as _os

from . import _skyloop
from ._skyloop import __version__  # the VERSION file's, shared with `skyloop --version` and the docs
from ._skyloop import ACTIONS, LEARNERS, MAX_SEQUENTIAL_PASSES, PLANNERS, Beamformer, Cluster, InputError, Network, Snapshot, SystemModel, beamformers, derive_seed

__all__ = [
    "__version__", "ACTIONS", "LEARNERS", "MAX_SEQUENTIAL_PASSES", "PLANNERS", "Beamformer", "Cluster", "Config", "InputError", "Network", "Snapshot", "SystemModel", "VecEnv",
    "beamformer", "beamformers", "config", "derive_seed", "evaluate_layouts", "network_sum_rate", "plan", "rates", "sinr", "sum_rate",
    "user_powers",
]

# An installed package carries models/ and configs/ under data/; from a build tree the source
# directory compiled into the module is used.
_here = _os.path.dirname(_os.path.abspath(__file__))
if _os.path.isdir(_os.path.join(_here, "data", "models")) and not _os.environ.get("SKYLOOP_DATA_DIR"):
    _skyloop.set_data_dir(_os.path.join(_here, "data"))

Config = _skyloop.Config
# A Config pickles as its TOML text (multiprocessing, vector-env wrappers that pickle their makers).
def _config_from_toml(text: str) -> Config:
    return _skyloop.config_from_toml(text)


Config.__reduce__ = lambda self: (_config_from_toml, (self.toml(),))


# ---- input checks: every bad argument raises InputError with one line --------------------------

# The one shared validator (skyloop/_check.py): every entry point and adapter checks with it
# before it converts anything.
from ._check import MAX_SEED, as_actions as _as_actions, as_array as _as_array, as_bool as _as_bool  # noqa: E402,F401
from ._check import as_int as _as_int, as_real as _as_real, as_seed as _as_seed, as_str as _as_str  # noqa: E402,F401


def _as_names(v, name: str) -> list:
    """A list of names: one string, or a list / tuple of strings (no repeats)."""
    if isinstance(v, (str, _os.PathLike)):
        v = [v]
    if not isinstance(v, (list, tuple)):
        raise InputError(f"{name} = {v!r} has the wrong type: allowed a string or a list of strings")
    out = [_as_str(x, name) for x in v]
    seen = set()
    for x in out:
        if x in seen:
            raise InputError(f"{name} = {out!r} names {x!r} twice: allowed each at most once")
        seen.add(x)
    return out


def _one_line(name: str, err: TypeError) -> InputError:
    """pybind11's argument-conversion TypeError (a multi-line dump) as one InputError line."""
    text = str(err)
    lines = [ln.strip() for ln in text.splitlines() if ln.strip()]
    if "incompatible" not in text:
        return InputError(f"{name}: {lines[0] if lines else text}")
    allowed = next((ln[3:] for ln in lines if ln[:2].rstrip(".").isdigit()), "")
    given = next((ln for ln in lines if ln.startswith("Invoked with")), "")
    return InputError(f"{name}: wrong argument types ({given.replace('Invoked with: ', 'given ')}): allowed {allowed}")


def _guard(fn, name: str):
    import functools

    @functools.wraps(fn)
    def guarded(*args, **kwargs):
        try:
            return fn(*args, **kwargs)
        except TypeError as e:
            if "incompatible" in str(e):
                raise _one_line(name, e) from None
            raise
    return guarded


def _guard_class(cls):
    """Wraps the constructor and methods of a module class so that wrong argument types raise
    InputError (one line) rather than pybind11's TypeError listing."""
    for attr in list(vars(cls)):
        if attr.startswith("__") and attr not in ("__init__", "__getitem__"):
            continue
        member = getattr(cls, attr)
        if callable(member) and not isinstance(member, type) and not isinstance(vars(cls)[attr], (property, staticmethod)):
            setattr(cls, attr, _guard(member, f"{cls.__name__}.{attr.replace('__init__', '')}".rstrip(".")))


for _cls in (_skyloop.Config, _skyloop.Cluster, _skyloop.SystemModel, _skyloop.Beamformer, _skyloop.Network,
             _skyloop.VecEnv):
    _guard_class(_cls)
for _name in ("sum_rate", "sinr", "rates", "network_sum_rate", "user_powers", "plan", "evaluate_layouts", "beamformer",
              "derive_seed", "env_spec"):
    if hasattr(_skyloop, _name):
        setattr(_skyloop, _name, _guard(getattr(_skyloop, _name), _name))
derive_seed = _skyloop.derive_seed
_cluster_init = _skyloop.Cluster.__init__


def _checked_cluster_init(self, G, *args, **kwargs):
    import numpy as np
    if hasattr(G, "detach"):
        G = G.detach().cpu().numpy()
    if not isinstance(G, str) and np.ndim(G) != 2:
        raise InputError(f"G has {np.ndim(G)} dimensions: allowed a complex [K_n, L] array (row k = h_k^H)")
    _cluster_init(self, G, *args, **kwargs)


_skyloop.Cluster.__init__ = _checked_cluster_init


def _as_w(W):
    """A beamformer from numpy, a torch tensor (any device, detached) or a nested list: finite complex128."""
    if hasattr(W, "detach"):  # torch
        W = W.detach().cpu().resolve_conj().numpy() if hasattr(W, "resolve_conj") else W.detach().cpu().numpy()
    import numpy as np
    return _as_array(W, "W", "a finite complex [L, K_n] array", dtype=np.complex128)


def sum_rate(cluster: Cluster, W) -> float:
    """The cluster's sum rate (bit/s/Hz) under W [L, K_n] (numpy, torch or a list; complex)."""
    return _skyloop.sum_rate(cluster, _as_w(W))


def sinr(cluster: Cluster, W):
    """Per-user SINR [K_n] (linear) under W [L, K_n] (eq:sinr)."""
    return _skyloop.sinr(cluster, _as_w(W))


def rates(cluster: Cluster, W):
    """Per-user rates log2(1 + SINR) [K_n] under W [L, K_n] (eq:rate)."""
    return _skyloop.rates(cluster, _as_w(W))


def network_sum_rate(network: Network, W) -> float:
    """The network sum rate (bit/s/Hz) under one W [L, K_i] per cluster, with the network's spectrum
    model (shared: inter-cluster interference counted; see SystemModel.network)."""
    return _skyloop.network_sum_rate(network, [_as_w(w) for w in W])


def user_powers(network: Network, W):
    """Per cluster, per user: dicts of the received signal, intra- and inter-cluster interference,
    noise (W) and the SINR."""
    return _skyloop.user_powers(network, [_as_w(w) for w in W])


def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return repr(v)  # 40.0, 1e-05, inf, nan: all TOML
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"').replace("\n", "\\n").replace("\t", "\\t") + '"'
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    try:  # numpy scalars and arrays
        import numpy as np
        if isinstance(v, np.ndarray):
            return _toml_value(v.tolist())
        if isinstance(v, np.generic):
            return _toml_value(v.item())
    except ImportError:  # pragma: no cover
        pass
    raise InputError(f"value {v!r} has the wrong type: allowed a number, a bool, a string, a list of numbers or a list of [x, y] pairs")


def _flatten(d, prefix=""):
    for k, v in d.items():
        key = f"{prefix}.{k}" if prefix else str(k)
        if isinstance(v, dict):
            yield from _flatten(v, key)
        else:
            yield key, v


def config(path: str | None = None, overrides: dict | None = None, **sections) -> Config:
    """A validated configuration: the paper's defaults, then the TOML file ``path``, then
    ``overrides`` ({"channel.p_max_dbm": 40} or {"channel": {"p_max_dbm": 40}}), then keyword
    sections (``channel={"p_max_dbm": 40}``). Bad keys or values raise InputError with the CLI's line."""
    if overrides is not None and not isinstance(overrides, dict):
        raise InputError(f"overrides = {overrides!r} has the wrong type: allowed a dict such as {{'channel.p_max_dbm': 40}}")
    items = list(_flatten(overrides or {}))
    for section, values in sections.items():
        if not isinstance(values, dict):
            raise InputError(f"{section} = {values!r} has the wrong type: allowed a dict of that section's keys, "
                             f"e.g. channel={{'p_max_dbm': 40}}")
        items += list(_flatten(values, section))
    import re
    for k, _ in items:
        if not re.fullmatch(r"[A-Za-z0-9_]+(\.[A-Za-z0-9_]+)*", k):  # a key that smuggles a value in ("p=50 #")
            raise InputError(f"configuration key {k!r} is malformed: allowed section.name, e.g. 'channel.p_max_dbm'")
    return _skyloop.Config(None if path is None else _as_str(path, "path"), [f"{k}={_toml_value(v)}" for k, v in items])


def _as_config(cfg) -> Config:
    if cfg is None:
        return config()
    if isinstance(cfg, Config):
        return cfg
    if isinstance(cfg, dict):
        return config(overrides=cfg)
    if isinstance(cfg, (str, _os.PathLike)):
        return config(str(cfg))
    raise InputError(f"config {cfg!r} has the wrong type: allowed skyloop.Config, a dict of overrides or a TOML path")


def beamformer(spec: str, cfg=None) -> Beamformer:
    """A registered beamformer by its spec string: "mrt", "zf", "zfsel", "zfgain", "rzf", "wmmse", "ga",
    "ga=pso", "gnn", "gnn=PATH" (a model.pt or its directory), "deepsets", "mspointnet". A learned
    model is served as ``cfg`` says: ``nn={"selection": "ranked"}`` lets it choose whom to serve and ZF how."""
    return _skyloop.beamformer(_as_str(spec, "spec"), _as_config(cfg))


def plan(cfg=None, planner: str = "optimal", users_seed: int = 3, users=None, planner_seed: int | None = None) -> dict:
    """One episode of a planner on the trajectory scenario of ``cfg``: a name of ``PLANNERS`` ("optimal" is the
    exact optimum of P2.2) or the path of a trained policy directory (``skyloop train``).
    Users: K uniform users from ``users_seed`` (as ``skyloop plan --seed``), or an explicit [K, 2] array;
    the random planner's stream is the CLI's for that seed unless ``planner_seed`` is given.
    Returns positions [T, N, 2], actions [T-1, N], rates [T], objective, T, success, arrivals,
    collisions, boundary, reward."""
    import numpy as np
    try:
        u = None if users is None else np.asarray(users, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(f"users = {users!r} is not numeric: allowed a [K, 2] array of (x, y) in metres") from None
    if u is not None and (u.ndim != 2 or u.shape[1:] != (2,) or not np.all(np.isfinite(u))):
        raise InputError(f"users has shape {list(u.shape)}: allowed a finite [K, 2] array of (x, y) in metres")
    return _skyloop.plan(_as_config(cfg), _as_str(planner, "planner"), _as_seed(users_seed, "users_seed"), u,
                         None if planner_seed is None else _as_seed(planner_seed, "planner_seed"))


def evaluate_layouts(cfg=None, policies=(), planners=("greedy", "random"), layouts: int = 100, split: str = "test",
                     first: int = 0, unsafe: bool = False, cache: str = "", threads: int = 0, rollout: bool = False) -> dict:
    """Policies (run directories of ``skyloop train``) and planners on ``layouts`` user layouts of
    ``split`` ("test", "validation" or "train"; disjoint seed ranges, see ``skyloop eval --layouts``),
    each scored against that layout's exact optimum (cached in ``cache`` when given). ``cfg``
    defaults to the first policy's training configuration. Returns {"rows": [...], "summary": [...]}:
    one dict per (layout, planner) and per planner, with the columns of layouts.csv and summary.csv
    (complete_rate, collisions, boundary_events, fraction_mean, fraction_p5, fraction_worst, ...).
    ``unsafe``: also each policy without mask and shield ("<algo>/raw"); ``rollout``: also each policy as
    the base of a multiagent rollout ("<algo>+rollout", as ``skyloop eval --rollout``)."""
    policies = _as_names(policies, "policies")
    planners = _as_names(planners, "planners")
    unsafe, rollout = _as_bool(unsafe, "unsafe"), _as_bool(rollout, "rollout")
    if cfg is None and policies:  # the configuration stored inside the policy, as `skyloop eval` reads it
        cfg = _skyloop.policy_config(policies[0])
    return _skyloop.evaluate_layouts(_as_config(cfg), policies, planners, _as_int(layouts, "layouts", 1, 1_000_000),
                                     _as_str(split, "split"), _as_int(first, "first", 0, 2**62 - 1), unsafe,
                                     rollout, _as_str(cache, "cache"), _as_int(threads, "threads", 0, 1024))


from .env import VecEnv  # noqa: E402  (needs the names above)
