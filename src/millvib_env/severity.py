"""Vibration severity: an ISO 20816-3-style broadband velocity RMS (10-1000 Hz), its zone, and bands.

The paper scores every case by its "vibration intensity", computed with an improved
frequency-domain integral method based on low-frequency filtering. We implement that measure
as ISO 20816-3:2022 (which replaced ISO 10816-3) defines the evaluation quantity: the RMS of
vibration velocity, in mm/s, over 10-1000 Hz. It is "ISO-style": the standard measures on a
machine's bearing housings, we on the piston of the screw-down cylinder, so the zones
(configs/severity.yaml, with the machine group and support they assume) grade the number as a
plant engineer would read it, not as a certification. `band_levels` also gives the level of the
pump line (the pulsation frequency and its harmonics) and of the 10-100 Hz band. An acceleration
signal is integrated in the frequency domain (its spectrum divided by j*omega) and every bin outside
the band is zeroed: the low-frequency cut removes the drift that time-domain integration accumulates,
the high cut removes hiss. The RMS then follows from Parseval's theorem over the retained bins.

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

The mirror image has the same mean square as the record, so no window correction is needed. The
extension's spectrum is computed as the record's n-point DCT-II (DST-II for the odd extension) times a
phase factor: the same bins as an FFT of the 2n samples, within rounding, in a third of the time.

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
from scipy import fft as sfft

from millvib_env._checks import as_float, band as checked_band, choice, real, shown, shown_path
from millvib_env._paths import config_dir
from millvib_env._yaml import load_yaml

__all__ = ["vibration_severity", "vibration_severity_rows", "band_velocity_spectrum", "band_levels",
           "band_levels_rows", "iso_zone", "IsoZoneTable", "iso_table"]

Quantity = Literal["acceleration", "velocity", "displacement"]
#: power of j*omega that turns each quantity's spectrum into velocity
_POWER = {"acceleration": -1, "velocity": 0, "displacement": 1}


def severity_band() -> tuple[float, float]:
    """The severity's frequency band (Hz), `band_hz` of configs/severity.yaml (ISO 20816-3: 10-1000 Hz),
    the default of every function here, of the environments' reward filter and of `SimResult.severity`."""
    return _load_severity_config()["band"]


def _resolved_band(band: tuple[float, float] | None, name: str = "band") -> tuple[float, float]:
    """`band` checked, or the configured severity band where it is None."""
    return checked_band(name, band) or severity_band()


def _check_signal(signal: np.ndarray, fs: float, band: tuple[float, float] | None, quantity: str,
                  band_name: str = "band", rows: bool = False) -> tuple[np.ndarray, tuple[float, float]]:
    """The record (or, with `rows`, a 2-D array of equally long records, one per row) as a float array
    and the band it is measured in, both checked against each other."""
    if isinstance(fs, bool) or not isinstance(fs, (int, float, np.integer, np.floating)) \
            or not math.isfinite(as_float(fs)) or fs <= 0:
        raise ValueError(f"fs = {shown(fs)} is invalid: the sampling rate in Hz, a finite number > 0")
    what = "a 2-D array of numbers, one record per row" if rows else "a 1-D array of numbers"
    try:
        x = np.asarray(signal, dtype=np.float64)
    except (TypeError, ValueError, OverflowError):
        raise ValueError(f"signal = {str(signal)[:40]!r} is invalid: {what}") from None
    if x.ndim != (2 if rows else 1):
        raise ValueError(f"signal must be {2 if rows else 1}-D, got shape {x.shape}")
    choice("quantity", quantity, sorted(_POWER))
    n = x.shape[-1]
    if n < 8:
        raise ValueError(f"signal has {n} samples; at least 8 are needed")
    if not np.all(np.isfinite(x)):
        raise ValueError("signal contains NaN or inf (a diverged simulation has no severity)")
    return x, _band_for_record(n, fs, band, band_name)


