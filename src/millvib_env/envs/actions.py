"""The gain/action mapping, in one place: gain-schedule actions in [-1, 1]^k <-> PID gains.

Each gain is mapped onto its bounds (config section ``actions``), on a log scale by default,
``g = 10 ** (log10(lo) + (a + 1) / 2 * (log10(hi) - log10(lo)))``, or linearly with
``actions.scale: linear``, ``g = lo + (a + 1) / 2 * (hi - lo)`` (bounds may then be negative: the
LQR reference's position gain can be, when its pressure feedback carries the position loop).
The action has three entries (KP, KI, KD) or, with ``actions.pressure_feedback: true``, four
(KP, KI, KD, KPL).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from millvib_env.envs.config import EnvConfig

__all__ = ["GainMap", "GAIN_NAMES", "GAIN_UNITS"]

GAIN_NAMES = ("kp", "ki", "kd", "kpl")
GAIN_UNITS = {"kp": "V/m", "ki": "V/(m s)", "kd": "V s/m", "kpl": "V/Pa"}


@dataclass(frozen=True)
class GainMap:
    """Map between actions in [-1, 1]^dim and the gains `names` with bounds [lo, hi]."""

    names: tuple[str, ...]
    lo: np.ndarray
    hi: np.ndarray
    log: bool = True

    @classmethod
    def from_config(cls, config: EnvConfig, pressure_feedback: bool | None = None) -> "GainMap":
        acts = config["actions"]
        pf = config.pressure_feedback if pressure_feedback is None else pressure_feedback
        names = GAIN_NAMES if pf else GAIN_NAMES[:3]
        return cls(names, np.array([acts[k][0] for k in names], float), np.array([acts[k][1] for k in names], float),
                   acts.get("scale", "log") == "log")

    @property
    def dim(self) -> int:
        return len(self.names)

    @property
    def log_lo(self) -> np.ndarray:
        return np.log10(self.lo)

    @property
    def log_hi(self) -> np.ndarray:
        return np.log10(self.hi)

    def gains(self, action: np.ndarray) -> np.ndarray:
        """Gains (..., dim) for actions (..., dim); actions outside [-1, 1] are clipped."""
        frac = (np.clip(action, -1.0, 1.0) + 1.0) / 2.0
        if self.log:
            return 10.0 ** (self.log_lo + frac * (self.log_hi - self.log_lo))
        return self.lo + frac * (self.hi - self.lo)

    def action(self, gains) -> np.ndarray:
        """The action that maps to `gains` (..., dim, or 3: a missing KPL means the lowest); clipped."""
        g = np.asarray(gains, dtype=np.float64)
        if g.shape[-1] == 3 and self.dim == 4:
            g = np.concatenate([g, np.full(g.shape[:-1] + (1,), self.lo[3])], axis=-1)
        g = g[..., :self.dim]
        if self.log:
            frac = (np.log10(np.maximum(g, 1e-300)) - self.log_lo) / (self.log_hi - self.log_lo)
        else:
            frac = (g - self.lo) / (self.hi - self.lo)
        return np.clip(2.0 * frac - 1.0, -1.0, 1.0)
