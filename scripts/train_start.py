"""Seconds from the command to the first rollout of `millvib train`: Python's start, the imports, the run folder,
the environments, the model, up to the moment PPO starts collecting its first rollout.

    MILLVIB_NUM_THREADS=1 python scripts/train_start.py [--runs 3] [--hog] [-- TRAIN ARGS ...]

Each run is a fresh `python` process that runs the `millvib` command itself (default: ``train --algo ppo``,
the shipped configs/agents/ppo.yml) and stops at the first call of SB3's ``collect_rollouts``; the clock
starts before the interpreter does. ``--hog`` runs a busy loop per core beside it.
"""
from __future__ import annotations

import argparse
import multiprocessing as mp
import os
import statistics
import subprocess
import sys
import tempfile
import time

CHILD = """
import os, sys, time
from stable_baselines3.common.on_policy_algorithm import OnPolicyAlgorithm

def first_rollout(self, *args, **kwargs):
    sys.stderr.write(f"FIRST_ROLLOUT {time.time()!r}\\n")
    sys.stderr.flush()
    os._exit(0)

OnPolicyAlgorithm.collect_rollouts = first_rollout
from millvib_cli import main
sys.argv = ["millvib"] + sys.argv[1:]
main()
"""


def _hog(stop) -> None:
    while not stop.is_set():
        sum(i * i for i in range(10000))


def one_run(train_args: list[str]) -> float:
    with tempfile.TemporaryDirectory() as tmp:
        args = train_args + ["--log-dir", os.path.join(tmp, "logs"), "--save-dir", os.path.join(tmp, "agent")]
        t0 = time.time()
        out = subprocess.run([sys.executable, "-c", CHILD, *args], capture_output=True, text=True, cwd=tmp)
    for line in out.stderr.splitlines():
        if line.startswith("FIRST_ROLLOUT "):
            return float(line.split()[1]) - t0
    raise SystemExit(f"no rollout started (exit {out.returncode}): {out.stderr.strip()[-400:]}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--hog", action="store_true", help="a busy loop per core beside each run")
    ap.add_argument("train_args", nargs="*", default=["train", "--algo", "ppo"])
    args = ap.parse_args()
    stop = mp.Event()
    hogs = [mp.Process(target=_hog, args=(stop,), daemon=True) for _ in range(os.cpu_count() or 1)] if args.hog else []
    for h in hogs:
        h.start()
    try:
        times = [one_run(args.train_args) for _ in range(args.runs)]
    finally:
        stop.set()
        for h in hogs:
            h.join()
    print(f"first rollout after {statistics.median(times):.2f} s (median of {len(times)}: "
          + ", ".join(f"{t:.2f}" for t in times) + f"){' with a busy loop per core' if args.hog else ''}")


if __name__ == "__main__":
    main()
