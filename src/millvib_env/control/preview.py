"""`pid-pf-preview`: the classical controller of the preview's information, a two-degree-of-freedom PID + pressure
feedback with a feedforward of the pass schedule and of the entry gauge's force preview.

It reads exactly what the shipped preview students read and nothing of the plant: it runs in the students'
environment (the residual valve action on `pid-pf-robust`'s digital PID, the load cells, the preview's eight
look-aheads k = 0.5-20 ms of the force's and the set-point's change: `preview_env_kwargs`) and adds to the PID's command

    u_ff = sum_k a_k dF_k + sum_k b_k dXd_k + c F_m      (V; then the amplifier's +-10 V clips the sum)

with dF_k (N) the preview's force change from now to k samples ahead, dXd_k (m) the set-point's, F_m (N) the load
cells' force deviation: one fixed linear gain per channel, 17 in all, read back from the observation's signed-log
channels (`envs.observation.slog`, inverted exactly). The family holds the textbook designs: a P term on the
set-point L samples ahead (a reference prefilter: one b_k), a flow term on the set-point's speed (b_(k2) - b_(k1)),
and a feedforward AGC that moves the cylinder a lead ahead of a force change (a_k: a pulse of L samples before the
change arrives, scaled by the stand's stiffness); any feedforward linear in these channels is one point of it.

The gains are tuned by `millvib tune` (`tuning.search.tune_preview`) on the task's tuning plants, with the
preview as the benchmark measures it (`envs.gauge`): the benchmark's mean cost is, for a loop that stays linear,
a sum of norms of an affine function of the gains (convex), so a quasi-Newton search from zero (the reference
itself) finds the family's best.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from millvib_env._checks import shown
from millvib_env.control.base import Controller
from millvib_env.tasks import default_task
from millvib_env.envs.feedforward import ChannelFeedforward
from millvib_env.envs.observation import Observer

__all__ = ["DEFAULT_PREVIEW", "FF_CHANNELS", "FF_SCALES", "PreviewFeedforward", "preview_env_kwargs"]

#: the preview's look-aheads (control samples: 0.5-20 ms at 2 kHz)
DEFAULT_PREVIEW = (1, 2, 4, 8, 16, 24, 32, 40)


def preview_env_kwargs(preview: Sequence[int] = DEFAULT_PREVIEW, range_v: float = 100.0,
                       base: str | list[float] = "pid-pf-robust",
                       history: Sequence[int] = (), loop_sample: str = "current", gauge: str | dict = "exact",
                       filters: Sequence[int] = ()) -> dict:
    """The environment of a controller that reads the preview: a residual of +-`range_v` on `base` (a fixed-gain
    baseline's name, or its gains), the load cells,
    the preview's look-aheads, (where `history` names lags) the measured channels' history, the loop's sample it
    reads (`observation.loop_sample`), the preview exact or measured (`gauge`: `envs.gauge`), and (where `filters`
    names time constants) the channels' moving averages (`observation.history_filters`)."""
    seen: dict = {"force": True, "preview_samples": list(preview)}
    if history:
        seen["history_samples"] = list(history)
    if filters:
        seen["history_filters"] = list(filters)
    if loop_sample != "previous":
        seen["loop_sample"] = loop_sample
    if gauge != "exact":
        seen["preview_gauge"] = gauge
    return {"residual": True, "reward": {"w_vibration": 1.0, "w_effort": 0.0}, "observation": seen,
            "actions": {"residual_gains": base, "residual_range_v": float(range_v)}}


#: the channels the feedforward reads, in its gains' order
FF_CHANNELS = tuple([f"preview_force_{k}" for k in DEFAULT_PREVIEW] + [f"preview_setpoint_{k}" for k in DEFAULT_PREVIEW]
                    + ["load_force"])
#: a gain of 1 in the tuner's units: 1 V per 10 kN of force, 1 V per 1 um of set-point (the reference's KP is about
#: 1.3 V/um; a force step moves the stand about 1 um per 2 kN)
FF_SCALES = np.array([1e-4] * len(DEFAULT_PREVIEW) + [1e6] * len(DEFAULT_PREVIEW) + [1e-4])


class PreviewFeedforward(Controller):
    """The linear preview feedforward on the reference's PID (module docstring). `gains`: the 17 gains in the
    tuner's units (`FF_SCALES`), one row for every environment, or one row per environment (a tuning batch)."""

    env_id = "MillVib-Valve-v1"
    batch_exact = True

    def __init__(self, name: str, gains, base_gains: Sequence[float], description: str = ""):
        g = np.asarray(gains, float)
        if g.ndim not in (1, 2) or g.shape[-1] != len(FF_CHANNELS) or not np.all(np.isfinite(g)):
            raise ValueError(f"{name} gains = {shown(gains)} are invalid: {len(FF_CHANNELS)} finite numbers "
                             f"({', '.join(FF_CHANNELS)}), or one row of them per environment")
        self.name, self.description = name, description
        self.gains = g
        self._volts = g * FF_SCALES  # V per N or per m
        #: the students' environment on the reference's gains (`base_gains`, as numbers: the env layer takes no names)
        self.env_kwargs = preview_env_kwargs(base=[float(v) for v in base_gains])
        self._ff: ChannelFeedforward | None = None

    def _feedforward(self) -> ChannelFeedforward:
        """The feedforward on `FF_CHANNELS` of this controller's environment (`envs.feedforward`)."""
        if self._ff is None:
            task = self.task or default_task()
            seen = {**task.configs["v1"].raw["observation"], **self.env_kwargs.get("observation", {})}
            names = Observer("valve", residual=True, gain_names=(), observe_phase=bool(seen.get("phase")),
                             observe_params=bool(seen.get("params")), observe_force=bool(seen.get("force")),
                             noise=None, delay=0, n=1, preview_samples=tuple(seen.get("preview_samples", ())),
                             history_samples=tuple(seen.get("history_samples", ()))).names
            self._ff = ChannelFeedforward(FF_CHANNELS, self._volts, names, where=self.name)
        return self._ff

    def feedforward_gains(self) -> dict:
        """The feedforward as an environment's ``actions.residual_feedforward`` (channel -> V per N or per m): the
        environment then runs this controller under a residual action (its zero action is this controller)."""
        if self._volts.ndim != 1:
            raise ValueError(f"{self.name} holds one gain set per environment (a tuning batch); one set is needed")
        return {c: float(v) for c, v in zip(FF_CHANNELS, self._volts)}

    def command_v(self, obs: np.ndarray) -> np.ndarray:
        """The feedforward's command (V) for observation rows `obs`: one sum per row, channel by channel (each
        row's number is the same whatever the batch)."""
        return self._feedforward().command_v(obs)

    def predict(self, observation, state=None, episode_start=None, deterministic: bool = True):
        obs = np.asarray(observation, dtype=np.float32)
        rows = obs[None, :] if obs.ndim == 1 else obs
        range_v = float(self.env_kwargs["actions"]["residual_range_v"])
        action = np.clip(self.command_v(rows) / range_v, -1.0, 1.0).astype(np.float32)[:, None]
        return (action[0] if obs.ndim == 1 else action), state
