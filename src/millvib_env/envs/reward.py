"""The per-step reward and the running vibration measure the agent observes.

``r = -(w_v RMS(v_b) / vibration_scale + w_e RMS(e) / tracking_scale + w_u effort + w_o offset) - P [terminated]``
with v_b the band-limited (10-1000 Hz, causal 4th-order Butterworth) piston velocity and
e = xd - x, both over the period's plant samples; effort is the mean |change of the gain action|
(gain mode) or the squared valve action (valve mode); offset (gain mode, ``w_offset``, default 0) is
the mean squared action: with a relative action, how far the gains are from their base controller.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import signal as ssig

__all__ = ["Reward"]


class Reward:
    """Reward weights and the band-pass filter state of a batch of environments."""

    def __init__(self, spec: dict, *, period_s: float, sample_rate_hz: float, n: int):
        self.w_vib, self.w_trk, self.w_eff = spec["w_vibration"], spec["w_tracking"], spec["w_effort"]
        self.w_off = float(spec.get("w_offset", 0.0))
        self.vib_scale = spec["vibration_scale_mm_s"] * 1e-3
        self.trk_scale = spec["tracking_scale_um"] * 1e-6
        self.penalty = spec["terminal_penalty"]
        self.ema_gain = 1.0 - math.exp(-period_s / spec["vib_time_constant_s"])
        from millvib_env.severity import severity_band

        self.sos = ssig.butter(2, severity_band(), btype="bandpass", fs=sample_rate_hz, output="sos")
        self.zi = np.zeros((self.sos.shape[0], n, 2))
        self.vib_ema = np.zeros(n)

    def start(self, i: int) -> None:
        self.zi[:, i, :] = 0.0
        self.vib_ema[i] = 0.0

    def step(self, v: np.ndarray, e: np.ndarray, effort: np.ndarray, terminated: np.ndarray,
             offset: np.ndarray | None = None):
        """(reward, mean square of band velocity, mean square of error) of this period, per env."""
        v_band, self.zi = ssig.sosfilt(self.sos, v, axis=1, zi=self.zi)
        vib_ms = np.mean(v_band**2, axis=1)
        err_ms = np.mean(e**2, axis=1)
        self.vib_ema += self.ema_gain * (vib_ms - self.vib_ema)
        reward = -(self.w_vib * np.sqrt(vib_ms) / self.vib_scale + self.w_trk * np.sqrt(err_ms) / self.trk_scale
                   + self.w_eff * effort) - self.penalty * terminated
        if self.w_off and offset is not None:
            reward = reward - self.w_off * offset
        return reward, vib_ms, err_ms

    @property
    def vib_rms(self) -> np.ndarray:
        """Running RMS of the band-limited velocity (m/s), time constant vib_time_constant_s."""
        return np.sqrt(self.vib_ema)
