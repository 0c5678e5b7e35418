"""Butterworth designs (`scipy.signal.butter`, second-order sections), each made by scipy once per machine.

An environment's reward band-passes the velocity (`envs.reward.Reward`) and the adaptive PID high-passes its
regression (`control.adaptive`), each with a second-order Butterworth filter that scipy designs. Importing
`scipy.signal` costs more than making the environment (scipy 1.17 builds its functions' docstrings at import;
docs/performance.md), and every new process (a CLI command, a worker, a test's subprocess) paid it again.

`butter_sos` keeps each design in this version's cache folder (`_numba_cache`, beside the compiled kernels): the
float64 array scipy returned, bit for bit, in a file named by a hash of the design's arguments, of this module's
`FORMAT`, of scipy's and numpy's versions and of the CPU features numpy dispatches to (which can move a
transcendental function's last bit). A process that finds the file reads it (`np.load`, no pickles) and never
imports `scipy.signal`; one that does not asks scipy and writes the file atomically. Where no cache folder is set,
or it cannot be written, scipy designs it in every process, as before.
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

import numpy as np

from millvib_env._paths import atomic_path

__all__ = ["butter_sos"]

#: the kept files' format and `_design`'s arguments: part of every file's name, so a change to either (raise it)
#: never reads a file an earlier version wrote
FORMAT = 1
#: designs made or read in this process: (order, band, btype, fs) -> sos
_MEMO: dict[tuple, np.ndarray] = {}


def butter_sos(order: int, wn: float | tuple[float, ...], btype: str, fs: float) -> np.ndarray:
    """``scipy.signal.butter(order, wn, btype=btype, fs=fs, output="sos")`` as a C-contiguous float64 array (a
    fresh copy each call), the same bits scipy gives on this machine (module docstring)."""
    band = tuple(float(w) for w in np.atleast_1d(wn))
    key = (int(order), band, str(btype), float(fs))
    sos = _MEMO.get(key)
    if sos is None:
        sos = _MEMO[key] = _read_or_design(key)
    return sos.copy()


def _design(key: tuple) -> np.ndarray:
    from scipy import signal

    order, band, btype, fs = key
    return np.ascontiguousarray(signal.butter(order, band[0] if len(band) == 1 else list(band), btype=btype,
                                              fs=fs, output="sos"), dtype=np.float64)


def _file(key: tuple) -> Path | None:
    folder = os.environ.get("NUMBA_CACHE_DIR")
    if not folder:
        return None
    import scipy

    try:
        from numpy._core._multiarray_umath import __cpu_features__ as features
    except ImportError:  # another numpy's layout: the versions alone
        features = {}
    text = repr((FORMAT, key, scipy.__version__, np.__version__, sorted(k for k, on in features.items() if on)))
    return Path(folder) / "filters" / f"butter-{hashlib.sha256(text.encode()).hexdigest()[:24]}.npy"


def _read_or_design(key: tuple) -> np.ndarray:
    path = _file(key)
    if path is not None:
        try:
            sos = np.load(path, allow_pickle=False)
            if sos.dtype == np.float64 and sos.ndim == 2 and sos.shape[1] == 6 and np.all(np.isfinite(sos)):
                return np.ascontiguousarray(sos)
        except (OSError, ValueError):
            pass  # absent, or damaged: designed again and rewritten below
    sos = _design(key)
    if path is not None:
        try:
            with atomic_path(path) as tmp:
                with open(tmp, "wb") as f:
                    np.save(f, sos, allow_pickle=False)
        except OSError:
            pass  # a read-only cache: scipy designs it in every process
    return sos