def _band_for_record(n: int, fs: float, band: tuple[float, float] | None, band_name: str = "band") \
        -> tuple[float, float]:
    """`band` (or the configured one) checked against a record of n samples at fs Hz."""
    lo, hi = _resolved_band(band, band_name)
    if hi > fs / 2:
        raise ValueError(f"band upper edge {hi} Hz is above the Nyquist frequency {fs / 2} Hz (fs = {fs} Hz)")
    duration = n / fs
    if lo > 0 and duration < 1.0 / lo - 0.5 / fs:
        raise ValueError(f"record of {n} samples ({duration:.4g} s at {fs:g} Hz) is too short for the band's "
                         f"low edge {lo:g} Hz: at least one period, {1.0 / lo:.4g} s, is needed")
    if hi - lo < 1.0 / duration:
        raise ValueError(f"band = {shown(band)} Hz is narrower than the record's frequency resolution allows: a "
                         f"{duration:.4g} s record needs a band at least {1.0 / duration:.4g} Hz wide")
    return lo, hi


def _detrended(x: np.ndarray, fs: float, quantity: str) -> np.ndarray:
    """The records (rows of `x`), trend-corrected (module docstring): their mirror extension to 2n samples,
    odd for a velocity and even otherwise, is smooth."""
    n = x.shape[-1]
    t = np.arange(n) / fs
    span = t[-1]
    if quantity == "velocity":
        return x - (x[:, :1] + (x[:, -1:] - x[:, :1]) * t / span)
    if quantity == "acceleration":
        return x - x.mean(axis=1, keepdims=True)
    v0 = (x[:, 1:2] - x[:, :1]) * fs
    v1 = (x[:, -1:] - x[:, -2:-1]) * fs
    y = x - (v0 * t + (v1 - v0) * t * t / (2.0 * span))
    y -= y.mean(axis=1, keepdims=True)
    return y


def _extension_bins(y: np.ndarray, odd: bool, bins: np.ndarray, workers: int = 1) -> np.ndarray:
    """Bins `bins` (0 <= k <= n) of the real FFT of the rows' mirror extensions to 2n samples, [y, y reversed]
    (even) or [y, -y reversed] (odd), from the n-point DCT-II or DST-II of y: with theta_k = pi k / (2 n),
    X_k = exp(i theta_k) DCT-II(y)_k and X_k = -i exp(i theta_k) DST-II(y)_(k-1) (scipy's unnormalised
    transforms; X_0 of an odd and X_n of an even extension are 0). The same numbers as `sfft.rfft` of the
    extension in exact arithmetic, within rounding in floating point (tests/test_severity.py), and
    faster at the environments' record lengths, 10,001 and 9,001 samples, whose extensions' lengths
    (2 x 73 x 137, 2 x 9001) are slow for an FFT (docs/performance.md)."""
    n = y.shape[1]
    twiddle = np.exp(1j * np.pi * bins / (2 * n))
    out = np.zeros((y.shape[0], bins.size), dtype=complex)
    if odd:
        inside = bins >= 1
        coef = sfft.dst(y, type=2, axis=1, workers=workers)
        out[:, inside] = coef[:, bins[inside] - 1] * (-1j * twiddle[inside])
    else:
        inside = bins < n
        coef = sfft.dct(y, type=2, axis=1, workers=workers)
        out[:, inside] = coef[:, bins[inside]] * twiddle[inside]
    return out


@dataclass(frozen=True)
class _BandSpectra:
    """One-sided velocity spectra of records over their 2n-sample mirror extension, kept on the band's bins (the
    rest are zero): `freqs` (Hz) and `vel` (rows) of those bins, the first one's index `first`, each bin's
    Parseval `weight` (2, or 1 for Nyquist; DC is never in a band) and the extension's length `n2` = 2n."""

    freqs: np.ndarray
    vel: np.ndarray
    weight: np.ndarray
    n2: int
    first: int

    def mean_square(self, mask: np.ndarray | None = None) -> np.ndarray:
        """Each row's mean square (Parseval) over the kept bins, or over those of them where `mask` (per bin, or
        per row and bin) is True."""
        power = np.abs(self.vel) ** 2
        if mask is not None:
            power = np.where(mask, power, 0.0)
        return np.sum(self.weight * power, axis=-1) / self.n2**2


