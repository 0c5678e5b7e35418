"""The registered env ids' entry points: the environments of `envs`, with named gain sets in their keyword
arguments resolved to numbers first (`control.named`), so ``gym.make(id, actions={"residual_gains": "pid-pf-ff"})``
and the zoo's files work while the env layer takes numbers only. Each entry point carries its environment's
docstring (the manual) and the class itself as ``__wrapped__``."""

from __future__ import annotations

from typing import Any, Callable

from millvib_env.control.named import resolve_named_gains
from millvib_env.envs import environments, vector

__all__ = ["GainScheduleEnv", "ValveEnv", "GainScheduleVectorEnv", "ValveVectorEnv"]


def _resolved(kwargs: dict[str, Any]) -> dict[str, Any]:

    return resolve_named_gains(kwargs)


def _entry(cls: type, vector_env: bool = False) -> Callable:
    make: Callable[..., Any]
    if vector_env:
        def make_vector(num_envs: int = 1, **kwargs: Any):
            return cls(num_envs, **_resolved(kwargs))
        make = make_vector
    else:
        def make_single(**kwargs: Any):
            return cls(**_resolved(kwargs))
        make = make_single
    make.__name__ = make.__qualname__ = cls.__name__
    make.__doc__ = cls.__doc__
    make.__wrapped__ = cls  # type: ignore[union-attr]
    return make


GainScheduleEnv = _entry(environments.GainScheduleEnv)
ValveEnv = _entry(environments.ValveEnv)
GainScheduleVectorEnv = _entry(vector.GainScheduleVectorEnv, vector_env=True)
ValveVectorEnv = _entry(vector.ValveVectorEnv, vector_env=True)
