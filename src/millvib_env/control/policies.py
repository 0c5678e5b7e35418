"""Controllers with Stable-Baselines3's `predict` signature, so one evaluation loop runs them all.

* `FixedGainPolicy`: a PID with fixed gains, acting in the gain-schedule environment by holding the
  action that maps to its gains (pid-paper, pid-nominal, pid-robust).
* `OraclePolicy`: knows each episode's true c1 and Ct (the evaluation loop hands it
  ``info["params"]`` at every reset) and uses gains tuned offline for that plant, interpolated on
  a (log c1, log Ct) grid: the bound a gain scheduler can approach, not a deployable controller.
* `AgentPolicy`: a trained SB3 model with its VecNormalize statistics.

The PID gains of the baselines and how they were found live in configs/control/.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from millvib_env._paths import agents_dir, config_dir
from millvib_env._yaml import load_yaml
from millvib_env.envs.config import EnvConfig, load_env_config
from millvib_env.envs.core import action_from_gains
from millvib_env.params import PAPER_GAINS, PIDGains

__all__ = ["Controller", "FixedGainPolicy", "OraclePolicy", "AgentPolicy", "gains_to_action", "load_controller",
           "baseline_names", "list_agents", "load_pid_config"]

PID_NAMES = ("pid-paper", "pid-nominal", "pid-robust", "pid-oracle")


def gains_to_action(gains: Sequence[float], config: EnvConfig | None = None) -> np.ndarray:
    """The gain-schedule action in [-1, 1]^3 that maps to (KP, KI, KD) (clipped to the bounds)."""
    return action_from_gains(gains, config or load_env_config("default")).astype(np.float32)


class Controller:
    """Common interface: `predict` as in SB3, plus hooks the evaluation loop calls."""

    name = "controller"
    env_id = "MillVib-GainSchedule-v0"
    env_kwargs: dict = {}
    recurrent = False

    def on_reset(self, infos: Sequence[dict], indices: Sequence[int]) -> None:
        """Called with the reset infos of the environments that just started an episode."""

    def predict(self, observation, state=None, episode_start=None, deterministic: bool = True):
        raise NotImplementedError


class FixedGainPolicy(Controller):
    def __init__(self, name: str, gains: PIDGains, config: EnvConfig | None = None, description: str = ""):
        self.name, self.gains, self.description = name, gains, description
        self._action = gains_to_action(gains.to_array(), config)

    def predict(self, observation, state=None, episode_start=None, deterministic: bool = True):
        obs = np.asarray(observation)
        if obs.ndim == 1:
            return self._action.copy(), state
        return np.tile(self._action, (obs.shape[0], 1)), state

    def __repr__(self) -> str:
        return f"FixedGainPolicy({self.name}, KP={self.gains.kp:.3g}, KI={self.gains.ki:.3g}, KD={self.gains.kd:.3g})"


class OraclePolicy(Controller):
    """Per-plant gains from an offline-tuned grid over (log c1, log Ct), interpolated bilinearly."""

    name = "pid-oracle"

    def __init__(self, c1_grid: Sequence[float], ct_grid: Sequence[float], log_gains: np.ndarray,
                 config: EnvConfig | None = None):
        from scipy.interpolate import RegularGridInterpolator

        self.config = config or load_env_config("default")
        self.c1_grid, self.ct_grid = np.asarray(c1_grid, float), np.asarray(ct_grid, float)
        self.log_gains = np.asarray(log_gains, float)  # (n_c1, n_ct, 3), log10 of KP, KI, KD
        self._interp = RegularGridInterpolator((np.log(self.c1_grid), np.log(self.ct_grid)), self.log_gains,
                                               bounds_error=False, fill_value=None)
        self._actions: np.ndarray | None = None

    def gains_for(self, c1: float, ct: float) -> PIDGains:
        point = np.clip([np.log(c1), np.log(ct)], [np.log(self.c1_grid[0]), np.log(self.ct_grid[0])],
                        [np.log(self.c1_grid[-1]), np.log(self.ct_grid[-1])])
        return PIDGains(*(10.0 ** self._interp(point[None, :])[0]))

    def on_reset(self, infos, indices) -> None:
        n = max(indices) + 1
        if self._actions is None or self._actions.shape[0] < n:
            grown = np.zeros((n, 3), dtype=np.float32)
            if self._actions is not None:
                grown[: self._actions.shape[0]] = self._actions
            self._actions = grown
        for info, i in zip(infos, indices):
            g = self.gains_for(info["params"]["c1"], info["params"]["Ct"])
            self._actions[i] = gains_to_action(g.to_array(), self.config)

    def predict(self, observation, state=None, episode_start=None, deterministic: bool = True):
        if self._actions is None:
            raise RuntimeError("pid-oracle needs the episode's true parameters: call on_reset(infos, indices) "
                               "after every reset (the benchmark's evaluation loop does)")
        obs = np.asarray(observation)
        return (self._actions[0].copy() if obs.ndim == 1 else self._actions[: obs.shape[0]].copy()), state


class AgentPolicy(Controller):
    """A trained SB3 agent (PPO, SAC or RecurrentPPO) with its VecNormalize observation statistics."""

    def __init__(self, folder: str | Path):
        folder = Path(folder)
        card_path = folder / "card.json"
        if not card_path.exists():
            raise ValueError(f"{folder} is not an agent folder: no card.json (see agents/README.md)")
        self.card = json.loads(card_path.read_text())
        self.name = self.card.get("name", folder.name)
        self.env_id = self.card["env_id"]
        self.env_kwargs = dict(self.card.get("env_kwargs", {}))
        algo = self.card["algo"].lower()
        if algo == "ppo":
            from stable_baselines3 import PPO as cls
        elif algo == "sac":
            from stable_baselines3 import SAC as cls
        elif algo == "recurrentppo":
            from sb3_contrib import RecurrentPPO as cls
        else:
            raise ValueError(f"unknown algo {algo!r} in {card_path}")
        self.recurrent = algo == "recurrentppo"
        self.model = cls.load(folder / "model.zip", device="cpu")
        self.obs_rms = None
        stats = folder / "vecnormalize.pkl"
        if stats.exists():
            import pickle

            with open(stats, "rb") as fh:
                vn = pickle.load(fh)
            self.obs_rms, self.clip_obs, self.epsilon = vn.obs_rms, vn.clip_obs, vn.epsilon

    def normalize(self, obs: np.ndarray) -> np.ndarray:
        if self.obs_rms is None:
            return obs
        return np.clip((obs - self.obs_rms.mean) / np.sqrt(self.obs_rms.var + self.epsilon),
                       -self.clip_obs, self.clip_obs).astype(np.float32)

    def predict(self, observation, state=None, episode_start=None, deterministic: bool = True):
        obs = self.normalize(np.asarray(observation, dtype=np.float32))
        if self.recurrent:
            return self.model.predict(obs, state=state, episode_start=episode_start, deterministic=deterministic)
        return self.model.predict(obs, deterministic=deterministic)


def load_pid_config() -> dict[str, Any]:
    """configs/control/pid.yaml: the tuned fixed gains and the oracle's grid."""
    return load_yaml(config_dir() / "control" / "pid.yaml")


def baseline_names() -> list[str]:
    return list(PID_NAMES)


def list_agents() -> list[str]:
    root = agents_dir()
    return sorted(p.name for p in root.iterdir() if (p / "card.json").exists()) if root.is_dir() else []


def load_controller(name: str, config: EnvConfig | None = None) -> Controller:
    """A controller by name: a PID baseline, a shipped agent (agents/<name>) or an agent folder path."""
    if name == "pid-paper":
        return FixedGainPolicy(name, PAPER_GAINS, config, "the paper's gains")
    if name in PID_NAMES:
        data = load_pid_config()
        if name == "pid-oracle":
            oracle = data["pid-oracle"]
            return OraclePolicy(oracle["c1_grid"], oracle["ct_grid"], np.array(oracle["log10_gains"]), config)
        entry = data[name]
        return FixedGainPolicy(name, PIDGains(*entry["gains"]), config, entry.get("how", ""))
    path = Path(name)
    if not path.exists():
        path = agents_dir() / name
    if path.is_dir():
        return AgentPolicy(path)
    raise ValueError(f"controller {name!r} unknown: use one of {list(PID_NAMES)}, a shipped agent "
                     f"{list_agents()} or an agent folder path")
