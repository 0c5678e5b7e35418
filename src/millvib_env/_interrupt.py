"""A Ctrl-C or SIGTERM that a library cannot swallow.

Python raises KeyboardInterrupt wherever the main thread is when the signal's handler runs. Inside a library's
callback (llvmlite while numba compiles, a solver's C loop) the exception can be caught and dropped, and the run
would go on to write its result (where Python drops it, in a weakref's or the garbage collector's callback, it
prints the traceback as an "Exception ignored": the command's `sys.unraisablehook` leaves that out, since the
signal is acted on anyway). The `millvib` command installs `handler`, which records the signal before it
raises, and the places that matter ask `check`: every environment step (so a run ends within a step, a few ms) and
every result's commit (`_paths.atomic_path`, `atomic_folder`), so nothing is written after a signal, whichever
library held it.
"""

from __future__ import annotations

import signal
import sys

__all__ = ["install", "restore", "check", "pending", "leave_note", "take_note"]

#: the signal received since `install` (0: none)
_got = 0
#: what a long run has kept so far, said on the line of its interruption (`leave_note`)
_note = ""


class Terminated(KeyboardInterrupt):
    """SIGTERM, unwound as Ctrl-C is (the command says 'terminated' and exits 143)."""


def handler(signum, frame):
    global _got
    _got = signum
    raise Terminated if signum == signal.SIGTERM else KeyboardInterrupt


def _unraisable(previous):
    """`sys.unraisablehook` that drops the interrupt a callback could not raise (a weakref's or a garbage
    collector's callback, llvmlite's): the recorded signal ends the run at the next check, in one line. Anything
    else goes to the previous hook."""
    def hook(info):
        if _got and isinstance(info.exc_value, KeyboardInterrupt):
            return
        previous(info)
    return hook


def install() -> dict:
    """Install `handler` for SIGINT (unless it is ignored) and SIGTERM, in the main thread only; return the
    previous handlers for `restore`."""
    global _got, _note
    _got, _note = 0, ""
    previous: dict = {"unraisablehook": sys.unraisablehook}
    sys.unraisablehook = _unraisable(sys.unraisablehook)
    for sig in (signal.SIGINT, signal.SIGTERM):
        try:
            if sig == signal.SIGINT and signal.getsignal(sig) is signal.SIG_IGN:
                continue  # a process started to ignore Ctrl-C (a shell's `cmd &`) keeps ignoring it
            previous[sig] = signal.signal(sig, handler)
        except ValueError:  # not the main thread: the caller's own handling stays
            pass
    return previous


def restore(previous: dict) -> None:
    global _got, _note
    _got, _note = 0, ""
    for key, h in previous.items():
        if key == "unraisablehook":
            sys.unraisablehook = h
        else:
            signal.signal(key, h)


def leave_note(note: str) -> None:
    """What the command has kept so far and how to go on from it ('' for nothing): said on the one line of an
    interruption (`millvib tune` names the journal of its finished entries and --resume)."""
    global _note
    _note = note


def take_note() -> str:
    """The note left (`leave_note`), once: '' after it is taken."""
    global _note
    note, _note = _note, ""
    return note


def pending() -> int:
    """The signal received and not yet acted on (0: none)."""
    return _got


def check() -> None:
    """Raise the received signal's exception again (one that a library swallowed), or do nothing."""
    if _got:
        raise Terminated if _got == signal.SIGTERM else KeyboardInterrupt
