"""JAX's persistent compilation cache for the sbx learners, beside numba's (`_numba_cache`).

sbx compiles its networks' initialisation, prediction and update steps in every process: a short
`millvib train --algo sac` (sbx, the shipped config) spends a third of its CPU time on them when every
compilation is made afresh (docs/performance.md). JAX keeps what it compiled on disk and
loads it in the next process (`jax_compilation_cache_dir`); it keys each entry by the computation,
JAX's version, the backend and the XLA flags, so a run gives the same bytes whether the cache was
cold or warm. JAX keeps only compilations slower than a second by default; sbx's are many small
ones, so every one is kept here. Folders are per JAX version and processor (an executable compiled
for one processor's instructions is never loaded on another that shares the home folder), bounded
in size (least recently used entries go first) and pruned after 30 days unused, as numba's are.
Set ``JAX_COMPILATION_CACHE_DIR`` (or ``JAX_ENABLE_COMPILATION_CACHE=false``) yourself to override.

Called by `catalog.agents.algo_class` before sbx (and so JAX) is imported: JAX reads these settings
from the environment once, at import. Where JAX was imported first, nothing is changed.
"""

from __future__ import annotations

import hashlib
import importlib.metadata
import os
import platform
import sys

from millvib_env._numba_cache import _candidate_roots, _prune, writable_folder

#: bytes: the cache's bound (the test suite's SACs and PPOs take about 1 MB)
MAX_BYTES = 256 * 2**20


def configure() -> None:
    if "jax" in sys.modules or "JAX_COMPILATION_CACHE_DIR" in os.environ:
        return  # too late to set from the environment, or the user's own choice
    try:
        version = importlib.metadata.version("jax")
    except importlib.metadata.PackageNotFoundError:
        return
    name = f"jax-{version}-{_cpu_key()}"
    for root in _candidate_roots():
        if not writable_folder(root / name):
            continue
        os.utime(root / name)  # in use (see _prune)
        _prune(root, keep=root / name, prefix="jax-")
        os.environ["JAX_COMPILATION_CACHE_DIR"] = str(root / name)
        os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0")
        os.environ.setdefault("JAX_COMPILATION_CACHE_MAX_SIZE", str(MAX_BYTES))
        return


def _cpu_key() -> str:
    """A short hash of the processor: its architecture and, on Linux, its model and instruction-set flags."""
    text = platform.machine()
    try:
        with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as f:
            for line in f:
                if line.startswith(("model name", "flags", "Features")):
                    text += line
                if line.strip() == "":
                    break  # the first processor's block is enough
    except OSError:
        pass
    return hashlib.sha1(text.encode()).hexdigest()[:8]
