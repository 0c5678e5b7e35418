"""The one builder of the environments' engine. The four constructors (the Gymnasium environments, the native
VecEnv, Gymnasium's VectorEnv and the evaluation's `EpisodeBatch`) take the same keywords and build their
`MillVibCore` here, from an `EnvConfig` built once at the edge (a task's, `Task.configs`) or from a config's name,
path or dict (`load_env_config`)."""

from __future__ import annotations

from typing import Any, Mapping, Sequence

from millvib_env.envs.actions import base_controller_overrides
from millvib_env.envs.config import EnvConfig, load_env_config
from millvib_env.envs.core import MillVibCore

__all__ = ["build_core"]


def build_core(n: int, mode: str, version: str, config: str | Mapping | EnvConfig | None, *, residual: bool = False,
               observe_params: bool | None = None, observe_phase: bool | None = None,
               extra_disturbances: Sequence | None = None, reward_fn: Any = None, envelope_fn: Any = None,
               base_controller: Any = None, overrides: Mapping | None = None) -> MillVibCore:
    """`n` environments of engine `mode` ("gain" or "valve") in environment version `version`: `config` (an
    EnvConfig is taken as it is; a name, path or dict is loaded) with keyword `overrides` and, where given, the
    fixed `base_controller` under the action (`envs.actions.base_controller_overrides`) merged in."""
    merged = base_controller_overrides(mode, residual, base_controller, overrides or {})
    cfg = load_env_config(config, version=version, **merged)
    return MillVibCore(n, mode, cfg, residual=residual, observe_params=observe_params, observe_phase=observe_phase,
                       extra_disturbances=extra_disturbances, reward_fn=reward_fn, envelope_fn=envelope_fn)
