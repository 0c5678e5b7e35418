"""What kind of motion a run settles into: decay, periodic (period-k) or quasi-periodic.

The paper describes its cases as convergent, periodic, multi-period or quasi-periodic from phase
portraits. We measure it from the tail of a run with the standard peak map: the local maxima of
x(t) after the transient take one value for a period-1 oscillation, k values repeating in turn
for period-k, and fill an interval for quasi-periodic (or chaotic) motion.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import signal as ssig

from millvib_env._checks import instance, integer, real
from millvib_env.plant.integrate import SimResult
from millvib_env.severity import vibration_severity

__all__ = ["Motion", "classify_motion", "SETTLED_MM_S"]

#: band-limited vibration velocity (mm/s RMS, 10-1000 Hz) over the tail below which a run has settled
SETTLED_MM_S = 0.01
#: a tail whose second half vibrates with less than this fraction of its first half's RMS is decaying
DECAY_RATIO = 0.7


@dataclass(frozen=True)
class Motion:
    kind: str  # "decay", "periodic", "quasi-periodic", "diverged"
    period: int  # k for period-k, 0 otherwise
    amplitude_m: float  # half the peak-to-peak displacement over the tail
    frequency_hz: float  # dominant frequency of x over the tail (0 for decay)
    n_peaks: int

    @property
    def label(self) -> str:
        if self.kind == "periodic":
            return "periodic" if self.period == 1 else f"period-{self.period}"
        return self.kind

    @property
    def settled(self) -> bool:
        return self.kind == "decay"


def classify_motion(result: SimResult, *, tail: float = 0.4, tol: float = 0.02, max_period: int = 8,
                    settled_mm_s: float = SETTLED_MM_S) -> Motion:
    """Classify the last `tail` fraction of a run.

    Vibration is measured in the severity band (10-1000 Hz), so a slow approach to the set-point
    does not count. The tail is a decay if its vibration is below `settled_mm_s` or still
    shrinking (second half below DECAY_RATIO x the first); otherwise the peak map of the
    detrended displacement decides: k repeating maximum levels (within tol x peak-to-peak) =
    period-k, no repeating pattern up to `max_period` = quasi-periodic.
    """
    instance("result", result, SimResult, "a SimResult (plant.integrate.simulate)")
    tail = real("tail", tail, lo=0.0, hi=1.0, lo_open=True)
    tol = real("tol", tol, lo=0.0, lo_open=True)
    max_period = integer("max_period", max_period, lo=1, hi=64)
    settled_mm_s = real("settled_mm_s", settled_mm_s, lo=0.0)
    if result.diverged:
        return Motion("diverged", 0, float("nan"), float("nan"), 0)
    n = len(result.x)
    x = result.x[int(n * (1 - tail)):]
    fs = 1.0 / result.dt
    half = x.size // 2
    if half < 8:
        raise ValueError(f"t_end = {result.t[-1]:.3g} s is too short to classify the motion: its last {tail:.0%} "
                         f"must hold at least 16 samples (t_end >= {16 / (tail * fs):.3g} s at {fs:.0f} Hz)")
    # the severity band, its low edge raised where the tail's halves are shorter than 0.1 s
    band = (max(10.0, fs / half), 1000.0)
    vib = vibration_severity(x, fs, quantity="displacement", band=band)
    shrinking = (vibration_severity(x[half:], fs, quantity="displacement", band=band)
                 < DECAY_RATIO * vibration_severity(x[:half], fs, quantity="displacement", band=band))
    xb = ssig.detrend(x)
    ptp = float(np.ptp(xb))
    spec = np.abs(np.fft.rfft(xb * np.hanning(xb.size)))
    freq = float(np.fft.rfftfreq(xb.size, 1.0 / fs)[np.argmax(spec[1:]) + 1])
    if vib < settled_mm_s or shrinking:
        return Motion("decay", 0, ptp / 2, 0.0, 0)
    peaks, _ = ssig.find_peaks(xb, prominence=0.05 * ptp)
    maxima = xb[peaks][1:-1]  # the first and last may be cut by the window
    for k in range(1, max_period + 1):
        m = (maxima.size // k) * k
        if m < 3 * k:
            break
        groups = maxima[:m].reshape(-1, k)
        if np.all(np.ptp(groups, axis=0) < tol * ptp):
            return Motion("periodic", k, ptp / 2, freq, int(maxima.size))
    return Motion("quasi-periodic", 0, ptp / 2, freq, int(maxima.size))
