"""A user's own envelope (a constraint monitor), given to an environment as ``envelope_fn=``.

The config's envelope (``envelope``: the stroke |x| < x_max_m, the load pressure within [p_min_pa, p_max_factor x
the supply]) always holds. A user's envelope adds constraints of its own: a callable ``envelope(terms) -> left``
that takes the period's terms (`EnvelopeTerms`) and returns, per environment, whether the episode left it. An
episode that leaves it ends as one that leaves the config's envelope: terminated, scored as diverged.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from millvib_env._checks import callable_or_none, shown

__all__ = ["EnvelopeTerms", "EnvelopeFunction", "user_envelope", "left_flags"]


@dataclass(frozen=True)
class EnvelopeTerms:
    """One agent period, one value per environment (arrays of shape (n,))."""

    x_abs_max_m: np.ndarray   # the largest |x| over the period's samples (m)
    pl_min_pa: np.ndarray     # the smallest load pressure over them (Pa)
    pl_max_pa: np.ndarray     # the largest (Pa)
    x_m: np.ndarray           # the position at the period's end (m)
    v_m_s: np.ndarray         # the velocity there (m/s)
    pl_pa: np.ndarray         # the load pressure there (Pa)
    t_s: np.ndarray           # the time there (s)
    left_config: np.ndarray   # the config's envelope already ended the episode in this period


class EnvelopeFunction(Protocol):
    """A user's envelope (``envelope_fn=`` of every environment): the period's terms -> left, per environment."""

    def __call__(self, terms: EnvelopeTerms) -> Any: ...


def user_envelope(fn: Any) -> EnvelopeFunction | None:
    """An environment's ``envelope_fn``, checked: None or a callable."""
    return callable_or_none("envelope_fn", fn, "a callable envelope(terms) -> whether each environment left it "
                                               "(envs.envelope.EnvelopeFunction)")


def left_flags(fn: EnvelopeFunction, terms: EnvelopeTerms, n: int) -> np.ndarray:
    """What `fn` says of `terms`: n booleans (True or False, or 0 and 1), else one line that says so."""
    out = fn(terms)
    flags = np.asarray(out)
    if flags.shape not in ((), (n,)) or flags.dtype.kind not in "bui" or (flags.dtype.kind != "b" and
                                                                          not np.isin(flags, (0, 1)).all()):
        raise ValueError(f"envelope_fn {shown(fn)} returned {shown(out)}: one True or False per environment ({n}) "
                         "is needed")
    return np.broadcast_to(flags.astype(bool), (n,)).copy()
