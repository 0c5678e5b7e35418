"""A batch of episodes on given seeds, stepped together with auto-reset, without Stable-Baselines3.

What the evaluation loop, the tuning and the benchmark need from a vector env, on the same engine
(`MillVibCore`) and with the same semantics as the SB3 `MillVibVecEnv` (an auto-reset continues each
environment's own generator), so a run of baselines never imports torch.
"""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from millvib_env._checks import shown
from millvib_env.envs.build import build_core
from millvib_env.envs.config import ENV_VERSIONS, EnvConfig
from millvib_env.envs.specs import ENV_SPECS

__all__ = ["EpisodeBatch", "ENV_IDS", "ID_CONFIGS", "env_mode", "env_version", "env_id_for", "id_config"]

#: registered id -> (the engine's mode, the environment's version): a view of `envs.specs.ENV_SPECS`
ENV_IDS = {env_id: (spec.mode, spec.version) for env_id, spec in ENV_SPECS.items()}
#: per-config id (e.g. MillVib-Valve-Rolling-v1) -> its config: the same environment with that config
ID_CONFIGS = {env_id: spec.config for env_id, spec in ENV_SPECS.items() if spec.config is not None}


def _entry(env_id: str) -> tuple[str, str]:
    if not isinstance(env_id, str) or env_id not in ENV_IDS:
        raise ValueError(f"env_id = {shown(env_id)} is not a MillVib environment; known: {sorted(ENV_IDS)}")
    return ENV_IDS[env_id]


def id_config(env_id: str, config: str | dict | EnvConfig | None) -> str | dict | EnvConfig:
    """The config an environment of `env_id` runs: `config`, or the id's own (a per-config id; "startup" for the
    two generic ids). A per-config id given another config, or an EnvConfig, is refused."""
    spec = ENV_SPECS.get(env_id)
    own = None if spec is None else spec.config
    if config is None:
        return own or "startup"
    if spec is not None and own is not None and isinstance(config, EnvConfig):
        raise ValueError(f"config is an EnvConfig, but env_id {shown(env_id)} runs its own config {shown(own)}: use "
                         f"{shown(spec.generic_id)} with config=<the EnvConfig>")
    if spec is not None and own is not None and config != own:
        raise ValueError(f"config = {shown(config)} contradicts env_id {shown(env_id)}, whose config is "
                         f"{shown(own)}: use {shown(spec.generic_id)} with config={shown(config)}")
    return config


def env_mode(env_id: str) -> str:
    """'gain' or 'valve': the engine's mode of a registered id."""
    return _entry(env_id)[0]


def env_version(env_id: str) -> str:
    """The version of a registered id ('v0' or 'v1')."""
    return _entry(env_id)[1]


def env_id_for(mode: str, version: str) -> str:
    """The registered id of an engine mode ('gain' or 'valve') in a version."""
    for env_id, entry in ENV_IDS.items():
        if entry == (mode, version):
            return env_id
    raise ValueError(f"no MillVib environment of mode {shown(mode)} and version {shown(version)}; versions: "
                     f"{list(ENV_VERSIONS)}")


class EpisodeBatch:
    """N environments of `env_id`; `reset(seeds)` starts environment i on seeds[i], `step` advances
    them all and restarts the finished ones (their next episode's first observation is returned)."""

    def __init__(self, env_id: str, n: int, *, config: str | dict | EnvConfig | None = None, residual: bool = False,
                 observe_params: bool | None = None, observe_phase: bool | None = None,
                 extra_disturbances: Sequence | None = None, reward_fn: Any = None,
                 envelope_fn: Any = None, **overrides: Any):
        self.core = build_core(n, env_mode(env_id), env_version(env_id), id_config(env_id, config), residual=residual,
                               observe_params=observe_params, observe_phase=observe_phase,
                               extra_disturbances=extra_disturbances, reward_fn=reward_fn, envelope_fn=envelope_fn,
                               overrides=overrides)
        self.config = self.core.settings.cfg
        self.n = n
        self.reset_infos: list[dict] = [{} for _ in range(n)]

    def reset(self, seeds: Sequence[int], options: dict | Sequence[dict | None] | None = None) -> np.ndarray:
        """Start environment i on seeds[i] with `options` (Gymnasium's reset options: one dict for every
        environment, or one dict or None per environment)."""
        if options is None or isinstance(options, dict):
            per_env: Sequence[dict | None] = [options] * self.n
        elif isinstance(options, (list, tuple)) and len(options) == self.n:
            per_env = options
        else:
            raise ValueError(f"options = {shown(options)} is invalid: a dict of reset options, or a list of "
                             f"{self.n} (one dict or None per environment)")
        obs = np.zeros((self.n, *self.core.observation_space.shape), dtype=np.float32)
        for i in range(self.n):
            obs[i], self.reset_infos[i] = self.core.reset_env(i, int(seeds[i]), per_env[i])
        return obs

    def step(self, actions, *, restart: bool = True) -> tuple[np.ndarray, np.ndarray, list[dict]]:
        """(observations, done flags, infos); a done environment's info is its episode's last. With `restart`
        False a done environment is not started again: its observation is its episode's last, and it must be
        `reset` before it steps again (for a caller whose last episodes end at this step)."""
        obs, _, terminated, truncated, infos = self.core.step(actions)
        dones = terminated | truncated
        if restart:
            for i in np.flatnonzero(dones):
                obs[i], self.reset_infos[i] = self.core.reset_env(int(i))
        else:
            self.core.started[dones] = False
        return obs, dones, infos
