"""How hard the environments' integrator works: step attempts per accepted step, attempts and accepted steps
per agent period, and env steps/s (64 environments, serial).

    MILLVIB_NUM_THREADS=1 python scripts/step_attempts.py [--steps 300] [--traced-steps 40]

Two measurements per environment, each in a fresh process:

* counted: the compiled kernel, 64 environments stepped serially with random actions in [-0.3, 0.3]
  (`scripts/thread_bench.py`'s protocol, the startup task): env steps/s, and step attempts per agent
  period from the kernel's own counter (`MillVibCore.n_steps`, attempts including rejected ones);
* traced: the same kernel run as Python (NUMBA_DISABLE_JIT=1) on the first 4 of those environments with
  their actions, with a line tracer on `plant.kernel.advance` counting attempts and accepted steps: the
  share of rejected steps, which the compiled kernel does not count, and the steps cut short to land on a
  sample instant.

The traced run is the same arithmetic as the compiled one, so over the same window (environments 0-3, the
first --traced-steps steps after the warm-up) the two attempt counts agree; it is slow, so it covers fewer
steps.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys

ENVS = ("MillVib-Valve-v0", "MillVib-Valve-v1", "MillVib-GainSchedule-v0", "MillVib-GainSchedule-v1")

COUNTED = """
import json, sys, time, warnings
import numpy as np
warnings.filterwarnings("ignore", category=DeprecationWarning)
from millvib_env.envs.batch import EpisodeBatch
env_id, steps, traced = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
b = EpisodeBatch(env_id, 64, config="startup")
b.reset(list(range(64)))
a = np.random.default_rng(0).uniform(-0.3, 0.3, (WARM + steps, 64, b.core.settings.act_dim))
for k in range(WARM):
    b.step(a[k])
attempts = 0
first4 = 0  # the traced window: environments 0-3, the first `traced` steps after the warm-up
t = time.perf_counter()
for k in range(WARM, WARM + steps):
    b.step(a[k])
    attempts += int(b.core.n_steps.sum())
    if k < WARM + traced:
        first4 += int(b.core.n_steps[:4].sum())
wall = time.perf_counter() - t
print(json.dumps({"period_s": b.core.settings.period_s, "steps_per_s": 64 * steps / wall,
                  "attempts_per_period": attempts / (64 * steps), "attempts_window": first4 / (4 * traced)}))
"""

TRACED = """
import inspect, json, sys, warnings
import numpy as np
warnings.filterwarnings("ignore", category=DeprecationWarning)
from millvib_env.plant import kernel
from millvib_env.envs.batch import EpisodeBatch
env_id, steps = sys.argv[1], int(sys.argv[2])
src, first = inspect.getsourcelines(kernel.advance)
def line(text):
    return first + next(i for i, s in enumerate(src) if text in s)
lines = {line("n_steps += 1"): "attempts", line("tn = t1 if last else t + hh"): "accepted", line("last = True"): "cut"}
counts = dict.fromkeys(lines.values(), 0)
code = kernel.advance.__code__
def local(frame, event, arg):
    if event == "line" and frame.f_lineno in lines:
        counts[lines[frame.f_lineno]] += 1
    return local
def tracer(frame, event, arg):
    return local if frame.f_code is code else None
n = 4  # the first 4 of the counted run's environments, with their actions
b = EpisodeBatch(env_id, n, config="startup")
b.reset(list(range(n)))
a = np.random.default_rng(0).uniform(-0.3, 0.3, (WARM + steps, 64, b.core.settings.act_dim))[:, :n]
for k in range(WARM):
    b.step(a[k])
sys.settrace(tracer)
for k in range(WARM, WARM + steps):
    b.step(a[k])
sys.settrace(None)
print(json.dumps({k: v / (n * steps) for k, v in counts.items()}))
"""


WARM = 20  # agent steps before the measured ones


def _run(code: str, *argv, **env) -> dict:
    code = code.replace("WARM", str(WARM))
    out = subprocess.run([sys.executable, "-c", code, *map(str, argv)], capture_output=True, text=True,
                         env={**os.environ, **env}, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--steps", type=int, default=300, help="agent steps timed per environment (compiled)")
    ap.add_argument("--traced-steps", type=int, default=40, help="agent steps traced (Python) per environment")
    ap.add_argument("--envs", nargs="+", default=list(ENVS))
    args = ap.parse_args()
    print("| env | agent period (ms) | env steps/s (64 envs, serial) | attempts per period (compiled) "
          "| the same, traced window: compiled / traced | accepted per period | attempts per accepted step "
          "| steps cut at a sample |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|")
    for env_id in args.envs:
        c = _run(COUNTED, env_id, args.steps, args.traced_steps)
        t = _run(TRACED, env_id, args.traced_steps, NUMBA_DISABLE_JIT="1")
        cells = [env_id, f"{1e3 * c['period_s']:g}", f"{c['steps_per_s']:,.0f}", f"{c['attempts_per_period']:.1f}",
                 f"{c['attempts_window']:.2f} / {t['attempts']:.2f}", f"{t['accepted']:.1f}",
                 f"{t['attempts'] / t['accepted']:.2f}", f"{t['cut']:.1f}"]
        print("| " + " | ".join(cells) + " |", flush=True)


if __name__ == "__main__":
    main()
