"""Run the timing suite (benchmarks/, pytest-benchmark) and write its table into docs/performance.md.

    python scripts/timing_suite.py                 # the whole suite, about 3 minutes; run it on an idle machine
    python scripts/timing_suite.py -k main_job     # a part (pytest's -k); the table then holds that part only
    python scripts/timing_suite.py --no-write      # print the table, leave the docs as they are

The table replaces what stands between the markers in docs/performance.md, with the command, the machine, the
commit and the date; pytest-benchmark's own result is kept beside it (docs/timings.json). Compare a change with
the code before it in the same session (both runs on the same machine): the machine a session gets changes.
"""

from __future__ import annotations

import argparse
import json
import shlex
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "performance.md"
RESULT = ROOT / "docs" / "timings.json"
START, END = "<!-- timing suite: start -->", "<!-- timing suite: end -->"


def _row(b: dict) -> str:
    s, info = b["stats"], b.get("extra_info", {})
    name = b["name"].removeprefix("test_")
    wall = f"{s['median']:.3g} s ({s['min']:.3g}-{s['max']:.3g})"
    if "command" in info:
        cpu = info.get("cpu_s") or []
        cpu_text = f"{statistics.median(cpu):.3g} ({min(cpu):.3g}-{max(cpu):.3g})" if cpu else "-"
        if "cpu_s" not in info:  # a process timed from here (a refusal): its slowest round too
            wall += f", slowest {s['max']:.3g} s"
        return f"| {name} | `{info['command']}` | {wall} | {cpu_text} | {s['rounds']} |"
    rate = ""
    for key, unit in (("env_steps", "env steps/s"), ("samples", "samples/s"), ("episodes", "episodes/s")):
        if key in info:
            rate = f"; {info[key] / s['median']:,.0f} {unit}"
    if "kernel_share" in info:
        rate += f"; the kernel {info['kernel_share']:.0%} of it"
    return f"| {name} | `benchmarks/test_timings.py::{b['name']}` | {wall}{rate} | - | {s['rounds']} |"


def table(result: dict, command: str) -> str:
    m, c = result["machine_info"], result.get("commit_info", {})
    cpu = m.get("cpu", {})
    head = (f"Made by `{command}` on {result['datetime'][:10]}, commit {str(c.get('id', '?'))[:7]}"
            f"{' (with changes)' if c.get('dirty') else ''}: {cpu.get('brand_raw', m.get('processor', '?'))}, "
            f"{cpu.get('count', '?')} logical cores, Python {m.get('python_version', '?')}. Wall time per round "
            "(median, min-max); CPU seconds of every process a command starts.")
    lines = [head, "", "| what | command | wall | CPU-s | rounds |", "|---|---|---|---|---|"]
    lines += [_row(b) for b in result["benchmarks"]]
    return "\n".join(lines)


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("-k", metavar="EXPR", help="run the benchmarks pytest's -k selects")
    ap.add_argument("--no-write", action="store_true", help="print the table only")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "timings.json"
        cmd = [sys.executable, "-m", "pytest", "benchmarks", "-q", f"--benchmark-json={out}"]
        if args.k:
            cmd += ["-k", args.k]
        rc = subprocess.call(cmd, cwd=ROOT)
        if rc != 0 or not out.exists():
            print(f"timing_suite: the suite failed (exit {rc}); nothing written", file=sys.stderr)
            return 1
        result = json.loads(out.read_text())
    shown = "python scripts/timing_suite.py" + (f" -k {shlex.quote(args.k)}" if args.k else "")
    text = table(result, shown)
    print(text)
    if args.no_write:
        return 0
    from millvib_env._paths import write_text_atomic

    doc = DOC.read_text()
    if START not in doc or END not in doc:
        print(f"timing_suite: {DOC} has no markers {START} ... {END}", file=sys.stderr)
        return 1
    before, rest = doc.split(START, 1)
    after = rest.split(END, 1)[1]
    write_text_atomic(DOC, f"{before}{START}\n{text}\n{END}{after}")
    write_text_atomic(RESULT, json.dumps(result, indent=1) + "\n")
    print(f"wrote {DOC.relative_to(ROOT)} and {RESULT.relative_to(ROOT)}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
