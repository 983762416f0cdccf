"""What a cached stage value must satisfy before a bake uses it.

An entry that passes its checksum and the codec holds only sssbake's own types, not necessarily a
value its stage could have made: whoever may write a shared cache folder can rewrite an entry with a
valid checksum around an index past an array, a NaN or an array cut short, and every rerun of a good
input would then fail, blamed on the input. So each stage declares its invariants next to it
(`invariants_of`, in `stages`): shapes consistent with each other and with the stage's inputs, index
ranges, finiteness, dtypes. The stage runner checks a cached value with `check_cached` before it
trusts it; a value that breaks them is a damaged entry (`cache.StageCache.lookup`): deleted,
recomputed and reported.

The helpers below raise `BrokenInvariant` naming the field and what is wrong with it.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable

import numpy as np


class BrokenInvariant(ValueError):
    """A cached value its stage could not have made."""


# stage function -> its check, ``check(value, *inputs, params)`` (``check(value, *inputs)`` for a stage without params)
_CHECKS: dict[Callable, Callable] = {}


def invariants_of(stage: Callable) -> Callable[[Callable], Callable]:
    """Register the decorated function as the check of `stage`'s cached values.

    The check is called as the stage is, with the cached value first: ``check(value, *inputs,
    params)`` (``check(value, *inputs)`` when the stage takes no params), and raises (any exception;
    `BrokenInvariant` by the helpers here) when the value breaks the stage's invariants.
    """

    def register(check: Callable) -> Callable:
        _CHECKS[stage] = check
        return check

    return register


def check_cached(stage: Callable, value, inputs: tuple, params) -> None:
    """Raise unless `value`, read from the cache for ``stage(*inputs, params)``, keeps the stage's
    invariants; a stage that declares none accepts any value."""
    check = _CHECKS.get(stage)
    if check is not None:
        check(value, *inputs) if params is None else check(value, *inputs, params)


def need(condition, message: str) -> None:
    """Raise BrokenInvariant(`message`) unless `condition`."""
    if not condition:
        raise BrokenInvariant(message)


def of_type(value, kind: type | tuple[type, ...], where: str):
    """`value`, when it is an instance of `kind` (a bool is no int here)."""
    kinds = kind if isinstance(kind, tuple) else (kind,)
    need(isinstance(value, kinds) and not (isinstance(value, bool) and bool not in kinds),
         f"{where} is a {type(value).__name__}, not {' or '.join(k.__name__ for k in kinds)}")
    return value


# dtype kinds by the names the checks use
_KINDS = {"float": "f", "int": "iu", "bool": "b"}


def array(value, where: str, kind: str, shape: tuple, finite: bool = True) -> np.ndarray:
    """`value`, when it is an ndarray of `kind` (``"float"``, ``"int"``: signed or unsigned,
    ``"bool"``) and `shape` (an int per axis, None for any length), all finite when it is a float
    array and `finite`."""
    need(type(value) is np.ndarray, f"{where} is a {type(value).__name__}, not an array")
    need(value.dtype.kind in _KINDS[kind], f"{where} has dtype {value.dtype}, not {kind}")
    need(value.ndim == len(shape) and all(s is None or s == n for s, n in zip(shape, value.shape)),
         f"{where} has shape {value.shape}, not ({', '.join('*' if s is None else str(s) for s in shape)})")
    if kind == "float" and finite:
        need(np.isfinite(value).all(), f"{where} holds NaN or infinity")
    return value


def indices(value, where: str, count: int, shape: tuple) -> np.ndarray:
    """`value`, when it is an integer array of `shape` whose entries all lie in ``[0, count)``."""
    a = array(value, where, "int", shape)
    if a.size:
        low, high = int(a.min()), int(a.max())
        need(low >= 0 and high < count, f"{where} holds index {low if low < 0 else high} outside [0, {count})")
    return a


def number(value, where: str, low: float = -math.inf, high: float = math.inf) -> float:
    """`value`, when it is a finite int or float (numpy's too) within ``[low, high]``."""
    need(isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, (bool, np.bool_)),
         f"{where} is a {type(value).__name__}, not a number")
    need(math.isfinite(value) and low <= value <= high, f"{where} is {value}, not a finite number in [{low}, {high}]")
    return value


def count(value, where: str, high: float = math.inf) -> int:
    """`value`, when it is an int (numpy's too) in ``[0, high]``."""
    need(isinstance(value, (int, np.integer)) and not isinstance(value, (bool, np.bool_)),
         f"{where} is a {type(value).__name__}, not an integer")
    need(0 <= value <= high, f"{where} is {value}, not in [0, {high}]")
    return int(value)


def triple(value, where: str, low: float = -math.inf, high: float = math.inf) -> tuple:
    """`value`, when it is a tuple of three finite numbers within ``[low, high]``."""
    need(isinstance(value, tuple) and len(value) == 3, f"{where} is not a tuple of three numbers")
    for i, x in enumerate(value):
        number(x, f"{where}[{i}]", low, high)
    return value


def all_finite(value, where: str) -> None:
    """Every float in `value` finite: its float arrays, floats and numpy floats, through tuples,
    lists, dict values and dataclass fields."""
    if isinstance(value, np.ndarray):
        need(value.dtype.kind not in "fc" or np.isfinite(value).all(), f"{where} holds NaN or infinity")
    elif isinstance(value, (float, np.floating)):
        need(math.isfinite(value), f"{where} is {value}")
    elif isinstance(value, (tuple, list)):
        for i, x in enumerate(value):
            all_finite(x, f"{where}[{i}]")
    elif isinstance(value, dict):
        for k, x in value.items():
            all_finite(x, f"{where}[{k!r}]")
    elif dataclasses.is_dataclass(value) and not isinstance(value, type):
        for f in dataclasses.fields(value):
            all_finite(getattr(value, f.name), f"{where}.{f.name}")
