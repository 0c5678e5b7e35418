"""Point numba's on-disk cache at a folder keyed by a hash of this package's source.

numba's `cache=True` invalidates a cached function when its own file changes, but not when a
function it calls in another module changes (the integration kernels call `plant_rhs` in
another file). Keying the cache folder by a hash of the package's compiled modules (those with
@njit, plus params.py, which fixes the parameter vector's layout) means an edit to any compiled
code recompiles everything once and a stale kernel is never loaded. The compile cost is then
paid once per source version, not per process.
Set NUMBA_CACHE_DIR yourself to override.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import sys
from pathlib import Path


def configure() -> None:
    if os.environ.get("NUMBA_CACHE_DIR"):
        return
    pkg = Path(__file__).resolve().parent
    digest = hashlib.sha1()
    for path in sorted(pkg.rglob("*.py")):
        source = path.read_bytes()
        if b"@njit" in source or path.name == "params.py":  # params fixes the vector layout
            digest.update(path.relative_to(pkg).as_posix().encode())
            digest.update(source)
    root = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "millvib-env"
    target = root / f"numba-{digest.hexdigest()[:16]}"
    try:
        target.mkdir(parents=True, exist_ok=True)
        for old in root.glob("numba-*"):
            if old != target:
                shutil.rmtree(old, ignore_errors=True)
    except OSError:
        return  # unwritable home: numba falls back to its own default locations
    os.environ["NUMBA_CACHE_DIR"] = str(target)
    if "numba" in sys.modules:  # imported before us: tell its live config too
        sys.modules["numba"].config.CACHE_DIR = str(target)
