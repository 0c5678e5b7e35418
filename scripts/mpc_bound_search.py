"""Settings of the preview bound (`mpc-preview`) against the classical preview controller on a task's tuning plants:
for each candidate, its mean and CVaR-20 cost and theirs relative to `pid-pf-preview`'s on the same plants (a
bound must be below on both). A design tool: the tuning plants only, never the held-out ones.

    MILLVIB_NUM_THREADS=1 python scripts/mpc_bound_search.py --task rolling --episodes 16 \
        --set horizon=40 --set horizon=80 --set horizon=80,r_d=0

Each ``--set`` is a comma-separated list of `control.mpc.MPCSettings` fields laid over the task's shipped
`mpc-preview` settings.
"""
import argparse
import json

import numpy as np

from millvib_env.catalog.factory import control_entry, load_controller
from millvib_env.control.mpc import MPCPolicy, MPCSettings
from millvib_env.evaluation.evaluate import run_episodes
from millvib_env.evaluation.stats import cvar
from millvib_env.tasks import get_task


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--task", default="rolling")
    ap.add_argument("--episodes", type=int, default=16)
    ap.add_argument("--set", action="append", default=[], metavar="K=V[,K=V]")
    args = ap.parse_args()
    t = get_task(args.task)
    first = t.seeds["tuning"].start + 100  # the pid-robust tuning plants, as pid-pf-preview's
    seeds = list(range(first, first + args.episodes))
    ff = [r["cost"] for r in run_episodes(load_controller("pid-pf-preview", t, version="v1"), seeds, task=t,
                                          env_kwargs={"observation": {"preview_gauge": "measured"}})]
    print(json.dumps({"controller": "pid-pf-preview", "mean": float(np.mean(ff)), "cvar20": float(cvar(ff))}),
          flush=True)
    shipped = dict(control_entry(t, "mpc-preview", "v1")["settings"])
    for spec in args.set or [""]:
        over = {k: float(v) if "." in v or "e" in v else int(v) for k, v in (kv.split("=") for kv in spec.split(",")
                                                                           if kv)}
        settings = MPCSettings(**{**shipped, **over, "preview": True})
        ctrl = MPCPolicy("mpc-preview", settings, "v1")
        ctrl.task = t
        costs = [r["cost"] for r in run_episodes(ctrl, seeds, task=t)]
        print(json.dumps({"set": over, "mean": float(np.mean(costs)), "cvar20": float(cvar(costs)),
                          "vs_ff_mean": float(np.mean(costs) / np.mean(ff) - 1),
                          "vs_ff_cvar20": float(cvar(costs) / cvar(ff) - 1)}), flush=True)


if __name__ == "__main__":
    main()
