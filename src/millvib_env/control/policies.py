"""Controllers with Stable-Baselines3's `predict` signature, so one evaluation loop runs them all.

* `FixedGainPolicy`: a PID with fixed gains, acting in the gain-schedule environment by holding the
  action that maps to its gains (pid-paper, pid-nominal, pid-robust).
* `OraclePolicy`: knows the plant's true c1 and Ct (the evaluation loop hands it ``info["params"]``
  at every reset and step) and uses gains tuned offline for that plant, interpolated on a
  (log c1, log Ct) grid: the bound for a fixed-gain PID on a fixed plant, not a deployable
  controller. On the `change` task it takes the table's gains for the plant of the moment (the
  `rolling` table): no longer a bound there, since gains tuned for fixed plants need not handle
  the change itself.
* `LQRPolicy` (`lqr-oracle`): knows c1 and Ct and designs an LQR with integral action for the
  PID + pressure-feedback structure on the linearised plant (`control.lqr`).
* `AdaptivePolicy` (`pid-adaptive`, `control.adaptive`): estimates c1 and Ct online from what a
  mill measures and takes the oracle's gains for the estimate: deployable.

Trained agents (`AgentPolicy`) and their folders are in `catalog.agents`; `catalog.factory.load_controller`
builds any of them by name.

The gains of the baselines and how they were found live in configs/control/<task>.yaml.
"""

from __future__ import annotations

import numpy as np

from millvib_env._checks import shown
from millvib_env.control.base import Controller, GainTable, PerEnvGains
from millvib_env.control.lqr import lqr_gains
from millvib_env.envs.actions import GainMap, fixed_actions, wide_actions
from millvib_env.envs.config import load_env_config
from millvib_env.tasks import Task

__all__ = ["FixedGainPolicy", "OraclePolicy", "LQRPolicy"]



class FixedGainPolicy(Controller):
    """A fixed-gain controller (a PID, + pressure feedback with 4 gains, + force feedforward with 5). It
    runs in an env whose action is relative to its gains with zero range (`fixed_actions`), so the
    gains that run are exactly the ones given: never clipped to an action's bounds (a 1e12 gain in a
    config runs as 1e12, or is refused if it is negative or not finite). The gains are all it needs: the
    environment's action bounds (its GainMap) play no part."""

    batch_exact = True

    def __init__(self, name: str, gains, description: str = ""):
        if not isinstance(description, str):
            raise ValueError(f"description = {shown(description)} is invalid: a string (a FixedGainPolicy takes a "
                             "name, its gains and a description)")
        self.name, self.description = name, description
        self.gains = np.asarray(gains.to_array() if hasattr(gains, "to_array") else gains, float)
        self.env_kwargs = {"actions": fixed_actions(self.gains)}
        self._action = np.zeros(len(self.gains), dtype=np.float32)

    def predict(self, observation, state=None, episode_start=None, deterministic: bool = True):
        obs = np.asarray(observation)
        if obs.ndim == 1:
            return self._action.copy(), state
        return np.tile(self._action, (obs.shape[0], 1)), state

    def loop_gains(self) -> list[float]:
        """Its gains, for an environment's loop to run under the agent's action (``base_controller=``)."""
        return [float(g) for g in self.gains]

    def __repr__(self) -> str:
        return f"FixedGainPolicy({self.name}, gains={np.array2string(self.gains, precision=3)})"


class OraclePolicy(PerEnvGains):
    """Per-plant gains from the offline-tuned grid (`GainTable`) for the true (c1, Ct); a table of
    four gains (pid-pf-oracle) runs with pressure feedback in the wide-bounds action."""

    name = "pid-oracle"

    def __init__(self, table: GainTable, gain_map: GainMap, name: str = "pid-oracle", config: str = "startup"):
        """`config`: the task's env config (`Task.config`), whose action a wide table widens."""
        self.table, self.gain_map, self.name = table, gain_map, name
        if table.log_gains.shape[-1] > 3:

            self.env_kwargs = {"actions": wide_actions(table.log_gains.shape[-1])}
            self.gain_map = GainMap.from_config(load_env_config(config, **self.env_kwargs))
        self._actions = None

    def gains_for(self, c1: float, ct: float) -> np.ndarray:
        return self.table(c1, ct)


class LQRPolicy(PerEnvGains):
    """`lqr-oracle`: LQR gains (PID + pressure feedback) designed for the true (c1, Ct)."""

    name = "lqr-oracle"
    #: the gain-schedule env with the pressure-feedback action, linearly scaled (the LQR's position
    #: gain can be negative when its pressure feedback carries the position loop); KD keeps the
    #: same 300 V s/m limit as every other controller
    ENV_KWARGS = {"actions": {"pressure_feedback": True, "scale": "linear", "kp": [-2.0e7, 2.0e7],
                              "ki": [0.0, 1.0e9], "kd": [0.0, 300.0], "kpl": [0.0, 1.0e-2]}}

    def __init__(self, weights, base_params, task: Task, loop=None):

        self.weights, self.base_params = weights, base_params
        #: the sampled loop's period (s), for a discrete-time design; None: the continuous design (v0)
        self.dt_s = None if loop is None else loop.dt_s
        self.env_kwargs = dict(self.ENV_KWARGS)
        self.gain_map = GainMap.from_config(load_env_config(task.config, **self.env_kwargs))
        self._lqr = lqr_gains
        self._actions = None
        self.clipped = 0

    def gains_for(self, c1: float, ct: float) -> np.ndarray:
        g = self._lqr(self.base_params.replace(c1=c1, Ct=ct), self.weights, dt_s=self.dt_s)
        if np.any(g < self.gain_map.lo) or np.any(g > self.gain_map.hi):
            self.clipped += 1
        return g


