"""The one validator every Python entry point and adapter calls before it converts anything.

Each check takes the user's value and the name the user knows it by, and either returns the value
in the type the module wants or raises ``InputError`` with one line naming the argument, the value
and what is allowed. Nothing is truncated (2.7 is not an integer, an action of 4.9 is not action 4)
and nothing non-finite passes as a number.
"""
from __future__ import annotations

import math
import numbers
import os

import numpy as np

#: The largest seed (run.seed's bound, which the command line's --seed also takes): one range for every seed.
from ._skyloop import MAX_SEED, InputError


def as_int(v, name: str, lo: int | None = None, hi: int | None = None) -> int:
    """An integer: ints, numpy integers and integral floats (2.0); never a bool, 2.7, NaN or "3"."""
    rng = f" in [{lo}, {hi}]" if lo is not None and hi is not None else ""
    if isinstance(v, (bool, np.bool_)) or not isinstance(v, numbers.Real):
        raise InputError(f"{name} = {v!r} has the wrong type: allowed an integer{rng}")
    if not isinstance(v, numbers.Integral):
        f = float(v)
        if not math.isfinite(f) or not f.is_integer():
            raise InputError(f"{name} = {v!r} has the wrong type: allowed an integer{rng}")
        v = int(f)
    v = int(v)
    if (lo is not None and v < lo) or (hi is not None and v > hi):
        raise InputError(f"{name} = {v} is out of range: allowed an integer{rng}")
    return v


def as_seed(v, name: str = "seed") -> int:
    """A seed: an integer in [0, MAX_SEED], the command line's range."""
    return as_int(v, name, 0, MAX_SEED)


def as_real(v, name: str, lo: float = -math.inf, hi: float = math.inf) -> float:
    """A finite real number in [lo, hi]; never a bool, a string, NaN or an infinity."""
    if isinstance(v, (bool, np.bool_)) or not isinstance(v, numbers.Real):
        raise InputError(f"{name} = {v!r} has the wrong type: allowed a finite number")
    f = float(v)
    if not math.isfinite(f) or f < lo or f > hi:
        bounds = "" if (lo == -math.inf and hi == math.inf) else f" in [{lo:g}, {hi:g}]"
        raise InputError(f"{name} = {v!r} is out of range: allowed a finite number{bounds}")
    return f


def as_bool(v, name: str) -> bool:
    if not isinstance(v, (bool, np.bool_)):
        raise InputError(f"{name} = {v!r} has the wrong type: allowed True or False")
    return bool(v)


def as_str(v, name: str) -> str:
    if isinstance(v, os.PathLike):
        v = os.fspath(v)
    if not isinstance(v, str):
        raise InputError(f"{name} = {v!r} has the wrong type: allowed a string")
    return v


def _numpy(v, name: str, allowed: str) -> np.ndarray:
    """``v`` as a numpy array (a torch tensor detached and moved to the CPU first), or InputError."""
    if hasattr(v, "detach"):
        v = v.detach().cpu().numpy()
    try:
        return np.asarray(v)
    except (TypeError, ValueError):
        raise InputError(f"{name} = {v!r} is not an array: allowed {allowed}") from None


def as_array(v, name: str, allowed: str, dtype=np.float64) -> np.ndarray:
    """A finite numeric array, as ``dtype`` (None: as given)."""
    a = _numpy(v, name, allowed)
    if a.dtype.kind not in "biufc":
        raise InputError(f"{name} has dtype {a.dtype}: allowed {allowed}")
    if a.dtype.kind in "fc" and not np.all(np.isfinite(a)):
        bad = tuple(int(i) for i in np.argwhere(~np.isfinite(a))[0])
        raise InputError(f"{name}{list(bad)} = {a[bad]!r} is invalid (not finite): allowed {allowed}")
    return a if dtype is None else a.astype(dtype, copy=False)


def as_actions(v, name: str, shape: tuple, num_actions: int | None) -> np.ndarray:
    """Discrete actions of ``shape``: an integer array (or int scalars) with values in
    0..num_actions-1, as int64. Floats are refused, even integral ones (as VecEnv's own step
    refuses them), and the message names the first entry that is not an integer (4.9, NaN).
    ``num_actions`` None: integers, the range left to the caller (take_turn ignores the entries of
    environments whose turns are over)."""
    allowed = (f"integers in 0..{num_actions - 1}" if num_actions is not None else "integers") + f" of shape {list(shape)}"
    a = _numpy(v, name, allowed)
    if a.dtype == bool or a.dtype.kind not in "iuf":
        raise InputError(f"{name} = {v!r} has dtype {a.dtype}: allowed {allowed}")
    a = _shaped(a, name, shape, allowed)
    if a.dtype.kind == "f":
        bad = ~np.isfinite(a) | (a != np.round(a))
        if bad.any():
            i = tuple(int(x) for x in np.argwhere(bad)[0])
            raise InputError(f"{name}{list(i)} = {a[i]!r} is not an integer: allowed {allowed}")
        raise InputError(f"{name} has dtype {a.dtype}: allowed {allowed} (an integer dtype)")
    out = a.astype(np.int64)
    if num_actions is None:
        return out
    wrong = (out < 0) | (out >= num_actions)
    if wrong.any():
        i = tuple(int(x) for x in np.argwhere(wrong)[0])
        raise InputError(f"{name}{list(i)} = {out[i]} is invalid: allowed {allowed}")
    return out


def as_commands(v, name: str, shape: tuple) -> np.ndarray:
    """Continuous commands of ``shape`` (last axis the command's size): finite reals, as float64
    (the environment clamps them to [-1, 1])."""
    allowed = f"finite commands in [-1, 1] of shape {list(shape)}"
    a = as_array(v, name, allowed, dtype=None)
    if a.dtype.kind == "c":
        raise InputError(f"{name} has dtype {a.dtype}: allowed {allowed}")
    return _shaped(a, name, shape, allowed).astype(np.float64)


def _shaped(a: np.ndarray, name: str, shape: tuple, allowed: str) -> np.ndarray:
    """``a`` as ``shape``: the same shape, a scalar where one value is wanted, or the shape with a
    trailing axis of 1 (the MAPPO runner's [M, N, 1]); anything else is refused."""
    shape = tuple(shape)
    if a.shape == shape:
        return a
    if (a.ndim == 0 and int(np.prod(shape)) == 1) or a.shape == shape + (1,):
        return a.reshape(shape)
    raise InputError(f"{name} has shape {list(a.shape)}: allowed {allowed}")
