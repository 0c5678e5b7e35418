"""The controller interface every baseline and agent implements (SB3's `predict` plus the evaluation
loop's hooks), the per-environment gain holder of the plant-aware baselines, the offline gain table,
and the wrapper that runs a controller in a plain Gymnasium loop."""

from __future__ import annotations

from typing import Any, Sequence

import gymnasium as gym
import numpy as np

from millvib_env.envs.actions import GainMap
from millvib_env.envs.config import _merge
from millvib_env.tasks import Task

__all__ = ["Controller", "PerEnvGains", "GainTable", "ControllerLoop"]


class Controller:
    """Common interface: `predict` as in SB3, plus hooks the evaluation loop calls."""

    name = "controller"
    env_id = "MillVib-GainSchedule-v0"
    env_kwargs: dict = {}
    recurrent = False
    #: True: the evaluation loop asks the env for every step's measured signals (info["signals"])
    needs_signals = False
    #: True: an oracle that reads the plant itself (its true state, parameters and disturbances): the
    #: evaluation loop hands it the environments' core with `attach` before the first reset
    reads_plant = False
    #: the task it was built for (resolved once where the name entered: `load_controller`, an agent's card)
    task: Task | None = None
    #: a trained agent's card (`card.json`) and training seed (`catalog.agents.AgentPolicy`); None for a baseline
    card: dict | None = None
    seed: int | None = None
    #: True: an environment's actions depend on that environment alone, bit for bit, whatever else is in the
    #: batch (the baselines). False by default: a network's products round with the batch's size, so the
    #: benchmark runs such a controller's named scenarios one at a time
    batch_exact = False

    def env_kwargs_for(self, task: Task | None = None, env_kwargs: dict | None = None) -> dict:
        """The environment keyword arguments this controller runs with on `task`: the task's config,
        then the controller's own settings (its action, observation, training reward), then `env_kwargs`."""

        kwargs = {"config": task.config} if task is not None else {}
        return _merge(_merge(kwargs, self.env_kwargs), env_kwargs or {})

    def make_env(self, **env_kwargs):
        """The Gymnasium environment this controller runs in (its task's config and its own settings,
        the signals it measures switched on), wrapped so that the calls it needs on reset and step
        are made for it: a plain loop ``obs, info = env.reset(seed=s)``, ``action, _ =
        ctrl.predict(obs)``, ``env.step(action)`` gives the benchmark's episode on seed s."""
        return ControllerLoop(gym.make(self.env_id, **self.env_kwargs_for(self.task, env_kwargs)), self)

    def attach(self, core) -> None:
        """Called once with the environments' core (`envs.core.MillVibCore`) where `reads_plant`."""

    def on_reset(self, infos: Sequence[dict], indices: Sequence[int] | np.ndarray) -> None:
        """Called with the reset infos of the environments that just started an episode."""

    def on_step(self, infos: Sequence[dict]) -> None:
        """Called after every step with the step's infos (one per environment)."""

    def episode_extras(self, i: int) -> dict:
        """Extra per-episode numbers of environment i (e.g. an estimator's error), at the episode's end."""
        return {}

    def predict(self, observation, state=None, episode_start=None, deterministic: bool = True):
        raise NotImplementedError


class PerEnvGains(Controller):
    """A controller that holds one action per environment, set from each plant's (c1, Ct)."""

    batch_exact = True

    gain_map: GainMap
    _actions: np.ndarray | None = None  # (n, dim) float32, grown by _ensure

    def _ensure(self, n: int) -> None:
        actions = self._actions
        have = 0 if actions is None else actions.shape[0]
        if have < n:
            grown = np.zeros((n, self.gain_map.dim), dtype=np.float32)
            if actions is not None and have:
                grown[:have] = actions
            self._actions = grown
            self._plant = getattr(self, "_plant", []) + [None] * (n - have)

    @property
    def _held(self) -> np.ndarray:
        """(n, dim): the action each environment holds (grown by `_ensure` before it is read)."""
        assert self._actions is not None
        return self._actions

    def gains_for(self, c1: float, ct: float) -> np.ndarray:
        raise NotImplementedError

    def _set(self, i: int, params: dict) -> None:
        key = (params["c1"], params["Ct"])
        if self._plant[i] != key:  # the plant changed (a new episode, or a change within one)
            self._plant[i] = key
            self._held[i] = self.gain_map.action(self.gains_for(*key))

    def on_reset(self, infos, indices) -> None:
        self._ensure(max(indices) + 1)
        for info, i in zip(infos, indices):
            self._set(i, info["params"])

    def on_step(self, infos) -> None:
        self._ensure(len(infos))
        for i, info in enumerate(infos):
            self._set(i, info["params"])

    def predict(self, observation, state=None, episode_start=None, deterministic: bool = True):
        actions = self._actions
        if actions is None:
            what = "the measured signals" if self.needs_signals else "the episode's true c1 and Ct"
            raise ValueError(f"{self.name} reads {what} through on_reset(infos, indices) after every reset and "
                             "on_step(infos) after every step: run it in env = ctrl.make_env(), which makes those "
                             "calls (the benchmark's evaluation loop makes them too)")
        obs = np.asarray(observation)
        return (actions[0].copy() if obs.ndim == 1 else actions[: obs.shape[0]].copy()), state


class GainTable:
    """Gains tuned offline on a (log c1, log Ct) grid, interpolated bilinearly in log gains."""

    def __init__(self, c1_grid: Sequence[float] | np.ndarray, ct_grid: Sequence[float] | np.ndarray,
                 log_gains: np.ndarray):
        from scipy.interpolate import RegularGridInterpolator

        self.c1_grid, self.ct_grid = np.asarray(c1_grid, float), np.asarray(ct_grid, float)
        self.log_gains = np.asarray(log_gains, float)  # (n_c1, n_ct, 3), log10 of KP, KI, KD
        self._lo = np.log([self.c1_grid[0], self.ct_grid[0]])
        self._hi = np.log([self.c1_grid[-1], self.ct_grid[-1]])
        self._interp = RegularGridInterpolator((np.log(self.c1_grid), np.log(self.ct_grid)), self.log_gains)

    def __call__(self, c1: float, ct: float) -> np.ndarray:
        """(KP, KI, KD) for the plant (c1, Ct); plants outside the grid take its edge."""
        return self.at(np.array([c1]), np.array([ct]))[0]

    def at(self, c1: np.ndarray, ct: np.ndarray) -> np.ndarray:
        """(n, 3): (KP, KI, KD) for the plants (c1[k], Ct[k]) in one call; each row is what the plant alone gets
        (elementwise operations, one point after another in the interpolation)."""
        point = np.clip(np.log(np.stack([c1, ct], axis=1)), self._lo, self._hi)
        return 10.0 ** self._interp(point)


class ControllerLoop(gym.Wrapper):
    """A controller's environment for a plain Gymnasium loop (`Controller.make_env`): switches on the
    signals it measures and calls its on_reset / on_step hooks, as the benchmark's evaluation loop does."""

    def __init__(self, env: gym.Env, controller: Controller):
        super().__init__(env)
        self.controller = controller
        unwrapped: Any = env.unwrapped  # a millvib env: its core is an envs.core.MillVibCore
        core = unwrapped.core
        core.record_signals = bool(controller.needs_signals)
        if controller.reads_plant:
            controller.attach(core)

    def reset(self, **kwargs):
        obs, info = self.env.reset(**kwargs)
        self.controller.on_reset([info], [0])
        return obs, info

    def step(self, action):
        obs, reward, terminated, truncated, info = self.env.step(action)
        self.controller.on_step([info])
        return obs, reward, terminated, truncated, info
