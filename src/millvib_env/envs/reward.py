"""The per-step reward and the running vibration measure the agent observes.

``r = -(w_v RMS(v_b) / vibration_scale + w_e RMS(e) / tracking_scale + w_u effort + w_o offset)
- (P + P_s n_left) [terminated]``
with v_b the band-limited (10-1000 Hz, causal 4th-order Butterworth) piston velocity and
e = xd - x, both over the period's plant samples (their mean squares come from `envs.period`, which
runs the filter with the sections designed here); effort is the mean |change of the gain action|
(gain mode) or the squared valve action (valve mode); offset (gain mode, ``w_offset``, default 0) is
the mean squared action: with a relative action, how far the gains are from their base controller.
P (``terminal_penalty``) is paid once when an episode leaves its envelope, and P_s
(``terminal_per_step``, v1: `DIVERGED_COST`) for each of the n_left steps it did not run, so an
episode that fails early never earns more than one that runs to its end at that cost per step.
"""

from __future__ import annotations

import math

import numpy as np

from millvib_env.envs.config import RewardSettings

__all__ = ["Reward", "DIVERGED_COST"]

#: what an episode that leaves its envelope (or whose integration fails) costs at least, in the
#: benchmark's cost units (severity / 4.5 mm/s + tracking RMS / 10 um): twice the tracking cost of
#: holding the envelope's edge (5 mm) for a whole episode, so no episode that runs to its end inside the
#: envelope at a plausible severity costs as much. The benchmark and every tuner score a diverged
#: episode at max(its cost, this); the v1 reward charges it per step not run.
DIVERGED_COST = 1000.0


class Reward:
    """Reward weights and the band-pass filter state of a batch of environments."""

    def __init__(self, spec: RewardSettings, *, period_s: float, sample_rate_hz: float, n: int):
        self.w_vib, self.w_trk, self.w_eff = spec.w_vibration, spec.w_tracking, spec.w_effort
        self.w_off = float(spec.w_offset)
        self.vib_scale = spec.vibration_scale_mm_s * 1e-3
        self.trk_scale = spec.tracking_scale_um * 1e-6
        self.penalty = spec.terminal_penalty
        self.penalty_per_step = float(spec.terminal_per_step)
        self.ema_gain = 1.0 - math.exp(-period_s / spec.vib_time_constant_s)
        from scipy import signal as ssig  # here, not at import: 1-2 s that a refused config should not wait for

        from millvib_env.severity import severity_band

        self.sos = np.ascontiguousarray(ssig.butter(2, severity_band(), btype="bandpass", fs=sample_rate_hz,
                                                    output="sos"))
        #: the filter's section states, per environment (n, sections, 2)
        self.zi = np.zeros((n, self.sos.shape[0], 2))
        self.vib_ema = np.zeros(n)

    def start(self, i: int) -> None:
        self.zi[i] = 0.0
        self.vib_ema[i] = 0.0

    def step(self, vib_ms: np.ndarray, err_ms: np.ndarray, effort: np.ndarray, terminated: np.ndarray,
             offset: np.ndarray | None = None, remaining: np.ndarray | None = None) -> np.ndarray:
        """This period's reward per env, from the mean squares of its band-passed velocity and of its
        position error (`envs.period.summarize_period`, which also advances `zi`)."""
        self.vib_ema += self.ema_gain * (vib_ms - self.vib_ema)
        reward = -(self.w_vib * np.sqrt(vib_ms) / self.vib_scale + self.w_trk * np.sqrt(err_ms) / self.trk_scale
                   + self.w_eff * effort) - self.penalty * terminated
        if self.w_off and offset is not None:
            reward = reward - self.w_off * offset
        if self.penalty_per_step and remaining is not None:
            reward = reward - self.penalty_per_step * np.maximum(remaining, 0) * terminated
        return reward

    @property
    def vib_rms(self) -> np.ndarray:
        """Running RMS of the band-limited velocity (m/s), time constant vib_time_constant_s."""
        return np.sqrt(self.vib_ema)
