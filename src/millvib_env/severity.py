"""Vibration severity (ISO 10816 / ISO 20816 broadband velocity RMS) and its ISO 10816-3 zone.

The paper scores every case by its "vibration intensity", computed with an improved
frequency-domain integral method based on low-frequency filtering. We implement that measure
as the standards define it: the RMS of vibration velocity, in mm/s, over a band (default
10-1000 Hz). An acceleration signal is integrated in the frequency domain (its spectrum divided
by j*omega) and every bin outside the band is zeroed: the low-frequency cut removes the drift
that time-domain integration accumulates, the high cut removes hiss. The RMS then follows from
Parseval's theorem over the retained bins.

A record that is not periodic in its window (a transient, a slow drift) would leak energy into
the band through the jump between its ends. We remove that jump without a taper window (a
taper would hide a transient at the start of the record): the record is extended by its mirror
image before the transform, as a DCT does, after removing the one low-order trend that makes
the extension smooth. The three input quantities get the same treatment expressed in their own
terms, so they give the same severity for the same motion:

* velocity: subtract the straight line through its two end values (the record then starts and
  ends at zero) and extend it by its negated mirror image (odd extension);
* acceleration: subtract its mean (= the slope of that same line) and extend it evenly;
* displacement: subtract the parabola whose slope matches the record's slope at both ends (the
  integral of that line; end slopes from one-sided differences) and extend it evenly.

The mirror image has the same mean square as the record, so no window correction is needed.

What the extension cannot remove is the kink that strong content just above the band (hiss an
octave above the upper edge) makes at the record's ends: a few percent of such content's RMS
lands in the band (measured in tests/test_severity.py). A vibration meter's analogue anti-alias
filter plays that role for measured data; simulated data sampled at 10 kHz has little there.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache
from typing import Literal

import numpy as np
from millvib_env._yaml import load_yaml
from scipy import fft as sfft

from millvib_env._paths import config_dir

__all__ = ["vibration_severity", "band_velocity_spectrum", "iso_zone", "IsoZoneTable", "iso_table"]

Quantity = Literal["acceleration", "velocity", "displacement"]
#: power of j*omega that turns each quantity's spectrum into velocity
_POWER = {"acceleration": -1, "velocity": 0, "displacement": 1}


def _check_signal(signal: np.ndarray, fs: float, band: tuple[float, float], quantity: str) -> np.ndarray:
    x = np.asarray(signal, dtype=np.float64)
    if x.ndim != 1:
        raise ValueError(f"signal must be 1-D, got shape {x.shape}")
    if x.size < 8:
        raise ValueError(f"signal has {x.size} samples; at least 8 are needed")
    if not np.all(np.isfinite(x)):
        raise ValueError("signal contains NaN or inf (a diverged simulation has no severity)")
    if not (math.isfinite(fs) and fs > 0):
        raise ValueError(f"fs = {fs!r} Hz is invalid: must be finite and > 0")
    lo, hi = band
    if not (0 <= lo < hi):
        raise ValueError(f"band = {band!r} is invalid: need 0 <= low < high (Hz)")
    if hi > fs / 2:
        raise ValueError(f"band upper edge {hi} Hz is above the Nyquist frequency {fs / 2} Hz (fs = {fs} Hz)")
    if quantity not in _POWER:
        raise ValueError(f"quantity = {quantity!r} is invalid: one of {sorted(_POWER)}")
    return x


def _smooth_extension(x: np.ndarray, fs: float, quantity: str) -> np.ndarray:
    """The record, trend-corrected and mirror-extended to 2n samples (module docstring)."""
    n = x.size
    t = np.arange(n) / fs
    span = t[-1]
    if quantity == "velocity":
        y = x - (x[0] + (x[-1] - x[0]) * t / span)
        return np.concatenate([y, -y[::-1]])
    if quantity == "acceleration":
        y = x - x.mean()
    else:
        v0 = (x[1] - x[0]) * fs
        v1 = (x[-1] - x[-2]) * fs
        y = x - (v0 * t + (v1 - v0) * t * t / (2.0 * span))
        y -= y.mean()
    return np.concatenate([y, y[::-1]])


def band_velocity_spectrum(signal: np.ndarray, fs: float, *, quantity: Quantity = "acceleration",
                           band: tuple[float, float] = (10.0, 1000.0)) -> tuple[np.ndarray, np.ndarray]:
    """One-sided velocity spectrum of the extended record (2n samples), restricted to `band`.

    Returns (frequencies Hz, V_k); bins outside the band are zero. Acceleration is divided by
    j*omega, displacement multiplied by it.
    """
    x = _check_signal(signal, fs, band, quantity)
    ext = _smooth_extension(x, fs, quantity)
    spec = sfft.rfft(ext)
    freqs = sfft.rfftfreq(ext.size, d=1.0 / fs)
    keep = (freqs >= band[0]) & (freqs <= band[1]) & (freqs > 0)
    out = np.zeros_like(spec)
    jw = 2j * np.pi * freqs[keep]
    out[keep] = spec[keep] * jw ** _POWER[quantity]
    return freqs, out


def vibration_severity(signal: np.ndarray, fs: float, *, quantity: Quantity = "acceleration",
                       band: tuple[float, float] = (10.0, 1000.0)) -> float:
    """Vibration severity in mm/s: RMS of the band-limited vibration velocity.

    Parameters
    ----------
    signal : 1-D array in SI units: m/s^2 (acceleration), m/s (velocity) or m (displacement),
        sampled uniformly at `fs`.
    fs : sampling rate in Hz; the band's upper edge must be at or below fs/2.
    quantity : what `signal` is.
    band : (low, high) Hz; ISO 10816-3 uses 10-1000 Hz for machines above 600 rpm.
    """
    _, vel = band_velocity_spectrum(signal, fs, quantity=quantity, band=band)
    n = 2 * len(signal)  # the mirror-extended record
    # Parseval for a one-sided spectrum: interior bins count twice, DC and Nyquist once
    weight = np.full(vel.size, 2.0)
    weight[0] = 1.0
    if n % 2 == 0:
        weight[-1] = 1.0
    mean_sq = float(np.sum(weight * np.abs(vel) ** 2)) / n**2
    return 1000.0 * math.sqrt(mean_sq)


@dataclass(frozen=True)
class IsoZoneTable:
    """Zone boundaries (mm/s) A/B, B/C, C/D of one machine class, with the source named."""

    name: str
    boundaries_mm_s: tuple[float, float, float]
    source: str
    description: str = ""

    def zone(self, severity_mm_s: float) -> str:
        if not math.isfinite(severity_mm_s) or severity_mm_s < 0:
            raise ValueError(f"severity_mm_s = {severity_mm_s!r} is invalid: must be finite and >= 0")
        ab, bc, cd = self.boundaries_mm_s
        if severity_mm_s <= ab:
            return "A"
        if severity_mm_s <= bc:
            return "B"
        if severity_mm_s <= cd:
            return "C"
        return "D"


@lru_cache(maxsize=None)
def _load_iso_tables() -> tuple[str, str, dict[str, IsoZoneTable]]:
    data = load_yaml(config_dir() / "severity.yaml")
    tables = {name: IsoZoneTable(name, tuple(float(b) for b in t["boundaries_mm_s"]), data["source"],
                                 t.get("description", ""))
              for name, t in data["iso10816_3"].items()}
    return data["default_class"], data["source"], tables


def iso_table(name: str | None = None) -> IsoZoneTable:
    """The ISO 10816-3 zone table `name` from configs/severity.yaml (default: its default_class)."""
    default, _, tables = _load_iso_tables()
    key = default if name is None else name
    if key not in tables:
        raise ValueError(f"ISO machine class {key!r} unknown; available: {sorted(tables)}")
    return tables[key]


def iso_zone(severity_mm_s: float, machine_class: str | None = None) -> str:
    """ISO 10816-3 zone ('A', 'B', 'C' or 'D') of a severity in mm/s."""
    return iso_table(machine_class).zone(severity_mm_s)
