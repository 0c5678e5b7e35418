"""The registered env ids' entry points: the environments of `envs`, with named gain sets in their keyword
arguments resolved to numbers first (`catalog.named`), so ``gym.make(id, actions={"residual_gains": "pid-pf-ff"})``
and the zoo's files work while the env layer takes numbers only. Each entry point carries its environment's
docstring (the manual) and the class itself as ``__wrapped__``."""

from __future__ import annotations

from typing import Any, Callable

from millvib_env._checks import shown
from millvib_env.catalog.named import resolve_named_gains
from millvib_env.envs import environments, vector

__all__ = ["GainScheduleEnv", "ValveEnv", "GainScheduleVectorEnv", "ValveVectorEnv"]


def _resolved(kwargs: dict[str, Any]) -> dict[str, Any]:

    return resolve_named_gains(kwargs)


def _within(env: Any, max_episode_steps: Any) -> Any:
    """`env`, where its episode ends within `max_episode_steps` (a per-task id's registered length, or the one a
    caller passed): an episode longer than that would be cut by Gymnasium's TimeLimit (or, in a vector env, not
    at all), so it is refused in one line."""
    if max_episode_steps is None:
        return env
    if isinstance(max_episode_steps, bool) or not isinstance(max_episode_steps, int) or max_episode_steps < 1:
        raise ValueError(f"max_episode_steps = {shown(max_episode_steps)} is invalid: a positive integer")
    steps = env.unwrapped.core.settings.max_steps if hasattr(env, "unwrapped") else env.core.settings.max_steps
    if steps > max_episode_steps:
        config = env.unwrapped.config if hasattr(env, "unwrapped") else env.config
        raise ValueError(f"episode_s = {config.episode_s} s gives {steps} steps, past max_episode_steps = "
                         f"{max_episode_steps} (Gymnasium's TimeLimit would cut the episode there): a shorter "
                         "episode_s or a larger max_episode_steps (a per-task id registers its task's episode length; "
                         "the generic ids, MillVib-Valve-v1 and MillVib-GainSchedule-v1, none)")
    return env


def _entry(cls: type, vector_env: bool = False) -> Callable:
    make: Callable[..., Any]
    if vector_env:
        def make_vector(num_envs: int = 1, max_episode_steps: int | None = None, **kwargs: Any):
            return _within(cls(num_envs, **_resolved(kwargs)), max_episode_steps)
        make = make_vector
    else:
        def make_single(max_episode_steps: int | None = None, **kwargs: Any):
            return _within(cls(**_resolved(kwargs)), max_episode_steps)
        make = make_single
    make.__name__ = make.__qualname__ = cls.__name__
    make.__doc__ = cls.__doc__
    make.__wrapped__ = cls  # type: ignore[union-attr]
    return make


GainScheduleEnv = _entry(environments.GainScheduleEnv)
ValveEnv = _entry(environments.ValveEnv)
GainScheduleVectorEnv = _entry(vector.GainScheduleVectorEnv, vector_env=True)
ValveVectorEnv = _entry(vector.ValveVectorEnv, vector_env=True)
