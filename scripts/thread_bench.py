"""Plant threads under load and idle: the 64-env VecEnvs stepped serially, on two threads that sleep
when idle (the default, OMP_WAIT_POLICY=PASSIVE), on two threads that spin (OpenMP's own default,
OMP_WAIT_POLICY=ACTIVE) and on numba's workqueue layer (and, asked for, threads that spin a bounded
count before they sleep: spin10k, spin100k), each in a fresh process, with and without a CPU hog (one
busy process per core) beside them.

    python scripts/thread_bench.py [--steps 1500] [--repeats 5] [--settings serial passive ...]
    python scripts/thread_bench.py --idle-cpu    # CPU an idle plant pool burns in 0.5 s, per wait policy

The settings run in turn within each repeat (serial, passive, spinning, workqueue, serial, ...), so
each threaded rate is paired with the serial rate measured just before it: the machine's drift moves
both. Prints one table per load setting: env steps/s (median of the repeats) and the paired ratio to
serial (median, with the smallest and largest of the repeats).
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
    "serial": ("serial", {"MILLVIB_NUM_THREADS": "1"}),
    "passive": ("2 threads, passive (default)", {"MILLVIB_NUM_THREADS": "2", "OMP_WAIT_POLICY": "PASSIVE"}),
    "spinning": ("2 threads, spinning", {"MILLVIB_NUM_THREADS": "2", "OMP_WAIT_POLICY": "ACTIVE"}),
    "workqueue": ("2 threads, workqueue", {"MILLVIB_NUM_THREADS": "2", "NUMBA_THREADING_LAYER": "workqueue"}),
    # bounded spinning: GOMP_SPINCOUNT overrides the passive policy's spin count of 0 (not run by default)
    "spin10k": ("2 threads, spin 10,000 then sleep", {"MILLVIB_NUM_THREADS": "2", "OMP_WAIT_POLICY": "PASSIVE",
                                                      "GOMP_SPINCOUNT": "10000"}),
    "spin100k": ("2 threads, spin 100,000 then sleep", {"MILLVIB_NUM_THREADS": "2", "OMP_WAIT_POLICY": "PASSIVE",
                                                        "GOMP_SPINCOUNT": "100000"}),
}
DEFAULT_SETTINGS = ["serial", "passive", "spinning", "workqueue"]
ENVS = ("MillVib-Valve-v0", "MillVib-GainSchedule-v0")
#: a fresh process's 64-env VecEnv (argv: env id, steps), random actions `a`, 20 steps of warm-up
SETUP = """
import sys, time, numpy as np, millvib_env
env_id, steps = sys.argv[1], int(sys.argv[2])
venv = millvib_env.make_vec_env(env_id, 64, seed=0, **({"residual": True} if "Valve" in env_id else {}))
venv.reset()
a = np.random.default_rng(0).uniform(-0.3, 0.3, (steps + 20, 64, venv.action_space.shape[0])).astype(np.float32)
for k in range(20):
    venv.step(a[k])
"""
STEP = SETUP + """
t = time.perf_counter()
for k in range(steps):
    venv.step(a[20 + k])
