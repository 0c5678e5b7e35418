"""Native batched VecEnv: all N plants advance in one compiled call (Stable-Baselines3 semantics)."""

from __future__ import annotations

from typing import Any, Sequence

import gymnasium as gym
import numpy as np
from stable_baselines3.common.vec_env import VecEnv, VecMonitor
from stable_baselines3.common.vec_env.base_vec_env import VecEnvIndices

from millvib_env._checks import seed_or_none, shown
from millvib_env.envs.build import build_core
from millvib_env.envs.config import EnvConfig

__all__ = ["MillVibVecEnv", "make_vec_env", "ENV_IDS"]

from millvib_env.envs.batch import ENV_IDS, env_mode, env_version, id_config  # noqa: E402 (one table of ids)


class MillVibVecEnv(VecEnv):
    """N MillVib environments stepped together, with SB3's auto-reset semantics.

    Identical, step for step, to ``DummyVecEnv`` over N single environments with the same seeds
    (``seed(s)`` seeds env i with s + i; an auto-reset continues each env's own generator):
    done environments report ``terminal_observation`` and ``TimeLimit.truncated`` in their info and
    return the first observation of their next episode.
    """

    def __init__(self, env_id: str, n_envs: int, *, seed: int | None = None, render_mode: str | None = None,
                 config: str | dict | EnvConfig | None = None, residual: bool = False,
                 observe_params: bool | None = None, observe_phase: bool | None = None,
                 extra_disturbances: Sequence | None = None, reward_fn: Any = None,
                 envelope_fn: Any = None, base_controller: Any = None, **overrides: Any):
        mode = env_mode(env_id)
        if render_mode not in (None, "rgb_array", "human"):
            raise ValueError(f"render_mode = {shown(render_mode)} is invalid")
        self.env_id = env_id
        self.render_mode = render_mode
        self.core = build_core(n_envs, mode, env_version(env_id), id_config(env_id, config), residual=residual,
                               observe_params=observe_params, observe_phase=observe_phase,
                               extra_disturbances=extra_disturbances, reward_fn=reward_fn, envelope_fn=envelope_fn,
                               base_controller=base_controller, overrides=overrides)
        self.config = self.core.settings.cfg
        self.core.keep_history = render_mode is not None  # the render's recent samples: kept only where drawn
        super().__init__(n_envs, self.core.observation_space, self.core.action_space)
        self._actions: np.ndarray | None = None
        self._figure = None
        if seed is not None:
            self.seed(seed)

    # --- VecEnv API -----------------------------------------------------------------------------
    def seed(self, seed: int | None = None) -> Sequence[int | None]:
        """Seed environment i with `seed` + i at the next reset (SB3's VecEnv.seed), the public way
        to give a VecEnv's environments their plants."""
        return super().seed(seed_or_none("seed", seed))

    def reset(self) -> np.ndarray:
        obs = np.zeros((self.num_envs, *self.core.observation_space.shape), dtype=np.float32)
        for i in range(self.num_envs):
            obs[i], self.reset_infos[i] = self.core.reset_env(i, self._seeds[i], self._options[i] or None)
        self._reset_seeds()
        self._reset_options()
        return obs

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = actions

    def step_wait(self):
        obs, reward, terminated, truncated, infos = self.core.step(self._actions)
        dones = terminated | truncated
        for info, cut in zip(infos, (truncated & ~terminated).tolist()):
            info["TimeLimit.truncated"] = cut
        for i in np.flatnonzero(dones):
            infos[i]["terminal_observation"] = obs[i].copy()
            obs[i], self.reset_infos[i] = self.core.reset_env(i)
        return obs, reward.astype(np.float32), dones, infos

    def close(self) -> None:
        if self._figure is not None:
            import matplotlib.pyplot as plt

            plt.close(self._figure)
            self._figure = None

    def get_images(self) -> Sequence[np.ndarray | None]:
        from millvib_env.envs.rendering import render_frame

        frame, self._figure = render_frame(self.core, self._figure)
        return [frame]

    def _per_env(self, name: str) -> list | None:
        per_env: dict[str, list] = {"params": self.core.params, "scenario": self.core.scenario,
                                    "np_random": self.core.np_random}
        return per_env.get(name)

    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        idx = list(self._get_indices(indices))
        values = self._per_env(attr_name)
        if values is not None:
            return [values[i] for i in idx]
        for owner in (self, self.core, self.core.settings):  # the engine's state, then its fixed settings
            if hasattr(owner, attr_name):
                return [getattr(owner, attr_name)] * len(idx)
        raise AttributeError(f"MillVib environments have no attribute {shown(attr_name)}")

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        if attr_name == "render_mode":
            self.render_mode = value
            self.core.keep_history = self.core.keep_history or value is not None
            return
        raise AttributeError(f"setting {shown(attr_name)} on a batched MillVib env is not supported; make a new one")

    def env_method(self, method_name: str, *method_args, indices: VecEnvIndices = None, **method_kwargs) -> list[Any]:
        idx = list(self._get_indices(indices))
        if method_name == "reset":
            return [self.core.reset_env(i, *method_args, **method_kwargs) for i in idx]
        raise AttributeError(f"MillVib environments have no method {shown(method_name)} callable through the VecEnv")

    def env_is_wrapped(self, wrapper_class: type[gym.Wrapper], indices: VecEnvIndices = None) -> list[bool]:
        return [False] * len(list(self._get_indices(indices)))


def make_vec_env(env_id: str, n_envs: int = 1, seed: int | None = None, *, monitor: bool = True,
                 **env_kwargs: Any) -> VecEnv:
    """The native batched VecEnv for a MillVib id (optionally wrapped in SB3's VecMonitor).

    ``env_kwargs`` are the environment's keyword arguments (``config``, ``residual``,
    ``observe_params``, any config key). With ``monitor=True`` (default) episode returns and lengths
    are reported in ``info["episode"]`` as SB3's Monitor does.
    """
    venv: VecEnv = MillVibVecEnv(env_id, n_envs, seed=seed, **env_kwargs)
    if monitor:
        venv = VecMonitor(venv)
    return venv
