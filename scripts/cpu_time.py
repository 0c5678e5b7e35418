"""The wall time and CPU time (user + sys) of a command and of every process it starts, orphans included (Linux).

    python scripts/cpu_time.py python -m pytest -q
    python scripts/cpu_time.py millvib reproduce --out /tmp/r --quiet --jobs 2

`/usr/bin/time` counts the processes that the command itself waits for. A `--jobs N` pool's workers are forks of
multiprocessing's fork server (`millvib_env.distributed`), which outlives the command by a moment and is not
waited for: their CPU time would be missed. This script makes itself the "child subreaper" of everything below
it (prctl PR_SET_CHILD_SUBREAPER), so an orphan is handed to it rather than to init, and it waits for every one
before it reads its children's resource usage. Where it may make a control group (root, on Linux), it also runs
the command in one of its own and prints the group's CPU time: that counts the processes whose parent discards
their usage, which no wait can recover (Ray's workers). It prints one line on stderr and exits with the command's
status.
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
    group = _CpuGroup.make()
    try:
        return _run(argv, group)
    finally:
        if group is not None and os.path.isdir(group.path):
            group.close()


def _run(argv: list[str], group: _CpuGroup | None) -> int:
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
    grouped = "" if group is None else f"; {group.close():.1f} CPU-s in its control group"
    print(f"cpu_time: exit {rc}, {wall:.1f} s wall, {used.ru_utime + used.ru_stime:.1f} CPU-s "
          f"(user {used.ru_utime:.1f}, sys {used.ru_stime:.1f}){grouped}", file=sys.stderr)
    return rc


class _CpuGroup:
    """A control group of its own for the command (cgroup v1's cpuacct or v2; needs the right to make one, as
    root has): it counts the CPU time of every process that ever ran in it, also those whose usage never reaches
    RUSAGE_CHILDREN (Ray's workers: their parent, the raylet, does not hand it on; measured, a Ray task that
    burns 3 CPU-s shows 2.2 CPU-s by usage and 6.6 in the group; most likely the raylet ignores SIGCHLD, which
    discards a child's usage). None where no group can be made; then only the usage line is printed."""

    ROOTS = (("/sys/fs/cgroup/cpuacct", "cpuacct.usage", 1e-9), ("/sys/fs/cgroup/unified", "cpu.stat", 1e-6),
             ("/sys/fs/cgroup", "cpu.stat", 1e-6))

    def __init__(self, path: str, usage_file: str, unit: float, parent_procs: str):
        self.path, self.usage_file, self.unit, self.parent_procs = path, usage_file, unit, parent_procs
        self.start = 0.0  # the group's usage when it was made, less this script's own

    @classmethod
    def make(cls) -> _CpuGroup | None:
        for root, usage_file, unit in cls.ROOTS:
            if not os.path.exists(os.path.join(root, usage_file)) and \
                    not os.path.exists(os.path.join(root, "cgroup.procs")):
                continue
            path = os.path.join(root, f"cpu_time-{os.getpid()}")
            try:
                os.mkdir(path)
            except OSError:
                continue
            try:
                with open(os.path.join(path, "cgroup.procs"), "w") as f:
                    f.write(str(os.getpid()))
                group = cls(path, usage_file, unit, os.path.join(root, "cgroup.procs"))
                group.start = group._usage() - group._own()
                return group
            except OSError:
                os.rmdir(path)
        return None

    def _usage(self) -> float:
        with open(os.path.join(self.path, self.usage_file)) as f:
            text = f.read()
        if self.usage_file == "cpu.stat":
            text = dict(line.split() for line in text.splitlines())["usage_usec"]
        return int(text) * self.unit

    @staticmethod
    def _own() -> float:
        me = resource.getrusage(resource.RUSAGE_SELF)
        return me.ru_utime + me.ru_stime

    def close(self) -> float:
        """The CPU-seconds of everything that ran in the group since it was made, this script's own excluded."""
        used = self._usage() - self._own() - self.start
        with open(self.parent_procs, "w") as f:
            f.write(str(os.getpid()))
        os.rmdir(self.path)
        return used


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
