"""Plant threads under load and idle: the 64-env VecEnvs stepped serially, on two threads that sleep
when idle (the default, OMP_WAIT_POLICY=PASSIVE), on two threads that spin (OpenMP's own default,
OMP_WAIT_POLICY=ACTIVE) and on numba's workqueue layer, each in a fresh process, with and without a
CPU hog (one busy process per core) beside them.

    python scripts/thread_bench.py [--steps 600] [--repeats 3]

Prints one table (env steps/s, median of the repeats) per load setting.
"""
from __future__ import annotations

import argparse
import multiprocessing as mp
import os
import statistics
import subprocess
import sys
import time

SETTINGS = {
    "serial": {"MILLVIB_NUM_THREADS": "1"},
    "2 threads, passive (default)": {"MILLVIB_NUM_THREADS": "2", "OMP_WAIT_POLICY": "PASSIVE"},
    "2 threads, spinning": {"MILLVIB_NUM_THREADS": "2", "OMP_WAIT_POLICY": "ACTIVE"},
    "2 threads, workqueue": {"MILLVIB_NUM_THREADS": "2", "NUMBA_THREADING_LAYER": "workqueue"},
}
STEP = """
import sys, time, numpy as np, millvib_env
env_id, steps = sys.argv[1], int(sys.argv[2])
venv = millvib_env.make_vec_env(env_id, 64, seed=0, **({"residual": True} if "Valve" in env_id else {}))
venv.reset()
a = np.random.default_rng(0).uniform(-0.3, 0.3, (steps + 20, 64, venv.action_space.shape[0])).astype(np.float32)
for k in range(20):
    venv.step(a[k])
t = time.perf_counter()
for k in range(steps):
    venv.step(a[20 + k])
print(64 * steps / (time.perf_counter() - t))
"""


def _hog(stop) -> None:
    while not stop.is_set():
        sum(i * i for i in range(10000))


def _rate(env_id: str, steps: int, setting: dict) -> float:
    env = {**os.environ, **setting}
    env.pop("OMP_WAIT_POLICY", None) if "OMP_WAIT_POLICY" not in setting else None
    out = subprocess.run([sys.executable, "-c", STEP, env_id, str(steps)], env=env, capture_output=True, text=True,
                         check=True, timeout=600)
    return float(out.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--steps", type=int, default=600)
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    for loaded in (False, True):
        stop, hogs = mp.Event(), []
        if loaded:
            hogs = [mp.Process(target=_hog, args=(stop,), daemon=True) for _ in range(os.cpu_count() or 2)]
            for h in hogs:
                h.start()
            time.sleep(1.0)
        print(f"\n{'loaded: a CPU hog on every core' if loaded else 'idle'} (load {os.getloadavg()[0]:.1f}, "
              f"{os.cpu_count()} CPUs); env steps/s, median of {args.repeats}:\n")
        print("| setting | MillVib-Valve-v0 (residual) | MillVib-GainSchedule-v0 |")
        print("|---|---|---|")
        for name, setting in SETTINGS.items():
            cells = []
            for env_id in ("MillVib-Valve-v0", "MillVib-GainSchedule-v0"):
                steps = args.steps if "Valve" in env_id else max(args.steps // 10, 30)
                cells.append(statistics.median(_rate(env_id, steps, setting) for _ in range(args.repeats)))
            print(f"| {name} | {cells[0]:,.0f} | {cells[1]:,.0f} |", flush=True)
        stop.set()
        for h in hogs:
            h.join()


if __name__ == "__main__":
    main()
