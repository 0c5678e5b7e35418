"""The wall time and CPU time (user + sys) of a command and of every process it starts, orphans included (Linux).

    python scripts/cpu_time.py python -m pytest -q
    python scripts/cpu_time.py millvib reproduce --out /tmp/r --quiet --jobs 2

`/usr/bin/time` counts the processes that the command itself waits for. A `--jobs N` pool's workers are forks of
multiprocessing's fork server (`millvib_env.distributed`), which outlives the command by a moment and is not
waited for: their CPU time would be missed. This script makes itself the "child subreaper" of everything below
it (prctl PR_SET_CHILD_SUBREAPER), so an orphan is handed to it rather than to init, and it waits for every one
before it reads its children's resource usage. It prints one line on stderr and exits with the command's status.
"""

from __future__ import annotations

import ctypes
import os
import resource
import subprocess
import sys
import time

PR_SET_CHILD_SUBREAPER = 36


def main(argv: list[str]) -> int:
    if not argv or argv[0] in ("-h", "--help"):
        print(__doc__.strip(), file=sys.stderr)
        return 2 if not argv else 0
    if not sys.platform.startswith("linux"):
        print("cpu_time: needs Linux (prctl PR_SET_CHILD_SUBREAPER)", file=sys.stderr)
        return 2
    if ctypes.CDLL(None, use_errno=True).prctl(PR_SET_CHILD_SUBREAPER, 1, 0, 0, 0) != 0:
        print(f"cpu_time: prctl failed: {os.strerror(ctypes.get_errno())}", file=sys.stderr)
        return 2
    start = time.monotonic()
    try:
        rc = subprocess.call(argv)
    except OSError as err:
        print(f"cpu_time: cannot run {argv[0]!r}: {err.strerror}", file=sys.stderr)
        return 2
    while True:  # the orphans handed to us: wait for each, so its CPU time (and its children's) is counted
        try:
            os.waitpid(-1, 0)
        except ChildProcessError:
            break
    wall = time.monotonic() - start
    used = resource.getrusage(resource.RUSAGE_CHILDREN)
    print(f"cpu_time: exit {rc}, {wall:.1f} s wall, {used.ru_utime + used.ru_stime:.1f} CPU-s "
          f"(user {used.ru_utime:.1f}, sys {used.ru_stime:.1f})", file=sys.stderr)
    return rc


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
