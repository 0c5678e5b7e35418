"""Episode-end levels of the acceleration records: the severity over the whole record, its first part and the rest,
the pump line's and the 10-100 Hz band's levels (`MillVibCore.episode_metrics_batch`)."""

from __future__ import annotations

import math

import numpy as np

from millvib_env.severity import band_levels_rows, vibration_severity_rows
from millvib_env.threads import numba_threads, use_threads

__all__ = ["record_levels"]


def record_levels(records: list[np.ndarray], fs: float, line_hz: np.ndarray, split: int) -> dict[str, np.ndarray]:
    """Each record's levels (mm/s): "broadband", "pump_line" (at its `line_hz`), "low_band", "start" (its first
    `split` samples) and "rest". Records of equal length are transformed together, on the plant threads
    (`threads.use_threads`): the same numbers as one record at a time. A record with NaN or inf, or too short for
    the band (an episode that ended at once), keeps inf."""
    inf = math.inf
    levels = {k: np.full(len(records), inf) for k in ("broadband", "pump_line", "low_band", "start", "rest")}
    for length in {r.size for r in records}:
        rows = np.array([j for j, r in enumerate(records) if r.size == length])
        acc = np.stack([records[j] for j in rows])
        finite = np.isfinite(acc).all(axis=1)
        if not finite.all():  # a record with NaN or inf has no severity: it keeps inf
            rows, acc = rows[finite], acc[finite]
        if not rows.size:
            continue
        workers = numba_threads() if use_threads(len(rows), "metrics") else 1
        try:  # a record too short for the band (an episode that ended at once) keeps inf
            parts = band_levels_rows(acc, fs, line_hz=line_hz[rows], workers=workers)
            for key in ("broadband", "pump_line", "low_band"):
                levels[key][rows] = parts[key]
            levels["start"][rows] = vibration_severity_rows(acc[:, :split], fs, workers=workers)
            levels["rest"][rows] = vibration_severity_rows(acc[:, split - 1:], fs, workers=workers)
        except ValueError:
            pass
    return levels
