"""Where a batched step's time goes: the plant kernel (which the plant threads share) and the rest
(observation, reward, episode ends and resets: serial Python), per step of the 64-env VecEnvs, on one
and on two plant threads, each in a fresh process.

    python scripts/step_split.py [--steps 1500] [--repeats 3]

The part no thread can share bounds what threads give: with a kernel K and a rest R per step, two
threads give at most (K + R) / (K / 2 + R).
"""
from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys

from thread_bench import SETUP  # the same env, actions and warm-up

STEP = SETUP + """
from millvib_env.plant import kernel
inner, spent = kernel.advance_batch, [0.0]
def timed(*args):
    t = time.perf_counter()
    inner(*args)
    spent[0] += time.perf_counter() - t
kernel.advance_batch = timed
t = time.perf_counter()
for k in range(steps):
    venv.step(a[20 + k])
total = time.perf_counter() - t
print(1e3 * total / steps, 1e3 * spent[0] / steps)
"""


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--steps", type=int, default=1500, help="valve steps per run (the gain env runs a tenth)")
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    if args.steps < 1 or args.repeats < 1:
        ap.error(f"--steps {args.steps} and --repeats {args.repeats}: each must be >= 1")
    print("| environment (64 envs) | plant threads | step (ms) | kernel (ms) | rest (ms) | rest / step |")
    print("|---|---:|---:|---:|---:|---:|")
    for env_id in ("MillVib-Valve-v0", "MillVib-GainSchedule-v0"):
        steps = args.steps if "Valve" in env_id else max(args.steps // 10, 30)
        for threads in ("1", "2"):
            runs = []
            for _ in range(args.repeats):
                out = subprocess.run([sys.executable, "-c", STEP, env_id, str(steps)], capture_output=True, text=True,
                                     check=True, timeout=600, env={**os.environ, "MILLVIB_NUM_THREADS": threads})
                runs.append(tuple(float(v) for v in out.stdout.split()))
            step = statistics.median(r[0] for r in runs)
            kern = statistics.median(r[1] for r in runs)
            rest = step - kern
            print(f"| {env_id} | {threads} | {step:.3f} | {kern:.3f} | {rest:.3f} | {rest / step:.0%} |", flush=True)


if __name__ == "__main__":
    main()
