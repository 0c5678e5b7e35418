"""Point numba's on-disk cache at a folder keyed by a hash of this package's source.

numba's `cache=True` invalidates a cached function when its own file changes, but not when a
function it calls in another module changes (the integration kernels call `plant_rhs` in
another file). Keying the cache folder by a hash of the package's compiled modules (those with
@njit, plus params.py, which fixes the parameter vector's layout) means an edit to any compiled
code recompiles everything once and a stale kernel is never loaded. The compile cost is then
paid once per source version, not per process. Versions keep their own folders (two installed
versions never delete each other's cache); folders unused for 30 days are pruned. Where the home
folder cannot be written (a read-only install in a container), the cache goes to a folder under
the system's temporary directory, with a one-line notice. The process that creates a version's folder
says, in one line on stderr, that its first simulation compiles (about a minute, once).
Set NUMBA_CACHE_DIR yourself to override.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

STALE_DAYS = 30


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
    name = f"numba-{digest.hexdigest()[:16]}"
    target = None
    for root in _candidate_roots():
        fresh = not (root / name).exists()
        if not writable_folder(root / name):
            continue
        target = root / name
        os.utime(target)  # marks this version's cache as in use (see _prune)
        if root != _home_root():
            print(f"millvib-env: {_home_root()} is not writable; compiled code is cached in {target}",
                  file=sys.stderr)
        if fresh:  # the first process of this version: say why its first simulation waits
            print(f"millvib-env: first run of this version: the plant kernels compile on first use (about a minute, "
                  f"once; cached in {target})", file=sys.stderr)
        _prune(root, keep=target)
        break
    if target is None:
        print("millvib-env: no writable cache folder; numba compiles in every process", file=sys.stderr)
        return
    os.environ["NUMBA_CACHE_DIR"] = str(target)
    if "numba" in sys.modules:  # imported before us: tell its live config too
        sys.modules["numba"].config.CACHE_DIR = str(target)


def writable_folder(folder: Path) -> bool:
    """Make `folder` (and its parents) and check that a file can be written in it."""
    try:
        folder.mkdir(parents=True, exist_ok=True)
        probe = folder / ".write-test"
        probe.write_text("")
        probe.unlink()
    except OSError:
        return False
    return True


def _home_root() -> Path:
    try:
        home = Path.home()
    except (RuntimeError, KeyError):
        home = Path("/nonexistent")
    return Path(os.environ.get("XDG_CACHE_HOME") or home / ".cache") / "millvib-env"


def _candidate_roots() -> list[Path]:
    user = os.environ.get("USER") or str(os.getuid() if hasattr(os, "getuid") else "user")
    return [_home_root(), Path(tempfile.gettempdir()) / f"millvib-env-{user}"]


def _prune(root: Path, keep: Path, prefix: str = "numba-") -> None:
    """Remove other versions' cache folders (`prefix`*) that have not been used for STALE_DAYS."""
    cutoff = time.time() - STALE_DAYS * 86400
    for old in root.glob(f"{prefix}*"):
        try:
            if old != keep and old.stat().st_mtime < cutoff:
                shutil.rmtree(old, ignore_errors=True)
        except OSError:
            pass
