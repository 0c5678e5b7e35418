"""A fixed linear feedforward on observation channels: the classical part under a residual valve action.

A residual valve environment adds the agent's action (+-``actions.residual_range_v``) to its fixed PID's
command. With ``actions.residual_feedforward`` (observation channel -> gain in V per unit of the channel) it adds
one more fixed term, computed from the very observation the agent acted on:

    u_ff = clip(sum_c g_c q_c, +-u_range_v)      (V; the amplifier's +-10 V then clips the loop's whole command)

with q_c the channel read back in its physical unit (`envs.observation.unslog`: N for the force channels, m for
the position and set-point ones), held within the valve action's full scale (``actions.u_range_v``, 100 V) as a
valve action is. The zero action is then exactly the classical controller that reads those
channels (`control.preview.PreviewFeedforward`, tuned by `millvib tune`), and a student learns only what that
controller misses, within a range a commissioning engineer accepts (``residual_range_v``).
"""

from __future__ import annotations

from typing import Mapping, Sequence

import numpy as np

from millvib_env._checks import shown
from millvib_env.envs.observation import OBS_SCALES, unslog

__all__ = ["ChannelFeedforward", "channel_scale"]


def channel_scale(name: str) -> str | None:
    """The signed-log scale (`OBS_SCALES` key) of observation channel `name`, None where it has none."""
    if name.startswith("preview_force_"):
        return "load_force"
    if name.startswith("preview_setpoint_"):
        return "error"
    for key in OBS_SCALES:
        if name == key or name.startswith(key + "_lag_"):
            return key
    return None


class ChannelFeedforward:
    """u = sum_c g_c unslog(obs_c) over the channels `gains` names (V per N or per m). `gains` is one gain per
    channel, or (`volts`) one row of gains per environment; the sum runs channel by channel in the given order, so
    a row's number is the same whatever the batch."""

    def __init__(self, channels: Sequence[str], volts: np.ndarray, names: Sequence[str], where: str):
        names = list(names)
        missing = [c for c in channels if c not in names]
        if missing:
            raise ValueError(f"{where} reads {missing}, which the observation does not carry; it carries "
                             f"{names}")
        scales = [channel_scale(c) for c in channels]
        bad = [c for c, s in zip(channels, scales) if s is None]
        if bad:
            raise ValueError(f"{where} reads {bad}: a feedforward reads signed-log channels only (the force, "
                             "preview, error, velocity, acceleration and vibration channels and their lags)")
        self.channels = tuple(channels)
        self.cols = np.array([names.index(c) for c in channels], dtype=np.intp)
        self.scales: tuple[str, ...] = tuple(s for s in scales if s is not None)
        self.volts = np.asarray(volts, float)

    @classmethod
    def from_mapping(cls, gains: Mapping[str, float], names: Sequence[str],
                     where: str = "actions.residual_feedforward") -> "ChannelFeedforward":
        volts = np.array([float(v) for v in gains.values()])
        if not np.all(np.isfinite(volts)):
            raise ValueError(f"{where} = {shown(dict(gains))} is invalid: finite gains (V per N or per m)")
        return cls(list(gains), volts, names, where)

    def command_v(self, obs: np.ndarray) -> np.ndarray:
        """The feedforward's command (V) for observation rows `obs`."""
        x = obs[:, self.cols].astype(float)
        for scale in set(self.scales):
            cols = [k for k, s in enumerate(self.scales) if s == scale]
            x[:, cols] = unslog(x[:, cols], scale)
        v = self.volts if self.volts.ndim == 2 else np.broadcast_to(self.volts, x.shape)
        u = np.zeros(len(x))
        for j in range(x.shape[1]):
            u += v[: len(x), j] * x[:, j]
        return u
