"""Argument checks for the public API: each raises a ValueError of one line that names the argument,
the value and what is allowed (never a TypeError or AttributeError from deep inside, never a silent
NaN). The functions return the value converted (a float, an int, a list), so a caller writes
``t = real("t_end", t_end, lo=0.0, lo_open=True)`` once at its entry."""

from __future__ import annotations

import math
import re
from typing import Any, Sequence

import numpy as np

__all__ = ["as_float", "shown", "shown_path", "real", "integer", "integers", "choice", "instance", "strings", "reals",
           "band", "seed_or_none"]


def shown(value: Any) -> str:
    """A value as an error message shows it: its repr on one line (an array's repr breaks its rows over lines),
    cut to 60 characters."""
    text = re.sub(r"\s*\n\s*", " ", repr(value))
    return text if len(text) <= 60 else text[:57] + "..."


def shown_path(path: Any) -> str:
    """A path as an error message shows it: as it is, or its repr where it holds a line break or another
    character that does not print, so that the message stays one line."""
    text = str(path)
    return text if text.isprintable() else repr(text)


def _fail(name: str, value: Any, allowed: str):
    raise ValueError(f"{name} = {shown(value)} is invalid: {allowed}")


def as_float(value: Any) -> float:
    """float(value), with an integer beyond a float's range as +-inf (not an OverflowError), so the caller's
    finiteness check refuses it in its one line."""
    try:
        return float(value)
    except OverflowError:
        return math.inf if value > 0 else -math.inf


def _is_real(value: Any) -> bool:
    return isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, (bool, np.bool_))


def real(name: str, value: Any, *, lo: float = -math.inf, hi: float = math.inf, lo_open: bool = False,
         hi_open: bool = False) -> float:
    """A finite real number in [lo, hi] (or with open ends)."""
    bounds = []
    if lo > -math.inf:
        bounds.append(f"{'>' if lo_open else '>='} {lo:g}")
    if hi < math.inf:
        bounds.append(f"{'<' if hi_open else '<='} {hi:g}")
    allowed = "a finite number" + (" " + " and ".join(bounds) if bounds else "")
    if not _is_real(value) or not math.isfinite(as_float(value)):
        _fail(name, value, allowed)
    v = as_float(value)
    if v < lo or v > hi or (lo_open and v == lo) or (hi_open and v == hi):
        _fail(name, value, allowed)
    return v


def integer(name: str, value: Any, *, lo: int | None = None, hi: int | None = None) -> int:
    """A whole number (an int, not a bool or a float) in [lo, hi]."""
    allowed = "a whole number" + (f" >= {lo}" if lo is not None and hi is None else "") + \
        (f" in [{lo}, {hi}]" if lo is not None and hi is not None else "") + \
        (f" <= {hi}" if hi is not None and lo is None else "")
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
        _fail(name, value, allowed)
    if (lo is not None and value < lo) or (hi is not None and value > hi):
        _fail(name, value, allowed)
    return int(value)


def integers(name: str, value: Any, *, lo: int | None = 0, min_len: int = 1) -> list[int]:
    """A list of at least `min_len` whole numbers (>= lo): seeds, plant indices."""
    if isinstance(value, (str, bytes, dict)) or not hasattr(value, "__len__") or len(value) < min_len:
        _fail(name, value, f"a list of at least {min_len} whole numbers" + (f" >= {lo}" if lo is not None else ""))
    return [integer(f"{name}[{k}]", v, lo=lo) for k, v in enumerate(value)]


def seed_or_none(name: str, value: Any) -> int | None:
    """None or a seed: a whole number >= 0."""
    return None if value is None else integer(name, value, lo=0)


def choice(name: str, value: Any, choices: Sequence[Any]) -> Any:
    """One of `choices` (compared as given: a list or dict is never one of them)."""
    if not isinstance(value, (str, int, float, type(None))) or isinstance(value, bool) or value not in choices:
        _fail(name, value, f"one of {list(choices)}")
    return value


def callable_or_none(name: str, value: Any, what: str) -> Any:
    """None or a callable (described to the user as `what`): a user's function handed to an environment."""
    if value is not None and not callable(value):
        _fail(name, value, f"None or {what}")
    return value


def instance(name: str, value: Any, kind: type | tuple[type, ...], what: str) -> Any:
    """An instance of `kind` (described to the user as `what`)."""
    if not isinstance(value, kind):
        _fail(name, value, what)
    return value


def strings(name: str, value: Any, what: str = "names", *, allow_empty: bool = False) -> list[str]:
    """A list (or tuple) of non-empty strings; a bare string is refused (it is not a list of names)."""
    if isinstance(value, str) or not isinstance(value, (list, tuple)) or (not value and not allow_empty) or \
            not all(isinstance(v, str) and v for v in value):
        _fail(name, value, f"a list of {what} (strings)")
    return list(value)


def reals(name: str, value: Any, *, lo: float = -math.inf, lo_open: bool = False, min_len: int = 1) -> list[float]:
    """A list of at least `min_len` finite numbers (>= or > lo)."""
    if isinstance(value, (str, bytes, dict)) or not hasattr(value, "__len__") or len(value) < min_len:
        _fail(name, value, f"a list of at least {min_len} finite numbers")
    return [real(f"{name}[{k}]", v, lo=lo, lo_open=lo_open) for k, v in enumerate(value)]


def band(name: str, value: Any) -> tuple[float, float] | None:
    """None or a frequency band (low, high) in Hz with 0 <= low < high."""
    if value is None:
        return None
    if isinstance(value, (str, bytes, dict)) or not hasattr(value, "__len__") or len(value) != 2:
        _fail(name, value, "None or a (low, high) pair in Hz with 0 <= low < high")
    lo, hi = (real(f"{name}[{k}]", v, lo=0.0) for k, v in enumerate(value))
    if not lo < hi:
        _fail(name, value, "None or a (low, high) pair in Hz with 0 <= low < high")
    return lo, hi