def _velocity_spectra(x: np.ndarray, fs: float, quantity: str, band: tuple[float, float],
                      workers: int = 1) -> _BandSpectra:
    """Band-limited one-sided velocity spectra of checked records (rows of `x`) over the 2n-sample mirror
    extension's bins (the band's bins are one run; `_BandSpectra`): the one computation behind every severity
    figure. One transform over all rows (`workers` threads of scipy.fft), computed as a DCT-II or DST-II of the
    records (`_extension_bins`)."""
    y = _detrended(x, fs, quantity)
    n = y.shape[1]
    freqs = sfft.rfftfreq(2 * n, d=1.0 / fs)
    keep = np.flatnonzero((freqs >= band[0]) & (freqs <= band[1]) & (freqs > 0))
    bins = np.arange(keep[0], keep[-1] + 1) if keep.size else keep
    weight = np.where(bins == n, 1.0, 2.0)  # interior bins count twice, Nyquist (bin n) once; DC is never kept
    vel = _extension_bins(y, quantity == "velocity", bins, workers)
    if bins.size:
        vel *= (2j * np.pi * freqs[bins]) ** _POWER[quantity]
    return _BandSpectra(freqs[bins], vel, weight, 2 * n, int(bins[0]) if bins.size else 0)


def band_velocity_spectrum(signal: np.ndarray, fs: float, *, quantity: Quantity = "acceleration",
                           band: tuple[float, float] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """One-sided velocity spectrum of the extended record (2n samples), restricted to `band`.

    Returns (frequencies Hz, V_k); bins outside the band are zero. Acceleration is divided by
    j*omega, displacement multiplied by it.
    """
    x, band = _check_signal(signal, fs, band, quantity)
    spectra = _velocity_spectra(x[None, :], fs, quantity, band)
    freqs = sfft.rfftfreq(spectra.n2, d=1.0 / fs)
    out = np.zeros(freqs.size, dtype=complex)
    out[spectra.first:spectra.first + spectra.freqs.size] = spectra.vel[0]
    return freqs, out


def vibration_severity(signal: np.ndarray, fs: float, *, quantity: Quantity = "acceleration",
                       band: tuple[float, float] | None = None) -> float:
    """Vibration severity in mm/s: RMS of the band-limited vibration velocity.

    Parameters
    ----------
    signal : 1-D array in SI units: m/s^2 (acceleration), m/s (velocity) or m (displacement),
        sampled uniformly at `fs`.
    fs : sampling rate in Hz; the band's upper edge must be at or below fs/2.
    quantity : what `signal` is.
    band : (low, high) Hz; ISO 20816-3 uses 10-1000 Hz for machines above 600 rpm.
    """
    x, band = _check_signal(signal, fs, band, quantity)
    return 1000.0 * math.sqrt(_velocity_spectra(x[None, :], fs, quantity, band).mean_square()[0])


def vibration_severity_rows(records: np.ndarray, fs: float, *, quantity: Quantity = "acceleration",
                            band: tuple[float, float] | None = None, workers: int = 1) -> np.ndarray:
    """`vibration_severity` of every row of a 2-D array of equally long records (mm/s, one per row),
    in one transform on `workers` threads: the same numbers as one call per row, at a fraction of
    the cost (the environments score all episodes that end together this way)."""
    x, band = _check_signal(records, fs, band, quantity, rows=True)
    return 1000.0 * np.sqrt(_velocity_spectra(x, fs, quantity, band, _checked_workers(workers)).mean_square())


def _line_per_row(line_hz, rows: int) -> np.ndarray:
    """`line_hz` (Hz, >= 0): one frequency for every row, or a sequence of one per row."""
    if isinstance(line_hz, (str, bytes, dict)) or not hasattr(line_hz, "__len__") or np.ndim(line_hz) == 0:
        return np.full(rows, real("line_hz", line_hz, lo=0.0))
    if len(line_hz) != rows:
        raise ValueError(f"line_hz has {len(line_hz)} values for {rows} records: one frequency in Hz, or one per "
                         "record")
    return np.array([real(f"line_hz[{k}]", f, lo=0.0) for k, f in enumerate(line_hz)])


#: the most threads a severity transform takes (scipy.fft's workers)
MAX_WORKERS = 1024


def _checked_workers(workers: int) -> int:
    if isinstance(workers, bool) or not isinstance(workers, (int, np.integer)) or not 1 <= workers <= MAX_WORKERS:
        raise ValueError(f"workers = {shown(workers)} is invalid: a number of threads in [1, {MAX_WORKERS}]")
    return int(workers)


def band_levels(signal: np.ndarray, fs: float, *, quantity: Quantity = "acceleration",
                line_hz: float = 115.5, band: tuple[float, float] | None = None,
                low_band: tuple[float, float] = (10.0, 100.0), line_width_hz: float | None = None) -> dict[str, float]:
    """Velocity RMS (mm/s) of a record: broadband (`band`), the pump line and the low band.

    * ``broadband``: `vibration_severity` over `band`;
    * ``pump_line``: the bins within +-`line_width_hz` (default: 3 Hz or two bins of the record's
      resolution, whichever is wider) of line_hz and its harmonics inside `band` (the pump
      pulsation and what it drives);
    * ``low_band``: `low_band` (10-100 Hz: roll eccentricity, the loop's slow modes).

    The squares of the parts are parts of the broadband square (the line and the low band overlap
    only if line_hz < 100 Hz).
    """
    x, _ = _check_signal(signal, fs, band, quantity)
    levels = band_levels_rows(x[None, :], fs, quantity=quantity, line_hz=line_hz, band=band, low_band=low_band,
                              line_width_hz=line_width_hz)
    return {k: float(v[0]) for k, v in levels.items()}


def band_levels_rows(records: np.ndarray, fs: float, *, quantity: Quantity = "acceleration",
                     line_hz: float | np.ndarray = 115.5, band: tuple[float, float] | None = None,
                     low_band: tuple[float, float] = (10.0, 100.0), line_width_hz: float | None = None,
                     workers: int = 1) -> dict[str, np.ndarray]:
    """`band_levels` of every row of a 2-D array of equally long records, in one transform on
    `workers` threads; `line_hz` is one frequency or one per row. Returns arrays, one value per row."""
    x, band = _check_signal(records, fs, band, quantity, rows=True)
    if low_band is None:
        raise ValueError("low_band = None is invalid: a (low, high) pair in Hz with 0 <= low < high")
    low_band = _band_for_record(x.shape[1], fs, checked_band("low_band", low_band), "low_band")
    lines = _line_per_row(line_hz, x.shape[0])
    n = 2 * x.shape[1]
    resolution = fs / n
    if line_width_hz is None:
        line_width_hz = max(3.0, 2.0 * resolution)
    line_width_hz = real("line_width_hz", line_width_hz, lo=0.0, lo_open=True)
    if line_width_hz < resolution:
        raise ValueError(f"line_width_hz = {line_width_hz} Hz is below the record's resolution {resolution:.3g} Hz")
    unresolved = lines[(lines > 0) & (lines < resolution)]
    if unresolved.size:  # harmonics closer than one spectral bin, and band / line_hz of them
        raise ValueError(f"line_hz = {unresolved[0]:.6g} Hz is invalid: 0 (no line) or at least the record's "
                         f"resolution {resolution:.3g} Hz")
    spectra = _velocity_spectra(x, fs, quantity, band, _checked_workers(workers))
    freqs = spectra.freqs
    on_line = np.zeros(spectra.vel.shape, dtype=bool)
    for line in np.unique(lines):
        harmonics = np.arange(1, int(band[1] // line) + 1) * line if line > 0 else np.array([])
        mask = np.zeros(freqs.size, dtype=bool)
        for f in harmonics:
            mask |= np.abs(freqs - f) <= line_width_hz
        on_line[lines == line] = mask
    low = (freqs >= low_band[0]) & (freqs <= low_band[1])
    return {"broadband": 1000.0 * np.sqrt(spectra.mean_square()),
            "pump_line": 1000.0 * np.sqrt(spectra.mean_square(on_line)),
            "low_band": 1000.0 * np.sqrt(spectra.mean_square(low))}


@dataclass(frozen=True)
class IsoZoneTable:
    """Zone boundaries (mm/s) A/B, B/C, C/D of one machine class, with the source named."""

    name: str
    boundaries_mm_s: tuple[float, float, float]
    source: str
    description: str = ""

    def zone(self, severity_mm_s: float) -> str:
        if isinstance(severity_mm_s, bool) or not isinstance(severity_mm_s, (int, float, np.integer, np.floating)) \
                or not math.isfinite(as_float(severity_mm_s)) or severity_mm_s < 0:
            raise ValueError(f"severity_mm_s = {shown(severity_mm_s)} is invalid: must be finite and >= 0")
        ab, bc, cd = self.boundaries_mm_s
        if severity_mm_s <= ab:
            return "A"
        if severity_mm_s <= bc:
            return "B"
        if severity_mm_s <= cd:
            return "C"
        return "D"


def _bad(key: str, value, allowed: str) -> ValueError:
    return ValueError(f"configs/severity.yaml {key} = {value!r} is invalid: {allowed}")


def _finite(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(as_float(v))


@lru_cache(maxsize=None)
def _load_severity_config() -> dict:
    """configs/severity.yaml, every value checked (a wrong zone boundary would grade silently wrong)."""
    path = config_dir() / "severity.yaml"
    data = load_yaml(path, "severity config")  # unreadable, broken, or a !!python tag: one line
    if not isinstance(data, dict):
        raise ValueError(f"{shown_path(path)} must be a mapping with keys source, band_hz, default_class, zones")
    source = data.get("source", "")
    if not isinstance(source, str):
        raise _bad("source", source, "a text naming the standard")
    band = data.get("band_hz")
    if not (isinstance(band, list) and len(band) == 2 and all(_finite(b) for b in band) and 0 < band[0] < band[1]):
        raise _bad("band_hz", band, "a [low, high] pair in Hz with 0 < low < high")
    zones = data.get("zones")
    if not isinstance(zones, dict) or not zones:
        raise _bad("zones", zones, "a mapping of machine classes, each with boundaries_mm_s")
    tables = {}
    for name, t in zones.items():
        b = t.get("boundaries_mm_s") if isinstance(t, dict) else None
        if not (isinstance(b, list) and len(b) == 3 and all(_finite(v) for v in b) and 0 < b[0] < b[1] < b[2]):
            raise _bad(f"zones.{name}.boundaries_mm_s", b, "three boundaries A/B, B/C, C/D in mm/s, finite, > 0 "
                                                           "and increasing")
        description = t.get("description", "")
        if not isinstance(description, str):
            raise _bad(f"zones.{name}.description", description, "a text")
        tables[name] = IsoZoneTable(str(name), (float(b[0]), float(b[1]), float(b[2])), source, description)
    default = data.get("default_class")
    if not isinstance(default, str) or default not in tables:
        raise _bad("default_class", default, f"one of the zones {sorted(tables)}")
    return {"band": (float(band[0]), float(band[1])), "default": default, "source": source, "tables": tables}


def _load_iso_tables() -> tuple[str, str, dict[str, IsoZoneTable]]:
    cfg = _load_severity_config()
    return cfg["default"], cfg["source"], cfg["tables"]


def iso_table(name: str | None = None) -> IsoZoneTable:
    """The ISO 20816-3 zone table `name` from configs/severity.yaml (default: its default_class)."""
    default, _, tables = _load_iso_tables()
    key = default if name is None else choice("machine_class", name, sorted(tables))
    if key not in tables:
        raise ValueError(f"ISO machine class {shown(key)} unknown; available: {sorted(tables)}")
    return tables[key]


def iso_zone(severity_mm_s: float, machine_class: str | None = None) -> str:
    """ISO 20816-3 zone ('A', 'B', 'C' or 'D') of a severity in mm/s (configs/severity.yaml's class)."""
    return iso_table(machine_class).zone(severity_mm_s)
