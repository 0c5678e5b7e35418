"""The `millvib` command's launcher, a package of its own so that nothing heavy loads before it.

Importing `millvib_env` loads numpy, numba and Gymnasium (half a second idle, several seconds on a busy
machine). A Ctrl-C or SIGTERM in that window would end in the interpreter's traceback if the command
started inside the package. The launcher catches it first and says so in one line. After the command,
an interrupted run leaves at once (`os._exit`, streams flushed, exit handlers run): its temporary result folders were
removed while the exception unwound, and the interpreter's own shutdown (torch, numba) can take over a
second on a busy machine. `millvib_env.cli.main` stays the API: it returns a status and never exits.
"""
from __future__ import annotations

import os
import signal
import sys

INTERRUPTED, TERMINATED = 130, 143  # 128 + SIGINT, 128 + SIGTERM: what a shell reports for either


def _leave(status: int) -> None:
    _finished()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):  # a closed pipe: nothing more can be said
            pass
    import atexit

    try:  # what the run registered to do at exit (multiprocessing's clean-up, Ray's shutdown): milliseconds
        atexit._run_exitfuncs()
    except Exception:  # noqa: BLE001 (a handler's failure must not turn an interrupt into a traceback)
        pass
    os._exit(status)


def _process_defaults() -> None:
    """Settings a command's process takes before numpy loads, each unless the user set it.

    ``NUMPY_MADVISE_HUGEPAGE=0``: numpy asks the kernel for huge pages on every array of 4 MB or more, and where
    the kernel's transparent huge pages are on request with compaction on request (the setting of many Linux
    machines), a fault in such an array may compact memory first. The commands write their large arrays (a map's
    runs: 141 MB for `reproduce`'s motion map) once and read them a few times: on this project's 2-core machine
    that array cost far more kernel time with huge pages than without (docs/performance.md).

    ``OPENBLAS_NUM_THREADS=1``: numpy's BLAS multiplies matrices of at most a few hundred rows here (the MPC's
    condensed QP, linearisations, Riccati equations), where a second thread gives nothing, and once woken it spins
    on the other core (a measurable part of the main job's CPU time: docs/performance.md), and in worker processes
    (`--jobs`, which inherit the setting) it takes the cores the other workers run on. The plant's threads are
    numba's and torch's own."""
    os.environ.setdefault("NUMPY_MADVISE_HUGEPAGE", "0")
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")


def main() -> int:
    got = []
    _process_defaults()

    def _terminated(signum, frame):
        got.append(signum)
        raise KeyboardInterrupt

    try:
        signal.signal(signal.SIGTERM, _terminated)
        from millvib_env.cli import main as run
    except KeyboardInterrupt:
        print(f"millvib: {'terminated' if got else 'interrupted'} while loading", file=sys.stderr)
        _leave(TERMINATED if got else INTERRUPTED)
    status = run()
    _finished()  # a finished command ignores a late signal
    if status in (INTERRUPTED, TERMINATED):
        _leave(status)
    _skip_final_collection()
    return status


def _finished() -> None:
    """The command has ended and said so: a Ctrl-C or SIGTERM from now on is ignored, since its result is whole (or
    its line is printed) and the exit takes milliseconds. Without this, one that arrived while the interpreter shut
    down (its handlers reset to the default by then) killed the process without a word, exit -2, after a
    successful run."""
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, signal.SIG_IGN)


def _skip_final_collection() -> None:
    """Leave the objects a finished command holds out of the interpreter's shutdown collections.

    At exit Python clears every module and then runs its cyclic garbage collector over everything still alive:
    numba's, scipy's and matplotlib's objects, 0.3-0.5 s after `millvib reproduce` or a benchmark here, a sixth of
    the main job (docs/performance.md). Frozen (`gc.freeze`), they are not traversed: the modules are still cleared
    and what the run registered at exit (multiprocessing's clean-up, Ray's shutdown) still runs first; only objects
    in reference cycles are left to the process's end, as `os._exit` would leave them all. The command's files are
    written and closed before it returns."""
    import gc

    gc.freeze()
