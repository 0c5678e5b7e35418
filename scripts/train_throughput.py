"""Training throughput (environment steps per wall second) with the plant's threads as before and now.

    python scripts/train_throughput.py                  # PPO and SAC, ~3 minutes on 2 idle cores

"before": the plant on numba's threads for every batch, through GNU OpenMP (numba's default layer),
as the project ran until the threads change (MILLVIB_NUM_THREADS=2, NUMBA_THREADING_LAYER=omp);
"now": the defaults (`millvib train` runs the plant serially; workqueue layer). Each run is a fresh
process training the shipped hyperparameters of the gain-schedule env for a fixed number of steps,
alternating the two settings, repeated; the median is reported.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys

SETTINGS = {"before": {"MILLVIB_NUM_THREADS": "2", "NUMBA_THREADING_LAYER": "omp"},
            "now": {}}
CODE = """
import json, sys, time
from millvib_env.training.train import train
algo, steps = sys.argv[1], int(sys.argv[2])
t = time.perf_counter()
card = train(algo, seed=0, n_timesteps=steps, log_dir=sys.argv[3], eval_freq=10**9, checkpoint_freq=10**9,
             progress=False)
print(json.dumps({"steps": card["n_timesteps"], "wall_s": card["wall_time_s"]}))
"""


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--steps", nargs=2, type=int, default=[65536, 8000], metavar=("PPO", "SAC"))
    ap.add_argument("--json", help="also write the results here")
    args = ap.parse_args()
    out = {}
    for algo, steps in (("ppo", args.steps[0]), ("sac", args.steps[1])):
        rates = {k: [] for k in SETTINGS}
        for r in range(args.repeats):
            for name, env in SETTINGS.items():
                run_env = {k: v for k, v in os.environ.items() if k not in ("MILLVIB_NUM_THREADS",
                                                                          "NUMBA_THREADING_LAYER")}
                run_env.update(env)
                proc = subprocess.run([sys.executable, "-c", CODE, algo, str(steps), f"/tmp/throughput_{name}"],
                                      env=run_env, capture_output=True, text=True, check=True)
                res = json.loads(proc.stdout.strip().splitlines()[-1])
                rates[name].append(res["steps"] / res["wall_s"])
                print(f"{algo} {name} run {r}: {rates[name][-1]:.0f} env steps/s", flush=True)
        out[algo] = {k: sorted(v)[len(v) // 2] for k, v in rates.items()}
        out[algo]["all"] = rates
    print("\n| algorithm | before (plant on 2 OpenMP threads) | now (plant serial) | speed-up |\n|---|---|---|---|")
    for algo, r in out.items():
        print(f"| {algo.upper()} | {r['before']:.0f} | {r['now']:.0f} | {r['now'] / r['before']:.2f}x |")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(out, fh, indent=2)


if __name__ == "__main__":
    main()
