"""What the MPC bounds cost per plant and loop sample: CPU time of `mpc-oracle` / `mpc-preview` on the same
episodes as `pid-pf-robust`, minus the reference's (the environment's own share), divided by the samples.

    MILLVIB_NUM_THREADS=1 python scripts/mpc_cost.py [--task rolling] [--episodes 8]

It runs each controller once to warm up (compilation, imports) and then times a second run; the numbers
are this machine's, under whatever else it is doing: a benchmark, never a test.
"""
import argparse
import time

from millvib_env.control.factory import load_controller
from millvib_env.tasks import get_task
from millvib_env.evaluation.evaluate import run_episodes


def cpu_of(name: str, task: str, seeds: list[int]) -> float:
    run_episodes(load_controller(name, task, version="v1"), seeds[:1], task=task)  # warm-up
    start = time.process_time()
    run_episodes(load_controller(name, task, version="v1"), seeds, task=task)
    return time.process_time() - start


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--task", default="rolling")
    ap.add_argument("--episodes", type=int, default=8)
    args = ap.parse_args()
    t = get_task(args.task)
    first = t.seeds["validation"].start
    seeds = list(range(first, first + args.episodes))
    ref = cpu_of("pid-pf-robust", t.name, seeds)
    cfg = t.configs["v1"]
    samples = args.episodes * round(cfg.episode_s / cfg.control_dt_s)
    print(f"pid-pf-robust: {ref:.2f} CPU-s for {args.episodes} episodes ({samples} loop samples)")
    for name in ("mpc-oracle", "mpc-preview"):
        c = cpu_of(name, t.name, seeds)
        horizon = load_controller(name, t.name, version="v1").settings.horizon
        print(f"{name} (horizon {horizon}): {c:.2f} CPU-s; {1e3 * (c - ref) / samples:.3f} ms per plant and sample "
              "beyond the reference's")


if __name__ == "__main__":
    main()