print(64 * steps / (time.perf_counter() - t))
"""


def _hog(stop) -> None:
    while not stop.is_set():
        sum(i * i for i in range(10000))


def _rate(env_id: str, steps: int, setting: dict) -> float:
    env = {k: v for k, v in os.environ.items()
           if k not in ("OMP_WAIT_POLICY", "NUMBA_THREADING_LAYER", "GOMP_SPINCOUNT")}
    env.update(setting)
    out = subprocess.run([sys.executable, "-c", STEP, env_id, str(steps)], env=env, capture_output=True, text=True,
                         check=True, timeout=600)
    return float(out.stdout.strip().splitlines()[-1])


def _table(rates: dict, names: list[str]) -> list[str]:
    lines = [f"| setting | {ENVS[0]} (residual) | x serial (min-max) | {ENVS[1]} | x serial (min-max) |",
             "|---|---:|---:|---:|---:|"]
    for name in names:
        cells = []
        for env_id in ENVS:
            runs = rates[name][env_id]
            cells.append(f"{statistics.median(runs):,.0f}")
            if name == "serial":
                cells.append("1")
                continue
            ratios = [r / s for r, s in zip(runs, rates["serial"][env_id])]
            cells.append(f"{statistics.median(ratios):.2f}x ({min(ratios):.2f}-{max(ratios):.2f})")
        lines.append(f"| {SETTINGS[name][0]} | " + " | ".join(cells) + " |")
    return lines


#: a fresh process: a threaded batch starts numba's pool, then the CPU it burns during a 0.5 s sleep
IDLE_CPU = """
import time, numpy as np, millvib_env, numba
venv = millvib_env.make_vec_env("MillVib-GainSchedule-v0", 16, seed=0, monitor=False)
venv.reset(); venv.step(np.zeros((16, 3)))
t0 = time.process_time(); time.sleep(0.5); print(numba.threading_layer(), f"{time.process_time() - t0:.3f}")
"""


def idle_cpu(repeats: int) -> None:
    """What an idle plant pool costs: CPU seconds burnt in a 0.5 s sleep after a threaded batch, per
    wait policy (a timing, so a measurement here and not a test: load on the machine moves it)."""
    base = {k: v for k, v in os.environ.items() if k != "OMP_WAIT_POLICY"}
    print(f"CPU seconds an idle 2-thread plant pool burns during a 0.5 s sleep (1-min load "
          f"{os.getloadavg()[0]:.1f}):")
    for label, extra in (("passive (the default)", {}), ("a user's OMP_WAIT_POLICY=ACTIVE", {"OMP_WAIT_POLICY":
                                                                                              "ACTIVE"})):
        out = [subprocess.run([sys.executable, "-c", IDLE_CPU], capture_output=True, text=True, check=True,
                              env={**base, "MILLVIB_NUM_THREADS": "2", "NUMBA_NUM_THREADS": "2", **extra}
                              ).stdout.split() for _ in range(repeats)]
        print(f"  {label}: layer {out[0][0]}, " + ", ".join(o[1] for o in out) + " s")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--idle-cpu", action="store_true", help="only measure the CPU an idle pool burns, per policy")
    ap.add_argument("--steps", type=int, default=1500, help="valve steps per run (the gain env runs a tenth)")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--settings", nargs="+", choices=list(SETTINGS), default=DEFAULT_SETTINGS,
                    help="which settings (serial always runs: it is what the others are paired with)")
    ap.add_argument("--loads", nargs="+", choices=["idle", "hog"], default=["idle", "hog"])
    args = ap.parse_args()
    if args.steps < 1 or args.repeats < 1:
        ap.error(f"--steps {args.steps} and --repeats {args.repeats}: each must be >= 1")
    if args.idle_cpu:
        idle_cpu(args.repeats)
        return
    names = ["serial"] + [s for s in args.settings if s != "serial"]
    for load in args.loads:
        stop, hogs = mp.Event(), []
        if load == "hog":
            hogs = [mp.Process(target=_hog, args=(stop,), daemon=True) for _ in range(os.cpu_count() or 2)]
            for h in hogs:
                h.start()
            time.sleep(1.0)
        rates = {name: {env_id: [] for env_id in ENVS} for name in names}
        loads = []
        for _ in range(args.repeats):
            for env_id in ENVS:
                steps = args.steps if "Valve" in env_id else max(args.steps // 10, 30)
                for name in names:
                    rates[name][env_id].append(_rate(env_id, steps, SETTINGS[name][1]))
            loads.append(os.getloadavg()[0])
        stop.set()
        for h in hogs:
            h.join()
        what = "loaded: a CPU hog on every core" if load == "hog" else "idle"
        print(f"\n{what} (1-min load average {min(loads):.1f}-{max(loads):.1f} over the runs, {os.cpu_count()} "
              f"CPUs); env steps/s, median of {args.repeats}, and the ratio to the serial run just before:\n")
        print("\n".join(_table(rates, names)), flush=True)


if __name__ == "__main__":
    main()
