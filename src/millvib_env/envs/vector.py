"""Gymnasium's vector API on the batched engine: ``gym.make_vec(id, n, vectorization_mode="vector_entry_point")``.

All N plants advance in one compiled call (`MillVibCore`), as in the SB3 `MillVibVecEnv`, behind Gymnasium's
`VectorEnv` interface: batched spaces, ``reset(seed=s)`` seeding environment i with s + i (or a list of seeds),
infos as dictionaries of arrays with their ``_key`` masks, and Gymnasium's auto-reset modes (keyword
``autoreset_mode``; Gymnasium's `make_vec` takes no ``vector_kwargs`` for a vector entry point):

* ``AutoresetMode.NEXT_STEP`` (the default, as Gymnasium's): a finished environment returns its last
  observation; the next ``step`` ignores its action and returns its next episode's first observation, with
  reward 0 and neither end flag;
* ``AutoresetMode.SAME_STEP``: a finished environment returns its next episode's first observation at once,
  its last one in ``infos["final_obs"]`` (its last info in ``infos["final_info"]``).

Step for step the same as ``SyncVectorEnv`` over N single environments in either mode with the same seeds
(`tests/test_envs.py`), so Gymnasium's vector wrappers (``NormalizeObservation``, ``RecordEpisodeStatistics``)
run on it.
"""

from __future__ import annotations

import copy
from typing import Any, Sequence

import numpy as np
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from millvib_env._checks import seed_or_none, shown
from millvib_env.envs.build import build_core
from millvib_env.envs.config import DEFAULT_VERSION, EnvConfig

__all__ = ["MillVibVectorEnv", "GainScheduleVectorEnv", "ValveVectorEnv"]


class MillVibVectorEnv(VectorEnv):
    """N MillVib environments of one mode and version, Gymnasium's vector API (module docstring)."""

    mode = "gain"
    metadata = {"render_modes": [], "autoreset_mode": AutoresetMode.NEXT_STEP}

    def __init__(self, num_envs: int = 1, *, config: str | dict | EnvConfig | None = "startup", residual: bool = False,
                 observe_params: bool | None = None, observe_phase: bool | None = None,
                 env_version: str = DEFAULT_VERSION,
                 render_mode: str | None = None, extra_disturbances: Sequence | None = None, reward_fn: Any = None,
                 envelope_fn: Any = None, base_controller: Any = None,
                 autoreset_mode: AutoresetMode | str = AutoresetMode.NEXT_STEP, **overrides: Any):
        modes = {m.value: m for m in (AutoresetMode.NEXT_STEP, AutoresetMode.SAME_STEP)}
        mode = autoreset_mode.value if isinstance(autoreset_mode, AutoresetMode) else autoreset_mode
        if mode not in modes:
            raise ValueError(f"autoreset_mode = {shown(autoreset_mode)} is invalid: one of {list(modes)} "
                             "(gymnasium.vector.AutoresetMode.NEXT_STEP or SAME_STEP)")
        self.autoreset_mode = modes[mode]
        self.metadata = {**type(self).metadata, "autoreset_mode": self.autoreset_mode}
        if render_mode is not None:
            raise ValueError(f"render_mode = {shown(render_mode)} is invalid for the vector environment: None (render "
                             "one environment: gym.make)")
        self.core = build_core(num_envs, self.mode, env_version, config, residual=residual,
                               observe_params=observe_params, observe_phase=observe_phase,
                               extra_disturbances=extra_disturbances, reward_fn=reward_fn, envelope_fn=envelope_fn,
                               base_controller=base_controller, overrides=overrides)
        self.config = self.core.settings.cfg
        self.num_envs = self.core.settings.n
        self.single_observation_space = self.core.observation_space
        self.single_action_space = self.core.action_space
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self.render_mode = None
        self._autoreset = np.zeros(self.num_envs, dtype=bool)  # next-step mode: who restarts at the next step

    def _seeds(self, seed) -> list:
        if seed is None:
            return [None] * self.num_envs
        if isinstance(seed, (list, tuple)):
            if len(seed) != self.num_envs:
                raise ValueError(f"seed has {len(seed)} entries; expected one per environment ({self.num_envs})")
            return [seed_or_none(f"seed[{i}]", s) for i, s in enumerate(seed)]
        seed = seed_or_none("seed", seed)
        return [seed + i for i in range(self.num_envs)]

    def reset(self, *, seed: int | list | None = None, options: dict | None = None):
        infos: dict = {}
        shape: tuple[int, ...] = self.observation_space.shape  # type: ignore[assignment]  # a Box's is set
        obs = np.zeros(shape, dtype=np.float32)
        for i, s in enumerate(self._seeds(seed)):
            obs[i], info = self.core.reset_env(i, s, options)
            infos = self._add_info(infos, info, i)
        self._autoreset[:] = False
        return obs, infos

    def step(self, actions):
        if self.autoreset_mode == AutoresetMode.NEXT_STEP:
            return self._step_next(actions)
        obs, reward, terminated, truncated, step_infos = self.core.step(actions)
        infos: dict = {}
        for i in range(self.num_envs):
            info = step_infos[i]
            if terminated[i] or truncated[i]:
                infos = self._add_info(infos, {"final_obs": obs[i].copy(), "final_info": info}, i)
                obs[i], info = self.core.reset_env(i)
            infos = self._add_info(infos, info, i)
        return obs, reward, terminated, truncated, infos

    def _step_next(self, actions):
        """The next-step auto-reset: the environments that ended at the last step start their next episode now.
        The engine steps every environment at once, so those are started before the step (to run on) and again,
        from the same generator state, after it: the new episode's first observation, exactly as a reset gives it."""
        restart = np.flatnonzero(self._autoreset)
        states = {i: copy.deepcopy(self.core.np_random[i].bit_generator.state) for i in restart}
        for i in restart:
            self.core.reset_env(i)
        obs, reward, terminated, truncated, step_infos = self.core.step(actions)
        infos: dict = {}
        for i in range(self.num_envs):
            info = step_infos[i]
            if i in states:
                self.core.np_random[i].bit_generator.state = states[i]
                obs[i], info = self.core.reset_env(i)
                reward[i], terminated[i], truncated[i] = 0.0, False, False
            infos = self._add_info(infos, info, i)
        self._autoreset = terminated | truncated
        return obs, reward, terminated, truncated, infos


class GainScheduleVectorEnv(MillVibVectorEnv):
    """`MillVibVectorEnv` of the gain-schedule environment (`GainScheduleEnv`)."""

    mode = "gain"


class ValveVectorEnv(MillVibVectorEnv):
    """`MillVibVectorEnv` of the valve environment (`ValveEnv`)."""

    mode = "valve"
