"""The learner backends side by side: SAC (or PPO) with the shipped hyperparameters on the gain-schedule
env, trained by Stable-Baselines3 (PyTorch) and by sbx (JAX), each in a fresh process, in turn
(A B A B ...), so a drift of the machine's speed touches both.

    python scripts/backend_bench.py [--algo sac] [--steps 6000] [--repeats 3] [--hog]

Each run builds the agent as `millvib train` does (hyperparameter file, VecNormalize, one plant
thread, one torch / XLA thread), learns past `learning_starts` once (compilation and the buffer's
warm-up), then times `--steps` further environment steps. `--hog` runs one busy process per core
beside them. Prints env steps/s (median of the repeats), the ratio and the machine's load.
"""
from __future__ import annotations

import argparse
import multiprocessing as mp
import os
import statistics
import subprocess
import sys

CONFIG = {"sac": "configs/agents/pf/sac.yml", "ppo": "configs/agents/pf/ppo.yml"}
RUN = """
import sys, time
algo, backend, config, steps = sys.argv[1], sys.argv[2], sys.argv[3], int(sys.argv[4])
from millvib_env.catalog.agents import algo_class
from millvib_env.training.train import jit_noise_key_split, resolve_named_gains
from millvib_env.training.hyperparams import load_hyperparams
from millvib_env.envs.vec_env import make_vec_env
from stable_baselines3.common.vec_env import VecNormalize
import torch
torch.set_num_threads(1)
cls = algo_class(algo, backend)
hp = load_hyperparams(algo, "MillVib-GainSchedule-v0", config)
n_envs = hp.pop("n_envs"); hp.pop("n_timesteps"); policy = hp.pop("policy"); hp.pop("normalize")
env_kwargs = resolve_named_gains(dict(hp.pop("env_kwargs", None) or {}), "startup")
venv = VecNormalize(make_vec_env("MillVib-GainSchedule-v0", n_envs, seed=1, **env_kwargs), gamma=hp.get("gamma", 0.99))
model = cls(policy, venv, seed=0, device="cpu", verbose=0, **hp)
if backend == "sbx":
    jit_noise_key_split(model)  # as millvib train does
model.learn(int(hp.get("learning_starts", 0)) + 2 * int(hp.get("n_steps", 1)) * n_envs + 1000)
t = time.perf_counter()
model.learn(steps, reset_num_timesteps=False)
print(steps / (time.perf_counter() - t))
"""


def _hog(stop) -> None:
    while not stop.is_set():
        sum(i * i for i in range(10000))


def _rate(algo: str, backend: str, steps: int) -> float:
    env = {**os.environ, "MILLVIB_NUM_THREADS": "1"}
    out = subprocess.run([sys.executable, "-c", RUN, algo, backend, CONFIG[algo], str(steps)], env=env,
                         capture_output=True, text=True, check=True, timeout=900)
    return float(out.stdout.strip().splitlines()[-1])


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--algo", choices=sorted(CONFIG), default="sac")
    ap.add_argument("--steps", type=int, default=6000)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--hog", action="store_true", help="one busy process per core beside the runs")
    args = ap.parse_args()
    stop = mp.Event()
    hogs = [mp.Process(target=_hog, args=(stop,), daemon=True) for _ in range(os.cpu_count() or 1)] if args.hog else []
    for h in hogs:
        h.start()
    rates: dict[str, list[float]] = {"sb3": [], "sbx": []}
    loads = []
    try:
        for _ in range(args.repeats):
            for backend in rates:
                rates[backend].append(_rate(args.algo, backend, args.steps))
                loads.append(os.getloadavg()[0])
    finally:
        stop.set()
        for h in hogs:
            h.join()
    sb3, sbx = statistics.median(rates["sb3"]), statistics.median(rates["sbx"])
    ratios = sorted(b / a for a, b in zip(rates["sb3"], rates["sbx"]))
    print(f"{args.algo.upper()} on MillVib-GainSchedule-v0 ({CONFIG[args.algo]}), {args.steps} steps per run, "
          f"{args.repeats} runs each, {os.cpu_count()} cores, {'a CPU hog per core beside' if args.hog else 'no hog'}, "
          f"load average {min(loads):.1f}-{max(loads):.1f}")
    print("| backend | env steps/s (median) | runs |\n|---|---:|---|")
    for name, med in (("sb3 (PyTorch)", sb3), ("sbx (JAX)", sbx)):
        runs = rates[name.split()[0]]
        print(f"| {name} | {med:,.0f} | {', '.join(f'{r:,.0f}' for r in runs)} |")
    print(f"sbx / sb3: {sbx / sb3:.2f}x (paired runs {ratios[0]:.2f}-{ratios[-1]:.2f}x)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
